"""``sea3d depth`` subcommands (not yet implemented)."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    """Add this area's subcommands to the top-level parser's subparsers."""
    del sub


def _unused(_: argparse.Namespace) -> int:  # pragma: no cover - placeholder
    return 0
