"""Odometry of a whole recording, one frame at a time: ``sea3d odometry SESSION`` and
``sea3d odometry rgbd``.

This module wires the parts: a frame source (a sea3d session, an EuRoC folder, or RGB-D image
files), depth per frame (:class:`sea3d.odometry.observe.Observer`), the odometry, and the
trajectory with its summary. ``sea3d process`` does the same with depth in parallel workers.

Bad input is checked before anything runs, and every decision is said in ``notes``: a session
without IMU samples or a rig without an IMU block runs visual-only; IMU stamps that do not
overlap the camera's disable the IMU; stamps out of order are sorted by the reader; dropped
frames are counted as gaps; no stored rig and no ``--rig`` is an error naming the session.
"""

from __future__ import annotations

import logging
import os
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError, OdometryError
from sea3d.geometry.rig import ImuSpec, StereoRig
from sea3d.odometry.config import OdometryConfig
from sea3d.odometry.observe import Observer, imu_chunks
from sea3d.odometry.rgbd_dense import DenseRgbdConfig
from sea3d.odometry.types import FrameObservation, ImuChunk, Odometry, TrackingStatus
from sea3d.pipeline.ordered import trusted_path_length_m
from sea3d.stereo.recipe import DepthConfig

__all__ = [
    "OdometryRun",
    "OdometrySummary",
    "StereoSource",
    "imu_clock_check",
    "imu_decision",
    "open_stereo_source",
    "rgbd_observations",
    "run_odometry",
    "session_odometry",
]

log = logging.getLogger(__name__)


@dataclass
class StereoSource:
    """Stereo frames of a recording with its rig and IMU.

    Attributes:
        path: the session or folder.
        rig: the rig (from ``--rig`` or stored with the session).
        t_ns: (N,) frame stamps, increasing.
        load: ``load(i) -> (left, right)`` raw images of frame ``i``.
        imu_t_ns, accel_mps2, gyro_radps: the IMU series (empty arrays without IMU).
        notes: what was noticed about the input (for the user).
        frame_gaps: frame intervals longer than 1.5 times the median (dropped frames).
        close: releases the reader.
    """

    path: Path
    rig: StereoRig
    t_ns: NDArray[np.int64]
    load: Callable[[int], tuple[NDArray[Any], NDArray[Any]]]
    imu_t_ns: NDArray[np.int64]
    accel_mps2: F64
    gyro_radps: F64
    notes: list[str] = field(default_factory=list)
    frame_gaps: int = 0
    close: Callable[[], None] = lambda: None


def _frame_gaps(t_ns: NDArray[np.int64]) -> int:
    if t_ns.size < 3:
        return 0
    d = np.diff(t_ns)
    return int(np.count_nonzero(d > 1.5 * np.median(d)))


def open_stereo_source(
    path: str | os.PathLike[str],
    rig_path: str | os.PathLike[str] | None = None,
    *,
    imu: bool = True,
) -> StereoSource:
    """Open a sea3d session (MCAP or folder) or an EuRoC folder; ``imu=False`` reads no IMU
    (an EuRoC folder then needs no ``imu0``).

    Raises:
        SessionError: unreadable input, or no rig (neither stored with the session nor
            given). RigFileError: a bad ``--rig``. OdometryError: fewer than two stereo pairs.
    """
    from sea3d.io.euroc import is_euroc, read_euroc
    from sea3d.io.rig_file import load_rig, resolve_rig

    p = Path(path)
    rig_given = load_rig(rig_path) if rig_path is not None else None
    if is_euroc(p):
        seq = read_euroc(p, imu=imu)
        src = StereoSource(
            path=p,
            rig=rig_given or seq.rig,
            t_ns=seq.t_ns,
            load=lambda i: (seq.image("left", i), seq.image("right", i)),
            imu_t_ns=seq.imu_t_ns,
            accel_mps2=seq.accel_mps2,
            gyro_radps=seq.gyro_radps,
        )
    else:
        from sea3d.io.session import open_session

        reader = open_session(p)
        try:
            rig = rig_given if rig_given is not None else resolve_rig(None, reader)
            match = reader.match_pairs()
            ls, rs = reader.stamps("left"), reader.stamps("right")
            li, ri = match.left_index, match.right_index
            imu_series = reader.imu() if imu else None
        except BaseException:
            reader.close()
            raise
        notes = []
        if match.unpaired_left or match.unpaired_right:
            notes.append(
                f"{match.unpaired_left} left and {match.unpaired_right} right frames have no "
                f"partner within {match.tolerance_ns * 1e-6:.1f} ms and are skipped"
            )

        def load(i: int) -> tuple[NDArray[Any], NDArray[Any]]:
            return (
                reader.image("left", int(li[i]), by="index"),
                reader.image("right", int(ri[i]), by="index"),
            )

        src = StereoSource(
            path=p,
            rig=rig,
            t_ns=np.asarray(ls[li], dtype=np.int64),
            load=load,
            imu_t_ns=np.asarray(
                imu_series.t_ns if imu_series is not None else [], dtype=np.int64
            ),
            accel_mps2=np.asarray(
                imu_series.accel_mps2 if imu_series is not None else [], dtype=np.float64
            ).reshape(-1, 3),
            gyro_radps=np.asarray(
                imu_series.gyro_radps if imu_series is not None else [], dtype=np.float64
            ).reshape(-1, 3),
            notes=notes,
            close=reader.close,
        )
        del rs
    if src.t_ns.size < 2:
        src.close()
        raise OdometryError(f"{p}: {src.t_ns.size} stereo pairs; odometry needs at least two")
    src.frame_gaps = _frame_gaps(src.t_ns)
    if src.frame_gaps:
        src.notes.append(
            f"{src.frame_gaps} gaps in the frame stamps (dropped frames): bridged by the IMU or "
            "re-tracked"
        )
    return src


def imu_clock_check(
    frame_t_ns: NDArray[np.int64],
    imu_t_ns: NDArray[np.int64],
    time_offset_s: float = 0.0,
    *,
    tolerance_s: float = 1.0,
) -> str | None:
    """Why an IMU series cannot be used with these camera frames, or None when it can.

    The IMU must cover the frames' time span, on the camera's clock (``t_imu - offset``), to
    within ``tolerance_s`` at both ends: an IMU clock seconds away from the camera's (an
    unsynchronised recorder, a wrong offset) fails this, as does an IMU that stopped early.

    Args:
        frame_t_ns: (N,) camera stamps in use, increasing.
        imu_t_ns: (M,) IMU stamps, increasing.
        time_offset_s: the rig's ``t_imu = t_cam + offset``.
        tolerance_s: allowed shortfall at either end, seconds
            (:attr:`~sea3d.odometry.config.OdometryConfig.imu_max_clock_offset_s`).
    """
    if imu_t_ns.size == 0:
        return "the session has no IMU samples"
    if frame_t_ns.size == 0:
        return None
    ti = imu_t_ns.astype(np.float64) * 1e-9 - time_offset_s
    tc = frame_t_ns.astype(np.float64) * 1e-9
    if ti[0] > tc[0] + tolerance_s or ti[-1] < tc[-1] - tolerance_s:
        start, end = ti[0] - tc[0], ti[-1] - tc[-1]
        return (
            f"the IMU stamps ({ti[0]:.3f}..{ti[-1]:.3f} s, after the rig's offset "
            f"{time_offset_s:g} s) do not cover the camera's ({tc[0]:.3f}..{tc[-1]:.3f} s): they "
            f"start {start:+.2f} s and end {end:+.2f} s from it (more than {tolerance_s:g} s); "
            "clocks not synchronised or a wrong time offset"
        )
    return None


def imu_decision(use_imu: bool, rig_imu: ImuSpec | None, frame_t_ns: NDArray[np.int64] | None,
                 imu_t_ns: NDArray[np.int64] | None, *,
                 tolerance_s: float = 1.0) -> tuple[bool, str | None]:
    """Whether the odometry gets the IMU, and why not: the one decision of ``sea3d odometry``,
    ``sea3d process`` and ``sea3d live``.

    Policy: an unusable IMU is never an error: the odometry runs visual-only, which is right
    for the intact camera data, and the reason is said (the summary's ``imu_note``). The IMU
    is left out when it is switched off, when there are no IMU samples, when the rig has no
    ``imu`` block, or when its stamps do not cover the frames (:func:`imu_clock_check`).

    Args:
        use_imu: the IMU is wanted (``--no-imu``: not).
        rig_imu: the rig's ``imu`` block, or None.
        frame_t_ns: (N,) camera stamps to be run, increasing; None when not known yet (live
            cameras: the clock is checked on the first pair).
        imu_t_ns: (M,) IMU stamps, increasing; None when they are still to come (a live IMU
            stream: the clock is checked on its first samples).
        tolerance_s: allowed clock disagreement, seconds
            (:attr:`~sea3d.odometry.config.OdometryConfig.imu_max_clock_offset_s`).

    Returns:
        ``(use, why)``: whether to give the IMU to the odometry, and why not (None when it is
        given), ending in ``: visual-only``.
    """
    if not use_imu:
        return False, "use_imu off: visual-only"
    if imu_t_ns is not None and imu_t_ns.size == 0:
        return False, "the session has no IMU samples: visual-only"
    if rig_imu is None:
        return False, (
            "the rig has no imu block (T_left_imu): visual-only; add it from a Kalibr "
            "camera-IMU calibration or estimate it with 'sea3d calibrate imu'"
        )
    if frame_t_ns is None or imu_t_ns is None:
        return True, None
    why = imu_clock_check(frame_t_ns, imu_t_ns, rig_imu.time_offset_s, tolerance_s=tolerance_s)
    if why is not None:
        return False, why + ": visual-only"
    return True, None


@dataclass(frozen=True, kw_only=True)
class OdometrySummary:
    """The figures of an odometry run: what ``sea3d odometry`` prints, and with ``--json``
    :meth:`to_json`'s object.

    The last five fields belong to some runs only (None elsewhere, and left out of the
    JSON): ``seconds_depth`` to runs that compute depth, ``frame_gaps``,
    ``frames_without_depth`` and ``depth_range_m`` to stereo sessions, ``trajectory`` to a
    run written to a file.
    """

    frames: int
    """Frames fed to the odometry."""
    keyframes: int
    frames_lost: int
    loop_closures: int
    relinks: int
    """Closures that only re-link neighbouring keyframes across a lost stretch."""
    loop_checks: dict[str, int | bool]
    """What became of the loop candidates (:meth:`~sea3d.odometry.types.LoopChecks.as_dict`)."""
    path_length_m: float
    """Length of the trusted parts of the trajectory, metres."""
    seconds: float
    """Wall seconds of the run (reading, depth and odometry)."""
    seconds_odometry: float
    """Of ``seconds``: the odometry's steps."""
    ms_per_frame_odometry: float
    statuses: dict[str, int]
    """Frames by :class:`~sea3d.odometry.types.TrackingStatus` value, every status named."""
    segments: int
    """Connected segments the frames fell into."""
    imu: bool
    """Whether the IMU was used."""
    imu_note: str | None
    """Why it was not (None when it was)."""
    notes: tuple[str, ...]
    """What was noticed about the input and decided about it, for the user."""
    seconds_depth: float | None = None
    """Of ``seconds``: the depth maps'."""
    frame_gaps: int | None = None
    """Frame intervals longer than 1.5 times the median (dropped frames)."""
    frames_without_depth: int | None = None
    """Frames with no valid depth in ``depth_range_m``."""
    depth_range_m: tuple[float, float] | None = None
    """The stereo depth range, metres."""
    trajectory: str | None = None
    """The TUM file the trajectory was written to."""

    def to_json(self) -> dict[str, Any]:
        """The summary as a JSON object (the figures in the order above; the fields of other
        runs left out)."""
        out = asdict(self)
        for key in ("seconds_depth", "frame_gaps", "frames_without_depth", "depth_range_m",
                    "trajectory"):
            if out[key] is None:
                del out[key]
        return out


@dataclass(frozen=True, kw_only=True, eq=False)
class OdometryRun:
    """The result of a run.

    Attributes:
        t_ns: (N,) frame stamps.
        T_world_left: (N, 4, 4) final poses (after the last loop closure).
        statuses: per frame :class:`TrackingStatus`.
        segments: per frame segment id (as reported when the frame was processed).
        summary: the run's figures.
    """

    t_ns: NDArray[np.int64]
    T_world_left: F64
    statuses: list[TrackingStatus]
    segments: list[int]
    summary: OdometrySummary


def run_odometry(
    frames: Iterator[FrameObservation],
    odometry: Odometry,
    *,
    progress: Callable[[int], None] | None = None,
    notes: list[str] | None = None,
    seconds_depth: Callable[[], float] | None = None,
) -> OdometryRun:
    """Feed frames in order to an odometry and collect the trajectory and the summary."""
    t0 = time.perf_counter()
    statuses: list[TrackingStatus] = []
    segments: list[int] = []
    seconds_odo = 0.0
    for frame in frames:
        t1 = time.perf_counter()
        est = odometry.step(frame)
        seconds_odo += time.perf_counter() - t1
        statuses.append(est.status)
        segments.append(int(est.segment))
        if progress is not None:
            progress(1)
    t_ns, T = odometry.trajectory()
    counts = Counter(s.value for s in statuses)
    n = len(statuses)
    summary = OdometrySummary(
        frames=n,
        keyframes=int(odometry.keyframe_count),
        frames_lost=int(counts.get(TrackingStatus.LOST.value, 0)),
        loop_closures=int(odometry.loop_closures),
        relinks=int(odometry.relinks),
        loop_checks=odometry.loop_checks.as_dict(),
        path_length_m=trusted_path_length_m(T, statuses, segments),
        seconds=time.perf_counter() - t0,
        seconds_odometry=seconds_odo,
        ms_per_frame_odometry=1e3 * seconds_odo / max(n, 1),
        statuses={s.value: int(counts.get(s.value, 0)) for s in TrackingStatus},
        segments=len(set(segments)) if segments else 0,
        imu=odometry.imu_disabled_reason is None,
        imu_note=odometry.imu_disabled_reason,
        notes=tuple(notes or ()),
        seconds_depth=seconds_depth() if seconds_depth is not None else None,
    )
    return OdometryRun(
        t_ns=t_ns, T_world_left=T, statuses=statuses, segments=segments, summary=summary
    )


def session_odometry(
    path: str | os.PathLike[str],
    *,
    rig_path: str | os.PathLike[str] | None = None,
    use_imu: bool = True,
    observe: DepthConfig | None = None,
    config: OdometryConfig | None = None,
    max_frames: int | None = None,
    progress: Callable[[int], None] | None = None,
    on_open: Callable[[StereoSource, bool, str | None], None] | None = None,
) -> OdometryRun:
    """Stereo(-inertial) odometry of a recorded session or an EuRoC folder.

    Raises:
        SessionError, RigFileError, OdometryError: unusable input (see the module docstring).
    """
    from sea3d.odometry import create_odometry
    from sea3d.stereo.recipe import StereoDepth

    if max_frames is not None and int(max_frames) < 1:
        raise ConfigError(f"max_frames must be >= 1, got {max_frames}")
    cfg = config or OdometryConfig()
    src = open_stereo_source(path, rig_path, imu=use_imu)
    try:
        n_run = src.t_ns.size if max_frames is None else max(int(max_frames), 1)
        imu_ok, why = imu_decision(use_imu, src.rig.imu, src.t_ns[:n_run], src.imu_t_ns,
                                   tolerance_s=cfg.imu_max_clock_offset_s)
        notes = list(src.notes)
        if why:
            notes.append(why)
        if on_open is not None:
            on_open(src, imu_ok, why)
        stereo = StereoDepth(src.rig, observe)
        maps = stereo.maps
        odo = create_odometry(src.rig, maps, use_imu=imu_ok, config=cfg)
        if why:
            odo.imu_disabled_reason = why
        observer = Observer(stereo)
        n = src.t_ns.size if max_frames is None else min(src.t_ns.size, int(max_frames))
        chunks: list[ImuChunk | None] = [None] * n
        if imu_ok and src.rig.imu is not None:
            # slice by camera time (t_cam = t_imu - offset); the odometry shifts the stamps
            off_ns = round(src.rig.imu.time_offset_s * 1e9)
            chunks = imu_chunks(src.t_ns[:n] + off_ns, src.imu_t_ns, src.accel_mps2, src.gyro_radps)
        depth_s = [0.0]
        no_depth = [0]

        def frames() -> Iterator[FrameObservation]:
            for i in range(n):
                left, right = src.load(i)
                t1 = time.perf_counter()
                obs = observer.observe(int(src.t_ns[i]), left, right, chunks[i])
                depth_s[0] += time.perf_counter() - t1
                if not np.isfinite(obs.depth_m).any():
                    no_depth[0] += 1
                yield obs

        run = run_odometry(
            frames(), odo, progress=progress, notes=notes, seconds_depth=lambda: depth_s[0]
        )
        lo, hi = observer.depth_range_m
        notes_after = () if not no_depth[0] else (
            f"{no_depth[0]} of {n} frames have no valid depth in the depth range "
            f"{lo:.3g}..{hi:.3g} m: the range may exclude the scene (set "
            "min_depth_m/max_depth_m)",
        )
        return replace(run, summary=replace(
            run.summary, frame_gaps=src.frame_gaps, frames_without_depth=no_depth[0],
            depth_range_m=(lo, hi), notes=run.summary.notes + notes_after))
    finally:
        src.close()


# ---------------------------------------------------------------------- RGB-D
def _expand(pattern: str, what: str) -> list[Path]:
    from sea3d.io.image_files import image_paths

    paths = image_paths(pattern)
    if not paths:
        raise ConfigError(f"{what} {pattern!r} matches no files")
    return paths


def frame_times_s(paths: list[Path]) -> F64:
    """Times of frames from their file names when every name is a number (seconds, or
    nanoseconds when above 1e12), else the frame index."""
    vals_list = []
    for p in paths:
        value = None
        for cand in (p.stem, p.name.split(".")[0]):
            try:
                value = float(cand)
                break
            except ValueError:
                continue
        if value is None:
            return np.arange(len(paths), dtype=np.float64)
        vals_list.append(value)
    vals = np.asarray(vals_list, dtype=np.float64)
    if np.all(np.diff(vals) > 0):
        return vals * 1e-9 if vals.max() > 1e12 else vals
    return np.arange(len(paths), dtype=np.float64)


# A depth camera's valid range is centimetres to tens of metres: a median outside this says the
# depth units are wrong (millimetres read as metres, or metres as millimetres)
_RGBD_MEDIAN_DEPTH_RANGE_M = (0.02, 200.0)


def rgbd_observations(
    color: str,
    depth: str,
    intrinsics: tuple[float, float, float, float],
    *,
    depth_scale: float = 1000.0,
) -> tuple[list[Path], list[Path], F64, tuple[int, int]]:
    """Resolve and check RGB-D inputs: sorted colour and depth files, their times (seconds),
    and the image size. Depth is read by :func:`sea3d.io.depth_files.read_depth` (16-bit
    depth in units of ``1 / depth_scale`` m, float depth in metres).

    Raises:
        ConfigError: no files, different counts, bad intrinsics (a principal point outside
            the image) or scale, a first depth image whose median is no plausible depth.
        ReconError: an unreadable first colour image, or colour and depth of different sizes.
        StereoError: an unreadable first depth image, or 8-bit depth.
    """
    from sea3d.errors import ReconError
    from sea3d.io.depth_files import read_depth
    from sea3d.io.rgbd_files import read_color

    if not depth_scale > 0:
        raise ConfigError(f"depth_scale must be > 0, got {depth_scale}")
    fx, fy, cx, cy = intrinsics
    if not (fx > 0 and fy > 0):
        raise ConfigError(f"intrinsics: focal lengths must be > 0, got {intrinsics}")
    cp, dp = _expand(color, "color"), _expand(depth, "depth")
    if len(cp) != len(dp):
        raise ConfigError(
            f"color matches {len(cp)} files but depth {len(dp)}; they must "
            "pair up one to one in sorted order"
        )
    c0 = read_color(cp[0])
    d0 = read_depth(dp[0], depth_scale)
    h, w = d0.shape
    if c0.shape[:2] != d0.shape[:2]:
        raise ReconError(
            f"{cp[0]} is {c0.shape[1]}x{c0.shape[0]} but {dp[0]} is {w}x{h}: "
            "colour must be registered to depth"
        )
    if not (0 <= cx < w and 0 <= cy < h):
        raise ConfigError(
            f"intrinsics: the principal point ({cx:g}, {cy:g}) px lies outside the "
            f"{w}x{h} image of {dp[0]}; give FX FY CX CY in pixels of this image"
        )
    valid = d0[np.isfinite(d0)]
    if valid.size == 0:
        raise ConfigError(f"{dp[0]}: the first depth image has no valid depth")
    med = float(np.median(valid))
    lo, hi = _RGBD_MEDIAN_DEPTH_RANGE_M
    if not lo <= med <= hi:
        raise ConfigError(
            f"{dp[0]}: median depth {med:.4g} m with depth_scale {depth_scale:g} is no "
            f"plausible depth ({lo:g}..{hi:g} m); give the depth units per metre "
            "(1000 for millimetres, 5000 for TUM) or float depth in metres"
        )
    return cp, dp, frame_times_s(cp), (int(w), int(h))


def read_rgbd_frame(
    color_path: Path, depth_path: Path, depth_scale: float
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """Colour (RGB uint8) and depth (float32 metres, NaN invalid) through
    :mod:`sea3d.io.rgbd_files` and :func:`sea3d.io.depth_files.read_depth`."""
    from sea3d.io.depth_files import read_depth
    from sea3d.io.rgbd_files import read_color

    return read_color(color_path), read_depth(depth_path, depth_scale)


def rgbd_odometry(
    color: str,
    depth: str,
    intrinsics: tuple[float, float, float, float],
    *,
    depth_scale: float = 1000.0,
    config: OdometryConfig | None = None,
    progress: Callable[[int], None] | None = None,
    method: str = "dense",
    dense_config: DenseRgbdConfig | None = None,
) -> OdometryRun:
    """RGB-D odometry over image files (one pose per input frame, in sorted order; ``t`` from
    the file names when they are numbers, else the frame index).

    ``method`` ``"dense"`` (default): dense frame-to-keyframe alignment
    (:class:`~sea3d.odometry.rgbd_dense.DenseRgbdOdometry`, ``dense_config``); ``"features"``:
    the stereo engine's sparse features, keyframes and windowed BA (``config``).
    """
    from sea3d.errors import ReconError
    from sea3d.odometry import create_dense_rgbd_odometry, create_rgbd_odometry

    if method not in ("dense", "features"):
        raise ConfigError(f"RGB-D method must be 'dense' or 'features', got {method!r}")
    cp, dp, t_s, (w, h) = rgbd_observations(color, depth, intrinsics, depth_scale=depth_scale)
    fx, fy, cx, cy = intrinsics
    odo: Any
    if method == "dense":
        odo = create_dense_rgbd_odometry(fx, fy, cx, cy, config=dense_config)
        baseline = 0.0
    else:
        odo = create_rgbd_odometry(fx, fy, cx, cy, w, h, config=config)
        baseline = odo.geometry.baseline_m
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    t_ns = np.round(t_s * 1e9).astype(np.int64)

    def frames() -> Iterator[FrameObservation]:
        for i, (c, d) in enumerate(zip(cp, dp, strict=True)):
            rgb, z = read_rgbd_frame(c, d, depth_scale)
            if rgb.shape[:2] != (h, w) or z.shape != (h, w):
                raise ReconError(f"{c} or {d}: size differs from the first frame's {w}x{h}")
            yield FrameObservation(
                t_ns=int(t_ns[i]),
                rect_left=rgb,
                rect_right=rgb,
                depth_m=z,
                K_rect=K,
                baseline_m=baseline,
                R_rect_left_left=np.eye(3),
            )

    run = run_odometry(frames(), odo, progress=progress,
                       notes=[f"RGB-D mode ({method}): no IMU"])
    return OdometryRun(
        t_ns=t_ns,
        T_world_left=run.T_world_left,
        statuses=run.statuses,
        segments=run.segments,
        summary=run.summary,
    )
