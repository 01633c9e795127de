"""The end-to-end demo: simulate an underwater stereo pair, compute refraction-corrected depth
and a coloured point cloud, measure it against ground truth, and write an HTML report.

This is sea3d's main job on its built-in default (``sea3d demo``): the paper's rig with acrylic
domes, the simulator's ``lake`` scene in coastal water, our own SGM engine.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ConfigError

__all__ = ["DemoConfig", "DemoResult", "run_demo"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class DemoConfig:
    """What the demo simulates and how it computes depth."""

    out_dir: Path = Path("out/demo")
    """Folder for the report and its files (created)."""
    scene: str = "lake"
    """Built-in scene (``lake``, ``tank``, ``reef``) or a scene YAML file."""
    water: str = "coastal"
    """Water preset: ``none``, ``clear``, ``coastal``, ``turbid``."""
    port: str = "dome"
    """Ports on the paper's rig: ``dome``, ``flat`` or ``none``."""
    engine: str = "sea3d"
    """Matching engine: ``sea3d`` (our SGM), ``sea3d-gpu`` (CuPy) or ``opencv`` (StereoSGBM)."""
    size_px: tuple[int, int] = (1920, 1080)
    """Image size; the paper computed depth at 1920x1080."""
    max_disparity_px: int = 256
    """Disparity search range at 1920 px width (scaled with the width)."""
    seed: int = 0
    """Sensor-noise seed."""
    eye_m: tuple[float, float, float] = (0.35, -1.6, 0.9)
    """Left camera position in the scene, metres (the scene's floor is near z = 0)."""
    target_m: tuple[float, float, float] = (0.0, 0.0, 0.1)
    """Point the camera looks at, metres."""

    def __post_init__(self) -> None:
        if self.size_px[0] < 64 or self.size_px[1] < 48:
            raise ConfigError(f"demo image size must be at least 64x48, got {self.size_px}")
        if self.max_disparity_px < 16:
            raise ConfigError(f"max_disparity_px must be >= 16, got {self.max_disparity_px}")


@dataclass(frozen=True, kw_only=True)
class DemoResult:
    """Figures and files of one demo run."""

    out_dir: Path
    report_html: Path
    summary: dict[str, Any] = field(default_factory=dict)


def _colorize(values: NDArray[np.floating], lo: float, hi: float) -> NDArray[np.uint8]:
    """Turbo colour map on a fixed, labelled range (never per-frame min-max); NaN is black."""
    import cv2

    v = np.asarray(values, dtype=np.float64)
    scaled = np.clip((v - lo) / (hi - lo), 0.0, 1.0)
    idx = np.nan_to_num(scaled * 255.0, nan=0.0).astype(np.uint8)
    rgb = np.ascontiguousarray(cv2.applyColorMap(idx, cv2.COLORMAP_TURBO)[..., ::-1], np.uint8)
    rgb[~np.isfinite(v)] = 0
    return rgb


def _scaled_disparity(config: DemoConfig) -> int:
    d = round(config.max_disparity_px * config.size_px[0] / 1920.0)
    return max(16, (d + 15) // 16 * 16)


def run_demo(config: DemoConfig, progress: Callable[[str], None] | None = None) -> DemoResult:
    """Run the demo and write its report; see the module docstring.

    Args:
        config: :class:`DemoConfig`.
        progress: called with a short message as each stage starts.

    Returns:
        :class:`DemoResult` with the summary figures (also in ``summary.json``).

    Raises:
        ConfigError, SimulationError, RectifyError, StereoError: bad configuration.
    """
    from sea3d.eval.depth_gt import point_depth_errors
    from sea3d.geometry.se3 import look_at
    from sea3d.io.depth_files import write_depth, write_depth_png_mm, write_disparity, write_ply
    from sea3d.io.rig_file import save_rig
    from sea3d.pipeline.report import write_demo_report
    from sea3d.rectify import rectify_rig
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim import builtin_scene, load_scene, scale_rig, simulate_pair
    from sea3d.stereo import make_config
    from sea3d.stereo.depth import compute_depth, disparity_to_depth

    def step(msg: str) -> None:
        log.debug(msg)
        if progress is not None:
            progress(msg)

    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}

    rig = scale_rig(paper_rig(config.port), config.size_px)  # type: ignore[arg-type]
    save_rig(rig, out / "rig.yaml")
    scene = (
        load_scene(config.scene)
        if config.scene.endswith((".yaml", ".yml"))
        else builtin_scene(config.scene)
    )
    T_world_left = look_at(config.eye_m, config.target_m)

    step(
        f"simulating a {config.size_px[0]}x{config.size_px[1]} pair of '{config.scene}' in "
        f"{config.water} water through {config.port} ports"
    )
    t0 = time.perf_counter()
    left, right, gt = simulate_pair(rig, scene, T_world_left, config.water, seed=config.seed)
    timings["simulate_s"] = time.perf_counter() - t0

    step("rectifying (virtual pinholes fitted to the refractive cameras)")
    t0 = time.perf_counter()
    maps = rectify_rig(rig, depth_range_m=(0.5, 8.0))
    timings["rectify_maps_s"] = time.perf_counter() - t0

    max_disp = _scaled_disparity(config)
    step(f"matching with the {config.engine} engine, {max_disp} disparities")
    engine_config = make_config(config.engine, max_disp)
    t0 = time.perf_counter()
    depth = compute_depth(maps, left, right, engine_config, max_depth_m=20.0)
    timings["depth_total_s"] = time.perf_counter() - t0
    timings.update({f"depth_{k}": v for k, v in depth.timings_s.items()})

    step("measuring against ground truth")
    errors = point_depth_errors(depth.points_left, rig.left, gt.depth_m)
    # Baseline: the best-fitting pinhole in water (z = f B / d), no refraction correction.
    z_pin = disparity_to_depth(depth.disparity_px, maps.focal_px, maps.baseline_m)
    ok = np.isfinite(z_pin) & (z_pin < 20.0)
    vv, uu = np.nonzero(ok)
    zz = z_pin[ok].astype(np.float64)
    rect_pts = np.stack(
        [(uu - maps.cx_px) * zz / maps.focal_px, (vv - maps.cy_px) * zz / maps.focal_px, zz], axis=1
    )
    pin_pts = rect_pts @ maps.R_rect_left_left
    baseline = point_depth_errors(pin_pts, rig.left, gt.depth_m)
    ignored = None
    if config.port != "none":
        # What a user gets by taking the in-air calibration underwater and ignoring the ports.
        step("matching again with the in-air rig (ports ignored), for comparison")
        rig_air = scale_rig(paper_rig("none"), config.size_px)
        t0 = time.perf_counter()
        depth_air = compute_depth(
            rectify_rig(rig_air), left, right, engine_config, max_depth_m=20.0
        )
        timings["ports_ignored_s"] = time.perf_counter() - t0
        ignored = point_depth_errors(depth_air.points_left, rig.left, gt.depth_m)

    step("writing depth, point cloud and report")
    write_depth_png_mm(out / "depth_mm.png", depth.depth_m)
    write_depth(out / "depth_m.npy", depth.depth_m)
    write_disparity(out / "disparity.pfm", depth.disparity_px)
    write_ply(out / "cloud.ply", depth.points_left, depth.colors_rgb)
    np.save(out / "gt_depth_m.npy", gt.depth_m.astype(np.float32))

    summary: dict[str, Any] = {
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(config).items()},
        "image_size_px": list(config.size_px),
        "max_disparity_px": max_disp,
        "valid_fraction": float(np.isfinite(depth.depth_m).mean()),
        "points": len(depth.points_left),
        "refraction_corrected": errors.as_dict(),
        "pinhole_in_water_baseline": baseline.as_dict(),
        "ports_ignored_baseline": ignored.as_dict() if ignored is not None else None,
        "virtual_pinhole_rms_px": (
            maps.report_left.rms_px if maps.report_left is not None else 0.0
        ),
        "timings_s": timings,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    report = write_demo_report(
        out / "report.html",
        left=left,
        right=right,
        disparity_rgb=_colorize(depth.disparity_px, 0.0, float(max_disp)),
        disparity_range=(0.0, float(max_disp)),
        depth_rgb=_colorize(depth.depth_m, 0.5, 5.0),
        depth_range_m=(0.5, 5.0),
        error_rgb=_colorize(_rectified_error(depth, rig, gt.depth_m), -0.05, 0.05),
        error_range_m=(-0.05, 0.05),
        cloud_rgb=_cloud_picture(depth.points_left, depth.colors_rgb),
        summary=summary,
    )
    step(f"report: {report}")
    return DemoResult(out_dir=out, report_html=report, summary=summary)


def _rectified_error(depth: Any, rig: Any, gt_depth_m: NDArray[np.floating]) -> NDArray[np.float64]:
    """Signed depth error (m) of each point, drawn at its pixel in the raw left image."""
    h, w = gt_depth_m.shape
    err = np.full((h, w), np.nan)
    uv, ok = rig.left.project(depth.points_left)
    u = np.rint(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    v = np.rint(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    inside = ok & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    err[v[inside], u[inside]] = depth.points_left[inside, 2] - gt_depth_m[v[inside], u[inside]]
    return err


def _cloud_picture(points: NDArray[np.float64], colors: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The point cloud seen from above and to the side of the left camera."""
    from sea3d.geometry.se3 import look_at
    from sea3d.recon.render import render_points

    if len(points) == 0:
        return np.zeros((540, 960, 3), np.uint8)
    centre = np.median(points, axis=0)
    # Camera frame: x right, y down, z forward. Step back, up and to the right.
    eye = centre + np.array([1.2, -1.5, -1.6])
    view = look_at(eye, centre, up=(0.0, -1.0, 0.0))
    step = max(1, len(points) // 1_500_000)
    return render_points(points[::step], colors[::step], view, size_px=(960, 540), splat_px=2)
