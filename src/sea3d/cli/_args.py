"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["add_output", "deprecated", "image_size", "plural"]


def image_size(text: str) -> tuple[int, int]:
    """Parse ``WIDTHxHEIGHT`` (e.g. ``1920x1080``) into positive ``(width, height)`` pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected WxH such as 1920x1080, got {text!r}") from err
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``1 pair``, ``2 pairs``, ``0 pairs`` (``nouns`` for irregular plurals)."""
    return f"{n} {noun}" if n == 1 else f"{n} {nouns or noun + 's'}"


def deprecated(old: str) -> str:
    """The help-text note of an old spelling kept as an alias."""
    return f"{old}: deprecated alias, kept for one release"


def add_output(parser: argparse.ArgumentParser, *, help: str, dest: str = "out",
               **kwargs: Any) -> None:
    """``-o/--output`` as every command spells it, with the old ``--out`` as an alias."""
    parser.add_argument("-o", "--output", "--out", dest=dest, help=f"{help} "
                        f"({deprecated('--out')})", **kwargs)
