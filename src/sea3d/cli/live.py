"""``sea3d live``: live reconstruction (odometry on every frame, depth and fusion as it keeps
up), here from a recorded session replayed at its rate (``--replay``)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sea3d.cli._args import image_size

__all__ = ["register"]


def _cmd_live(args: argparse.Namespace) -> int:
    from sea3d.errors import ConfigError
    from sea3d.pipeline.live import LiveConfig, run_live_replay
    from sea3d.pipeline.process import PoseConfig, ProcessConfig

    if args.replay is None:
        raise ConfigError("give --replay SESSION (live cameras: sea3d record's listener hook "
                          "is not wired to live yet)")
    config = ProcessConfig(out_dir=args.output, rig_path=args.rig, size_px=args.size,
                           poses=PoseConfig(poses_path=args.poses, use_imu=not args.no_imu),
                           max_frames=args.max_frames, report=False)
    summary, stats = run_live_replay(args.replay, config,
                                     LiveConfig(depth_in_flight=args.depth_in_flight),
                                     rate=args.rate)
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
        return 0
    live = summary["live"]
    lat = live["latency_s"]
    print(f"{stats.frames} frames: {live['fraction_tracked']:.0%} tracked, "
          f"{live['fraction_fused']:.0%} fused ({stats.depth_dropped} depth frames dropped to "
          f"keep up); latency p50 {lat['p50'] or 0:.2f} s, p99 {lat['p99'] or 0:.2f} s; "
          f"{live['stop_reason']}; outputs in {args.output}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("live", help="live reconstruction (from a replayed session)",
                       description=__doc__)
    p.add_argument("--replay", type=Path, help="a recorded session, replayed at its rate")
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    p.add_argument("--rate", type=float, default=1.0, help="replay speed (default 1: as "
                   "recorded)")
    p.add_argument("--rig", type=Path, help="rig file (default: the session's)")
    p.add_argument("--size", type=image_size, help="process at WxH")
    p.add_argument("--poses", type=Path, help="known T_world_left poses instead of odometry")
    p.add_argument("--no-imu", action="store_true", help="visual odometry only")
    p.add_argument("--max-frames", type=int, help="only the first N pairs")
    p.add_argument("--depth-in-flight", type=int, default=1,
                   help="depth frames computed at once (default 1)")
    p.add_argument("--json", action="store_true", help="print summary.json")
    p.set_defaults(handler=_cmd_live)
