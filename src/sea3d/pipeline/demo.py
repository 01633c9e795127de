"""The end-to-end demo: a short simulated dive, processed into a trajectory, a coloured mesh
and one HTML report, measured against the simulator's ground truth.

This is sea3d's main job on its built-in default (``sea3d demo``, ``bash scripts/run.sh``):

1. **dive**: the simulator flies a lawnmower survey over the ``lake`` scene in coastal water
   with the paper's rig behind acrylic domes (stereo at 10 fps, IMU at 200 Hz), written as a
   session folder with ground truth in ``gt/``;
2. **one pair**: the first pair's refraction-corrected depth against ground truth, beside the
   in-water pinhole and ports-ignored baselines;
3. **process**: :func:`sea3d.pipeline.process.run_process` on the whole session (per-frame
   stage in worker processes, odometry, keyframe-anchored TSDF submaps, mesh and cloud),
   trajectory and mesh measured against the ground truth;
4. one ``report.html`` with all of it, and ``summary.json``.

Poses come from sea3d's odometry when this build has it, otherwise from the simulator's
ground truth (the report and the summary say which).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ConfigError
from sea3d.io.ground_truth import GroundTruth, ground_truth_dir

__all__ = ["DemoConfig", "DemoResult", "run_demo"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class DemoConfig:
    """What the demo simulates and how it processes it."""

    out_dir: Path = Path("out/demo")
    """Folder for the session, the results and the report (created)."""
    scene: str = "lake"
    """Built-in scene (``lake``, ``tank``, ``reef``) or a scene YAML file."""
    water: str = "coastal"
    """Water preset: ``none``, ``clear``, ``coastal``, ``turbid``."""
    port: str = "dome"
    """Ports on the paper's rig: ``dome``, ``flat`` or ``none``."""
    engine: str = "sea3d"
    """Matching engine: ``sea3d`` (our SGM), ``sea3d-gpu`` (CuPy) or ``opencv`` (StereoSGBM)."""
    size_px: tuple[int, int] = (640, 360)
    """Image size of the simulated survey."""
    frames: int = 80
    """Stereo frames of the survey (10 per second)."""
    max_disparity_px: int = 256
    """Disparity search range at 1920 px width for the single-pair check (scaled)."""
    voxel_m: float = 0.02
    """TSDF voxel, metres."""
    workers: int | None = None
    """Local worker processes for the per-frame stage (None: one per core)."""
    seed: int = 0
    """Sensor-noise seed."""

    def __post_init__(self) -> None:
        if self.size_px[0] < 64 or self.size_px[1] < 48:
            raise ConfigError(f"demo image size must be at least 64x48, got {self.size_px}")
        if self.max_disparity_px < 16:
            raise ConfigError(f"max_disparity_px must be >= 16, got {self.max_disparity_px}")
        if self.frames < 3:
            raise ConfigError(f"the demo needs at least 3 frames, got {self.frames}")


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


def run_demo(
    config: DemoConfig,
    progress: Callable[[str], None] | None = None,
    bars: Any = None,
) -> DemoResult:
    """Run the demo and write its report; see the module docstring.

    Args:
        config: :class:`DemoConfig`.
        progress: called with a short message as each stage starts.
        bars: a progress-bar factory ``(stage, total) -> bar`` (the CLI's tqdm), or None.

    Returns:
        :class:`DemoResult` with the summary figures (also in ``summary.json``).

    Raises:
        ConfigError, SimulationError, RectifyError, StereoError: bad configuration.
    """
    from sea3d.io.process_outputs import write_summary_json
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter
    from sea3d.pipeline.process import ExecutorConfig, MapConfig, ProcessConfig, run_process
    from sea3d.pipeline.report import write_process_report
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim import builtin_scene, load_scene
    from sea3d.sim.survey import SurveyConfig, simulate_survey, with_survey_sensors
    from sea3d.stereo.recipe import DepthConfig

    def step(msg: str) -> None:
        log.debug(msg)
        if progress is not None:
            progress(msg)

    t_all = time.perf_counter()
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    rig = paper_rig(config.port).scaled(*config.size_px)  # type: ignore[arg-type]
    scene = (
        load_scene(config.scene)
        if config.scene.endswith((".yaml", ".yml"))
        else builtin_scene(config.scene)
    )
    session = out / "session"
    gt = GroundTruth(ground_truth_dir(session, folder=True))
    if session.exists():
        import shutil

        if not gt.sim_meta_path.is_file():
            raise ConfigError(f"{session} exists and is not a session the demo simulated; "
                              "choose another output folder")
        shutil.rmtree(session)  # a fresh dive each run (results below are recomputed too)
    step(
        f"simulating a {config.frames}-frame lawnmower survey of '{config.scene}' at "
        f"{config.size_px[0]}x{config.size_px[1]} in {config.water} water through "
        f"{config.port} ports"
    )
    t0 = time.perf_counter()
    bar = bars("dive", config.frames) if bars is not None else None
    survey = SurveyConfig(frames=config.frames, water=config.water, seed=config.seed)
    # the session's rig describes the simulated IMU (and echosounder), so the odometry uses it
    session_rig = with_survey_sensors(rig, survey)
    with SessionWriter(session, format="folder", rig_yaml=rig_to_yaml(session_rig)) as writer:
        simulate_survey(scene, rig, survey, writer, gt.root,
                        progress=bar.update if bar else None)
    if bar is not None:
        bar.close()
    timings["simulate_s"] = time.perf_counter() - t0

    step("checking one pair's depth against ground truth")
    t0 = time.perf_counter()
    pair_html, pair_summary, compile_s = _depth_check(config, rig, session, out)
    timings["depth_check_s"] = time.perf_counter() - t0 - compile_s
    timings["compile_s"] = compile_s

    step("processing the dive: depth, odometry, TSDF fusion, mesh")
    t0 = time.perf_counter()
    result = run_process(
        session,
        ProcessConfig(out_dir=out / "process", map=MapConfig(voxel_m=config.voxel_m),
                      executor=ExecutorConfig(workers=config.workers),
                      depth=DepthConfig(engine=config.engine), report=False, fresh=True),
        progress=bars,
    )
    timings["process_s"] = time.perf_counter() - t0
    timings["total_s"] = time.perf_counter() - t_all
    summary: dict[str, Any] = {
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(config).items()},
        "poses": "sea3d odometry",
        "depth_check": pair_summary,
        "process": result.summary,
        "timings_s": timings,
        "files": {"demo_report": str(out / "report.html"),
                  "demo_summary": str(out / "summary.json"),
                  **{k: str(v) for k, v in result.files.items() if Path(v).exists()}},
        "note": "compile_s is the one-off compilation (or cache load) of the matcher's kernels "
                "in this process; the worker processes' own is in process.one_off_s",
    }
    write_summary_json(out / "summary.json", summary, default=str)
    intro = _intro_html(config, summary)
    report = write_process_report(out / "report.html", result, title="sea3d demo: a simulated "
                                  "dive, processed", intro_html=intro, sections_html=pair_html)
    return DemoResult(out_dir=out, report_html=report, summary=summary)


def _intro_html(config: DemoConfig, summary: dict[str, Any]) -> str:
    import html

    t = summary["timings_s"]
    return (
        f"<p>A {config.frames}-frame lawnmower survey of the simulator's "
        f"<b>{html.escape(config.scene)}</b> scene in <b>{html.escape(config.water)}</b> water, "
        f"the paper's rig ({config.size_px[0]}x{config.size_px[1]}, baseline 107 mm) behind "
        f"<b>{html.escape(config.port)}</b> ports, stereo by the <b>{html.escape(config.engine)}"
        f"</b> engine; poses from <b>{html.escape(summary['poses'])}</b>.</p>"
        f"<p class=\"note\">Wall time: dive {t['simulate_s']:.0f} s, one-pair check "
        f"{t['depth_check_s']:.0f} s (plus {t['compile_s']:.1f} s one-off kernel compilation), "
        f"processing {t['process_s']:.0f} s; {t['total_s']:.0f} s in all.</p>"
    )


def _depth_check(config: DemoConfig, rig: Any, session: Path, out: Path
                 ) -> tuple[str, dict[str, Any], float]:
    """The first pair's depth against ground truth (HTML fragment, figures, compile seconds)."""
    from sea3d.eval.depth_gt import depth_error_map, point_depth_errors
    from sea3d.io.depth_files import write_depth
    from sea3d.io.session import open_session
    from sea3d.pipeline.report import depth_check_html
    from sea3d.refraction.presets import paper_rig
    from sea3d.stereo.depth import disparity_to_depth
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    depth_cfg = DepthConfig(engine=config.engine, max_disparity_px=_scaled_disparity(config))
    stereo = StereoDepth(rig, depth_cfg)
    compile_s = stereo.warm_up()
    with open_session(session) as s:
        t_ns = int(s.stamps("left")[0])
        left = s.image("left", 0, by="index")
        right = s.image("right", 0, by="index")
    gt_depth = GroundTruth(ground_truth_dir(session, folder=True)).read_depth(t_ns)
    maps = stereo.maps
    depth = stereo.compute(left, right)
    errors = point_depth_errors(depth.points_left, rig.left, gt_depth)
    # Baseline: the best-fitting pinhole in water (z = f B / d), no refraction correction.
    z_pin = disparity_to_depth(depth.disparity_px, maps.focal_px, maps.baseline_m)
    ok = np.isfinite(z_pin) & (z_pin <= stereo.max_depth_m)
    vv, uu = np.nonzero(ok)
    zz = z_pin[ok].astype(np.float64)
    rect_pts = np.stack(
        [(uu - maps.cx_px) * zz / maps.focal_px, (vv - maps.cy_px) * zz / maps.focal_px, zz], axis=1
    )
    baseline = point_depth_errors(rect_pts @ maps.R_rect_left_left, rig.left, gt_depth)
    ignored = None
    if config.port != "none":
        # What a user gets by taking the in-air calibration underwater and ignoring the ports.
        rig_air = paper_rig("none").scaled(*config.size_px)
        depth_air = StereoDepth(rig_air, depth_cfg).compute(left, right)
        ignored = point_depth_errors(depth_air.points_left, rig.left, gt_depth)
    summary: dict[str, Any] = {
        "t_ns": t_ns,
        "image_size_px": list(config.size_px),
        "max_disparity_px": stereo.max_disparity_px,
        "depth_range_m": list(stereo.depth_range_m),
        "valid_fraction": float(np.isfinite(depth.depth_m).mean()),
        "points": len(depth.points_left),
        "refraction_corrected": errors.as_dict(),
        "pinhole_in_water_baseline": baseline.as_dict(),
        "ports_ignored_baseline": ignored.as_dict() if ignored is not None else None,
        "virtual_pinhole_rms_px": (
            maps.report_left.rms_px if maps.report_left is not None else 0.0
        ),
        "timings_s": depth.timings_s,
    }
    write_depth(out / "pair_depth_m.npy", depth.depth_m)
    fragment = depth_check_html(
        left=left,
        right=right,
        disparity_rgb=_colorize(depth.disparity_px, 0.0, float(stereo.max_disparity_px)),
        disparity_range=(0.0, float(stereo.max_disparity_px)),
        depth_rgb=_colorize(depth.depth_m, 0.5, 5.0),
        depth_range_m=(0.5, 5.0),
        error_rgb=_colorize(depth_error_map(depth, gt_depth), -0.05, 0.05),
        error_range_m=(-0.05, 0.05),
        cloud_rgb=_cloud_picture(depth.points_left, depth.colors_rgb),
        summary=summary,
    )
    return fragment, summary, compile_s


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
