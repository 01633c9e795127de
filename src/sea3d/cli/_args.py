"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import inspect
import os
import re
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from sea3d._text import plural

if TYPE_CHECKING:
    from sea3d.odometry.config import OdometryConfig
    from sea3d.stereo.recipe import DepthConfig

__all__ = ["add_depth_range", "add_output", "check_output_suffix", "config_default",
           "config_option", "deprecated", "depth_config", "field_help", "image_size",
           "param_default", "param_option", "plural",
           "positive_depth", "positive_float"]


class Subcommands(Protocol):
    """What a command's ``register`` adds its subcommands to (``add_subparsers()``)."""

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser: ...


class ArgumentAdder(Protocol):
    """A parser, subparser or argument group: what the helpers add options to."""

    def add_argument(self, *name_or_flags: str, **kwargs: Any) -> argparse.Action: ...


def image_size(text: str) -> tuple[int, int]:
    """Parse ``WIDTHxHEIGHT`` (e.g. ``1920x1080``) into positive ``(width, height)`` pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected WxH such as 1920x1080, got {text!r}") from err
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h




def check_output_suffix(path: str | os.PathLike[str], flag: str, suffixes: tuple[str, ...],
                        what: str) -> None:
    """Refuse an output whose suffix no writer of the command accepts, before any work.

    Args:
        path: the output path given.
        flag: the option that gave it (``-o/--output``).
        suffixes: the accepted suffixes, lower case with the dot (``(".png", ".npy")``).
        what: what the file holds (``a depth map``), for the message.

    Raises:
        ConfigError: an unknown or missing suffix, naming the flag and the accepted ones.
    """
    from pathlib import Path

    from sea3d.errors import ConfigError

    suffix = Path(path).suffix.lower()
    if suffix not in suffixes:
        got = f"suffix {suffix!r}" if suffix else "no suffix"
        known = (suffixes[0] if len(suffixes) == 1
                 else f"{', '.join(suffixes[:-1])} or {suffixes[-1]}")
        raise ConfigError(f"{flag} {path}: {got}; {what} is written as {known}")


def check_session_output(path: str | os.PathLike[str], flag: str, format: str | None = None, *,
                         format_flag: bool = True) -> None:
    """Refuse, before any work, a session output the command should not write: a name with
    a file suffix other than ``.mcap`` (it would become a folder of that name), ``.mcap`` with
    ``--format folder``, or a path that holds a session (or a file) already.

    Args:
        path: the output path given.
        flag: the option that gave it (``-o/--output``).
        format: the ``--format`` given (``"mcap"``, ``"folder"``) or None.
        format_flag: the command has ``--format`` (its message then offers it).

    Raises:
        ConfigError: one line naming the flag, the path and what is wrong with it.
    """
    from pathlib import Path

    from sea3d.errors import ConfigError, SessionError
    from sea3d.io.session import check_new_session

    p = Path(path)
    suffix = p.suffix.lower()
    if format == "folder" and suffix == ".mcap":
        raise ConfigError(f"{flag} {path}: --format folder writes a folder, but the name ends "
                          "in .mcap (an MCAP file); drop --format folder, or name a folder")
    if format is None and suffix != ".mcap" and re.fullmatch(r"\.[a-z][a-z0-9]{0,4}", suffix):
        hint = " (pass --format folder for a folder of that name)" if format_flag else ""
        raise ConfigError(f"{flag} {path}: suffix {suffix!r}; a session is written as a "
                          f".mcap file or a folder{hint}")
    try:
        check_new_session(p, format)
    except SessionError as err:
        raise ConfigError(f"{flag}: {err} (write to a new session path)") from err


def _finite_positive(text: str, expected: str, must: str) -> float:
    try:
        value = float(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from err
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be {must}, got {text}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    return _finite_positive(text, "a positive number", "a positive number")


def positive_depth(text: str) -> float:
    """argparse type: a finite depth > 0 metres."""
    return _finite_positive(text, "a depth in metres", "a depth > 0 m")


def add_depth_range(parser: ArgumentAdder, *,
                    near: str = "nearest depth to resolve (sets the disparity range)",
                    far: str = "farthest depth kept") -> None:
    """``--min-depth M`` and ``--max-depth M`` (metres) of a stereo depth range, default from the
    rig (:mod:`sea3d.stereo.recipe`); ``--min-depth-m``/``--max-depth-m`` are hidden aliases."""
    rule = "default: from the rig's focal length, baseline and disparity range"
    parser.add_argument("--min-depth", dest="min_depth", type=positive_depth, default=None,
                        metavar="M", help=f"{near}, metres ({rule})")
    parser.add_argument("--max-depth", dest="max_depth", type=positive_depth, default=None,
                        metavar="M", help=f"{far}, metres ({rule})")
    parser.add_argument("--min-depth-m", dest="min_depth", type=positive_depth,
                        help=argparse.SUPPRESS)
    parser.add_argument("--max-depth-m", dest="max_depth", type=positive_depth,
                        help=argparse.SUPPRESS)


def depth_config(args: argparse.Namespace, **extra: Any) -> DepthConfig:
    """The :class:`~sea3d.stereo.recipe.DepthConfig` of a command's flags (``--engine``,
    ``--max-disparity``, ``--min-depth``, ``--max-depth``, ``--min-confidence`` where it has
    them).

    Raises:
        ConfigError: values the config refuses.
    """
    from sea3d.stereo.recipe import DepthConfig

    kw: dict[str, Any] = {
        "engine": getattr(args, "engine", "sea3d"),
        "max_disparity_px": getattr(args, "max_disparity", None),
        "min_depth_m": getattr(args, "min_depth", None),
        "max_depth_m": getattr(args, "max_depth", None),
    }
    if getattr(args, "min_confidence", None) is not None:
        kw["min_confidence"] = args.min_confidence
    kw.update(extra)
    return DepthConfig(**kw)


def add_loop_closure_flag(parser: ArgumentAdder) -> None:
    """``--no-loop-closure``: the odometry without place recognition and pose-graph loops."""
    parser.add_argument("--no-loop-closure", action="store_true",
                        help="odometry without loop closure (the keyframe pose graph is never "
                        "re-optimised)")


def odometry_config(args: argparse.Namespace) -> OdometryConfig | None:
    """The :class:`~sea3d.odometry.OdometryConfig` of a command's odometry flags
    (``--no-loop-closure``); None, the defaults, when none is given."""
    if not args.no_loop_closure:
        return None
    from sea3d.odometry import OdometryConfig

    return OdometryConfig(loop_closure=False)


def deprecated(old: str) -> str:
    """The help-text note of an old spelling kept as an alias."""
    return f"{old}: deprecated alias, kept for one release"


def add_output(parser: argparse.ArgumentParser, *, help: str, dest: str = "out",
               **kwargs: Any) -> None:
    """``-o/--output`` as every command spells it, with the old ``--out`` as an alias."""
    parser.add_argument("-o", "--output", "--out", dest=dest, help=f"{help} "
                        f"({deprecated('--out')})", **kwargs)


@functools.cache
def _attribute_docs(cls: type) -> dict[str, str]:
    """``{field: text}`` from the ``Attributes:`` section of a config dataclass's docstring."""
    doc = cls.__doc__ or ""
    m = re.search(r"^\s*Attributes:\s*$(.*?)(?:^\s*$|\Z)", doc, re.M | re.S)
    if m is None:
        return {}
    out: dict[str, str] = {}
    name = None
    for line in m.group(1).splitlines():
        head = re.match(r"^\s{4,8}([a-z_][a-z0-9_, ]*):\s*(.*)$", line)
        if head and not line.startswith(" " * 12):
            name = head.group(1)
            for n in name.split(","):
                out[n.strip()] = head.group(2).strip()
        elif name is not None:
            for n in name.split(","):
                out[n.strip()] = (out[n.strip()] + " " + line.strip()).strip()
    return {k: re.sub(r"``([^`]*)``", r"\1", v) for k, v in out.items()}


def field_help(cls: type, name: str) -> str:
    """A config field's documented meaning (its ``metadata["help"]``, else the docstring's
    ``Attributes:`` entry), for an option's help text."""
    f = {x.name: x for x in dataclasses.fields(cls)}[name]
    return str(f.metadata.get("help") or _attribute_docs(cls).get(name, ""))


def _tagged_option(parser: ArgumentAdder, source: object, name: str, default: Any,
                   flags: tuple[str, ...], text: str, shown: str | None,
                   kwargs: dict[str, Any]) -> argparse.Action:
    if "default" in kwargs:
        raise TypeError(f"{name}: the default comes from {source!r}; do not pass default=")
    if shown is None:
        shown = " ".join(str(v) for v in default) if isinstance(default, tuple) else str(default)
    kwargs.setdefault("dest", name)
    if default is not None:
        text = f"{text} (default {shown})".strip()
    action = parser.add_argument(*(flags or ("--" + name.replace("_", "-"),)), default=default,
                                 help=text.replace("%", "%%"), **kwargs)
    # for the test that defaults cannot drift
    action.sea3d_default_from = (source, name)  # type: ignore[attr-defined]
    return action


def config_default(cls: type, name: str) -> Any:
    """The default of the config dataclass ``cls``'s field ``name`` (None when it has none)."""
    f = {x.name: x for x in dataclasses.fields(cls)}[name]
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def param_default(func: Callable[..., object], name: str) -> Any:
    """The default of parameter ``name`` of the library function ``func``."""
    p = inspect.signature(func).parameters[name]
    return None if p.default is inspect.Parameter.empty else p.default


def config_option(parser: ArgumentAdder, cls: type, name: str, *flags: str, help: str | None = None,
                  shown: str | None = None, **kwargs: Any) -> argparse.Action:
    """An option whose default and help come from the config dataclass ``cls``'s field
    ``name``: the default is written once, in the dataclass; the help is its documentation
    with "(default X)" added. ``dest`` is the field name unless given.

    Args:
        parser: the (sub)parser.
        cls: a dataclass (frozen, kw-only config).
        name: the field.
        flags: the option strings (default ``--name-with-dashes``).
        help: help text instead of the field's documentation.
        shown: how the default is written in the help (default ``str(default)``).
        kwargs: passed to ``add_argument`` (``type``, ``choices``, ``metavar``, ``nargs``...;
            not ``default``).

    Returns:
        the argparse action.
    """
    text = help if help is not None else field_help(cls, name)
    return _tagged_option(parser, cls, name, config_default(cls, name), flags, text, shown,
                          kwargs)


def param_option(parser: ArgumentAdder, func: Callable[..., object], name: str, *flags: str,
                 help: str, shown: str | None = None, **kwargs: Any) -> argparse.Action:
    """An option whose value is passed to parameter ``name`` of the library function ``func``:
    its default is the parameter's (written once, in the function), added to ``help``.

    Returns:
        the argparse action.
    """
    return _tagged_option(parser, func, name, param_default(func, name), flags, help, shown,
                          kwargs)


def add_port_options(parser: ArgumentAdder, *, flat_help: str) -> None:
    """The port options of ``sea3d rig create`` and ``sea3d calibrate port``: ``--inner-radius-mm``
    (default the paper's dome), ``--thickness-mm``, ``--n-glass``/``--n-water``/``--n-air`` (the
    defaults of :class:`~sea3d.refraction.ports.DomePort`) and ``--flat-distance-mm`` (that of
    :class:`~sea3d.refraction.ports.FlatPort`), each default written once, in the library."""
    from sea3d.refraction.ports import DomePort, FlatPort
    from sea3d.refraction.presets import PAPER_DOME_INNER_RADIUS_M

    radius_mm = PAPER_DOME_INNER_RADIUS_M * 1e3
    parser.add_argument("--inner-radius-mm", type=float, default=radius_mm,
                        help=f"dome inner radius (default {radius_mm:g}, the paper's dome)")
    parser.add_argument("--thickness-mm", type=float,
                        help="glass thickness (dome 3.1, flat 10)")
    config_option(parser, DomePort, "n_glass", type=float, help="glass index (acrylic)")
    config_option(parser, DomePort, "n_water", type=float, help="water index")
    config_option(parser, DomePort, "n_air", type=float, help="index inside the housing")
    flat_mm = config_default(FlatPort, "distance_m") * 1e3
    parser.add_argument("--flat-distance-mm", type=float, default=flat_mm,
                        help=f"{flat_help} (default {flat_mm:g})")


def add_stall_options(parser: ArgumentAdder) -> None:
    """``--stall-warn S`` and ``--stall-stop S`` (0: never) of ``sea3d record`` and ``sea3d
    live --record``: a camera that delivers nothing for that long is warned about once, or
    stops the recording (the defaults are :class:`~sea3d.capture.recorder.RecorderConfig`'s)."""
    from sea3d.capture.recorder import RecorderConfig

    config_option(parser, RecorderConfig, "stall_warn_s", "--stall-warn", type=float,
                  metavar="S", help="warn once about a camera that has delivered nothing for "
                  "S seconds")
    config_option(parser, RecorderConfig, "stall_stop_s", "--stall-stop", type=float,
                  metavar="S", help="stop the recording when a camera has delivered nothing "
                  "for S seconds; 0: never")


def stall_limits(args: argparse.Namespace) -> dict[str, Any]:
    """The ``RecorderConfig`` fields of :func:`add_stall_options`' flags."""
    return {"stall_warn_s": args.stall_warn_s, "stall_stop_s": args.stall_stop_s or None}
