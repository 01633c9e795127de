"""What the pipelines need of a progress bar: the CLI passes a factory of tqdm bars
(:mod:`sea3d.cli._progress`), a library caller passes nothing."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

__all__ = ["ProgressBar", "ProgressFactory", "no_progress"]


class ProgressBar(Protocol):
    """What the pipeline needs of a progress bar (tqdm has it)."""

    def update(self, n: int = 1) -> Any: ...

    def close(self) -> None: ...


ProgressFactory = Callable[[str, int], ProgressBar]
"""``factory(stage, total)`` makes one bar per stage; the CLI passes tqdm."""


class _NoBar:
    def update(self, n: int = 1) -> None:
        return None

    def close(self) -> None:
        return None


def no_progress(stage: str, total: int) -> ProgressBar:
    """The factory of bars that show nothing."""
    return _NoBar()
