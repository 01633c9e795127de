"""Whole simulated sessions, single stereo pairs and calibration sets, with ground truth.

- :func:`simulate_pair`: one stereo pair of a scene from a pose, with the left view's ground truth.
- :func:`render_calibration_set`: images of a checkerboard or ChArUco board at varied poses
  (0.5-2.5 m, tilted, spread over the image) and the true ``T_left_board`` of each view.
- :func:`simulate_survey`: a trajectory through a scene: stereo frames at the camera rate, IMU at
  200 Hz, echosounder at 10 Hz, written through any writer with ``write_stereo``, ``write_imu``
  and ``write_sonar`` (:class:`sea3d.io.session.SessionWriter`), plus ground truth in ``gt/``.

Ground truth on disk (``gt/``, written by :func:`simulate_survey` through
:mod:`sea3d.io.ground_truth`, which owns the folder rule and the file names):

- ``depth/<t_ns>.tiff``: left depth, float32 metres along the left camera's z axis, NaN where
  nothing is hit, bit for bit (TIFF, deflate with the floating-point predictor: about 2.6 times
  smaller than ``.npy``; read it with :func:`read_gt_depth`, ``tifffile`` or ``cv2.imread``);
  ``object_id/<t_ns>.png``: 16-bit object id + 1 (0 = nothing);
- ``poses_left.tum`` and ``poses_body.tum``: ``t x y z qx qy qz qw`` (t in seconds), poses
  ``T_world_left`` and ``T_world_body``;
- ``scene.ply``: the scene mesh (world frame, vertex colours);
- ``sim.json``: scene, water, seed, rates, ``T_body_left``, ``T_body_sonar``, IMU biases file,
  and ``water_model``: the water's coefficients (``beta_D_per_m``, ``beta_B_per_m``,
  ``B_inf_rgb`` per R, G, B);
- with ``SurveyConfig.clean_reference``: ``clean/left/<t_ns>.png`` and ``clean/right/<t_ns>.png``,
  the same views without water and with the same sensor noise (:mod:`sea3d.sim.reference`),
  exposed not to clip (the exposure is in ``sim.json``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import FloatArray
from sea3d.calib.targets import BoardSpec
from sea3d.errors import SimulationError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.rig import ImuSpec, SonarSpec, StereoRig
from sea3d.geometry.se3 import invert_T
from sea3d.io.disk_space import disk_free_bytes
from sea3d.io.ground_truth import GroundTruth, write_calibration_truth, write_gt_depth
from sea3d.io.image_files import image_writer
from sea3d.io.trajectory_files import write_tum
from sea3d.sim.config import CalibrationSetConfig, SurveyConfig
from sea3d.sim.motion import (
    GRAVITY_WORLD,
    HandHeld,
    ImuNoise,
    ImuSamples,
    Lawnmower,
    Mount,
    Orbit,
    Trajectory,
    imu_samples,
    lanes_within,
    make_trajectory,
    poses,
    sample_times_ns,
)
from sea3d.sim.optics import Imaging
from sea3d.sim.reference import unclipped_exposure, water_model_dict
from sea3d.sim.render import Renderer, ViewTruth
from sea3d.sim.scene import Scene, load_scene, make_board, sim_board

__all__ = [
    "CalibrationSet",
    "SurveyConfig",
    "SurveyResult",
    "render_calibration_set",
    "simulate_pair",
    "simulate_survey",
]

_log = logging.getLogger(__name__)

Image = NDArray[np.uint8]


class SessionSink(Protocol):
    """What :func:`simulate_survey` writes to (:class:`sea3d.io.session.SessionWriter`)."""

    def write_stereo(self, t_ns: int, left: Image, right: Image) -> None: ...

    def write_imu(self, t_ns: int, accel_mps2: Any, gyro_radps: Any) -> None: ...

    def write_sonar(self, t_ns: int, range_m: float, confidence: float = ...) -> None: ...


def in_air(rig: StereoRig) -> StereoRig:
    """The rig's bare pinhole cameras (ports removed): the rig as it sees in air."""
    return rig.in_air


def _imaging(water: str | Imaging | None) -> Imaging:
    if isinstance(water, Imaging):
        return water
    if water is None:
        return Imaging.clean()
    return Imaging.underwater(water)


def simulate_pair(
    rig: StereoRig,
    scene: Scene | str,
    T_world_left: FloatArray,
    water: str | Imaging | None = None,
    *,
    seed: int = 0,
    time_s: float = 0.0,
    supersample: int = 2,
    renderer: Renderer | None = None,
) -> tuple[Image, Image, ViewTruth]:
    """Render one stereo pair.

    Args:
        rig: the stereo rig (pinhole, dome- or flat-port cameras).
        scene: a :class:`Scene`, a built-in scene name or a scene YAML path.
        T_world_left: ``(4, 4)`` left camera pose.
        water: ``"none"``/None (clean), ``"clear"``, ``"coastal"``, ``"turbid"`` (every effect on)
            or an :class:`Imaging` for full control.
        seed: sensor-noise seed (the same seed gives the same images).
        time_s: scene time (caustics).
        supersample: rays per pixel along each axis.
        renderer: reuse a renderer of the same scene (keeps its camera-ray cache).

    Returns:
        ``(left, right, gt_left)``: two ``(H, W, 3)`` uint8 RGB images and the left ground truth.

    Raises:
        SimulationError: bad scene, water or pose.
    """
    sc = load_scene(scene) if isinstance(scene, str) else scene
    r = renderer or Renderer(sc, supersample=supersample)
    imaging = _imaging(water)
    rng = np.random.default_rng(seed)
    T_wl = np.asarray(T_world_left, dtype=np.float64)
    left = r.render(rig.left, T_wl, imaging, time_s=time_s, rng=rng)
    right = r.render(rig.right, T_wl @ rig.T_left_right, imaging, time_s=time_s, rng=rng)
    return left.image, right.image, left.gt


# ----------------------------------------------------------------------------------------------
# Calibration sets
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, eq=False)
class CalibrationSet:
    """Rendered calibration views.

    Attributes:
        lefts: list of ``(H, W, 3)`` uint8 RGB images.
        rights: list of ``(H, W, 3)`` uint8 RGB images.
        T_left_board: list of ``(4, 4)`` float64 true board poses in the left camera frame.
        t_ns: list of int stamps (views are 1 s apart).
        board: the board, a :class:`sea3d.calib.targets.BoardSpec`.
    """

    lefts: list[Image]
    rights: list[Image]
    T_left_board: list[FloatArray]
    t_ns: list[int]
    board: BoardSpec

    def __iter__(self) -> Iterator[Any]:
        """Unpack as ``lefts, rights, T_left_board = render_calibration_set(...)``."""
        return iter((self.lefts, self.rights, self.T_left_board))


def _board_outline(spec: BoardSpec) -> FloatArray:
    s = spec.square_m
    cols, rows = spec.corner_grid
    x0, x1, y0, y1 = -s, cols * s, -s, rows * s
    return np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=np.float64)


def _visible(
    cam: CameraModel, T_cam_board: FloatArray, pts_board: FloatArray, margin_px: float
) -> bool:
    p = pts_board @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    if np.any(p[:, 2] <= 0.05):
        return False
    uv, ok = cam.project(p)
    if not np.all(ok):
        return False
    return bool(
        np.all(
            (uv[:, 0] >= margin_px)
            & (uv[:, 0] <= cam.width - 1 - margin_px)
            & (uv[:, 1] >= margin_px)
            & (uv[:, 1] <= cam.height - 1 - margin_px)
        )
    )


def _random_rotation_towards(
    z_axis: FloatArray, tilt_max_rad: float, roll_max_rad: float, g: np.random.Generator
) -> FloatArray:
    """A rotation whose third column is ``z_axis`` tilted by up to ``tilt_max_rad`` and rolled."""
    z = z_axis / np.linalg.norm(z_axis)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z  # board x roughly along the camera's x
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R0 = np.stack([x, y, z], axis=1)
    tilt = g.uniform(0.0, tilt_max_rad)
    az = g.uniform(0.0, 2 * np.pi)
    axis = np.array([np.cos(az), np.sin(az), 0.0])
    Rt = cv2.Rodrigues(axis * tilt)[0]
    roll = g.uniform(-roll_max_rad, roll_max_rad)
    Rr = cv2.Rodrigues(np.array([0.0, 0.0, roll]))[0]
    return np.asarray(R0 @ Rt @ Rr, dtype=np.float64)


def render_calibration_set(
    rig: StereoRig,
    board: BoardSpec | str,
    views: int,
    medium: str = CalibrationSetConfig.medium,
    seed: int = CalibrationSetConfig.seed,
    *,
    distance_range_m: tuple[float, float] = CalibrationSetConfig.distance_range_m,
    tilt_max_deg: float = 40.0,
    water: str | Imaging | None = None,
    supersample: int = 6,
    margin_px: float = 8.0,
    progress: Callable[[int], None] | None = None,
) -> CalibrationSet:
    """Render a calibration set of a board at random poses seen fully by both cameras.

    The board frame is that of :mod:`sea3d.calib.targets`: origin at the first inner corner, x
    along the first count, y along the second, z into the board. Poses: distance uniform in
    ``distance_range_m``, centre aimed at a random point of a 4x4 grid over the image (so views
    cover the whole image), tilted up to ``tilt_max_deg`` and rolled up to 30 degrees.

    Args:
        rig: the stereo rig.
        board: a :class:`sea3d.calib.targets.BoardSpec` or a board string as
            :func:`sea3d.calib.targets.parse_board` reads it (``checkerboard:9x6:40mm`` counts
            inner corners, ``charuco:5x7:40mm:30mm`` squares): checkerboard or ChArUco.
        views: number of views.
        medium: ``"water"`` (the rig's cameras as given, ports included) or ``"air"`` (the
            bare pinholes, ports removed: the in-air calibration the workflow starts with).
        seed: chooses the poses (and sensor noise if ``water`` has any).
        distance_range_m: board distances, metres.
        tilt_max_deg: largest tilt away from facing the camera.
        water: image effects (default clean).
        supersample: rays per pixel along each axis.
        margin_px: every board corner (outer squares included) stays this far inside both images.
        progress: called with 1 after each view.

    Returns:
        :class:`CalibrationSet`.

    Raises:
        SimulationError: bad board text, a board kind other than checkerboard or ChArUco,
            ``views < 1``, unknown medium, or no pose fits the image.
    """
    if views < 1:
        raise SimulationError(f"views must be >= 1, got {views}")
    if medium not in ("water", "air"):
        raise SimulationError(f"medium must be 'water' or 'air', got {medium!r}")
    spec = sim_board(board)
    cols, rows = spec.corner_grid
    cams = rig if medium == "water" else in_air(rig)
    g = np.random.default_rng(seed)
    # The board sits at the world origin; the cameras move (one scene, one ray cache).
    scene = Scene(name=f"calibration_{spec.kind}", surface_z_m=1e3)
    scene.add(make_board(spec, np.eye(4)))
    renderer = Renderer(scene, supersample=supersample)
    # Clean calibration images are lit evenly (a diffuse light box), so corners have full contrast.
    imaging = Imaging(ambient=1.0) if water is None or water == "none" else _imaging(water)
    outline = _board_outline(spec)
    centre_board = np.array([(cols - 1) * spec.square_m / 2, (rows - 1) * spec.square_m / 2, 0.0])
    T_right_left = invert_T(rig.T_left_right)
    grid = [(i, j) for j in range(4) for i in range(4)]
    lefts, rights, poses_lb, stamps = [], [], [], []
    for k in range(views):
        T_lb = None
        for _attempt in range(400):
            gi, gj = grid[k % len(grid)] if _attempt == 0 else grid[int(g.integers(len(grid)))]
            u = (gi + g.uniform(0.1, 0.9)) / 4 * cams.width
            v = (gj + g.uniform(0.1, 0.9)) / 4 * cams.height
            d = g.uniform(*distance_range_m)
            ray = cams.left.unproject(np.array([[u, v]]))
            if not ray.valid[0]:
                continue
            target = ray.at(np.array([d]))[0]
            R = _random_rotation_towards(
                ray.directions[0], np.deg2rad(tilt_max_deg), np.deg2rad(30.0), g
            )
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = target - R @ centre_board
            if _visible(cams.left, T, outline, margin_px) and _visible(
                cams.right, T_right_left @ T, outline, margin_px
            ):
                T_lb = T
                break
        if T_lb is None:
            raise SimulationError(
                f"no board pose at {distance_range_m} m keeps the whole board {spec.name} "
                f"inside both images; "
                f"use a smaller board or larger distances"
            )
        T_world_left = invert_T(T_lb)  # world = board frame
        rng = np.random.default_rng(seed * 1000 + k)
        lv = renderer.render(cams.left, T_world_left, imaging, rng=rng)
        rv = renderer.render(cams.right, T_world_left @ rig.T_left_right, imaging, rng=rng)
        lefts.append(lv.image)
        rights.append(rv.image)
        poses_lb.append(T_lb)
        stamps.append(int(k * 1_000_000_000))
        if progress is not None:
            progress(1)
    return CalibrationSet(
        lefts=lefts, rights=rights, T_left_board=poses_lb, t_ns=stamps, board=spec
    )


def write_calibration_set(cal: CalibrationSet, out: Path) -> None:
    """Write ``left/<t_ns>.png``, ``right/<t_ns>.png`` and ``gt/boards.json``.

    Raises:
        SimulationError: if the folder cannot be written.
    """
    try:
        for sub in ("left", "right", "gt"):
            (out / sub).mkdir(parents=True, exist_ok=True)
        write = image_writer(out, SimulationError)
        for t, li, ri in zip(cal.t_ns, cal.lefts, cal.rights, strict=True):
            write(f"left/{t}.png", li)
            write(f"right/{t}.png", ri)
        spec = cal.board
        boards = [
            {"t_ns": t, "T_left_board": T.tolist()}
            for t, T in zip(cal.t_ns, cal.T_left_board, strict=True)
        ]
        meta = {
            "board": {
                "kind": spec.kind,
                # inner corners (ChArUco too), as this file has always held
                "cols": spec.corner_grid[0],
                "rows": spec.corner_grid[1],
                "square_m": spec.square_m,
                "marker_m": spec.marker_m,
                # the simulator's old checkerboards carried the ChArUco default; kept so that
                # readers of this file see what they always did
                "dictionary": spec.dictionary or "DICT_6X6_250",
            }
        }
        write_calibration_truth(out, boards, meta)
    except OSError as err:
        raise SimulationError(f"cannot write calibration set to {out}: {err}") from err


# ----------------------------------------------------------------------------------------------
# Surveys
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, eq=False)
class SurveyResult:
    """What :func:`simulate_survey` produced.

    Attributes:
        frame_t_ns: ``(F,)`` int64 frame stamps.
        T_world_left: ``(F, 4, 4)`` true left camera poses.
        T_world_body: ``(F, 4, 4)`` true body poses.
        imu_count: IMU samples written.
        sonar_count: echosounder samples written.
    """

    frame_t_ns: NDArray[np.int64]
    T_world_left: FloatArray
    T_world_body: FloatArray
    imu_count: int
    sonar_count: int


def _scene_focus(scene: Scene) -> tuple[tuple[float, float, float], float]:
    for obj in scene.objects:
        if obj.name == "aruco_cube":
            c = obj.T_world_object[:3, 3]
            floor = (
                float(np.asarray(scene.floor_height(np.array([c[0]]), np.array([c[1]])))[0])
                if scene.floor_height
                else c[2]
            )
            return (float(c[0]), float(c[1]), float(c[2])), floor
    lo, hi = scene.bounds_m()
    c = (lo + hi) / 2
    floor = (
        float(np.asarray(scene.floor_height(np.array([c[0]]), np.array([c[1]])))[0])
        if scene.floor_height
        else float(lo[2])
    )
    return (float(c[0]), float(c[1]), floor), floor


def default_trajectory(scene: Scene, config: SurveyConfig) -> Trajectory:
    """The configured trajectory kind, sized to the scene: it stays inside the scene's footprint
    and under its water surface, and keeps the paper rig's 0.6 m minimum stereo range in mind
    where the scene allows (the tank does not quite)."""
    focus, floor = _scene_focus(scene)
    lo, hi = scene.bounds_m()
    extent = float(min(hi[0] - lo[0], hi[1] - lo[1]))
    water_m = float(scene.surface_z_m - floor)
    duration = max((config.frames - 1) / config.fps, 1.0 / config.fps)
    fx, fy, fz = focus
    kind = config.trajectory
    if kind == "lawnmower":
        width = min(3.0, 0.5 * extent)
        height = min(1.5, 0.7 * water_m)
        # The lanes stop before the cameras' view (where the tilted optical axis meets the floor
        # ahead, and a quarter of the height beyond) would leave the scene; the survey then
        # flies them back.
        reach = height / np.tan(np.radians(max(config.tilt_deg(), 10.0))) + 0.25 * height
        y0 = fy - width / 3
        lanes = lanes_within(y0, float(hi[1]) - min(reach, 0.35 * extent), width / 6)
        return Lawnmower(
            center_m=(fx, y0),
            z_m=floor + height,
            width_m=width,
            lane_spacing_m=width / 6,
            speed_mps=0.1 * width,
            duration_s=duration,
            lanes=lanes,
        )
    if kind == "orbit":
        return Orbit(
            target_m=(fx, fy, fz),
            radius_m=min(1.2, 0.3 * extent),
            height_m=min(0.8, 0.55 * water_m),
            period_s=max(duration, 20.0),
            duration_s=duration,
            camera_tilt_deg=config.tilt_deg(),
        )
    if kind in ("handheld", "hand-held"):
        off = min(0.9, 0.3 * extent)
        return HandHeld(
            start_m=(fx - off, fy - off, floor + min(1.0, 0.6 * water_m)),
            velocity_mps=(0.05 * off, 0.05 * off, 0.0),
            yaw_deg=45.0,
            pitch_deg=20.0,
            shake_m=0.04 * min(1.0, off / 0.9),
            duration_s=duration,
            seed=config.seed,
        )
    return make_trajectory(kind, duration_s=duration)  # raises for an unknown kind


@dataclass(frozen=True, kw_only=True)
class SurveyCost:
    """What a simulated survey will write and take, estimated before it starts.

    Attributes:
        image_bytes: the stereo images as lossless PNG (the session writer's default).
        gt_bytes: the ground truth (depth TIFFs and object-id PNGs).
        seconds: wall time of the rendering on two idle cores (more when other work shares
            them).
        startup_seconds: the fixed cost before the first frame (imports, the scene), plus the
            one-off compilation of the renderer when its compiled kernels are not cached yet.
        compiles: whether ``startup_seconds`` includes that compilation.
    """

    image_bytes: float
    gt_bytes: float
    seconds: float
    startup_seconds: float = 0.0
    compiles: bool = False

    @property
    def total_seconds(self) -> float:
        return self.seconds + self.startup_seconds

    @property
    def total_bytes(self) -> float:
        return self.image_bytes + self.gt_bytes


# Per pixel of one view, measured on the lake scene with benchmarks/bench_sim_storage.py
# (docs/simulator.md): PNG (zlib level 1) of the images with and without the water model's
# sensor noise, and the ground truth; wall seconds per pair per pixel on two idle cores
# (1.5 s per 1920x1080 pair with every effect on, 1.0 s clean: docs/simulator.md, Speed).
_PNG_BYTES_PER_PX = {"none": 1.25, "clear": 1.75, "coastal": 1.75, "turbid": 1.75}
_GT_BYTES_PER_PX = 1.5
_SECONDS_PER_PAIR_PX = {
    "none": 1.0 / 2.07e6,
    "clear": 1.5 / 2.07e6,
    "coastal": 1.5 / 2.07e6,
    "turbid": 1.5 / 2.07e6,
}
# Fixed costs, measured with `sea3d sim --frames 1 --size 320x180` (CPU seconds, this 2-core VM):
# about 4-5 s with the renderer's numba kernels cached, 41 s on a first run that compiles them.
_STARTUP_S = 4.0
_COMPILE_S = 40.0


def check_disk_room(targets: Iterable[Path], need_bytes: float) -> None:
    """Refuse a run the disk cannot hold (with a 10 % margin): each of ``targets`` (the session,
    its ground truth), or its nearest existing parent, must have ``1.1 * need_bytes`` free.

    Raises:
        SimulationError: too little free space, naming the place and both sizes.
    """
    from sea3d._text import size_text

    for target in set(targets):
        probe = Path(target)
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        free = disk_free_bytes(probe)
        if need_bytes * 1.1 > free:
            raise SimulationError(
                f"the run needs about {size_text(need_bytes)} but {probe} has "
                f"{size_text(free)} free; use fewer frames or a smaller image size"
            )


def renderer_is_compiled() -> bool:
    """Whether numba's on-disk cache holds the renderer's kernels (``sim/_kernels.py``), so a
    run starts without compiling them: index files beside the module or under
    ``NUMBA_CACHE_DIR``."""
    import os

    from sea3d.sim import _kernels

    module = Path(_kernels.__file__).resolve()
    places = [module.parent / "__pycache__"]
    if os.environ.get("NUMBA_CACHE_DIR"):
        root = Path(os.environ["NUMBA_CACHE_DIR"])
        places.append(root / module.parent.relative_to(module.anchor))
        places.append(root)
    return any(any(place.glob(f"{module.stem}.*.nbi")) for place in places if place.is_dir())


def estimate_survey_cost(
    width: int, height: int, config: SurveyConfig, *, ground_truth: bool = True
) -> SurveyCost:
    """Disk and time a survey of ``config.frames`` stereo frames of ``width x height`` will
    take (an estimate from the measured rates above; the scene changes it by tens of percent),
    with the fixed start-up and, when the renderer is not compiled yet, its compilation.
    """
    px = float(width * height)
    water = config.water if config.water in _PNG_BYTES_PER_PX else "coastal"
    compiled = renderer_is_compiled()
    return SurveyCost(
        image_bytes=2 * px * _PNG_BYTES_PER_PX[water] * config.frames,
        gt_bytes=px * _GT_BYTES_PER_PX * config.frames if ground_truth else 0.0,
        seconds=px
        * _SECONDS_PER_PAIR_PX[water]
        * config.frames
        * max(1.0, config.supersample / 2.0) ** 0.5,
        startup_seconds=_STARTUP_S + (0.0 if compiled else _COMPILE_S),
        compiles=not compiled,
    )


def _write_clean_reference(
    renderer: Renderer,
    rig: StereoRig,
    T_wl: FloatArray,
    imaging: Imaging,
    time_s: float,
    noise_state: Mapping[str, Any],
    gt_dir: Path,
    t_ns: int,
    exposure: float | None,
) -> float:
    """Render one frame without water with the frame's own noise draws; the exposure is chosen
    on the first frame (not to clip) and kept for the whole survey."""
    clean = imaging.without_water()
    quiet = clean.without_sensor_noise()
    lv = renderer.render(rig.left, T_wl, quiet, time_s=time_s)
    rv = renderer.render(rig.right, T_wl @ rig.T_left_right, quiet, time_s=time_s)
    e = unclipped_exposure(lv.radiance, clean) if exposure is None else exposure
    sensor = replace(clean, exposure=e)
    rng = np.random.default_rng()
    rng.bit_generator.state = noise_state
    left = sensor.sensor(lv.radiance, rng)
    right = sensor.sensor(rv.radiance, rng)
    try:
        GroundTruth(gt_dir).write_clean_pair(t_ns, left, right)
    except OSError as err:
        raise SimulationError(f"cannot write clean reference to {gt_dir}: {err}") from err
    return e


def survey_mount(rig: StereoRig, config: SurveyConfig) -> Mount:
    """Where the simulated survey puts its sensors: the rig's own IMU and echosounder when it has
    them, otherwise :meth:`Mount.default` for the rig's baseline and the configured tilt."""
    if rig.imu is None:
        default = Mount.default(baseline_m=rig.baseline_m, camera_tilt_deg=config.tilt_deg())
        if rig.sonar is None:
            return default
        T_body_left = default.T_body_left
    else:
        T_body_left = rig.imu.T_imu_left
    if rig.sonar is not None:
        T_body_sonar = T_body_left @ rig.sonar.T_left_sonar
    else:
        T_body_sonar = Mount.default(baseline_m=rig.baseline_m).T_body_sonar
    return Mount(T_body_left=T_body_left, T_body_sonar=T_body_sonar)


def survey_imu_noise(rig: StereoRig) -> ImuNoise:
    """The IMU noise the survey simulates: the rig's figures when it has an IMU, else MTi-300."""
    if rig.imu is None:
        return ImuNoise.mti300()
    return ImuNoise(
        gyro_noise_density_radps_sqrthz=rig.imu.gyro_noise_density_radps_sqrthz,
        gyro_bias_rw_radps_sqrts=rig.imu.gyro_random_walk_radps_sqrts,
        accel_noise_density_mps2_sqrthz=rig.imu.accel_noise_density_mps2_sqrthz,
        accel_bias_rw_mps2_sqrts=rig.imu.accel_random_walk_mps2_sqrts,
    )


def with_survey_sensors(
    rig: StereoRig, config: SurveyConfig, mount: Mount | None = None
) -> StereoRig:
    """The rig as the simulated session describes it: with the IMU (``T_left_imu``, rate, the
    simulated noise figures, gravity 9.81) and the echosounder (``T_left_sonar``, an ideal single
    ray: ``beam_deg`` 0) that :func:`simulate_survey` simulates, so the session is
    self-describing. Noise figures are given even with ``imu_noise=False`` (an estimator needs
    some weight; ``gt/sim.json`` says the readings were exact)."""
    import dataclasses

    m = mount or survey_mount(rig, config)
    noise = survey_imu_noise(rig)
    imu = ImuSpec(
        T_left_imu=invert_T(m.T_body_left),
        rate_hz=config.imu_rate_hz,
        gyro_noise_density_radps_sqrthz=noise.gyro_noise_density_radps_sqrthz,
        gyro_random_walk_radps_sqrts=noise.gyro_bias_rw_radps_sqrts,
        accel_noise_density_mps2_sqrthz=noise.accel_noise_density_mps2_sqrthz,
        accel_random_walk_mps2_sqrts=noise.accel_bias_rw_mps2_sqrts,
        gravity_mps2=float(-GRAVITY_WORLD[2]),
    )
    sonar = SonarSpec(
        T_left_sonar=invert_T(m.T_body_left) @ m.T_body_sonar,
        beam_deg=rig.sonar.beam_deg if rig.sonar is not None else 0.0,
    )
    return dataclasses.replace(rig, imu=imu, sonar=sonar)


def _sonar_ranges(
    renderer: Renderer, traj: Trajectory, mount: Mount, config: SurveyConfig, end_ns: int
) -> tuple[NDArray[np.int64], FloatArray]:
    """The echosounder's stamps up to ``end_ns`` and its noisy ranges (m, NaN = no hit)."""
    sonar_t = sample_times_ns(end_ns * 1e-9, config.sonar_rate_hz)
    T_wb_sonar = poses(traj, sonar_t.astype(np.float64) * 1e-9) @ mount.T_body_sonar
    hits = renderer.cast(T_wb_sonar[:, :3, 3], -T_wb_sonar[:, :3, 2])
    srng = np.random.default_rng(config.seed + 2)
    sonar_range = hits.t_m * (
        1.0 + config.sonar_noise_fraction * srng.standard_normal(hits.t_m.shape)
    )
    return sonar_t, sonar_range


def _write_ground_truth(
    gt: GroundTruth,
    gt_dir: Path,
    scene: Scene,
    config: SurveyConfig,
    mount: Mount,
    imaging: Imaging,
    frame_t: NDArray[np.int64],
    T_wl: FloatArray,
    T_wb: FloatArray,
    imu: ImuSamples,
    n_imu: int,
) -> None:
    """Write the survey-wide ground truth: poses, scene mesh, IMU biases and ``sim.json``.

    Raises:
        SimulationError: ``gt_dir`` cannot be written.
    """
    try:
        gt.depth_folder.mkdir(parents=True, exist_ok=True)
        gt.object_id_folder.mkdir(parents=True, exist_ok=True)
        write_tum(gt.poses_left_path, frame_t.tolist(), T_wl)
        write_tum(gt.poses_body_path, frame_t.tolist(), T_wb)
        gt.write_scene_mesh(scene.combined_mesh())
        gt.write_imu_bias(imu.t_ns[:n_imu], imu.accel_bias_mps2[:n_imu],
                          imu.gyro_bias_radps[:n_imu])
        meta = {
            "scene": scene.name,
            "water": config.water,
            "seed": config.seed,
            "frames": config.frames,
            "fps": config.fps,
            "imu_rate_hz": config.imu_rate_hz,
            "sonar_rate_hz": config.sonar_rate_hz,
            "trajectory": config.trajectory,
            "T_body_left": mount.T_body_left.tolist(),
            "T_body_sonar": mount.T_body_sonar.tolist(),
            "imu_noise": config.imu_noise,
            "depth": "depth/<t_ns>.tiff float32 m along the left camera z axis, NaN = no "
            "hit (TIFF, deflate, floating-point predictor: lossless)",
            "object_id": "object_id/<t_ns>.png uint16, object index + 1, 0 = no hit",
            "objects": [o.name for o in scene.objects],
            "water_model": water_model_dict(imaging),
        }
        if config.clean_reference:
            gt.clean_folder("left").mkdir(parents=True, exist_ok=True)
            gt.clean_folder("right").mkdir(parents=True, exist_ok=True)
            meta["clean_reference"] = (
                "clean/{left,right}/<t_ns>.png: the same views without water, same sensor "
                "noise, exposure clean_reference_exposure"
            )
        gt.write_meta(meta)
    except OSError as err:
        raise SimulationError(f"cannot write ground truth to {gt_dir}: {err}") from err


def simulate_survey(
    scene: Scene,
    rig: StereoRig,
    config: SurveyConfig,
    writer: SessionSink,
    gt_dir: Path | None = None,
    *,
    trajectory: Trajectory | None = None,
    mount: Mount | None = None,
    progress: Callable[[int], None] | None = None,
) -> SurveyResult:
    """Fly a trajectory through a scene and write the session and its ground truth.

    Streams are written in time order: IMU and echosounder samples up to each frame's stamp, then
    the frame. The first frame is at t = 0.

    Args:
        scene: the scene.
        rig: the stereo rig.
        config: :class:`SurveyConfig`.
        writer: a session writer (``write_stereo``, ``write_imu``, ``write_sonar``).
        gt_dir: folder for ground truth (created), or None for none.
        trajectory: overrides the configured trajectory.
        mount: sensor placement on the body (default :func:`survey_mount`: the rig's own IMU
            and echosounder if it has them, else :meth:`Mount.default` for the rig).
        progress: called with 1 after each frame.

    Returns:
        :class:`SurveyResult`.

    Raises:
        SimulationError: bad configuration or an unwritable ``gt_dir``.
    """
    traj = trajectory or default_trajectory(scene, config)
    mount = mount or survey_mount(rig, config)
    imaging = _imaging(config.water if config.water != "none" else None)
    rng = np.random.default_rng(config.seed)
    renderer = Renderer(scene, supersample=config.supersample)
    frame_t = sample_times_ns((config.frames - 1) / config.fps, config.fps)[: config.frames]
    end_ns = int(frame_t[-1])
    # The noise model needs the sample spacing, so it is drawn over at least two samples; only
    # those up to the last frame are written (one sample for a one-frame survey).
    imu_t = sample_times_ns(max(end_ns * 1e-9, 1.0 / config.imu_rate_hz), config.imu_rate_hz)
    imu = imu_samples(
        traj,
        imu_t,
        noise=survey_imu_noise(rig) if config.imu_noise else None,
        rng=np.random.default_rng(config.seed + 1),
    )
    n_imu = int(np.searchsorted(imu_t, end_ns, side="right"))
    imu_t = imu_t[:n_imu]
    sonar_t, sonar_range = _sonar_ranges(renderer, traj, mount, config, end_ns)
    T_wb = poses(traj, frame_t.astype(np.float64) * 1e-9)
    T_wl = T_wb @ mount.T_body_left
    gt = None
    if gt_dir is not None:
        gt = GroundTruth(Path(gt_dir))
        _write_ground_truth(gt, gt_dir, scene, config, mount, imaging, frame_t, T_wl, T_wb, imu,
                            n_imu)
    i_imu = 0
    i_sonar = 0
    ref_exposure: float | None = None
    for k, t_ns in enumerate(frame_t):
        while i_imu < len(imu_t) and imu_t[i_imu] <= t_ns:
            writer.write_imu(int(imu_t[i_imu]), imu.accel_mps2[i_imu], imu.gyro_radps[i_imu])
            i_imu += 1
        while i_sonar < len(sonar_t) and sonar_t[i_sonar] <= t_ns:
            hit = bool(np.isfinite(sonar_range[i_sonar]))
            writer.write_sonar(
                int(sonar_t[i_sonar]),
                float(sonar_range[i_sonar]) if hit else float("nan"),
                1.0 if hit else 0.0,
            )
            i_sonar += 1
        time_s = float(t_ns) * 1e-9
        noise_state = rng.bit_generator.state
        lv = renderer.render(rig.left, T_wl[k], imaging, time_s=time_s, rng=rng)
        rv = renderer.render(rig.right, T_wl[k] @ rig.T_left_right, imaging, time_s=time_s, rng=rng)
        writer.write_stereo(int(t_ns), lv.image, rv.image)
        if config.clean_reference and gt_dir is not None:
            ref_exposure = _write_clean_reference(
                renderer, rig, T_wl[k], imaging, time_s, noise_state, gt_dir, int(t_ns),
                ref_exposure,
            )
        if gt is not None:
            write_gt_depth(gt.new_depth_path(int(t_ns)), lv.gt.depth_m)
            gt.write_object_id(int(t_ns), (lv.gt.object_id + 1).astype(np.uint16))
        if progress is not None:
            progress(1)
    if config.clean_reference and gt is not None and ref_exposure is not None:
        meta = gt.read_meta()
        meta["clean_reference_exposure"] = ref_exposure
        gt.write_meta(meta)
    return SurveyResult(
        frame_t_ns=frame_t,
        T_world_left=T_wl,
        T_world_body=T_wb,
        imu_count=i_imu,
        sonar_count=i_sonar,
    )


__all__ += [
    "SurveyCost",
    "check_disk_room",
    "default_trajectory",
    "estimate_survey_cost",
    "in_air",
    "survey_imu_noise",
    "survey_mount",
    "with_survey_sensors",
    "write_calibration_set",
]


def survey_fold_note(scene: Scene, config: SurveyConfig) -> str | None:
    """A lawnmower longer than one pass over the scene flies its lanes again: the sentence
    that says so, with the frames one pass holds (None when the survey does not fold)."""
    traj = default_trajectory(scene, config)
    if not isinstance(traj, Lawnmower) or traj.pass_s is None:
        return None
    pass_frames = round(traj.pass_s * config.fps)
    if config.frames <= pass_frames:
        return None
    return (f"{scene.name} holds {traj.lanes} lanes of this survey, {pass_frames} frames at "
            f"{config.fps:g} fps; after that the survey turns back over the same lanes rather "
            "than leave the scene")


def _remove_created(path: Path, existed: bool) -> None:
    """Remove an output this run created (a session without a single frame, its ground truth)."""
    import shutil

    if existed or not path.exists():
        return
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def simulate_session(
    scene: Scene,
    rig: StereoRig,
    config: SurveyConfig,
    out: Path,
    gt_dir: Path,
    *,
    format: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> SurveyResult:
    """:func:`simulate_survey` into a session file or folder (:class:`~sea3d.io.session.
    SessionWriter`) whose stored rig carries the simulated IMU and echosounder.

    A run that stops before its first frame (an error, Ctrl-C) removes the session and ground
    truth it created; once frames are written they are kept, closed properly by the writer.

    Args:
        out: the session (``.mcap`` or a folder).
        gt_dir: the ground-truth folder (:func:`sea3d.io.ground_truth.ground_truth_dir`).
        format: ``mcap`` or ``folder`` (default from ``out``).
        progress: called with 1 after each frame.

    Raises:
        SimulationError, SessionWriteError: as :func:`simulate_survey` and the writer.
    """
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter, layout_of

    fmt = format or layout_of(out)
    mount = survey_mount(rig, config)
    session_rig = with_survey_sensors(rig, config, mount)  # the IMU and echosounder simulated
    existed = {path: path.exists() for path in (Path(out), Path(gt_dir))}
    frames_written = 0

    def advance(n: int) -> None:
        nonlocal frames_written
        frames_written += n
        if progress is not None:
            progress(n)

    try:
        with SessionWriter(out, format=fmt, rig_yaml=rig_to_yaml(session_rig)) as writer:
            return simulate_survey(scene, rig, config, writer, Path(gt_dir), mount=mount,
                                   progress=advance)
    except BaseException:
        if frames_written == 0:
            for path, was in existed.items():
                _remove_created(path, was)
        raise


__all__ += ["simulate_session", "survey_fold_note"]
