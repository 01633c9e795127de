"""Structure from motion of an image glob or a session, to files: what ``sea3d sfm`` runs; the
CLI only parses, calls and prints.

:func:`sfm_to_files` gathers the frames (a session's left images or stereo pairs, or an image
glob's files in natural order), runs :func:`sea3d.sfm.run_sfm`, makes a monocular model metric
from the IMU when asked (:func:`sea3d.sfm.metric.imu_scale_for`) and writes ``OUT/sparse/``,
``OUT/points.ply``, ``OUT/trajectory.tum`` and ``OUT/summary.json``
(:mod:`sea3d.io.sfm_files`); it returns :class:`SfmFiles`.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sea3d.errors import SfmError
from sea3d.sfm.types import PosePriors, SfmConfig, SfmFrame, SfmResult

if TYPE_CHECKING:
    from sea3d._typing import F64
    from sea3d.geometry.rig import StereoRig
    from sea3d.io.session import ImuSeries

__all__ = ["SfmFiles", "glob_frames", "read_pose_priors", "session_frames", "sfm_summary",
           "sfm_to_files"]

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True, kw_only=True, eq=False)
class SfmFiles:
    """A structure-from-motion run and the files written from it.

    Attributes:
        result: the model (:class:`~sea3d.sfm.SfmResult`, before the IMU scale).
        summary: what ``summary.json`` holds.
        out_dir: the output folder.
        imu_estimate: the IMU's scale estimate (its ``message``), or None when not asked for or
            skipped.
    """

    result: SfmResult
    summary: dict[str, Any]
    out_dir: Path
    imu_estimate: Any


# ---------------------------------------------------------------------- frames
def _read_frame_image(path: Path) -> Any:
    from sea3d.io.image_files import read_image_rgb

    img = read_image_rgb(path)
    if img is None:
        raise SfmError(f"{path}: cannot read the image (not an image file or damaged)")
    return img


def glob_frames(pattern: str) -> list[SfmFrame]:
    """The frames of an image glob or folder: natural order, ``t_s`` the 0-based index, named
    by file stem (by index when two stems clash); images are loaded when needed.

    Raises:
        SfmError: nothing matches.
    """
    from sea3d.io.image_files import image_paths

    paths = image_paths(pattern)
    if not paths:
        raise SfmError(f"{pattern}: matches no image files")
    stems = [re.sub(r"[^A-Za-z0-9._-]", "_", q.stem) for q in paths]
    unique = len(set(stems)) == len(stems)
    return [
        SfmFrame(name=stems[i] if unique else f"{i:06d}", t_s=float(i),
                 left=partial(_read_frame_image, q), source=str(q))
        for i, q in enumerate(paths)
    ]


def session_frames(reader: Any, camera: str, where: str) -> list[SfmFrame]:
    """The frames of an open session: its left images for ``camera="left"``, else its matched
    stereo pairs; named by their integer stamp, ``t_s`` the session's time in seconds.

    Raises:
        SfmError: the camera asked for has no images.
    """
    n_left = int(reader.stamps("left").size)
    n_right = int(reader.stamps("right").size)
    if camera in ("right", "stereo") and n_right == 0:
        raise SfmError(f"{where}: the session has no right camera images; camera {camera} "
                       f"needs a right camera")
    if camera == "left":
        if n_left == 0:
            raise SfmError(f"{where}: the session has no left camera images")
        stamps = reader.stamps("left")
        return [SfmFrame(name=str(int(t)), t_s=int(t) * 1e-9,
                         left=partial(reader.image, "left", i, by="index"),
                         source=f"{where} left t_ns={int(t)}")
                for i, t in enumerate(stamps)]
    match = reader.match_pairs()
    ls, rs = reader.stamps("left"), reader.stamps("right")
    return [SfmFrame(name=str(int(ls[li])), t_s=int(ls[li]) * 1e-9,
                     left=partial(reader.image, "left", int(li), by="index"),
                     right=partial(reader.image, "right", int(ri), by="index"),
                     source=f"{where} t_ns={int(ls[li])} (right t_ns={int(rs[ri])})")
            for li, ri in zip(match.left_index, match.right_index, strict=True)]


def read_pose_priors(path: str | os.PathLike[str], fmt: str | None = None,
                     kitti_times: str | os.PathLike[str] | None = None) -> PosePriors:
    """Pose priors from a trajectory file (TUM, KITTI with its times.txt, EuRoC CSV).

    Raises:
        SfmError: a KITTI trajectory without its times; OdometryError: an unreadable file.
    """
    from sea3d.io.trajectory_files import read_trajectory

    traj = read_trajectory(path, fmt, kitti_times=kitti_times)
    if not traj.timed:
        raise SfmError(f"{path}: a KITTI trajectory has no stamps; give its times.txt "
                       "(pose_priors_times)")
    return PosePriors(t_s=traj.t_ns.astype(np.float64) * 1e-9, T_world_left=traj.T_world_x,
                      source=str(path))


# ---------------------------------------------------------------------- summary
def sfm_summary(source: str, config: SfmConfig, result: SfmResult, rig: Any,
                priors: PosePriors | None) -> dict[str, Any]:
    """``summary.json`` of a run (before the IMU scale): status, counts, cameras, virtual
    pinholes, refractive bundle adjustment, timings."""
    metric_source = None
    if result.metric:
        metric_source = "pose_priors" if priors is not None and config.camera != "stereo" else (
            "stereo_rig")
    return {
        "input": source,
        "status": result.status,
        "message": result.message,
        "camera": config.camera,
        "matcher": config.matcher,
        "frames": result.frames,
        "registered_frames": result.registered,
        "images": result.images,
        "registered": result.registered_images,
        "points3d": len(result.points_world),
        "mean_reprojection_error_px": result.mean_reprojection_error_px,
        "metric": bool(result.metric),
        "metric_source": metric_source,
        "models": result.models,
        "intrinsics": "rig" if rig is not None else "self-calibrated",
        "trajectory_camera": "right" if config.camera == "right" and rig is None else "left",
        "cameras": result.cameras,
        "virtual_pinhole": {
            k: {"center_mm": [1e3 * c for c in v.center_m], "rms_px": v.rms_px,
                "max_px": v.max_px, "depths_m": list(v.depths_m),
                "rms_by_depth_px": list(v.rms_by_depth_px)}
            for k, v in result.virtual.items()
        },
        "refractive_ba": None if result.refractive_ba is None else {
            "observations": result.refractive_ba.observations,
            "rms_before_px": result.refractive_ba.rms_before_px,
            "rms_after_px": result.refractive_ba.rms_after_px,
            "time_s": result.refractive_ba.time_s,
        },
        "pose_priors": None if priors is None else str(priors.source),
        "timings_s": result.timings_s,
    }


# ---------------------------------------------------------------------- run
@dataclass(frozen=True, kw_only=True, eq=False)
class _Input:
    frames: Sequence[SfmFrame]
    rig: StereoRig | None
    imu: ImuSeries | None
    T_cam_body: F64 | None


def _gather(stack: contextlib.ExitStack, src: Path, source: str, session: bool,
            config: SfmConfig, rig: StereoRig | None, *, self_calibrate: bool, imu_scale: bool,
            imu_extrinsics: str | os.PathLike[str] | None) -> _Input:
    """The frames, the rig (given, else the session's unless self-calibrating) and the IMU."""
    imu = None
    if session:
        from sea3d.io.rig_file import rig_from_yaml
        from sea3d.io.session import open_session

        reader = stack.enter_context(open_session(src))
        if rig is None and reader.rig_yaml and not self_calibrate:
            rig = rig_from_yaml(reader.rig_yaml, f"{src} (stored rig.yaml)")
        frames = session_frames(reader, config.camera, str(src))
        if imu_scale:
            imu = reader.imu()
            if len(imu) < 10:
                raise SfmError(f"{src}: the IMU scale needs IMU samples; the session has "
                               f"{len(imu)}")
    else:
        if config.camera != "left":
            raise SfmError(f"{src}: an image glob has one camera; camera {config.camera} "
                           "needs a session with left and right images")
        frames = glob_frames(source)
    T_cam_body = None
    if imu is not None:
        from sea3d.io.sfm_files import read_imu_extrinsics
        from sea3d.sfm.metric import imu_extrinsics as rig_imu_extrinsics

        T_cam_body = rig_imu_extrinsics(
            rig, read_imu_extrinsics(imu_extrinsics) if imu_extrinsics else None)
    if self_calibrate:
        if config.camera == "stereo":
            raise SfmError("camera stereo needs the rig's extrinsics; self_calibrate cannot "
                           "be on")
        rig = None
    if config.camera == "stereo" and rig is None:
        raise SfmError("camera stereo needs the rig (its extrinsics fix the scale); give a rig "
                       "file or use a session that stores one")
    return _Input(frames=frames, rig=rig, imu=imu, T_cam_body=T_cam_body)


def sfm_to_files(
    source: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    config: SfmConfig,
    rig_path: str | os.PathLike[str] | None = None,
    self_calibrate: bool = False,
    pose_priors: PosePriors | None = None,
    imu_scale: bool = False,
    imu_extrinsics: str | os.PathLike[str] | None = None,
    export_images: bool = False,
    progress: Progress | None = None,
) -> SfmFiles:
    """Structure from motion of an image glob, image folder or session, written to files.

    Args:
        source: an image glob (``frames/*.jpg``), an image folder, or a session (MCAP or
            folder).
        out_dir: the output folder (made): ``sparse/`` (the COLMAP model), ``points.ply``,
            ``trajectory.tum`` (``T_world_left``; ``t`` the session's time in seconds, or the
            image's 0-based index for a glob), ``summary.json`` and, with ``export_images``,
            ``images/`` (the images as COLMAP saw them).
        config: :class:`~sea3d.sfm.SfmConfig`.
        rig_path: a rig file instead of the session's stored rig.
        self_calibrate: ignore the session's rig and self-calibrate the camera.
        pose_priors: left-camera positions over time (:func:`read_pose_priors`).
        imu_scale: monocular sessions: scale the model to metres from the IMU when the
            estimate is trustworthy.
        imu_extrinsics: JSON/YAML with ``T_left_imu`` or ``T_body_left`` instead of the rig's
            IMU block.
        export_images: also write the images as COLMAP saw them.
        progress: ``progress(stage, done, total)`` (:func:`sea3d.sfm.run_sfm`).

    Returns:
        :class:`SfmFiles`.

    Raises:
        SfmError: bad input (nothing to read, a camera the input lacks, no rig for a stereo
            run, an IMU scale asked of a stereo run or a glob) and a run that finds no model
            (raised after ``summary.json`` is written, with the run's message).
        ConfigError, SessionError, OdometryError: an unreadable rig, session or trajectory.
    """
    from sea3d.io.image_files import image_writer
    from sea3d.io.rig_file import load_rig
    from sea3d.io.session import is_session
    from sea3d.io.sfm_files import write_sfm_model, write_summary
    from sea3d.sfm import run_sfm
    from sea3d.sfm.metric import imu_scale_for, scaled_outputs

    src, out, text = Path(source), Path(out_dir), os.fspath(source)
    session = is_session(src)
    if imu_scale and (not session or config.camera == "stereo"):
        raise SfmError("the IMU scale needs a monocular run (camera left/right) of a session "
                       "with IMU samples")
    with contextlib.ExitStack() as stack:
        rig = load_rig(rig_path) if rig_path else None
        got = _gather(stack, src, text, session, config, rig, self_calibrate=self_calibrate,
                      imu_scale=imu_scale, imu_extrinsics=imu_extrinsics)
        out.mkdir(parents=True, exist_ok=True)
        sink = image_writer(out / "images", SfmError) if export_images else None
        try:
            result = run_sfm(got.frames, config, rig=got.rig, pose_priors=pose_priors,
                             workdir=out / ".work", progress=progress, image_sink=sink)
        finally:
            shutil.rmtree(out / ".work", ignore_errors=True)
    summary = sfm_summary(text, config, result, got.rig, pose_priors)
    estimate, scale = None, 1.0
    if got.imu is not None and got.T_cam_body is not None and result.status != "failed":
        decision = imu_scale_for(result, got.imu, got.T_cam_body)
        estimate, scale = decision.estimate, decision.scale
        summary["imu_scale"] = decision.summary
        if decision.summary.get("applied"):
            summary["metric"], summary["metric_source"] = True, "imu"
    if result.reconstruction is not None:
        T, points = scaled_outputs(result, scale)
        # sessions name frames by their integer stamp (exact); a glob's t is the image index
        t_ns = (np.array([int(n) for n in result.names], dtype=np.int64) if session else
                np.round(np.asarray(result.t_s) * 1e9).astype(np.int64))
        write_sfm_model(out, result.reconstruction, t_ns=t_ns, T_world_left=T,
                        points_world=points, colors_rgb=result.colors_rgb)
    write_summary(out / "summary.json", summary)
    if result.status == "failed":
        raise SfmError(f"{src}: {result.message}")
    return SfmFiles(result=result, summary=summary, out_dir=out, imu_estimate=estimate)
