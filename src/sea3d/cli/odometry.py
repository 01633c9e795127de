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
from typing import Any

from sea3d.cli._args import add_depth_range, depth_config
from sea3d.errors import ConfigError

__all__ = ["register", "register_calibrate_imu"]

_USAGE = (
    "sea3d odometry SESSION -o TRAJ.tum [--rig RIG] [--no-imu] [--json] ...\n"
    "       sea3d odometry rgbd --color GLOB --depth GLOB --intrinsics FX FY CX CY "
    "[--depth-scale 1000] -o TRAJ.tum [--json]"
)


def register(sub: Any) -> None:
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
    p.add_argument(
        "--engine",
        default="sea3d",
        help="stereo engine for the depth (sea3d, sea3d-gpu, opencv; default sea3d)",
    )
    add_depth_range(p, near="nearest depth searched", far="farthest depth kept")
    p.add_argument("--max-frames", type=int, help="stop after this many frames")
    p.add_argument("--no-loop-closure", action="store_true", help="odometry only")
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
    g.add_argument(
        "--method",
        choices=("dense", "features"),
        default="dense",
        help="dense: frame-to-keyframe dense alignment (default); features: sparse features, "
        "keyframes and windowed BA through the stereo engine",
    )
    g.add_argument(
        "--tracking",
        choices=("keyframe", "model"),
        default=DenseRgbdConfig().tracking,
        help="dense method: align each frame to the keyframe (default) or to the fused TSDF "
        "model ray-cast at the previous pose",
    )
    g.add_argument(
        "--depth-scale",
        type=float,
        default=1000.0,
        help="depth units per metre (default 1000: millimetres)",
    )
    p.set_defaults(handler=_run)


def _progress(total: int | None, desc: str, enabled: bool = True) -> Any:
    from sea3d.cli._progress import bar

    return bar(total, desc, enabled=enabled)


def _config(args: argparse.Namespace) -> Any:
    from sea3d.odometry import OdometryConfig

    return OdometryConfig(loop_closure=not args.no_loop_closure)


def _write_status(path: Path, run: Any) -> None:
    lines = ["t_ns,status,segment"]
    lines += [
        f"{t},{s.value},{g}"
        for t, s, g in zip(run.t_ns.tolist(), run.statuses, run.segments, strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")


def _check_output(args: argparse.Namespace) -> None:
    for path in (args.output, args.status):
        if path is not None and Path(path).is_dir():
            raise ConfigError(f"{path} is a folder; give a file name for the trajectory")


def _check_poses(run: Any) -> None:
    """Refuse a run that has no pose to report (identity poses are not a trajectory)."""
    import numpy as np

    from sea3d.errors import OdometryError
    from sea3d.odometry import TrackingStatus

    n = len(run.statuses)
    trusted = [s in (TrackingStatus.TRACKING, TrackingStatus.RELOCALISED,
                     TrackingStatus.IMU_ONLY) for s in run.statuses]
    no_depth = int(run.summary.get("frames_without_depth", 0))
    rng = run.summary.get("depth_range_m")
    within = f" {rng[0]:.3g}..{rng[1]:.3g} m" if rng else ""
    if n and no_depth == n:
        raise OdometryError(
            f"no frame has valid depth in the depth range{within} ({n} frames): the range "
            "excludes the whole scene, or the images have nothing to track; set "
            "--min-depth/--max-depth; no trajectory written"
        )
    if n and not any(trusted[1:]):
        raise OdometryError(
            f"no frame could be tracked ({n} frames, none with a pose beyond the first): the "
            "images have nothing to track (black, flat or featureless), or the depth range"
            f"{within} holds too little of the scene (--min-depth/--max-depth); no trajectory "
            "written"
        )
    T = np.asarray(run.T_world_left)
    if n > 2 and np.allclose(T, np.eye(4), atol=1e-12):
        raise OdometryError(
            f"every one of the {n} poses is the identity: nothing was tracked; no trajectory "
            "written"
        )


def _report(args: argparse.Namespace, run: Any) -> int:
    from sea3d.io.trajectory_files import write_tum

    _check_poses(run)
    write_tum(
        args.output,
        run.t_ns,
        run.T_world_left,
        header="t tx ty tz qx qy qz qw (T_world_left; t in seconds)",
    )
    if args.status:
        _write_status(args.status, run)
    s = run.summary
    s["trajectory"] = str(args.output)
    if args.json:
        json.dump(s, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        for note in s.get("notes", []):
            print(f"note: {note}")
        st = s["statuses"]
        print(
            f"wrote {s['frames']} poses to {args.output}: {s['keyframes']} keyframes, "
            f"{s['loop_closures']} loop closures, path {s['path_length_m']:.2f} m; frames "
            f"tracking {st['tracking']}, imu_only {st['imu_only']}, lost {st['lost']}, "
            f"relocalised {st['relocalised']}, initialising {st['initialising']}; "
            f"{'with IMU' if s['imu'] else 'visual-only'}; {s['seconds']:.1f} s"
        )
    bad = s["frames_lost"] + s["statuses"]["initialising"]
    if bad:
        print(
            f"sea3d: warning: {bad} of {s['frames']} frames have no trustworthy pose (status "
            f"lost/initialising{'; see --status' if not args.status else ''})",
            file=sys.stderr,
        )
    return 0


def _run(args: argparse.Namespace) -> int:
    _check_output(args)
    if args.max_frames is not None and args.max_frames < 1:
        raise ConfigError(f"--max-frames must be >= 1, got {args.max_frames}")
    if args.session == "rgbd":
        return _run_rgbd(args)
    for name in ("color", "depth", "intrinsics"):
        if getattr(args, name) is not None:
            raise ConfigError(f"--{name} belongs to 'sea3d odometry rgbd'")
    from sea3d.pipeline.odometry import session_odometry

    bar: Any = None

    def on_open(src: Any, imu_ok: bool, why: str | None) -> None:
        nonlocal bar
        n = src.t_ns.size if args.max_frames is None else min(src.t_ns.size, args.max_frames)
        bar = _progress(n, "odometry", not args.json)

    try:
        run = session_odometry(
            args.session,
            rig_path=args.rig,
            use_imu=not args.no_imu,
            observe=depth_config(args),
            config=_config(args),
            max_frames=args.max_frames,
            progress=lambda k: bar.update(k) if bar is not None else None,
            on_open=on_open,
        )
    finally:
        if bar is not None:
            bar.close()
    return _report(args, run)


def _run_rgbd(args: argparse.Namespace) -> int:
    from sea3d.odometry.rgbd_dense import DenseRgbdConfig
    from sea3d.pipeline.odometry import rgbd_observations, rgbd_odometry

    if args.color is None or args.depth is None or args.intrinsics is None:
        raise ConfigError(
            "sea3d odometry rgbd needs --color GLOB, --depth GLOB and --intrinsics FX FY CX CY"
        )
    cp, _, _, _ = rgbd_observations(
        args.color, args.depth, tuple(args.intrinsics), depth_scale=args.depth_scale
    )
    with _progress(len(cp), "rgbd odometry", not args.json) as bar:
        run = rgbd_odometry(
            args.color,
            args.depth,
            tuple(args.intrinsics),
            depth_scale=args.depth_scale,
            config=_config(args),
            progress=bar.update,
            method=args.method,
            dense_config=DenseRgbdConfig(
                tracking=args.tracking, loop_closure=not args.no_loop_closure
            ),
        )
    return _report(args, run)


# ---------------------------------------------------------------------- calibrate imu
def register_calibrate_imu(csub: Any) -> None:
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
    p.add_argument("--max-offset-s", type=float, default=0.5, help="offset searched (+-, s)")
    p.add_argument("--engine", default="sea3d", help="stereo engine for the depth")
    p.add_argument("--max-frames", type=int, help="use only the first frames")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(handler=_calibrate_imu)


def _calibrate_imu(args: argparse.Namespace) -> int:
    import dataclasses

    import numpy as np

    from sea3d.calib.imu import CameraImuStatus, estimate_camera_imu
    from sea3d.errors import CalibrationError
    from sea3d.geometry.rig import ImuSpec
    from sea3d.geometry.se3 import R_to_rotvec
    from sea3d.odometry import TrackingStatus
    from sea3d.pipeline.odometry import open_stereo_source, session_odometry
    from sea3d.stereo.recipe import DepthConfig

    src = open_stereo_source(args.session, args.rig)
    rig = src.rig
    imu_t, gyro = src.imu_t_ns, src.gyro_radps
    src.close()
    if imu_t.size == 0:
        raise CalibrationError(f"{args.session}: the session has no IMU samples")
    n = src.t_ns.size if args.max_frames is None else min(src.t_ns.size, args.max_frames)
    with _progress(n, "visual odometry", not args.json) as bar:
        run = session_odometry(
            args.session,
            rig_path=args.rig,
            use_imu=False,
            observe=DepthConfig(engine=args.engine),
            max_frames=args.max_frames,
            progress=bar.update,
        )
    good = np.array(
        [s in (TrackingStatus.TRACKING, TrackingStatus.RELOCALISED) for s in run.statuses],
        dtype=bool,
    )
    guess = rig.imu.T_left_imu[:3, :3] if rig.imu is not None else None
    res = estimate_camera_imu(
        run.t_ns,
        run.T_world_left[:, :3, :3],
        imu_t,
        gyro,
        max_offset_s=args.max_offset_s,
        valid=good,
    )
    out: dict[str, Any] = res.as_dict()
    if guess is not None:
        d = R_to_rotvec(guess.T @ res.R_cam_imu)
        out["change_from_rig_deg"] = float(np.degrees(np.linalg.norm(d)))
    if args.output is not None and res.status is CameraImuStatus.OK:
        from sea3d.io.rig_file import save_rig

        T = np.eye(4)
        T[:3, :3] = res.R_cam_imu
        if rig.imu is not None:
            T[:3, 3] = rig.imu.T_left_imu[:3, 3]
            imu = dataclasses.replace(rig.imu, T_left_imu=T, time_offset_s=res.time_offset_s)
        else:
            imu = ImuSpec(T_left_imu=T, time_offset_s=res.time_offset_s)
        save_rig(dataclasses.replace(rig, imu=imu), args.output)
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
                print(f"advice: {line}")
        print(
            f"sea3d: warning: no usable estimate ({res.status.value}); the rig was not written"
            if args.output
            else f"sea3d: warning: {res.status.value}",
            file=sys.stderr,
        )
        return 1
    return 0
