"""``sea3d eval sonar``: the echosounder against the stereo depth along its beam."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import add_depth_range, depth_config, param_option

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register_eval"]


def register_eval(esub: Subcommands) -> None:
    """Add ``eval sonar`` to the ``eval`` command's subparsers."""
    p = esub.add_parser(
        "sonar",
        help="echosounder ranges against the stereo depth along the beam",
        description="For every echosounder sample, the stereo range along the beam axis, "
        "measured in the depth maps of the frames around it through the poses (the footprint "
        "is often outside the view at the same instant), with a local plane fit at the "
        "crossing. Prints samples, median_abs_diff_m, bias and spread, and the Ping "
        "echosounder's own accuracy.",
    )
    p.add_argument("session", metavar="SESSION", help="session (.mcap or folder)")
    p.add_argument("--rig", help="rig.yaml with a sonar: block (default: the session's rig)")
    p.add_argument(
        "--beam-deg",
        type=float,
        metavar="DEG",
        help="beam cone (full angle): the echo is the nearest surface in it; default: the "
        "rig's beam_deg (0: the beam axis, as the simulator models it)",
    )
    p.add_argument(
        "--poses",
        metavar="TRAJ.tum",
        help="T_world_left poses (TUM), e.g. the odometry's trajectory.tum (default: the "
        "simulator's gt/poses_left.tum if there is one, else the same-instant fit)",
    )
    p.add_argument(
        "--depth",
        metavar="DIR",
        help="depth maps DIR[/depth]/<t_ns>.png from 'sea3d depth --session' (default: "
        "computed here)",
    )
    from sea3d.pipeline.sonar_check import run_sonar_check

    param_option(
        p, run_sonar_check, "depth_frame",
        choices=("rect", "raw"),
        help="the depth maps are along the rectified left camera (rect, sea3d depth) or the "
        "raw left camera (raw, the simulator's gt/depth)",
    )
    p.add_argument(
        "--engine", default="opencv", help="matching engine when depth is computed (opencv)"
    )
    param_option(p, run_sonar_check, "every", type=int, help="use every N-th frame")
    param_option(p, run_sonar_check, "window_s", type=float,
                 help="frames within this time of a ping, seconds")
    add_depth_range(p, near="nearest depth (as sea3d depth)", far="farthest depth kept")
    p.add_argument("--no-truth", action="store_true", help="ignore the simulator's ground truth")
    p.add_argument("--report", metavar="OUT.html", help="write an HTML report with a plot")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.set_defaults(handler=_eval_sonar)


def _fmt(c: Any) -> str:
    if c is None or c.samples == 0:
        return "no samples"
    return (
        f"samples {c.samples}  median_abs_diff_m {c.median_abs_diff_m:.4f}  "
        f"bias {c.bias_m:+.4f} m  spread {c.spread_m:.4f} m  ({c.median_abs_diff_pct:.2f} %)"
    )


def _eval_sonar(args: argparse.Namespace) -> int:
    from sea3d.cli._progress import bar as progress_bar
    from sea3d.pipeline.sonar_check import run_sonar_check, write_sonar_report

    rig = None
    if args.rig:
        from sea3d.io.rig_file import load_rig

        rig = load_rig(args.rig)
    with progress_bar(None, "depth", enabled=not args.json, leave=True) as bar:
        ev, info = run_sonar_check(
            args.session,
            rig=rig,
            poses_path=args.poses,
            depth_dir=args.depth,
            depth_frame=args.depth_frame,
            depth=depth_config(args),
            every=args.every,
            beam_deg=args.beam_deg,
            window_s=args.window_s,
            use_truth=not args.no_truth,
            progress=bar.update,
        )
    if args.report:
        write_sonar_report(args.report, ev, info)
    if args.json:
        out = {**ev.summary(), "inputs": info}
        if args.report:
            out["report"] = args.report
        json.dump(out, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    ds = ev.datasheet
    print(f"{ev.measured} of {ev.pings} pings measured by stereo ({info['views']} depth views)")
    print(f"stereo vs echosounder   {_fmt(ev.stereo_vs_sonar)}")
    if ev.stereo_vs_truth is not None:
        print(f"stereo vs truth         {_fmt(ev.stereo_vs_truth)}")
        print(f"echosounder vs truth    {_fmt(ev.sonar_vs_truth)}")
    print(
        f"echosounder datasheet   {ds['model']}: resolution "
        f"{100 * ds['resolution_fraction_of_range']:.1f} % of range, {ds['beam_deg']:g} deg beam"
    )
    print(f"method                  {ev.method}")
    print(f"mount                   {info['mount']}; depth {info['depth']}")
    if args.report:
        print(f"report -> {args.report}")
    return 0
