"""One way to make progress bars for every command: on stderr, off for ``--json`` or ``-q``.

``bar(total, desc)`` is one bar; ``stage_bars(enabled)`` makes a factory of stacked bars, one per
pipeline stage, as ``sea3d process`` and ``sea3d demo`` show them.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tqdm import tqdm

    from sea3d.pipeline.progress import ProgressBar

__all__ = ["bar", "once_per_message", "stage_bars"]


def _enabled(enabled: bool) -> bool | None:
    """tqdm's ``disable``: off when asked, or when logging is at WARNING (``-q``); else tqdm's
    own choice (None: off when stderr is not a terminal)."""
    if not enabled or logging.getLogger().getEffectiveLevel() > logging.INFO:
        return True
    return None


def bar(total: int | None = None, desc: str = "", *, unit: str = "frame", enabled: bool = True,
        iterable: Iterable[object] | None = None, leave: bool = False) -> tqdm[object]:
    """A tqdm bar on stderr; ``enabled=False`` (for ``--json``) or ``-q`` turns it off."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, file=sys.stderr,
                disable=_enabled(enabled), dynamic_ncols=True)


def stage_bars(enabled: bool) -> Callable[[str, int], ProgressBar]:
    """A ``progress(stage, total)`` factory of stacked bars, one line per stage."""
    from tqdm import tqdm

    position = [0]

    def make(stage: str, total: int) -> ProgressBar:
        b = tqdm(total=total, desc=f"{stage:>9}", unit="frame" if stage != "merge" else "map",
                 position=position[0], leave=True, disable=_enabled(enabled),
                 dynamic_ncols=True, file=sys.stderr)
        position[0] += 1
        return b

    return make


class _OncePerMessage(logging.Filter):
    """Lets the first record of each message through and counts the rest."""

    def __init__(self, prefix: str) -> None:
        super().__init__()
        self.prefix = prefix
        self.counts: dict[tuple[str, int, str], int] = {}
        self.first: dict[tuple[str, int, str], logging.LogRecord] = {}
        self.last: logging.LogRecord | None = None

    def filter(self, record: logging.LogRecord) -> bool:
        if not (record.name == self.prefix or record.name.startswith(self.prefix + ".")):
            return True
        key = (record.name, record.levelno, record.getMessage())
        first = self.first.get(key)
        if first is None:
            self.first[key] = record
            self.counts[key] = 1
            return True
        if first is record:  # the same record at the next handler
            return True
        if record is not self.last:
            self.counts[key] += 1
            self.last = record
        return False


@contextmanager
def once_per_message(logger: str, unit: str = "frame") -> Iterator[None]:
    """Within the block, each distinct message of ``logger`` (and its children) is logged once;
    at the end, one line says how many more times each repeated message came.

    A session loop (``enhance --session``) would otherwise print the same line per frame.
    """
    f = _OncePerMessage(logger)
    handlers = list(logging.getLogger().handlers)
    for h in handlers:
        h.addFilter(f)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(f)
        for (name, level, msg), n in f.counts.items():
            if n > 1:
                short = msg if len(msg) <= 60 else msg[:57] + "..."
                logging.getLogger(name).log(
                    level, "(the line %r came %d times in all, once per %s)", short, n, unit)
