"""Clean references for underwater views: the same view rendered without water, same noise seed.

Every simulated view can be rendered three ways from one pose, one scene time and one sensor
noise seed (the random numbers are drawn in the same order, so the sensor noise pattern is the
same):

- ``underwater``: the view as the camera sees it (:class:`~sea3d.sim.optics.Imaging` as given);
- ``clean``: no water at all (:meth:`Imaging.without_water`): white sunlight and lamp light reach
  the scene unattenuated and nothing scatters. This is the "true colour" reference; the lights,
  caustics, vignetting, blur and noise are the same;
- ``unattenuated``: only the water between the camera and the scene removed
  (:meth:`Imaging.without_line_of_sight_water`): the lights still reach the scene through the
  water. This is ``J`` of the formation model ``I = J exp(-beta_D z) + B_inf (1 - exp(-beta_B
  z))``, what a physics-based restoration such as Sea-thru estimates before its white balance.

Without water the scene is much brighter, so each reference is exposed on its own to keep its
highlights unclipped (by default the underwater exposure scaled down until the 99.5th percentile
of the brightest channel is at most 0.95); the exposures are returned with the images, and
image comparisons should allow one exposure gain (:mod:`sea3d.enhance.metrics`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import FloatArray
from sea3d.geometry.rig import StereoRig
from sea3d.sim.optics import Imaging
from sea3d.sim.render import Renderer, ViewTruth
from sea3d.sim.scene import Scene, load_scene

__all__ = [
    "ReferencePair",
    "simulate_pair_with_reference",
    "unclipped_exposure",
    "water_model_dict",
]

Image = NDArray[np.uint8]


def water_model_dict(imaging: Imaging) -> dict[str, Any]:
    """The water model behind an imaging setup, as a JSON-ready dict (coefficients per R, G,
    B channel, 1/m; ``None`` entries without water)."""
    w = imaging.water
    return {
        "model": "I = J exp(-beta_D z) + B_inf (1 - exp(-beta_B z)), per channel, z in m "
        "(Akkaynak and Treibitz, CVPR 2018)",
        "name": w.name if w else "none",
        "beta_D_per_m": list(w.beta_D_per_m) if w else None,
        "beta_B_per_m": list(w.beta_B_per_m) if w else None,
        "B_inf_rgb": list(w.B_inf_rgb) if w else None,
        "B_inf_units": "linear radiance before the exposure gain",
        "exposure": imaging.exposure,
        "vehicle_light": imaging.vehicle_light,
        "caustics": imaging.caustics,
    }


def unclipped_exposure(
    radiance: np.ndarray,
    imaging: Imaging,
    *,
    percentile: float = 99.5,
    level: float = 0.95,
) -> float:
    """The largest exposure, at most ``imaging.exposure``, at which the ``percentile`` of the
    brightest channel of ``radiance`` (linear, ``(H, W, 3)``) stays at or below ``level``."""
    top = float(np.percentile(np.asarray(radiance, dtype=np.float64).max(axis=-1), percentile))
    if not top > 0:
        return float(imaging.exposure)
    return float(min(imaging.exposure, level / top))


@dataclass(frozen=True, kw_only=True, eq=False)
class ReferencePair:
    """A stereo pair and its clean references (see the module docstring).

    Attributes:
        left, right: ``(H, W, 3)`` uint8 sRGB underwater images.
        left_clean, right_clean: the same views without water.
        left_unattenuated, right_unattenuated: the same views without water on the line of
            sight (``J``).
        gt: left ground truth (depth, range, points, normals, object ids).
        exposure_clean, exposure_unattenuated: the references' exposure gains (the underwater
            images use ``water["exposure"]``).
        water: :func:`water_model_dict` of the underwater imaging.
    """

    left: Image
    right: Image
    left_clean: Image
    right_clean: Image
    left_unattenuated: Image
    right_unattenuated: Image
    gt: ViewTruth
    exposure_clean: float
    exposure_unattenuated: float
    water: dict[str, Any]


def _render_reference(
    renderer: Renderer,
    rig: StereoRig,
    T_wl: FloatArray,
    imaging: Imaging,
    time_s: float,
    seed: int,
    exposure: float | None,
) -> tuple[Image, Image, float]:
    T_wr = T_wl @ rig.T_left_right
    views = []
    for cam, T in ((rig.left, T_wl), (rig.right, T_wr)):
        # The sensor runs again below with the chosen exposure, so render without noise here.
        views.append(renderer.render(cam, T, imaging.without_sensor_noise(), time_s=time_s))
    e = unclipped_exposure(views[0].radiance, imaging) if exposure is None else float(exposure)
    sensor = replace(imaging, exposure=e)
    rng = np.random.default_rng(seed)
    left = sensor.sensor(views[0].radiance, rng)
    right = sensor.sensor(views[1].radiance, rng)
    return left, right, e


def simulate_pair_with_reference(
    rig: StereoRig,
    scene: Scene | str,
    T_world_left: FloatArray,
    water: str | Imaging = "coastal",
    *,
    seed: int = 0,
    time_s: float = 0.0,
    supersample: int = 2,
    renderer: Renderer | None = None,
    reference_exposure: float | None = None,
) -> ReferencePair:
    """Render a stereo pair underwater and its two clean references from the same pose, time
    and noise seed.

    Args:
        rig: the stereo rig.
        scene: a :class:`Scene`, a built-in scene name or a scene YAML path.
        T_world_left: ``(4, 4)`` left camera pose.
        water: a water preset (``clear``, ``coastal``, ``turbid``: every effect on, as
            :meth:`Imaging.underwater`) or an :class:`Imaging`.
        seed: sensor-noise seed, shared by the underwater image and its references.
        time_s: scene time (caustics), seconds.
        supersample: rays per pixel along each axis.
        renderer: reuse a renderer of the same scene.
        reference_exposure: exposure of both references; None chooses each so it does not clip
            (:func:`unclipped_exposure`).

    Returns:
        :class:`ReferencePair`.

    Raises:
        SimulationError: bad scene, water or pose.
    """
    sc = load_scene(scene) if isinstance(scene, str) else scene
    r = renderer or Renderer(sc, supersample=supersample)
    imaging = water if isinstance(water, Imaging) else Imaging.underwater(water)
    T_wl = np.asarray(T_world_left, dtype=np.float64)
    rng = np.random.default_rng(seed)
    lv = r.render(rig.left, T_wl, imaging, time_s=time_s, rng=rng)
    rv = r.render(rig.right, T_wl @ rig.T_left_right, imaging, time_s=time_s, rng=rng)
    lc, rc, e_clean = _render_reference(
        r, rig, T_wl, imaging.without_water(), time_s, seed, reference_exposure
    )
    lu, ru, e_unatt = _render_reference(
        r, rig, T_wl, imaging.without_line_of_sight_water(), time_s, seed, reference_exposure
    )
    return ReferencePair(
        left=lv.image,
        right=rv.image,
        left_clean=lc,
        right_clean=rc,
        left_unattenuated=lu,
        right_unattenuated=ru,
        gt=lv.gt,
        exposure_clean=e_clean,
        exposure_unattenuated=e_unatt,
        water=water_model_dict(imaging),
    )
