"""Rig planning: what depth accuracy, nearest range and overlap a stereo rig gives.

For a rectified stereo pair with focal length ``f`` (pixels) and baseline ``B`` (metres), a
point at depth ``z`` has disparity ``d = f B / z``. A matching error of ``S`` pixels (standard
deviation) becomes a depth error of

    ``sigma_z = z^2 S / (f B)``                                   (first order in ``S``)

and the nearest depth the matcher can resolve with disparities ``0..N`` is ``z_min = f B / N``.
The paper ends with this advice: its rig's baseline was chosen for a 0.6 m minimum range and
it did best at medium distances (Sea3D paper, discussion).

Behind ports the rig is evaluated through its camera models, not through the formulas alone:

- the *effective focal length in water* is that of the virtual pinhole pair used for
  rectification (:func:`sea3d.rectify.rectify_rig`): a flat port magnifies by about the
  water's index (1.33), a centred dome not at all;
- the *virtual-pinhole residual* (RMS and largest, pixels) says how far the refractive cameras
  are from any pinhole over the range: that much vertical misalignment stays in the rectified
  images;
- the *overlap* of the two views at each range is counted with the true refracted rays;
- the *refraction bias* is the depth error one would make by ignoring the ports (triangulating
  the true refracted pixels with the in-air pinholes), median over the image, signed.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError
from sea3d.geometry.camera import CameraModel, Rays
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.triangulate import triangulate_midpoint

__all__ = [
    "PlanConfig",
    "PlanRow",
    "RigPlan",
    "override_rig",
    "plan_rig",
    "plot_plan",
]

_log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class PlanConfig:
    """What to plan for.

    Attributes:
        max_disparity_px: the largest disparity the matcher searches (``N``).
        disparity_noise_px: matching error, standard deviation in pixels (``S``); 0.25 px is a
            typical subpixel SGM figure on textured scenes.
        range_m: ``(near, far)`` depths of the table, metres; None: from the nearest range the
            disparity range allows to 10 m (or twice the nearest range if that is beyond 10 m).
        rows: number of table rows (at least 5), evenly spaced over the range.
        grid_step_px: row spacing of the pixel grid for the overlap and refraction figures
            (columns are 2 px apart).
    """

    max_disparity_px: int = 256
    disparity_noise_px: float = 0.25
    range_m: tuple[float, float] | None = None
    rows: int = 8
    grid_step_px: int = 24

    def __post_init__(self) -> None:
        if self.max_disparity_px < 1:
            raise ConfigError(f"max disparity must be >= 1 px, got {self.max_disparity_px}")
        if not self.disparity_noise_px >= 0:
            raise ConfigError(f"disparity noise must be >= 0 px, got {self.disparity_noise_px}")
        if self.rows < 5:
            raise ConfigError(f"a plan needs at least 5 rows, got {self.rows}")
        if self.grid_step_px < 1:
            raise ConfigError(f"grid step must be >= 1 px, got {self.grid_step_px}")
        if self.range_m is not None:
            near, far = (float(v) for v in self.range_m)
            if not (0 < near < far and np.isfinite(far)):
                raise ConfigError(f"range must satisfy 0 < MIN < MAX, got {near} and {far}")


@dataclass(frozen=True, kw_only=True)
class PlanRow:
    """The rig at one range.

    Attributes:
        range_m: depth along the left camera's z axis, metres.
        disparity_px: ``f B / z`` with the rectified focal length, pixels.
        depth_error_m: ``z^2 S / (f B)``, metres (one standard deviation).
        depth_error_pct: the same as a percentage of the range.
        overlap_fraction: fraction of the left image whose scene point at this depth is also
            inside the right image (0..1), counted with the camera models.
        refraction_bias_m: median signed depth error from ignoring the ports (triangulating
            the true pixels with the in-air pinholes), metres; None for a pinhole rig.
        in_range: the disparity fits the matcher's range (``d <= N``).
    """

    range_m: float
    disparity_px: float
    depth_error_m: float
    depth_error_pct: float
    overlap_fraction: float
    refraction_bias_m: float | None
    in_range: bool


@dataclass(frozen=True, kw_only=True)
class RigPlan:
    """A rig's depth accuracy, nearest range and overlap against range.

    Attributes:
        width, height: image size, pixels.
        focal_px: the in-air (pinhole) focal length of the left camera, pixels.
        focal_water_px: the effective focal length in water: the left virtual pinhole's (the
            best pinhole for the refractive camera over the range) for a port rig, the pinhole's
            own otherwise, pixels.
        focal_rectified_px: the focal length of the rectified views, in which disparities are
            measured and which the formulas use (OpenCV's ``stereoRectify`` with ``alpha=0``
            zooms in slightly when there is distortion to remove), pixels.
        baseline_m: the rectified baseline, metres.
        max_disparity_px: ``N``.
        disparity_noise_px: ``S``.
        min_range_m: ``f B / N``, metres: nearer than this the matcher cannot see.
        hfov_deg: horizontal field of view in water (air for pinhole rigs), degrees.
        refractive: the rig has ports.
        virtual_pinhole_rms_px, virtual_pinhole_max_px: the worse camera's virtual-pinhole
            residual over the range (None for pinhole rigs), pixels.
        rows: the table, nearest first.
    """

    width: int
    height: int
    focal_px: float
    focal_water_px: float
    focal_rectified_px: float
    baseline_m: float
    max_disparity_px: int
    disparity_noise_px: float
    min_range_m: float
    hfov_deg: float
    refractive: bool
    virtual_pinhole_rms_px: float | None
    virtual_pinhole_max_px: float | None
    rows: tuple[PlanRow, ...] = field(default=())

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (JSON-ready); ``rows`` is a list of dicts."""
        out = asdict(self)
        out["rows"] = [asdict(r) for r in self.rows]
        return out


# ----------------------------------------------------------------------------- rig edits


def _scaled(
    pin: PinholeCamera, fx_px: float | None, size_px: tuple[int, int] | None
) -> PinholeCamera:
    if size_px is not None:
        pin = pin.scaled(int(size_px[0]), int(size_px[1]))
    if fx_px is None:
        return pin
    return dataclasses.replace(pin, fx=float(fx_px), fy=pin.fy * (fx_px / pin.fx))


def override_rig(
    rig: StereoRig,
    *,
    fx_px: float | None = None,
    baseline_m: float | None = None,
    size_px: tuple[int, int] | None = None,
) -> StereoRig:
    """The rig with some of its values replaced; ports are kept.

    Args:
        rig: the rig.
        fx_px: new in-air focal length of both cameras (each ``fy`` keeps its ratio), pixels;
            applied after a size change.
        baseline_m: new distance between the cameras (the direction of ``T_left_right`` is kept).
        size_px: new ``(width, height)``: focal lengths and principal points scale with it
            (pixel centres stay pixel centres).

    Raises:
        ConfigError: a non-positive value.
    """
    if fx_px is not None and not fx_px > 0:
        raise ConfigError(f"focal length must be > 0 px, got {fx_px}")
    if baseline_m is not None and not baseline_m > 0:
        raise ConfigError(f"baseline must be > 0 m, got {baseline_m}")
    if size_px is not None and (size_px[0] <= 0 or size_px[1] <= 0):
        raise ConfigError(f"image size must be positive, got {size_px[0]}x{size_px[1]}")
    cams = [
        cam.with_lens(_scaled(cam.lens, fx_px, size_px)) for cam in (rig.left, rig.right)
    ]
    T = np.array(rig.T_left_right, dtype=np.float64)
    if baseline_m is not None:
        t = T[:3, 3]
        T[:3, 3] = t * (baseline_m / np.linalg.norm(t))
    return StereoRig(
        left=cams[0], right=cams[1], T_left_right=T, imu=rig.imu, sonar=rig.sonar
    )


# ----------------------------------------------------------------------------- figures


def _grid(width: int, height: int, step: int) -> F64:
    # Overlap is mostly a horizontal matter: columns 2 px apart, rows ``step`` apart.
    us = np.arange(1.0, width, 2.0, dtype=np.float64)
    vs = np.arange(step / 2, height, step, dtype=np.float64)
    uu, vv = np.meshgrid(us, vs)
    return np.stack([uu.ravel(), vv.ravel()], axis=1)


def _points_at_depth(rays: Rays, z_m: float) -> F64:
    """Points on ``rays`` whose z coordinate is ``z_m`` (NaN where the ray does not get there)."""
    dz = rays.directions[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (z_m - rays.origins[:, 2]) / dz
    s = np.where((dz > 1e-9) & (s > 0), s, np.nan)
    return rays.origins + s[:, None] * rays.directions


def _inside(uv: F64, valid: NDArray[np.bool_], cam: CameraModel) -> NDArray[np.bool_]:
    u, v = uv[:, 0], uv[:, 1]
    with np.errstate(invalid="ignore"):
        ok = valid & (u >= -0.5) & (u <= cam.width - 0.5) & (v >= -0.5) & (v <= cam.height - 0.5)
    return np.asarray(ok, dtype=np.bool_)


def _transform(T: F64, p: F64) -> F64:
    return np.asarray(p @ T[:3, :3].T + T[:3, 3], dtype=np.float64)


def _overlap_and_bias(
    rig: StereoRig, z_m: float, rays_left: Rays, refractive: bool
) -> tuple[float, float | None]:
    pts_left = _points_at_depth(rays_left, z_m)
    usable = np.isfinite(pts_left).all(axis=1)
    if not usable.any():
        return 0.0, None
    T_rl = rig.T_right_left
    uv_r, ok_r = rig.right.project(_transform(T_rl, pts_left[usable]))
    seen = _inside(uv_r, ok_r, rig.right)
    overlap = float(seen.sum() / usable.sum())
    if not refractive or not seen.any():
        return overlap, None
    # Ignore the ports: the true (refracted) pixels triangulated with the in-air pinholes.
    pts = pts_left[usable][seen]
    uv_l, ok_l = rig.left.project(pts)
    uv_r = uv_r[seen]
    pin_l, pin_r = rig.left.lens, rig.right.lens
    ray_l = pin_l.unproject(uv_l[ok_l])
    ray_r = pin_r.unproject(uv_r[ok_l])
    T_lr = np.asarray(rig.T_left_right, dtype=np.float64)
    ray_r_left = Rays(
        origins=_transform(T_lr, ray_r.origins),
        directions=np.asarray(ray_r.directions @ T_lr[:3, :3].T, dtype=np.float64),
    )
    tri, _gap = triangulate_midpoint(ray_l, ray_r_left)
    err = tri[:, 2] - pts[ok_l][:, 2]
    err = err[np.isfinite(err)]
    return overlap, (float(np.median(err)) if err.size else None)


def _hfov_deg(cam: CameraModel) -> float:
    cy = (cam.height - 1) / 2
    uv = np.array([[-0.5, cy], [cam.width - 0.5, cy]], dtype=np.float64)
    rays = cam.unproject(uv)
    d = rays.directions
    if not rays.valid.all():
        pin = cam.lens
        return float(np.degrees(2 * np.arctan(cam.width / (2 * pin.fx))))
    cosang = float(np.clip(np.dot(d[0], d[1]) / np.linalg.norm(d[0]) / np.linalg.norm(d[1]), -1, 1))
    return float(np.degrees(np.arccos(cosang)))


def plan_rig(rig: StereoRig, config: PlanConfig | None = None) -> RigPlan:
    """Depth error, nearest range and overlap of ``rig`` against range (see the module doc).

    Args:
        rig: the stereo rig (pinhole, dome- or flat-port cameras).
        config: :class:`PlanConfig` (default: 256 px disparity range, 0.25 px noise).

    Returns:
        :class:`RigPlan` with ``config.rows`` rows.

    Raises:
        ConfigError: bad configuration. RectifyError: the cameras are not side by side.
    """
    from sea3d.rectify import rectify_rig

    cfg = config or PlanConfig()
    pin = rig.left.lens
    B0 = rig.baseline_m
    refractive = rig.left.port is not None or rig.right.port is not None
    # Nearest range first with the in-air figures, then refine with the in-water focal length
    # (the virtual-pinhole fit depends on the range it is fitted over).
    z_min0 = pin.fx * B0 / cfg.max_disparity_px
    if cfg.range_m is not None:
        fit_range = (float(cfg.range_m[0]), float(cfg.range_m[1]))
    else:
        fit_range = (z_min0, max(10.0, 2 * z_min0))
    maps = rectify_rig(rig, depth_range_m=fit_range)
    f_eff, B = maps.focal_px, maps.baseline_m
    z_min = f_eff * B / cfg.max_disparity_px
    near, far = fit_range if cfg.range_m is not None else (z_min, max(10.0, 2 * z_min))
    ranges = np.linspace(near, far, cfg.rows)
    rays_left = rig.left.unproject(_grid(rig.width, rig.height, cfg.grid_step_px))
    rows = []
    for z in ranges:
        z = float(z)
        d = f_eff * B / z
        sigma = z * z * cfg.disparity_noise_px / (f_eff * B)
        overlap, bias = _overlap_and_bias(rig, z, rays_left, refractive)
        rows.append(
            PlanRow(
                range_m=z,
                disparity_px=float(d),
                depth_error_m=float(sigma),
                depth_error_pct=float(100 * sigma / z),
                overlap_fraction=overlap,
                refraction_bias_m=bias,
                in_range=bool(d <= cfg.max_disparity_px + 1e-9),
            )
        )
    reps = [r for r in (maps.report_left, maps.report_right) if r is not None]
    return RigPlan(
        width=rig.width,
        height=rig.height,
        focal_px=float(pin.fx),
        focal_water_px=float(maps.virtual_left.fx),
        focal_rectified_px=float(f_eff),
        baseline_m=float(B),
        max_disparity_px=int(cfg.max_disparity_px),
        disparity_noise_px=float(cfg.disparity_noise_px),
        min_range_m=float(z_min),
        hfov_deg=_hfov_deg(rig.left),
        refractive=bool(refractive),
        virtual_pinhole_rms_px=max(r.rms_px for r in reps) if reps else None,
        virtual_pinhole_max_px=max(r.max_px for r in reps) if reps else None,
        rows=tuple(rows),
    )


def plot_plan(plan: RigPlan, path: str | Path, *, title: str | None = None) -> Path:
    """Draw the plan (depth error and overlap against range; refraction bias for port rigs)
    into a PNG with matplotlib's Agg backend.

    Raises:
        ConfigError: the file cannot be written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.array([r.range_m for r in plan.rows])
    err = np.array([r.depth_error_m for r in plan.rows])
    ov = np.array([r.overlap_fraction for r in plan.rows])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    ax = axes[0]
    ax.plot(z, err * 100, "o-", label=f"depth error, S = {plan.disparity_noise_px:g} px")
    if plan.refractive:
        bias = np.array(
            [np.nan if r.refraction_bias_m is None else r.refraction_bias_m for r in plan.rows]
        )
        ax.plot(z, np.abs(bias) * 100, "s--", label="|bias| if the ports were ignored")
    ax.axvline(
        plan.min_range_m, color="grey", ls=":", label=f"nearest range {plan.min_range_m:.2f} m"
    )
    ax.set_xlabel("range z (m)")
    ax.set_ylabel("depth error (cm)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax = axes[1]
    ax.plot(z, ov * 100, "o-", color="tab:green")
    ax.set_ylim(0, 100)
    ax.set_xlabel("range z (m)")
    ax.set_ylabel("overlap of the two views (%)")
    ax.grid(True, alpha=0.3)
    fig.suptitle(
        title
        or f"f = {plan.focal_water_px:.0f} px, B = {plan.baseline_m * 1000:.0f} mm, "
        f"N = {plan.max_disparity_px} px, {plan.width}x{plan.height}"
    )
    out = Path(path)
    try:
        fig.savefig(out, dpi=100)
    except OSError as err_:
        raise ConfigError(f"cannot write the plot {out}: {err_}") from err_
    finally:
        plt.close(fig)
    return out
