"""Water and light: the revised underwater image formation model, lights, caustics, sensor.

Per colour channel c, a surface at water path length z (metres) with unattenuated radiance
``J_c`` is imaged as (Akkaynak and Treibitz, "A Revised Underwater Image Formation Model",
CVPR 2018, Eq. 1 with the attenuation split of their Sec. 3)::

    I_c = J_c * exp(-beta_D_c * z) + B_inf_c * (1 - exp(-beta_B_c * z))

``beta_D`` attenuates the direct signal, ``beta_B`` governs how fast backscatter saturates to the
veiling light ``B_inf``. ``J`` is albedo times the light reaching the surface: downwelling
sunlight (attenuated by ``beta_D`` over the depth below the surface, modulated by animated
caustics near the surface) plus the vehicle's own light (a spot with inverse-square falloff,
attenuated over the light-to-surface path). The sensor then adds vignetting, blur, shot and read
noise, and sRGB encoding. With :meth:`Imaging.clean` every effect is off: the image is albedo
times a fixed Lambertian sun (no noise, no water), so geometry can be tested alone.

The water presets are chosen by us, not fitted, and they are **not** Jerlov's table: they are
wideband camera-channel coefficients of the order of the clear ocean (``clear``), coastal
(``coastal``) and turbid coastal / lake (``turbid``) waters. Beside Jerlov's downward
irradiance attenuation ``K_d`` at 600/525/475 nm (N. G. Jerlov, *Marine Optics*, 2nd ed. 1976,
Table XXVII, p. 135; ``sea3d.enhance.water.JERLOV_KD_PER_M``), 1/m:

===========  ===================  ==========================
preset       ``beta_D`` R/G/B     nearest Jerlov ``K_d``
===========  ===================  ==========================
clear        0.40 / 0.08 / 0.05   II 0.26 / 0.076 / 0.062
coastal      0.60 / 0.22 / 0.32   3C 0.33 / 0.20 / 0.29
turbid       1.10 / 0.75 / 1.30   9C 0.60 / 0.78 / 1.23
===========  ===================  ==========================

Green and blue are close to the table; red is 1.5-1.8x it. A camera's red channel integrates
about 570-700 nm, where pure water alone absorbs from about 0.07 to 0.65 1/m (Pope and Fry,
Applied Optics 36(33), 1997), so a wideband red above ``K_d(600 nm)`` is expected (wideband
coefficients depend on the camera's spectral response: Akkaynak et al., "What is the space
of attenuation coefficients in underwater computer vision?", CVPR 2017), but the exact
values are ours. They are kept because every
rendered figure of the project (tests, the demo, the benchmarks) is pinned to them; the
independent formation judge (``sea3d.eval.enhance_formation``) uses the table itself.
``beta_B`` and ``B_inf`` are set so the veiling light has the hue typical of each water
(blue, green, yellow-green).

Vignetting is applied by the sensor to everything that reaches the lens, direct signal and
backscatter alike (after the water): that is the physical order (a lens attenuates the light
arriving off-axis whatever scattered it). So an image ``I = V(u) (D + B)`` has a backscatter
that falls off towards the corners with ``V``, which a per-image constant ``B_inf`` does not
hold: a restoration should divide by a calibrated flat field ``V`` before inverting the
water (``sea3d.enhance.water`` does not: no rig here carries a flat-field calibration).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F32, FloatArray
from sea3d.errors import SimulationError
from sea3d.sim._kernels import caustic_raw, expose, light_and_water, noise_and_encode

__all__ = ["WATER_PRESETS", "Imaging", "Water", "encode_srgb", "water_preset"]


@dataclass(frozen=True, kw_only=True)
class Water:
    """Optical properties of a water body, per RGB channel.

    Attributes:
        name: preset name.
        beta_D_per_m: direct-signal attenuation coefficients (R, G, B), 1/m.
        beta_B_per_m: backscatter coefficients (R, G, B), 1/m.
        B_inf_rgb: veiling light (R, G, B), linear image units.
    """

    name: str
    beta_D_per_m: tuple[float, float, float]
    beta_B_per_m: tuple[float, float, float]
    B_inf_rgb: tuple[float, float, float]

    def __post_init__(self) -> None:
        for key in ("beta_D_per_m", "beta_B_per_m", "B_inf_rgb"):
            v = np.asarray(getattr(self, key), dtype=np.float64)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0):
                raise SimulationError(
                    f"water {self.name!r}: {key} must be 3 non-negative numbers, got {v}"
                )


WATER_PRESETS: dict[str, Water] = {
    "clear": Water(
        name="clear",
        beta_D_per_m=(0.40, 0.08, 0.05),
        beta_B_per_m=(0.30, 0.06, 0.05),
        B_inf_rgb=(0.01, 0.10, 0.22),
    ),
    "coastal": Water(
        name="coastal",
        beta_D_per_m=(0.60, 0.22, 0.32),
        beta_B_per_m=(0.45, 0.25, 0.30),
        B_inf_rgb=(0.04, 0.20, 0.17),
    ),
    "turbid": Water(
        name="turbid",
        beta_D_per_m=(1.10, 0.75, 1.30),
        beta_B_per_m=(1.00, 0.90, 1.10),
        B_inf_rgb=(0.13, 0.22, 0.11),
    ),
}


def water_preset(name: str) -> Water | None:
    """A water preset by name; ``"none"`` gives None (no water effects).

    Raises:
        SimulationError: for an unknown name.
    """
    if name in ("none", "off", "air"):
        return None
    if name not in WATER_PRESETS:
        raise SimulationError(
            f"unknown water {name!r}; choose one of none, {', '.join(WATER_PRESETS)}"
        )
    return WATER_PRESETS[name]


@dataclass(frozen=True, kw_only=True)
class Imaging:
    """Every effect between the scene and the pixel values, each off at its zero value.

    Attributes:
        water: attenuation and backscatter, or None for none.
        sun_irradiance: downwelling light just under the surface (linear units).
        sun_direction_world: direction the sunlight travels (world frame, need not be unit).
        ambient: fraction of the sunlight that arrives diffusely from every direction.
        vehicle_light: radiant intensity of the vehicle's lamp (linear units times m^2: a surface
            1 m away, facing the lamp, gets this irradiance before attenuation).
        vehicle_light_offset_m: lamp position in the camera frame, metres.
        vehicle_light_cone_deg: half-angle at which the lamp's intensity drops to exp(-1).
        caustics: relative modulation of the sunlight by caustics (0 = off, 1 = strong).
        caustic_scale_m: size of the caustic cells, metres.
        caustic_speed_per_s: how fast the caustic pattern evolves, lattice units per second.
        caustic_fade_depth_m: caustics fade as exp(-depth below surface / this).
        vignetting: brightness lost at the image corners (0 = none, 0.4 = 40 %).
        blur_sigma_px: Gaussian blur (lens, forward scatter), pixels.
        full_well_e: electrons at full scale for shot noise (0 = no shot noise).
        read_noise: Gaussian read noise, standard deviation as a fraction of full scale.
        exposure: gain applied to linear radiance before the sensor.
        line_of_sight_water: False removes the water between the camera and the scene (no
            attenuation along the view ray, no backscatter; rays that hit nothing see black)
            while sunlight and lamp still reach the scene through the water: the image
            ``J`` of the formation model, which Sea-thru-like restorations estimate.
    """

    water: Water | None = None
    sun_irradiance: float = 1.0
    sun_direction_world: tuple[float, float, float] = (0.25, 0.15, -1.0)
    ambient: float = 0.35
    vehicle_light: float = 0.0
    vehicle_light_offset_m: tuple[float, float, float] = (0.0, -0.12, 0.0)
    vehicle_light_cone_deg: float = 35.0
    caustics: float = 0.0
    caustic_scale_m: float = 0.35
    caustic_speed_per_s: float = 0.4
    caustic_fade_depth_m: float = 4.0
    vignetting: float = 0.0
    blur_sigma_px: float = 0.0
    full_well_e: float = 0.0
    read_noise: float = 0.0
    exposure: float = 1.0
    line_of_sight_water: bool = True

    def __post_init__(self) -> None:
        for key in (
            "sun_irradiance",
            "ambient",
            "vehicle_light",
            "caustics",
            "vignetting",
            "blur_sigma_px",
            "full_well_e",
            "read_noise",
            "exposure",
            "caustic_scale_m",
            "caustic_fade_depth_m",
        ):
            v = float(getattr(self, key))
            if not np.isfinite(v) or v < 0:
                raise SimulationError(f"Imaging.{key} must be a finite number >= 0, got {v}")
        if self.vignetting >= 1:
            raise SimulationError(f"Imaging.vignetting must be below 1, got {self.vignetting}")

    @classmethod
    def clean(cls) -> Imaging:
        """No water, no lamp, no caustics, no sensor effects: albedo under a fixed sun."""
        return cls()

    @classmethod
    def underwater(cls, water: str | Water | None) -> Imaging:
        """Every effect on, for the named water preset (``clear``, ``coastal``, ``turbid``).

        Raises:
            SimulationError: for an unknown preset.
        """
        w = water_preset(water) if isinstance(water, str) else water
        if w is None:
            return cls.clean()
        return cls(
            water=w,
            sun_irradiance=1.4,
            vehicle_light=0.8,
            caustics=0.6,
            vignetting=0.35,
            blur_sigma_px=0.6,
            full_well_e=6000.0,
            read_noise=0.004,
            exposure=1.6,
        )

    def without_sensor_noise(self) -> Imaging:
        """The same imaging without shot and read noise."""
        return replace(self, full_well_e=0.0, read_noise=0.0)

    def without_water(self) -> Imaging:
        """The same lights, caustics and sensor with no water at all (white light reaches the
        scene, nothing attenuates or scatters): the clean reference of a view."""
        return replace(self, water=None)

    def without_line_of_sight_water(self) -> Imaging:
        """The same imaging with the water between camera and scene removed (lights still
        travel through water): the unattenuated image ``J`` of the formation model."""
        return replace(self, line_of_sight_water=False)

    # ------------------------------------------------------------------------------------------

    def shade(
        self,
        albedo: F32,
        points_world: FloatArray,
        normals_world: F32,
        path_m: FloatArray,
        *,
        surface_z_m: float,
        light_pos_world: FloatArray,
        light_axis_world: FloatArray,
        time_s: float,
    ) -> F32:
        """Radiance reaching the camera from each hit (linear, before exposure).

        Args:
            albedo: ``(N, 3)`` float32 linear albedo.
            points_world: ``(N, 3)`` float64 hit points, world frame, metres.
            normals_world: ``(N, 3)`` float32 unit normals facing the ray.
            path_m: ``(N,)`` float64 water path length from the camera (port surface) to the hit.
            surface_z_m: world z of the water surface.
            light_pos_world: ``(3,)`` lamp position, world.
            light_axis_world: ``(3,)`` lamp axis (unit), world.
            time_s: scene time for the caustic animation, seconds.

        Returns:
            ``(N, 3)`` float32 radiance.
        """
        m = albedo.shape[0]
        sun_dir = -np.asarray(self.sun_direction_world, dtype=np.float64)
        sun_dir /= np.linalg.norm(sun_dir)
        if self.caustics > 0:
            # Caustics only where direct sunlight falls and the water is shallow enough.
            depth_below = np.clip(surface_z_m - points_world[:, 2], 0.0, None)
            fade = np.exp(-depth_below / self.caustic_fade_depth_m)
            lit = np.flatnonzero((normals_world @ sun_dir.astype(np.float32) > 0) & (fade > 0.02))
            mod = np.ones(m, dtype=np.float32)
            if lit.size:
                c = caustic_pattern(
                    points_world[lit], time_s, self.caustic_scale_m, self.caustic_speed_per_s
                )
                mod[lit] = 1.0 + self.caustics * fade[lit] * (c - 1.0)
        else:
            mod = np.ones(m, dtype=np.float32)
        w = self.water
        zeros = np.zeros(3)
        return light_and_water(
            np.ascontiguousarray(albedo, dtype=np.float32),
            np.ascontiguousarray(points_world, dtype=np.float64),
            np.ascontiguousarray(normals_world, dtype=np.float32),
            np.ascontiguousarray(path_m, dtype=np.float64),
            mod,
            sun_dir,
            float(self.sun_irradiance),
            float(self.ambient),
            float(surface_z_m),
            np.asarray(w.beta_D_per_m, dtype=np.float64) if w else zeros,
            np.asarray(w.beta_B_per_m, dtype=np.float64) if w else zeros,
            np.asarray(w.B_inf_rgb, dtype=np.float64) if w else zeros,
            w is not None,
            bool(self.line_of_sight_water),
            np.asarray(light_pos_world, dtype=np.float64),
            np.asarray(light_axis_world, dtype=np.float64),
            float(self.vehicle_light),
            float(np.deg2rad(self.vehicle_light_cone_deg)),
        )

    def through_water(self, J: FloatArray, path_m: FloatArray) -> F32:
        """Akkaynak-Treibitz: ``J exp(-beta_D z) + B_inf (1 - exp(-beta_B z))`` per channel.

        ``path_m`` may be ``inf`` (the ray hits nothing): the result is ``B_inf``.
        """
        if self.water is None or not self.line_of_sight_water:
            return np.asarray(J, dtype=np.float32)
        z = np.asarray(path_m, dtype=np.float64)[:, None]
        bD = np.asarray(self.water.beta_D_per_m)[None, :]
        bB = np.asarray(self.water.beta_B_per_m)[None, :]
        Binf = np.asarray(self.water.B_inf_rgb)[None, :]
        with np.errstate(invalid="ignore"):
            direct = np.where(
                np.isfinite(z), J * np.exp(-bD * np.where(np.isfinite(z), z, 0.0)), 0.0
            )
        back = Binf * (1.0 - np.exp(-bB * z))
        return (direct + back).astype(np.float32)

    def background(self, count: int) -> F32:
        """Radiance of rays that hit nothing: the veiling light, or black without water."""
        if self.water is None or not self.line_of_sight_water:
            return np.zeros((count, 3), dtype=np.float32)
        return np.repeat(np.asarray(self.water.B_inf_rgb, dtype=np.float32)[None, :], count, axis=0)

    def sensor(self, radiance: F32, rng: np.random.Generator | None) -> NDArray[np.uint8]:
        """From linear radiance ``(H, W, 3)`` float32 to an sRGB ``(H, W, 3)`` uint8 image:
        exposure, vignetting, blur, shot and read noise, clipping, sRGB encoding.

        Raises:
            SimulationError: if noise is on and no generator is given.
        """
        h, w = radiance.shape[:2]
        img = np.empty((h, w, 3), dtype=np.float32)
        vig = (
            _vignette(h, w, float(self.vignetting))
            if self.vignetting > 0
            else np.empty((0, 0), dtype=np.float32)
        )
        expose(np.ascontiguousarray(radiance, dtype=np.float32), float(self.exposure), vig, img)
        if self.blur_sigma_px > 0:
            cv2.GaussianBlur(
                img, (0, 0), self.blur_sigma_px, dst=img, borderType=cv2.BORDER_REFLECT
            )
        normals: F32 = np.empty((0, 0, 0), dtype=np.float32)
        if self.full_well_e > 0 or self.read_noise > 0:
            if rng is None:
                raise SimulationError("sensor noise is on but no random generator was given")
            # Shot noise (Gaussian approximation of Poisson, thousands of electrons), read noise.
            normals = rng.standard_normal(img.shape, dtype=np.float32)
        return noise_and_encode(
            img, normals, float(self.full_well_e), float(self.read_noise), _srgb_lut()
        )


@lru_cache(maxsize=8)
def _vignette(h: int, w: int, strength: float) -> F32:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / (
        ((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2
    )
    out = (1.0 - strength * r2).astype(np.float32)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=1)
def _srgb_lut() -> NDArray[np.uint8]:
    x = np.arange(65536, dtype=np.float64) / 65535.0
    enc = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(enc * 255.0).astype(np.uint8)


def encode_srgb(linear: F32) -> NDArray[np.uint8]:
    """Linear ``[0, 1]`` to 8-bit sRGB (IEC 61966-2-1 transfer curve), clipping outside; through a
    16-bit lookup table (linear input quantised to 1/65535)."""
    idx = (np.clip(linear, 0.0, 1.0) * np.float32(65535.0) + np.float32(0.5)).astype(np.uint16)
    return _srgb_lut()[idx]


@lru_cache(maxsize=1)
def caustic_mean() -> float:
    """Mean of the unnormalised caustic pattern (the normalisation of :func:`caustic_pattern`)."""
    p = np.random.default_rng(0).random((200_000, 3)) * 50.0
    return float(np.mean(caustic_raw(p, 1.0, 0.0)))


def caustic_pattern(
    points_world: FloatArray, time_s: float, scale_m: float, speed_per_s: float
) -> FloatArray:
    """Animated caustic brightness on the floor, mean about 1: bright thin ridges of two
    interfering noise fields of ``(x, y) / scale_m`` and time.

    Args:
        points_world: ``(N, 3)`` float64 world points (only x, y are used).
        time_s: time, seconds.
        scale_m: cell size, metres.
        speed_per_s: animation speed, lattice units per second.

    Returns:
        ``(N,)`` float64, non-negative.
    """
    raw = caustic_raw(
        np.ascontiguousarray(points_world, dtype=np.float64),
        float(scale_m),
        float(time_s * speed_per_s),
    )
    return raw.astype(np.float64) / caustic_mean()
