"""Small wording helpers shared by messages and reports."""

from __future__ import annotations

__all__ = ["plural", "size_text"]


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``1 pair``, ``2 pairs``, ``0 pairs`` (``nouns`` for irregular plurals)."""
    return f"{n} {noun}" if n == 1 else f"{n} {nouns or noun + 's'}"


def loop_checks_text(checks: dict[str, int | bool]) -> str:
    """``; 2 loops refused (1 disagreed with the odometry, 1 with the solved graph)``, or an
    empty string when no verified loop was refused (a summary's ``loop_checks``)."""
    parts = [(checks.get("rejected_odometry", 0), "disagreed with the odometry"),
             (checks.get("rejected_graph", 0), "with the solved graph"),
             (checks.get("rejected_solver", 0), "failed to solve"),
             (checks.get("rejected_unconfirmed", 0), "not confirmed")]
    n = sum(k for k, _ in parts)
    if n == 0:
        return ""
    return (f"; {plural(n, 'verified loop')} refused ("
            + ", ".join(f"{k} {what}" for k, what in parts if k) + ")")


def size_text(n_bytes: float) -> str:
    """``3.2 GB``, ``450 MB``, ``12 kB`` (decimal units)."""
    if n_bytes >= 1e9:
        return f"{n_bytes / 1e9:.1f} GB"
    return f"{n_bytes / 1e6:.0f} MB" if n_bytes >= 1e6 else f"{n_bytes / 1e3:.0f} kB"
