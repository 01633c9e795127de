"""Small wording helpers shared by messages and reports."""

from __future__ import annotations

__all__ = ["plural"]


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``1 pair``, ``2 pairs``, ``0 pairs`` (``nouns`` for irregular plurals)."""
    return f"{n} {noun}" if n == 1 else f"{n} {nouns or noun + 's'}"
