"""The ``sea3d`` command: a thin shell over the library.

Each area has its own module here with a ``register(subparsers)`` function that adds its
subcommands; handlers import the heavy parts of sea3d lazily so that ``sea3d --help`` stays fast.
This module is the one error boundary: a :class:`~sea3d.errors.Sea3dError` becomes a one-line
message on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import re
import sys
from collections.abc import Sequence
from typing import Any

from sea3d import __version__
from sea3d.errors import Sea3dError

__all__ = ["FlagNames", "build_parser", "command_flags", "error_line", "main"]

# Modules under sea3d.cli that add subcommands, in the order they appear in --help.
_COMMAND_MODULES = (
    "rig", "session", "record", "stream", "bag", "sim", "calibrate", "depth", "enhance",
    "odometry", "sfm", "monodepth", "recon", "live", "eval", "demo",
)  # fmt: skip


# Config field names that library errors name, and the option that sets each: the one-line
# error speaks the command's language. A name is rewritten only where a message names it as a
# field ("workers must be...", "either workers or scheduler", "(strict)"), never inside a word.
_FLAG_OF_FIELD = {
    "voxel_m": "--voxel-m", "workers": "--workers", "scheduler": "--scheduler",
    "max_frames": "--max-frames", "rate": "--rate", "strict": "--strict",
    "fresh": "--fresh", "range_m": "--depth", "max_disparity_px": "--max-disparity",
    "min_depth_m": "--min-depth", "max_depth_m": "--max-depth", "depth_rate": "--depth-rate",
    "depth_scale": "--depth-scale", "rebuild_cache_config": "--rebuild-cache-config",
    "duration_s": "--duration", "queue_frames": "--queue", "encoder_threads": "--encoders",
    "png_compression": "--png-compression", "jpeg_quality": "--jpeg-quality",
    "stall_warn_s": "--stall-warn", "stall_stop_s": "--stall-stop",
}  # fmt: skip
_FIELD_RE = re.compile(
    r"(?<![\w./-])(" + "|".join(_FLAG_OF_FIELD) + r")(?= must\b| or |\)|, not both| to discard)"
    r"|(?<=either )(" + "|".join(_FLAG_OF_FIELD) + r")\b"
)
# Library phrases that name a setting, and how this CLI says them (library code names no flag:
# tests/test_layout.py). Each is specific enough to occur only in the message it comes from.
_PHRASES = {
    "use another output folder, or": "use another -o, or",
    "rerun with rebuild_cache_config to keep": "rerun with --rebuild-cache-config to keep",
    "choose another output folder": "choose another -o/--output folder",
    "stores no rig; give a rig file": "stores no rig; pass --rig rig.yaml",
    "add the echosounder's mount to rig.yaml and pass that rig":
        "add the echosounder's mount to rig.yaml and pass --rig",
    "size_px must be at least 32x24": "--size must be at least 32x24",
    "a topic entry expects": "--topic expects", "in topic entry": "in --topic",
    "min_depth_m/max_depth_m": "--min-depth/--max-depth",
    "use_imu off: visual-only": "--no-imu: visual-only",
    "add it from a Kalibr camera-IMU calibration": "add it with 'sea3d rig create --kalibr'",
    "; give the rig of this camera (size_px then sets the processing size)":
        "; pass the rig of this camera with --rig (--size then sets the processing size)",
    "widen max_offset_s": "widen --max-offset-s",
    "Add views or use the simple distortion model.": "Add views or use --distortion simple.",
    "(lower min_free_bytes)": "(lower it with --min-free-gb)",
    "must be >= stall_warn_s (": "must be >= --stall-warn (",
    "image_encoding raw is written to MCAP only": "--image-encoding raw is written to MCAP only",
    "or record without hardware sync (and": "or record without --sync (and",
    "; use restore_colours ": "; use --restore-colors ",
    "check the time base or max_diff_s": "check the time base or --max-diff-s",
    "use align 'none' for": "use --align none for",
    "; write raw-view depth (the raw grid) with sea3d depth":
        "; write raw-view depth with sea3d depth --grid raw",
    "(e.g. scale 16 for tsukuba": "(e.g. --scale 16 for tsukuba",
    "pixels: give the rig to resample it;": "pixels: pass --rig to resample it;",
    "(the grid option of sea3d depth)": "(sea3d depth --grid)",
    "(pass image_size to set it)": "(pass --size to set it)",
    "(is output_kind right?)": "(is --output-kind right?)",
    "device cuda: onnxruntime offers": "--device cuda: onnxruntime offers",
    "or use device cpu": "or use --device cpu",
    " with depth_scale ": " with --depth-scale ",
    "not aligned (align none)": "not aligned (--align none)",
    "give trajectories EST GT, or align by ICP for":
        "pass --trajectories EST GT, or --align icp for",
    "the IMU scale needs": "--imu-scale needs",
    "free; use fewer frames or a smaller image size":
        "free; use fewer --frames or a smaller --size",
    "(neither a rig nor focal_px)": "(--rig or --focal-px)",
    "a monocular run (camera left/right)": "a monocular run (--camera left/right)",
    " and no extrinsics file was given (T_left_imu": "; pass --imu-extrinsics FILE (T_left_imu",
    "; give its times.txt (pose_priors_times)": "; give its times.txt with --pose-priors-times",
    "camera stereo needs the rig's extrinsics; self_calibrate cannot be on":
        "--camera stereo needs the rig's extrinsics; drop --self-calibrate",
    "camera stereo needs the rig (its extrinsics fix the scale); give a rig file or":
        "--camera stereo needs the rig (its extrinsics fix the scale); pass --rig or",
}  # fmt: skip
_PATTERNS = (
    (re.compile(r"no right image; camera (\S+) needs"), r"no right image; --camera \1 needs"),
    (re.compile(r"(no right camera images|an image glob has one camera); camera (\S+) needs"),
     r"\1; --camera \2 needs"),
    (re.compile(r"^(color|depth) ('.*' matches no files)$"), r"--\1 \2"),
    (re.compile(r"^color matches (\d+) files but depth (\d+);"),
     r"--color matches \1 files but --depth \2;"),
    (re.compile(r"^intrinsics: "), "--intrinsics: "),
    (re.compile(r"^the (left|right|imu|sonar) source needs "), r"--\1 needs "),
    (re.compile(r"^align (se3|sim3) needs trajectories EST GT$"),
     r"--align \1 needs --trajectories EST GT"),
)


def _field_re(names: Sequence[str]) -> re.Pattern[str]:
    """Where a message names one of ``names`` as a field (see ``_FIELD_RE``)."""
    alt = "|".join(map(re.escape, names))
    return re.compile(rf"(?<![\w./-])({alt})(?= must\b| or |\)|, not both| to discard)"
                      rf"|(?<=either )({alt})\b")


def error_line(message: str, flags: dict[str, str] | None = None) -> str:
    """A library message (error, warning, note) with the config fields and settings it names
    spelt as this CLI's options (``voxel_m must be > 0`` -> ``--voxel-m must be > 0``).

    Args:
        message: the library's message.
        flags: the fields the command's own options set, each with its option
            (:func:`command_flags`); they are named first, the table's fields after.
    """
    for lib, cli in _PHRASES.items():
        message = message.replace(lib, cli)
    for pattern, repl in _PATTERNS:
        message = pattern.sub(repl, message)
    if flags:
        message = _field_re(sorted(flags, key=len, reverse=True)).sub(
            lambda m: flags[m.group(1) or m.group(2)], message)
    return _FIELD_RE.sub(lambda m: _FLAG_OF_FIELD[m.group(1) or m.group(2)], message)


def command_flags(parser: argparse.ArgumentParser, argv: Sequence[str]) -> dict[str, str]:
    """The config fields and library parameters that the options of the command in ``argv``
    set (those made by ``config_option`` and ``param_option``), each with its option's own
    spelling (its first long name; the others are deprecated aliases).

    Args:
        parser: the whole parser (:func:`build_parser`).
        argv: the command line, without the program name.
    """
    flags: dict[str, str] = {}
    node, rest = parser, list(argv)
    while True:
        subs: dict[str, argparse.ArgumentParser] = {}
        for action in node._actions:
            if isinstance(action, argparse._SubParsersAction):
                subs.update(action.choices)
            source = getattr(action, "sea3d_default_from", None)
            own = [o for o in action.option_strings if o.startswith("--")]
            if source is not None and own:
                flags.setdefault(source[1], own[0])
        at = next((i for i, t in enumerate(rest) if t in subs), None)
        if at is None:
            return flags
        node, rest = subs[rest[at]], rest[at + 1:]


class FlagNames(logging.Filter):
    """A log filter that rewrites a record's message with :func:`error_line`, so warnings from
    library code name this CLI's options; installed on the CLI's log handler.

    Args:
        flags: the running command's own options of fields (:func:`command_flags`).
    """

    def __init__(self, flags: dict[str, str] | None = None) -> None:
        super().__init__()
        self.flags = dict(flags or {})

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        new = error_line(text, self.flags)
        if new != text:
            record.msg, record.args = new, None
        return True


class _Parser(argparse.ArgumentParser):
    """A parser whose subcommands (at any depth) also accept ``-v`` and ``-q``.

    ``sea3d depth -q ...`` then works as ``sea3d -q depth ...`` does: the subcommand's copies
    default to "not given" (``SUPPRESS``), so they only override the top-level flags when used.
    """

    def __init__(self, *args: Any, _top: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not _top:
            self.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                              help="more log output (-vv for debug)")
            self.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                              help="only warnings and errors")


def build_parser() -> argparse.ArgumentParser:
    """Build the full argument parser with every area's subcommands registered."""
    parser = _Parser(
        _top=True,
        prog="sea3d",
        description="Underwater stereo 3D reconstruction: rigs, sessions, calibration, depth.",
    )
    parser.add_argument("--version", action="version", version=f"sea3d {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        module = importlib.import_module(f"sea3d.cli.{name}")
        module.register(sub)
    return parser


def _configure_logging(verbose: int, quiet: bool, flags: dict[str, str]) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    logging.basicConfig(
        level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    for handler in logging.getLogger().handlers:
        named = [f for f in handler.filters if isinstance(f, FlagNames)]
        for f in named:
            f.flags = dict(flags)  # this command's options (an earlier main() in-process)
        if not named:
            handler.addFilter(FlagNames(flags))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``sea3d`` command; return the process exit status."""
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    flags = command_flags(parser, argv)
    _configure_logging(args.verbose, args.quiet, flags)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 0 if args.command is None else 2
    try:
        status = handler(args)
    except Sea3dError as err:
        line = error_line(str(err), flags)
        print(f"sea3d: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sea3d: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader of our output went away (``sea3d ... | head``): not an error of ours.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    return int(status or 0)
