"""``sea3d bag``: read other cameras' ROS 2 bags and MCAP files by mapping their topics.

::

    sea3d bag info oak.mcap --preset oak-d
    sea3d bag export oak.mcap --preset oak-d -o oak_session.mcap --rgbd oak_rgbd/
    sea3d bag export zed_bag/ --topic left=/zed/zed_node/left/image_rect_color \\
        --topic right=/zed/zed_node/right/image_rect_color \\
        --topic left_info=/zed/zed_node/left/camera_info \\
        --topic right_info=/zed/zed_node/right/camera_info -o zed.mcap
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register"]


def _map_args(p: Any) -> None:
    p.add_argument("bag", metavar="BAG", help="rosbag2 folder, .mcap or .db3 file")
    p.add_argument("--preset", choices=("oak-d", "zed", "realsense"), help="a driver's layout")
    p.add_argument(
        "--topic",
        action="append",
        default=[],
        metavar="ROLE=/TOPIC",
        help="map a role (left, right, color, depth, left_info, right_info, color_info, "
        "depth_info, imu, sonar) to a topic; overrides the preset; ROLE= drops it",
    )


def register(sub: Subcommands) -> None:
    """Add ``bag info`` and ``bag export``."""
    p = sub.add_parser(
        "bag",
        help="read another camera's ROS 2 bag or MCAP (OAK-D, ZED, RealSense) by topic map",
        description="Map a ROS 2 bag's topics to sea3d's roles and export a sea3d session "
        "(stereo + IMU + rig from CameraInfo: sea3d depth, process and eval run on it) and/or "
        "RGB-D frames (color/, depth/ 16-bit mm, intrinsics.json) for the RGB-D tools.",
    )
    bsub = p.add_subparsers(dest="bag_command", metavar="ACTION")

    def usage(_args: argparse.Namespace) -> int:  # the command without a subcommand
        p.print_help(sys.stderr)
        return 2

    p.set_defaults(handler=usage)
    info = bsub.add_parser("info", help="topics and types; what a map picks")
    _map_args(info)
    info.add_argument("--json", action="store_true")
    info.set_defaults(handler=_info)
    ex = bsub.add_parser("export", help="to a sea3d session and/or RGB-D frame files")
    _map_args(ex)
    ex.add_argument("-o", "--output", metavar="SESSION", help="sea3d session (.mcap or folder)")
    ex.add_argument("--rgbd", metavar="DIR", help="RGB-D frames: color/, depth/, intrinsics.json")
    ex.add_argument("--max-frames", type=int, metavar="N", help="only the first N frames")
    ex.add_argument("--json", action="store_true", help="print the summary as JSON")
    ex.set_defaults(handler=_export)


def _map(args: argparse.Namespace) -> Any:
    from sea3d.io.topic_map import TopicMap, parse_topic_args

    tmap = TopicMap.build(args.preset, parse_topic_args(args.topic))
    if not tmap.topics and getattr(args, "handler", None) is not _info:
        from sea3d.errors import SessionError

        raise SessionError("no topics mapped: give --preset or --topic ROLE=/topic")
    return tmap


def _info(args: argparse.Namespace) -> int:
    from pathlib import Path

    from rosbags.highlevel import AnyReader

    from sea3d.errors import SessionError

    tmap = _map(args)
    if not Path(args.bag).exists():
        raise SessionError(f"bag {args.bag} does not exist")
    try:
        with AnyReader([Path(args.bag)]) as r:
            topics = {c.topic: (c.msgtype, c.msgcount) for c in r.connections}
    except Exception as err:  # rosbags' own error types
        raise SessionError(f"cannot open bag {args.bag}: {err}") from err
    # info lists what is there: a preset's roles the bag lacks are named, not an error (export
    # still refuses them).
    mapped = {role: t for role, t in tmap.topics.items() if t in topics}
    missing = {role: t for role, t in tmap.topics.items() if t not in topics}
    if args.json:
        out = {"topics": {t: {"type": ty, "count": n} for t, (ty, n) in topics.items()}}
        json.dump({**out, "map": mapped, "missing": missing}, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    role_of = {t: r for r, t in mapped.items()}
    for t, (ty, n) in sorted(topics.items()):
        print(f"{t:<55} {ty:<36} {n:>7}  {role_of.get(t, '')}")
    if missing:
        what = f"preset {args.preset}" if args.preset else "the map"
        print(f"not in this bag ({what}): "
              + ", ".join(f"{role} ({t})" for role, t in sorted(missing.items()))
              + "; 'sea3d bag export' needs them, or --topic ROLE=/topic (ROLE= drops one)")
    return 0


def _export(args: argparse.Namespace) -> int:
    from sea3d.errors import SessionError
    from sea3d.io.topic_map import export_rgbd, export_session

    if not (args.output or args.rgbd):
        raise SessionError("sea3d bag export needs -o SESSION and/or --rgbd DIR")
    from sea3d.io.topic_map import MappedBag

    bag = MappedBag(args.bag, _map(args))
    summary: dict[str, Any] = {"bag": args.bag}
    with bag:
        if args.output:
            summary["session"] = {
                "path": args.output,
                **export_session(bag, args.output, max_frames=args.max_frames),
            }
        if args.rgbd:
            summary["rgbd"] = {
                "path": args.rgbd,
                **export_rgbd(bag, args.rgbd, max_frames=args.max_frames),
            }
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    if "session" in summary:
        s = summary["session"]
        c = s["counts"]
        print(
            f"wrote {s['path']}: {c['left']} stereo pairs ({s['size'][0]}x{s['size'][1]}, "
            f"baseline {1000 * s['baseline_m']:.1f} mm), {c['imu']} IMU, {c['sonar']} echosounder; "
            f"{s['unpaired_left']} left and {s['unpaired_right']} right unpaired"
        )
        print(f"  next: sea3d depth --session {s['path']} -o depth_out/")
    if "rgbd" in summary:
        r = summary["rgbd"]
        i = r["intrinsics"]
        print(f"wrote {r['frames']} RGB-D frames to {r['path']} (depth 16-bit mm)")
        if "fx" in i:
            glob = f"--color '{r['path']}/color/*.png' --depth '{r['path']}/depth/*.png'"
            print(
                f"  RGB-D tools: {glob} --intrinsics {i['fx']:.3f} {i['fy']:.3f} "
                f"{i['cx']:.3f} {i['cy']:.3f} --depth-scale 1000"
            )
    return 0
