"""``sea3d sfm``: structure from motion of an image glob or a session (pycolmap); the run is
:func:`sea3d.pipeline.sfm_session.sfm_to_files`, this module parses, calls and prints.

Writes ``OUT/sparse/`` (the COLMAP model, binary and text), ``OUT/points.ply``,
``OUT/trajectory.tum`` (``T_world_left`` of every registered frame; ``t`` is the session's time
in seconds, or the image's 0-based index in sorted order for a glob) and ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import json
from functools import partial
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import config_option

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register"]


def register(sub: Subcommands) -> None:
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


# ---------------------------------------------------------------------- command
def _progress(enabled: bool) -> tuple[Any, Any]:
    """``progress(stage, done, total)`` drawing one bar per stage (the last one open), and a
    ``close()``."""
    from sea3d.cli._progress import bar as progress_bar

    bars: dict[str, Any] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if not enabled:
            return
        b = bars.get(stage)
        if b is None:
            for old in bars.values():
                old.close()
            unit = {"prepare": "img", "extract": "img", "match": "pair"}.get(stage, "frame")
            b = bars[stage] = progress_bar(total, stage, unit=unit)
        b.n = done
        b.refresh()

    def close() -> None:
        for b in bars.values():
            b.close()

    return progress, close


def _cmd_sfm(args: argparse.Namespace) -> int:
    from sea3d.pipeline.sfm_session import read_pose_priors, sfm_to_files
    from sea3d.sfm import SfmConfig

    make = SfmConfig.fast if args.fast else SfmConfig
    config = make(
        camera=args.camera, matcher=args.matcher, max_image_px=args.max_image_px,
        max_features=args.max_features, sequential_overlap=args.overlap,
        self_calibration_model=args.camera_model, depth_range_m=tuple(args.depth_range),
        refractive_ba=args.refractive_ba, prior_position_std_m=args.prior_std,
        num_threads=args.threads, seed=args.seed,
    )
    priors = (read_pose_priors(args.pose_priors, args.pose_priors_format,
                               kitti_times=args.pose_priors_times)
              if args.pose_priors else None)
    progress, close = _progress(not args.json)
    try:
        run = sfm_to_files(args.input, args.output, config=config, rig_path=args.rig,
                           self_calibrate=args.self_calibrate, pose_priors=priors,
                           imu_scale=args.imu_scale, imu_extrinsics=args.imu_extrinsics,
                           export_images=args.export_images, progress=progress)
    finally:
        close()
    summary, result = run.summary, run.result
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        imu_note = f"; {run.imu_estimate.message}" if run.imu_estimate is not None else ""
        print(f"{result.message}; {'metric' if summary['metric'] else 'up to scale'}{imu_note} "
              f"-> {run.out_dir}/ (sparse/, points.ply, trajectory.tum, summary.json) in "
              f"{result.timings_s.get('total_s', 0.0):.1f} s")
    return 0
