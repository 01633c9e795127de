"""``sea3d eval``: measure results against ground truth or a reference.

Each area adds its own ``eval`` subcommands through a ``register_eval(esub)`` function in its
CLI module; :data:`_EVAL_MODULES` lists them in the order they appear in ``--help``.
"""

from __future__ import annotations

import importlib
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import argparse

    from sea3d.cli._args import Subcommands

__all__ = ["register"]

_EVAL_MODULES = ("depth", "enhance", "sonar", "recon")


def register(sub: Subcommands) -> None:
    """Add ``eval`` and every area's ``eval`` subcommands to the top-level parser."""
    e = sub.add_parser("eval", help="evaluate results against ground truth")
    esub = e.add_subparsers(dest="eval_command", metavar="WHAT")
    for name in _EVAL_MODULES:
        importlib.import_module(f"sea3d.cli.{name}").register_eval(esub)

    def usage(_args: argparse.Namespace) -> int:  # the command without a subcommand
        e.print_help(sys.stderr)
        return 2

    e.set_defaults(handler=usage)
