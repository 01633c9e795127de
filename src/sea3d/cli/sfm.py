"""``sea3d sfm``: structure from motion of an image glob or a session (pycolmap).

Writes ``OUT/sparse/`` (the COLMAP model, binary and text), ``OUT/points.ply``,
``OUT/trajectory.tum`` (``T_world_left`` of every registered frame; ``t`` is the session's time
in seconds, or the image's 0-based index in sorted order for a glob) and ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import glob
import json
import re
from functools import partial
from pathlib import Path
from typing import Any

from sea3d.cli._args import config_option

__all__ = ["register"]

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm")


def register(sub: Any) -> None:
    """Add ``sfm`` to the top-level parser."""
    p = sub.add_parser(
        "sfm",
        help="structure from motion (COLMAP) of images or a session, metric with a stereo rig",
        description="Structure from motion on pycolmap: SIFT (CPU), sequential or exhaustive "
        "matching, incremental mapping and bundle adjustment. Without a rig the intrinsics "
        "are self-calibrated; with one they are used and held fixed; --camera stereo puts "
        "both cameras into one COLMAP rig with the calibrated extrinsics held fixed, so the "
        "model is metric. Port cameras are remapped into a virtual pinhole at their rays' "
        "closest point (residual reported); flat ports and large dome offsets are refined "
        "by refractive bundle adjustment.",
    )
    p.add_argument("input", metavar="INPUT",
                   help="image glob ('frames/*.jpg'), image folder, or session (.mcap or folder)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output folder")
    p.add_argument("--rig", metavar="RIG", help="rig file (default: the session's own rig)")
    p.add_argument("--self-calibrate", action="store_true",
                   help="ignore the session's rig and self-calibrate the camera")
    from sea3d.sfm.types import SfmConfig

    opt = partial(config_option, p, SfmConfig)
    opt("camera", choices=["left", "right", "stereo"], dest="camera")
    opt("matcher", choices=["sequential", "exhaustive"], dest="matcher")
    opt("sequential_overlap", "--overlap", type=int, dest="overlap")
    opt("max_image_px", type=int, dest="max_image_px")
    opt("max_features", type=int, dest="max_features")
    p.add_argument("--fast", action="store_true",
                   help="SIFT without upsampling (first octave 0): about 2.5x less extraction "
                        "time, less precise features (see docs/sfm.md)")
    opt("self_calibration_model", "--camera-model", dest="camera_model",
        choices=["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"])
    opt("depth_range_m", "--depth-range", type=float, nargs=2, metavar=("NEAR", "FAR"),
        dest="depth_range")
    opt("refractive_ba", choices=["auto", "on", "off"], dest="refractive_ba")
    p.add_argument("--pose-priors", metavar="TRAJ",
                   help="trajectory of the left camera (TUM, KITTI with --pose-priors-times, "
                        "or EuRoC CSV; sea3d odometry/process output or ground truth) used as "
                        "position priors; the model is then in its (metric) world")
    p.add_argument("--pose-priors-format", choices=["tum", "kitti", "euroc"],
                   help="format of --pose-priors (default: from its extension and first line)")
    p.add_argument("--pose-priors-times", metavar="TIMES.txt",
                   help="KITTI times.txt (one stamp in seconds per pose) for --pose-priors")
    opt("prior_position_std_m", "--prior-std", type=float, dest="prior_std")
    p.add_argument("--imu-scale", action="store_true",
                   help="monocular sessions: scale the model to metres from the IMU")
    p.add_argument("--imu-extrinsics", metavar="FILE",
                   help="JSON/YAML with T_body_left (4x4, e.g. a simulation's gt/sim.json) or "
                        "T_left_imu; default: the rig's IMU block")
    p.add_argument("--export-images", action="store_true",
                   help="also write the images as COLMAP saw them to OUT/images/")
    opt("num_threads", "--threads", type=int, dest="threads")
    opt("seed", type=int, dest="seed")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=_cmd_sfm)


# ---------------------------------------------------------------------- inputs
def _natural_key(path: Path) -> list[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(path))]


def _is_session(path: Path) -> bool:
    if path.is_file():
        with open(path, "rb") as fh:
            return path.suffix.lower() == ".mcap" or fh.read(8).startswith(b"\x89MCAP")
    return path.is_dir() and ((path / "left").is_dir() or (path / "session.json").is_file())


def _glob_images(pattern: str) -> list[Path]:
    from sea3d.errors import SfmError

    p = Path(pattern)
    if p.is_dir():
        paths = [q for q in p.iterdir() if q.suffix.lower() in _IMAGE_SUFFIXES]
    else:
        paths = [Path(q) for q in glob.glob(pattern)]
        paths = [q for q in paths if q.is_file()]
    if not paths:
        raise SfmError(f"{pattern}: matches no image files")
    return sorted(paths, key=_natural_key)


def _read_image(path: Path) -> Any:
    import cv2

    from sea3d.errors import SfmError

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SfmError(f"{path}: cannot read the image (not an image file or damaged)")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return img


def _glob_frames(paths: list[Path]) -> list[Any]:
    from sea3d.sfm import SfmFrame

    stems = [re.sub(r"[^A-Za-z0-9._-]", "_", q.stem) for q in paths]
    unique = len(set(stems)) == len(stems)
    return [
        SfmFrame(name=stems[i] if unique else f"{i:06d}", t_s=float(i),
                 left=partial(_read_image, q), source=str(q))
        for i, q in enumerate(paths)
    ]


def _session_frames(reader: Any, camera: str, where: str) -> list[Any]:
    from sea3d.errors import SfmError
    from sea3d.sfm import SfmFrame

    n_left = int(reader.stamps("left").size)
    n_right = int(reader.stamps("right").size)
    if camera in ("right", "stereo") and n_right == 0:
        raise SfmError(f"{where}: the session has no right camera images; --camera {camera} "
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


def _imu_extrinsics(args: argparse.Namespace, rig: Any) -> Any:
    """``T_cam_body`` (the IMU in the left camera frame) for --imu-scale."""
    from sea3d.errors import SfmError
    from sea3d.io.sfm_files import read_imu_extrinsics
    from sea3d.sfm.metric import imu_extrinsics

    if args.imu_extrinsics:
        return read_imu_extrinsics(args.imu_extrinsics)
    try:
        return imu_extrinsics(rig)
    except SfmError as err:
        raise SfmError("--imu-scale needs the IMU's place on the camera: the rig has no IMU "
                       "block; pass --imu-extrinsics FILE (T_left_imu or T_body_left)") from err


# ---------------------------------------------------------------------- command
def _cmd_sfm(args: argparse.Namespace) -> int:
    import contextlib

    import numpy as np

    from sea3d.cli._progress import bar as progress_bar
    from sea3d.errors import SfmError
    from sea3d.io.depth_files import write_ply
    from sea3d.io.rig_file import load_rig, rig_from_yaml
    from sea3d.io.sfm_files import write_colmap_model, write_summary
    from sea3d.io.trajectory_files import read_trajectory, write_tum
    from sea3d.sfm import PosePriors, SfmConfig, run_sfm
    from sea3d.sfm.metric import imu_scale_for, scaled_outputs

    make = SfmConfig.fast if args.fast else SfmConfig
    config = make(
        camera=args.camera, matcher=args.matcher, max_image_px=args.max_image_px,
        max_features=args.max_features, sequential_overlap=args.overlap,
        self_calibration_model=args.camera_model, depth_range_m=tuple(args.depth_range),
        refractive_ba=args.refractive_ba, prior_position_std_m=args.prior_std,
        num_threads=args.threads, seed=args.seed,
    )
    src = Path(args.input)
    out = Path(args.output)
    session = _is_session(src)
    if args.imu_scale and (not session or args.camera == "stereo"):
        raise SfmError("--imu-scale needs a monocular run (--camera left/right) of a session "
                       "with IMU samples")
    priors = None
    if args.pose_priors:
        traj = read_trajectory(args.pose_priors, args.pose_priors_format,
                               kitti_times=args.pose_priors_times)
        if not traj.timed:
            raise SfmError(f"{args.pose_priors}: a KITTI trajectory has no stamps; give its "
                           "times.txt with --pose-priors-times")
        priors = PosePriors(t_s=traj.t_ns.astype(np.float64) * 1e-9,
                            T_world_left=traj.T_world_x, source=str(args.pose_priors))
    with contextlib.ExitStack() as stack:
        rig = load_rig(args.rig) if args.rig else None
        imu = None
        if session:
            from sea3d.io.session import open_session

            reader = stack.enter_context(open_session(src))
            if rig is None and reader.rig_yaml and not args.self_calibrate:
                rig = rig_from_yaml(reader.rig_yaml, f"{src} (stored rig.yaml)")
            frames = _session_frames(reader, args.camera, str(src))
            if args.imu_scale:
                imu = reader.imu()
                if len(imu) < 10:
                    raise SfmError(f"{src}: --imu-scale needs IMU samples; the session has "
                                   f"{len(imu)}")
        else:
            if args.camera != "left":
                raise SfmError(f"{src}: an image glob has one camera; --camera {args.camera} "
                               "needs a session with left and right images")
            frames = _glob_frames(_glob_images(args.input))
        T_cam_body = _imu_extrinsics(args, rig) if imu is not None else None
        if args.self_calibrate:
            if args.camera == "stereo":
                raise SfmError("--camera stereo needs the rig's extrinsics; drop "
                               "--self-calibrate")
            rig = None
        out.mkdir(parents=True, exist_ok=True)
        sink = None
        if args.export_images:
            import cv2

            def sink(name: str, img: Any) -> None:
                path = out / "images" / name
                path.parent.mkdir(parents=True, exist_ok=True)
                arr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
                if not cv2.imwrite(str(path), arr):
                    raise SfmError(f"cannot write {path}")

        bars: dict[str, Any] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if args.json:
                return
            bar = bars.get(stage)
            if bar is None:
                for b in bars.values():
                    b.close()
                unit = {"prepare": "img", "extract": "img", "match": "pair"}.get(stage, "frame")
                bar = bars[stage] = progress_bar(total, stage, unit=unit)
            bar.n = done
            bar.refresh()

        if args.camera == "stereo" and rig is None:
            raise SfmError("--camera stereo needs the rig (its extrinsics fix the scale); "
                           "pass --rig or use a session that stores one")
        try:
            result = run_sfm(frames, config, rig=rig, pose_priors=priors,
                             workdir=out / ".work", progress=progress, image_sink=sink)
        finally:
            for b in bars.values():
                b.close()
            import shutil

            shutil.rmtree(out / ".work", ignore_errors=True)
    summary = _summary(args, result, rig, priors)
    imu_result, scale = None, 1.0
    if imu is not None and T_cam_body is not None and result.status != "failed":
        decision = imu_scale_for(result, imu, T_cam_body)
        imu_result, scale = decision.estimate, decision.scale
        summary["imu_scale"] = decision.summary
        if decision.summary.get("applied"):
            summary["metric"], summary["metric_source"] = True, "imu"
    if result.reconstruction is not None:
        T, points = scaled_outputs(result, scale)
        write_colmap_model(result.reconstruction, out / "sparse")
        write_ply(out / "points.ply", points, result.colors_rgb)
        # sessions name frames by their integer stamp (exact); a glob's t is the image index
        t_ns = (np.array([int(n) for n in result.names], dtype=np.int64) if session else
                np.round(np.asarray(result.t_s) * 1e9).astype(np.int64))
        write_tum(out / "trajectory.tum", t_ns, T,
                  header="t x y z qx qy qz qw (T_world_left, metres when metric)")
    write_summary(out / "summary.json", summary)
    if result.status == "failed":
        raise SfmError(f"{src}: {result.message}")
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        imu_note = f"; {imu_result.message}" if imu_result is not None else ""
        print(f"{result.message}; {'metric' if summary['metric'] else 'up to scale'}{imu_note} "
              f"-> {out}/ (sparse/, points.ply, trajectory.tum, summary.json) in "
              f"{result.timings_s.get('total_s', 0.0):.1f} s")
    return 0


def _summary(args: argparse.Namespace, result: Any, rig: Any, priors: Any) -> dict[str, Any]:
    metric_source = None
    if result.metric:
        metric_source = "pose_priors" if priors is not None and args.camera != "stereo" else (
            "stereo_rig")
    return {
        "input": str(args.input),
        "status": result.status,
        "message": result.message,
        "camera": args.camera,
        "matcher": args.matcher,
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
        "trajectory_camera": "right" if args.camera == "right" and rig is None else "left",
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
