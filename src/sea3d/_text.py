"""Small wording helpers shared by messages and reports."""

from __future__ import annotations

__all__ = ["plural", "size_text"]


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``1 pair``, ``2 pairs``, ``0 pairs`` (``nouns`` for irregular plurals)."""
    return f"{n} {noun}" if n == 1 else f"{n} {nouns or noun + 's'}"


def size_text(n_bytes: float) -> str:
    """``3.2 GB``, ``450 MB``, ``12 kB`` (decimal units)."""
    if n_bytes >= 1e9:
        return f"{n_bytes / 1e9:.1f} GB"
    return f"{n_bytes / 1e6:.0f} MB" if n_bytes >= 1e6 else f"{n_bytes / 1e3:.0f} kB"
