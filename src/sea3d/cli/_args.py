"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse
from typing import Any

from sea3d._text import plural

__all__ = ["add_depth_range", "depth_config", "image_size", "plural", "positive_depth"]


def image_size(text: str) -> tuple[int, int]:
    """Parse ``WIDTHxHEIGHT`` (e.g. ``1920x1080``) into positive ``(width, height)`` pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected WxH such as 1920x1080, got {text!r}") from err
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h




def positive_depth(text: str) -> float:
    """argparse type: a finite depth > 0 metres."""
    try:
        value = float(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected a depth in metres, got {text!r}") from err
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a depth > 0 m, got {text}")
    return value


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
