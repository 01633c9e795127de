"""Where the per-frame stage runs: in the caller, in local worker processes, or on Dask.

All three give the same small interface (:class:`Executor`): ``submit`` a function with its
arguments and get a future back; ``wait_first`` blocks until at least one of some futures is
done. The pipeline keeps a bounded window of futures in flight and consumes their results in
time order, whatever order they finish in.

- :class:`InlineExecutor` (``workers=0``): runs each call at once in the caller (debugging,
  tests, and machines where processes do not pay).
- :class:`ProcessExecutor` (``--workers N``, the default): a ``concurrent.futures`` process
  pool started with ``spawn`` (no forked copies of OpenCV/numba/Open3D thread pools). Its
  workers die with the parent, even when the parent is killed with SIGKILL.
- :class:`DaskExecutor` (``--scheduler tcp://HOST:PORT``, or a ``distributed.Client``):
  arrays are scattered straight to a worker, then the call is submitted next to them.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as cf_wait
from typing import Any, Protocol

from sea3d.errors import ConfigError

__all__ = ["DaskExecutor", "Executor", "InlineExecutor", "ProcessExecutor", "make_executor"]

log = logging.getLogger(__name__)


class Executor(Protocol):
    """The pipeline's view of an executor."""

    name: str
    workers: int

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Start ``fn(*args)``; return a future (``done()``, ``result()``)."""
        ...

    def share(self, obj: Any) -> Any:
        """Something to pass to ``submit`` that is ``obj`` on the workers, sent once (None
        where the executor's set-up already gave it to every worker)."""
        ...

    def wait_first(self, futures: Iterable[Any]) -> None:
        """Block until at least one of ``futures`` is done."""
        ...

    def close(self) -> None:
        """Stop the workers (pending calls are cancelled)."""
        ...


class InlineExecutor:
    """Runs every call immediately in the caller's process."""

    name = "inline"
    workers = 0

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        fut: Future[Any] = Future()
        try:
            fut.set_result(fn(*args))
        except BaseException as err:  # handed to the caller through the future
            fut.set_exception(err)
        return fut

    def share(self, obj: Any) -> Any:
        return obj

    def wait_first(self, futures: Iterable[Any]) -> None:
        return None

    def close(self) -> None:
        return None


PARENT_POLL_S = 0.5


def _die_with_parent(parent_pid: int) -> None:
    """Exit this worker as soon as ``parent_pid`` is no longer its parent (it died, even by
    SIGKILL, and the worker was handed to init): a thread polls ``os.getppid``. Once every
    worker is gone, multiprocessing's resource tracker sees its pipe close and ends too."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)  # no clean-up: the parent that would want results is gone

    threading.Thread(target=watch, name="sea3d-parent-watch", daemon=True).start()


def _init_worker(
    threads: int,
    setup: tuple[Callable[..., Any], tuple[Any, ...]] | None,
    parent_pid: int | None = None,
) -> None:
    """Worker initialiser: die with the parent, keep each worker's library thread pools to its
    share of cores, then run the caller's set-up (e.g. install the rectification maps)."""
    if parent_pid is not None:
        _die_with_parent(parent_pid)
    for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(threads))
    if "numba" in sys.modules:
        # numba was imported while the initargs were unpickled, before the variable above was
        # set: re-read it now, before any thread pool starts, or the first kernel compiled in
        # this worker (a cache miss) sees the change and refuses to run
        sys.modules["numba"].config.reload_config()
    if setup is not None:
        fn, args = setup
        fn(*args)


class ProcessExecutor:
    """A pool of ``workers`` local processes (spawned).

    Args:
        workers: number of processes (>= 1).
        setup: ``(fn, args)`` run once in each worker as it starts.
    """

    name = "processes"

    def __init__(self, workers: int,
                 setup: tuple[Callable[..., Any], tuple[Any, ...]] | None = None) -> None:
        if workers < 1:
            raise ConfigError(f"workers must be >= 1 for a process pool, got {workers}")
        self.workers = workers
        threads = max(1, (os.cpu_count() or 1) // workers)
        self._pool = ProcessPoolExecutor(
            max_workers=workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(threads, setup, os.getpid()),
        )

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        return self._pool.submit(fn, *args)

    def share(self, obj: Any) -> Any:
        return None  # the set-up gave it to every worker

    def wait_first(self, futures: Iterable[Any]) -> None:
        cf_wait(list(futures), return_when=FIRST_COMPLETED)

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    """The per-frame stage on a Dask ``distributed`` cluster.

    Args:
        scheduler: ``tcp://HOST:PORT`` of a running scheduler, or a ``distributed.Client``
            (which the caller keeps and closes).

    Raises:
        ConfigError: the scheduler cannot be reached.
    """

    name = "dask"

    def __init__(self, scheduler: str | Any, *, timeout_s: float = 5.0) -> None:
        import distributed

        self._own = isinstance(scheduler, str)
        self.client: Any
        if self._own:
            try:
                self.client = distributed.Client(scheduler, timeout=timeout_s,
                                                 set_as_default=False)
            except (OSError, TimeoutError) as err:
                raise ConfigError(f"cannot reach the Dask scheduler {scheduler}: {err}") from err
        else:
            self.client = scheduler
        self._distributed = distributed
        info = self.client.scheduler_info()
        self.workers = len(info.get("workers", {}))
        self.address = str(getattr(getattr(self.client, "scheduler", None), "address", "?"))
        if self.workers == 0:
            log.warning("the Dask cluster at %s has no workers yet; frames wait for one",
                        self.address)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        import numpy as np

        # Arrays go to a worker directly (not through the scheduler), then the call follows.
        big = [i for i, a in enumerate(args) if isinstance(a, np.ndarray) and a.nbytes > 1 << 16]
        if big:
            scattered = self.client.scatter([args[i] for i in big], direct=True)
            args = tuple(
                scattered[big.index(i)] if i in big else a for i, a in enumerate(args)
            )
        return self.client.submit(fn, *args, pure=False)

    def share(self, obj: Any) -> Any:
        return self.client.scatter(obj, broadcast=True)

    def wait_first(self, futures: Iterable[Any]) -> None:
        fs = list(futures)
        if fs:
            # distributed.wait looks for a default client: a Client made with
            # set_as_default=False (ours, for a --scheduler address) is not one.
            with self.client.as_current():
                self._distributed.wait(fs, return_when="FIRST_COMPLETED")

    def close(self) -> None:
        if self._own:
            self.client.close()


def make_executor(
    workers: int | None,
    scheduler: str | Any | None,
    *,
    setup: tuple[Callable[..., Any], tuple[Any, ...]] | None = None,
) -> Executor:
    """The executor for ``--workers N`` / ``--scheduler ADDRESS``.

    Args:
        workers: local processes; None: one per core (at most 8), 0: in the caller.
        scheduler: a Dask scheduler address or ``distributed.Client``; excludes ``workers``.
        setup: ``(fn, args)`` each local worker process runs as it starts.

    Raises:
        ConfigError: both given, or bad values.
    """
    if scheduler is not None:
        if workers is not None:
            raise ConfigError("give either workers or scheduler, not both")
        return DaskExecutor(scheduler)
    if workers is None:
        # One single-threaded worker per core (up to 8): the per-frame stage has serial
        # parts (triangulation, resampling) that threads inside one worker cannot fill.
        workers = max(1, min(os.cpu_count() or 1, 8))
    if workers == 0:
        return InlineExecutor()
    return ProcessExecutor(workers, setup)
