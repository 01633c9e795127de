"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse

__all__ = ["image_size", "plural"]


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
