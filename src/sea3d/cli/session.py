"""``sea3d session``: inspect and convert recorded sessions (MCAP files or folders)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from sea3d.cli._args import param_option, plural

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register"]


def register(sub: Subcommands) -> None:
    """Add ``session info``, ``session verify`` and ``session convert`` to the subparsers."""
    parser = sub.add_parser(
        "session",
        help="inspect and convert recorded sessions",
        description="Inspect and convert recorded sessions: an .mcap file of ROS 2 messages "
        "or a folder of left/<t_ns>.png, right/<t_ns>.png, imu.csv, sonar.csv, rig.yaml.",
    )
    ssub = parser.add_subparsers(dest="session_command", metavar="SUBCOMMAND")

    def usage(_args: argparse.Namespace) -> int:  # the command without a subcommand
        parser.print_help()
        return 2

    parser.set_defaults(handler=usage)

    info = ssub.add_parser("info", help="streams, counts, rates, gaps, duration, size")
    info.add_argument("path", help="session: .mcap file or folder")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    info.add_argument(
        "--tolerance-ms",
        type=float,
        default=None,
        help="stereo pairing tolerance in ms (default: half the median left frame interval)",
    )
    from sea3d.io.session import open_session, verify_session

    param_option(info, open_session, "name_unit", choices=("ns", "us"),
                 help="unit of the stamps in image file names of a folder (the paper used us)")
    info.set_defaults(handler=_info)

    ver = ssub.add_parser(
        "verify",
        help="check every CRC and decode every record; list damaged chunks and frames (exit "
        "status 1 if any)",
    )
    ver.add_argument("path", help="session: .mcap file or folder")
    ver.add_argument("--json", action="store_true", help="print JSON")
    param_option(ver, verify_session, "name_unit", choices=("ns", "us"),
                 help="unit of the stamps in image file names of a folder")
    ver.set_defaults(handler=_verify)

    conv = ssub.add_parser(
        "convert",
        help="folder to MCAP and back (chosen by OUT's extension; lossless for PNG)",
    )
    conv.add_argument("input", help="session to read: .mcap file or folder")
    conv.add_argument("output", help="new session: *.mcap writes MCAP, anything else a folder")
    conv.add_argument(
        "--image-encoding",
        choices=("png", "jpeg", "raw"),
        default=None,
        help="output image encoding (default: keep the input's)",
    )
    conv.add_argument(
        "--strict",
        action="store_true",
        help="refuse to convert a session with any damage (default: skip damaged records and "
        "list them; exit status 1)",
    )
    conv.set_defaults(handler=_convert)


def _fmt_t(t_ns: int | None) -> str:
    return "-" if t_ns is None else f"{t_ns * 1e-9:.6f}"


def _info(args: argparse.Namespace) -> int:
    from sea3d.io.session import open_session

    tol = None if args.tolerance_ms is None else round(args.tolerance_ms * 1e6)
    with open_session(args.path, name_unit=args.name_unit) as s:
        report = s.summary(tolerance_ns=tol)
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    out = sys.stdout
    out.write(f"session   {report['path']} ({report['format']})\n")
    out.write(f"size      {report['size_bytes'] / 1e6:.1f} MB\n")
    out.write(f"duration  {report['duration_s']:.3f} s\n")
    out.write(f"rig       {report['rig_status']}\n")
    out.write(f"checked   {report['checked']}\n")
    out.write(f"unchecked {report['not_checked']}\n")
    problems = report["problems"]
    if problems:
        out.write(f"problems  {len(problems)}, first: {problems[0]}\n")
    out.write("\n")
    out.write(
        f"{'stream':<8}{'count':>8} {'rate Hz':>11}{'first s':>21}{'last s':>21}{'gaps':>6}\n"
    )
    for name, st in report["streams"].items():
        out.write(
            f"{name:<8}{st['count']:>8} {st['rate_hz']:>11.2f}{_fmt_t(st['first_t_ns']):>21}"
            f"{_fmt_t(st['last_t_ns']):>21}{st['gaps']:>6}\n"
        )
    p = report["pairs"]
    out.write(
        f"\nstereo pairs {p['count']} within {p['tolerance_ns'] / 1e6:.3f} ms; unpaired: "
        f"{p['unpaired_left']} left, {p['unpaired_right']} right\n"
    )
    return 0


def _convert(args: argparse.Namespace) -> int:
    from sea3d.cli._progress import bar as make_bar
    from sea3d.io.session import convert_session

    bar = make_bar(0, "convert", unit="image")

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        report = convert_session(
            args.input,
            args.output,
            image_encoding=args.image_encoding,
            strict=args.strict,
            progress=progress,
        )
    finally:
        bar.close()
    skipped = report.pop("skipped", 0)
    problems = report.pop("problems", [])
    parts = ", ".join(f"{v} {k}" for k, v in report.items())
    line = f"wrote {args.output}: {parts}"
    if skipped:
        line += f"; skipped {plural(skipped, 'damaged record')}"
    print(line)
    for msg in problems:
        print(f"  {msg}")
    return 1 if problems else 0


def _verify(args: argparse.Namespace) -> int:
    from sea3d.io.session import verify_session

    report = verify_session(args.path, name_unit=args.name_unit)
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        counts = ", ".join(f"{v} {k}" for k, v in report["records"].items())
        n = len(report["problems"])
        print(f"{args.path}: {counts} readable; " + (plural(n, "problem") if n else "no problems"))
        for chunk in report["damaged_chunks"]:
            print(
                f"  damaged chunk at byte {chunk['offset']}: t_ns {chunk['start_ns']}.."
                f"{chunk['end_ns']}, streams {', '.join(chunk['streams'])} ({chunk['reason']})"
            )
        for frame in report["damaged_frames"]:
            print(f"  damaged {frame['stream']} frame t_ns={frame['t_ns']}")
        for msg in report["problems"]:
            print(f"  {msg}")
    return 0 if report["ok"] else 1
