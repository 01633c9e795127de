"""``sea3d odometry``: the camera trajectory of a recorded dive (stereo + IMU), or of RGB-D
frames, and ``sea3d calibrate imu``: the camera-IMU rotation and time offset.

    sea3d odometry dive.mcap -o traj.tum [--rig rig.yaml] [--no-imu] [--json]
    sea3d odometry euroc/V1_01_easy -o traj.tum
    sea3d odometry rgbd --color 'rgb/*.png' --depth 'depth/*.png' \\
        --intrinsics 585 585 320 240 [--depth-scale 1000] -o traj.tum
    sea3d calibrate imu dive.mcap [--rig rig.yaml] [-o rig_with_imu.yaml] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d._text import loop_checks_text
from sea3d.cli import error_line
from sea3d.cli._args import (
    add_depth_range,
    add_loop_closure_flag,
    config_option,
    depth_config,
    odometry_config,
    param_option,
)
from sea3d.errors import ConfigError

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands
    from sea3d.pipeline.odometry_session import OdometryFiles

__all__ = ["register", "register_calibrate_imu"]

_USAGE = (
    "sea3d odometry SESSION -o TRAJ.tum [--rig RIG] [--no-imu] [--json] ...\n"
    "       sea3d odometry rgbd --color GLOB --depth GLOB --intrinsics FX FY CX CY "
    "[--depth-scale 1000] -o TRAJ.tum [--json]"
)


def register(sub: Subcommands) -> None:
    """Add ``sea3d odometry``."""
    from sea3d.odometry.rgbd_dense import DenseRgbdConfig

    p = sub.add_parser(
        "odometry",
        usage=_USAGE,
        help="camera trajectory of a session (stereo + IMU) or of RGB-D frames",
        description="Stereo(-inertial) odometry with loop closure of a recorded session (MCAP, "
        "folder, or EuRoC), or keyframe-based RGB-D odometry with 'rgbd'. Writes a TUM "
        "trajectory of T_world_left (one line per frame, t in seconds) and says the status of "
        "every frame (tracking, imu_only, lost, relocalised).",
    )
    p.add_argument(
        "session", metavar="SESSION", help="session (.mcap or folder), EuRoC folder, or 'rgbd'"
    )
    p.add_argument("-o", "--output", required=True, type=Path, metavar="TRAJ.tum")
    p.add_argument("--rig", type=Path, help="rig file (default: the rig stored with the session)")
    p.add_argument("--no-imu", action="store_true", help="visual-only")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument(
        "--status", type=Path, metavar="CSV", help="also write t_ns,status,segment per frame"
    )
    from sea3d.stereo.recipe import DepthConfig

    config_option(p, DepthConfig, "engine",
                  help="stereo engine for the depth (sea3d, sea3d-gpu, opencv)")
    add_depth_range(p, near="nearest depth searched", far="farthest depth kept")
    p.add_argument("--max-frames", type=int, help="stop after this many frames")
    add_loop_closure_flag(p)
    g = p.add_argument_group("rgbd")
    g.add_argument("--color", metavar="GLOB", help="colour images (sorted naturally)")
    g.add_argument("--depth", metavar="GLOB", help="depth images, 16-bit (0 = invalid)")
    g.add_argument(
        "--intrinsics",
        type=float,
        nargs=4,
        metavar=("FX", "FY", "CX", "CY"),
        help="depth camera intrinsics, pixels",
    )
    from sea3d.pipeline.odometry_session import rgbd_odometry_to_files

    param_option(g, rgbd_odometry_to_files, "method", choices=("dense", "features"),
                 help="dense: frame-to-keyframe dense alignment; features: sparse features, "
                 "keyframes and windowed BA through the stereo engine")
    param_option(g, rgbd_odometry_to_files, "depth_scale", type=float, shown="1000: millimetres",
                 help="depth units per metre")
    config_option(g, DenseRgbdConfig, "tracking", choices=("keyframe", "model"),
                  help="dense method: align each frame to the keyframe or to the fused TSDF "
                  "model ray-cast at the previous pose")
    p.set_defaults(handler=_run)


def _progress(total: int | None, desc: str, enabled: bool = True) -> Any:
    from sea3d.cli._progress import bar

    return bar(total, desc, enabled=enabled)


def _report(args: argparse.Namespace, out: OdometryFiles) -> int:
    s = out.summary
    if args.json:
        json.dump(s.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        for note in s.notes:
            print(f"note: {error_line(note)}")
        st = s.statuses
        print(
            f"wrote {s.frames} poses to {args.output}: {s.keyframes} keyframes, "
            f"{s.loop_closures} loop closures ({s.relinks} re-links across lost "
            f"frames apart){loop_checks_text(s.loop_checks)}, path "
            f"{s.path_length_m:.2f} m; frames "
            f"tracking {st['tracking']}, imu_only {st['imu_only']}, lost {st['lost']}, "
            f"relocalised {st['relocalised']}, initialising {st['initialising']}; "
            f"{'with IMU' if s.imu else 'visual-only'}; {s.seconds:.1f} s"
        )
    bad = out.untrusted_frames
    if bad:
        print(
            f"sea3d: warning: {bad} of {s.frames} frames have no trustworthy pose (status "
            f"lost/initialising{'; see --status' if not args.status else ''})",
            file=sys.stderr,
        )
    return 0


class _Bar:
    """A progress bar opened once the pipeline knows the frame count."""

    def __init__(self, desc: str, enabled: bool) -> None:
        self.desc, self.enabled, self.bar = desc, enabled, None

    def start(self, n: int) -> None:
        self.bar = _progress(n, self.desc, self.enabled)

    def update(self, k: int) -> None:
        if self.bar is not None:
            self.bar.update(k)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _run(args: argparse.Namespace) -> int:
    if args.max_frames is not None and args.max_frames < 1:
        raise ConfigError(f"--max-frames must be >= 1, got {args.max_frames}")
    if args.session == "rgbd":
        return _run_rgbd(args)
    for name in ("color", "depth", "intrinsics"):
        if getattr(args, name) is not None:
            raise ConfigError(f"--{name} belongs to 'sea3d odometry rgbd'")
    from sea3d.pipeline.odometry_session import stereo_odometry_to_files

    bar = _Bar("odometry", not args.json)
    try:
        out = stereo_odometry_to_files(
            args.session,
            trajectory=args.output,
            status_csv=args.status,
            rig_path=args.rig,
            use_imu=not args.no_imu,
            depth=depth_config(args),
            config=odometry_config(args),
            max_frames=args.max_frames,
            progress=bar.update,
            on_start=bar.start,
        )
    finally:
        bar.close()
    return _report(args, out)


def _run_rgbd(args: argparse.Namespace) -> int:
    from sea3d.odometry.rgbd_dense import DenseRgbdConfig
    from sea3d.pipeline.odometry_session import rgbd_odometry_to_files

    if args.color is None or args.depth is None or args.intrinsics is None:
        raise ConfigError(
            "sea3d odometry rgbd needs --color GLOB, --depth GLOB and --intrinsics FX FY CX CY"
        )
    bar = _Bar("rgbd odometry", not args.json)
    try:
        out = rgbd_odometry_to_files(
            args.color,
            args.depth,
            tuple(args.intrinsics),
            trajectory=args.output,
            status_csv=args.status,
            depth_scale=args.depth_scale,
            method=args.method,
            config=odometry_config(args),
            progress=bar.update,
            on_start=bar.start,
            dense_config=DenseRgbdConfig(
                tracking=args.tracking, loop_closure=not args.no_loop_closure
            ),
        )
    finally:
        bar.close()
    return _report(args, out)


# ---------------------------------------------------------------------- calibrate imu
def register_calibrate_imu(csub: Subcommands) -> None:
    """Add ``sea3d calibrate imu`` (called from :mod:`sea3d.cli.calibrate`)."""
    p = csub.add_parser(
        "imu",
        help="camera-IMU rotation and time offset from a recorded session (gyro against vision)",
        description="Runs the visual odometry on the session, then matches the camera's angular "
        "velocity to the gyro's: time offset (t_imu = t_cam + offset) by cross-correlation, "
        "rotation in closed form, both refined with the gyro bias by robust least squares. The "
        "session needs rotation about at least two axes. The IMU's position on the rig is kept "
        "from the rig (or zero).",
    )
    p.add_argument("session", metavar="SESSION")
    p.add_argument("--rig", type=Path, help="rig file (default: the session's stored rig)")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="RIG",
        help="write the rig with the estimated IMU block",
    )
    from sea3d.pipeline.odometry_session import calibrate_camera_imu
    from sea3d.stereo.recipe import DepthConfig

    param_option(p, calibrate_camera_imu, "max_offset_s", type=float,
                 help="offset searched (+-, s)")
    config_option(p, DepthConfig, "engine", help="stereo engine for the depth")
    p.add_argument("--max-frames", type=int, help="use only the first frames")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(handler=_calibrate_imu)


def _calibrate_imu(args: argparse.Namespace) -> int:
    import numpy as np

    from sea3d.calib.imu import CameraImuStatus
    from sea3d.geometry.se3 import R_to_rotvec
    from sea3d.pipeline.odometry_session import calibrate_camera_imu
    from sea3d.stereo.recipe import DepthConfig

    bar = _Bar("visual odometry", not args.json)
    try:
        cal = calibrate_camera_imu(
            args.session,
            rig_path=args.rig,
            depth=DepthConfig(engine=args.engine),
            max_offset_s=args.max_offset_s,
            max_frames=args.max_frames,
            progress=bar.update,
            on_start=bar.start,
        )
    finally:
        bar.close()
    res, out = cal.result, dict(cal.summary)
    if args.output is not None and cal.rig is not None:
        from sea3d.io.rig_file import save_rig

        save_rig(cal.rig, args.output)
        out["rig"] = str(args.output)
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        ang = np.degrees(np.linalg.norm(R_to_rotvec(res.R_cam_imu)))
        print(
            f"camera-IMU: {res.status.value}; time offset {res.time_offset_s * 1e3:.2f} ms "
            f"(t_imu = t_cam + offset), rotation {ang:.2f} deg from identity, gyro bias "
            f"{np.round(res.gyro_bias_radps, 5).tolist()} rad/s, residual "
            f"{res.residual_rms_radps:.4f} rad/s over {res.samples} samples"
            + (f"; wrote {args.output}" if "rig" in out else "")
        )
    if res.status is not CameraImuStatus.OK:
        if not args.json:
            for line in res.advice:
                print(f"advice: {error_line(line)}")
        print(
            f"sea3d: warning: no usable estimate ({res.status.value}); the rig was not written"
            if args.output
            else f"sea3d: warning: {res.status.value}",
            file=sys.stderr,
        )
        return 1
    return 0
