"""SIGINT/SIGTERM routed to a stop callback, for the commands that run until stopped
(``record``, ``monitor``, ``live``, ``stream``)."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType

__all__ = ["StopOnSignals"]


class StopOnSignals:
    """While active, SIGINT and SIGTERM call ``stop("stopped by SIGINT")`` instead of raising
    (main thread only: elsewhere it does nothing); the previous handlers come back on exit.

    Attributes:
        received: the last signal number received, or None.
    """

    def __init__(self, stop: Callable[[str], object]) -> None:
        self.stop = stop
        self.old: dict[int, Callable[[int, FrameType | None], object] | int | None] = {}
        self.received: int | None = None

    def __enter__(self) -> StopOnSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        del frame
        self.received = signum
        self.stop(f"stopped by {signal.Signals(signum).name}")

    def __exit__(self, *exc: object) -> None:
        for sig, old in self.old.items():
            signal.signal(sig, old)
        self.old.clear()
