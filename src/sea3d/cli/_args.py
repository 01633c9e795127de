"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import re
from typing import Any

from sea3d._text import plural

__all__ = ["add_depth_range", "add_output", "config_option", "deprecated", "depth_config",
           "field_help", "image_size", "plural", "positive_depth",
           "positive_float"]


def image_size(text: str) -> tuple[int, int]:
    """Parse ``WIDTHxHEIGHT`` (e.g. ``1920x1080``) into positive ``(width, height)`` pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected WxH such as 1920x1080, got {text!r}") from err
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h




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


def add_depth_range(parser: Any, *, near: str = "nearest depth to resolve (sets the disparity "
                    "range)", far: str = "farthest depth kept") -> None:
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


def depth_config(args: argparse.Namespace, **extra: Any) -> Any:
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


def config_option(parser: Any, cls: type, name: str, *flags: str, help: str | None = None,
                  **kwargs: Any) -> None:
    """An option whose default and help come from the config dataclass ``cls``'s field
    ``name``: the default is written once, in the dataclass; the help is its documentation
    with "(default X)" added. ``dest`` is the field name unless given.

    Args:
        parser: the (sub)parser.
        cls: a dataclass (frozen, kw-only config).
        name: the field.
        flags: the option strings (default ``--name-with-dashes``).
        help: help text instead of the field's documentation.
        kwargs: passed to ``add_argument`` (``type``, ``choices``, ``metavar``, ``nargs``...).
    """
    f = {x.name: x for x in dataclasses.fields(cls)}[name]
    default = f.default if f.default is not dataclasses.MISSING else (
        f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
    text = help if help is not None else field_help(cls, name)
    shown = " ".join(str(v) for v in default) if isinstance(default, tuple) else default
    kwargs.setdefault("dest", name)
    if default is not None:
        text = f"{text} (default {shown})".strip()
    parser.add_argument(*(flags or ("--" + name.replace("_", "-"),)), default=default,
                        help=text.replace("%", "%%"), **kwargs)
