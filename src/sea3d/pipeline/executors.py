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

import contextlib
import functools
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Future, InvalidStateError, ProcessPoolExecutor
from concurrent.futures import wait as cf_wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol

from sea3d.errors import ConfigError, ExecutorError

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
WATCH_POLL_S = 0.2
"""Seconds between two checks that every local worker process is still alive."""
MAX_TRIES = 3
"""Times one call is started before the run gives up on it (its worker died every time)."""
EXIT_CODE_WAIT_S = 2.0
"""Seconds to wait for a dead worker's exit code (to name it) once the pool saw it go."""
CLOSE_GRACE_S = 10.0
"""Seconds ``close`` waits for the local workers to end by themselves before killing them."""


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
    setup_path: str | None,
    parent_pid: int | None = None,
) -> None:
    """Worker initialiser: die with the parent, keep each worker's library thread pools to its
    share of cores, then run the caller's set-up (e.g. install the rectification maps), read
    from ``setup_path`` (a pickled ``(fn, args)``)."""
    if parent_pid is not None:
        _die_with_parent(parent_pid)
    for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(threads))
    if "numba" in sys.modules:
        # numba was imported before the variable above was set: re-read it now, before any
        # thread pool starts, or the first kernel compiled in this worker (a cache miss)
        # sees the change and refuses to run
        sys.modules["numba"].config.reload_config()
    if setup_path is not None:
        from sea3d.io.worker_setup import read_worker_setup

        fn, args = read_worker_setup(setup_path)
        fn(*args)


def _signal_name(exitcode: int | None) -> str:
    """``exit 1``, ``signal SIGKILL`` ... for a process's ``exitcode``."""
    if exitcode is None:
        return "no exit code"
    if exitcode < 0:
        try:
            return f"signal {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"signal {-exitcode}"
    return f"exit {exitcode}"


class _Call:
    """One submitted call: what to run again if its worker dies, and the caller's future."""

    __slots__ = ("args", "fn", "inner", "outer", "tries")

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.fn, self.args = fn, args
        self.outer: Future[Any] = Future()
        self.inner: Any = None  # the pool's future (None: not started, or given up)
        self.tries = 0


class ProcessExecutor:
    """A pool of ``workers`` local processes (spawned) that outlives the death of a worker.

    A worker that dies (the out-of-memory killer, a crash in native code, ``kill -9``) is
    noticed within :data:`WATCH_POLL_S`: every worker of the pool is stopped, a fresh pool
    starts, and the calls that were in flight are started again there. A call that has been
    in flight at :data:`MAX_TRIES` deaths fails with :class:`~sea3d.errors.ExecutorError`
    (what is in flight dies with the worker that runs it, so a call that kills its worker
    every time is given up on, never retried forever).

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
        self.restarts = 0
        """Pools started again after a worker died."""
        self._threads = max(1, (os.cpu_count() or 1) // workers)
        self._setup_path: str | None = None
        if setup is not None:
            # The set-up (a stage's maps: megabytes) reaches each worker through a file, not
            # its start-up pipe: spawn writes that pipe while still holding its read end, so
            # a worker killed before reading it all would block the write, and this process,
            # forever. What goes through the pipe now fits in its buffer.
            from sea3d.io.worker_setup import write_worker_setup

            try:
                self._setup_path = write_worker_setup(setup)
            except OSError as err:
                raise ExecutorError(f"cannot hand the workers their set-up: {err}") from err
        self._lock = threading.RLock()
        self._calls: dict[int, _Call] = {}  # by id(outer), while not done
        self._closed = False
        self._wake = threading.Event()
        self._pool = self._new_pool()
        self._watch = threading.Thread(target=self._watch_workers, name="sea3d-worker-watch",
                                       daemon=True)
        self._watch.start()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(self._threads, self._setup_path, os.getpid()),
        )

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        call = _Call(fn, args)
        call.outer.add_done_callback(self._on_outer_done)
        with self._lock:
            if self._closed:
                raise RuntimeError("submit after close")
            self._calls[id(call.outer)] = call
            self._start(call)
        return call.outer

    def _start(self, call: _Call) -> None:
        """Hand ``call`` to the current pool (lock held); a pool already broken is replaced
        first."""
        call.tries += 1
        try:
            inner = self._pool.submit(call.fn, *call.args)
        except BrokenProcessPool:
            call.tries -= 1  # it never ran
            self._recover()  # starts this call again with the others in flight
            return
        call.inner = inner
        inner.add_done_callback(functools.partial(self._on_inner_done, call))

    def _on_inner_done(self, call: _Call, inner: Future[Any]) -> None:
        with self._lock:
            if call.inner is not inner or call.outer.done():
                return  # a call started again elsewhere, or cancelled
            if inner.cancelled():
                call.outer.cancel()
                return
            err = inner.exception()
            if isinstance(err, BrokenProcessPool):
                self._wake.set()  # the watcher starts it again (or gives up on it)
                return
            if err is not None:
                call.outer.set_exception(err)
            else:
                call.outer.set_result(inner.result())

    def _on_outer_done(self, outer: Future[Any]) -> None:
        with self._lock:
            call = self._calls.pop(id(outer), None)
        if call is not None and outer.cancelled() and call.inner is not None:
            call.inner.cancel()

    def _dead_worker(self) -> str | None:
        """``pid 123 (signal SIGKILL)`` of a worker of the current pool that ended, or None
        (one the pool did not stop itself with SIGTERM, after another died, if any)."""
        ended = [(pid, proc.exitcode) for pid, proc
                 in list((getattr(self._pool, "_processes", None) or {}).items())
                 if proc.exitcode is not None]
        ended.sort(key=lambda e: e[1] == -signal.SIGTERM)
        return f"pid {ended[0][0]}, {_signal_name(ended[0][1])}" if ended else None

    def _watch_workers(self) -> None:
        while True:
            self._wake.wait(WATCH_POLL_S)
            self._wake.clear()
            with self._lock:
                if self._closed:
                    return
                broken = getattr(self._pool, "_broken", False)
                dead = self._dead_worker()
                deadline = time.monotonic() + EXIT_CODE_WAIT_S
                while broken and dead is None and time.monotonic() < deadline:
                    time.sleep(0.02)  # the pool saw its pipe close; the exit code follows
                    dead = self._dead_worker()
                if dead is not None or broken:
                    said = broken[:1].lower() + broken[1:] if isinstance(broken, str) else ""
                    self._recover(dead or said or "it ended")

    def _recover(self, cause: str = "it ended") -> None:
        """Stop the current pool's workers, start a fresh pool and start again there every
        call in flight; fail those that were in flight :data:`MAX_TRIES` times (lock held)."""
        log.warning("a worker process died (%s); restarting the workers", cause)
        lost = [c for c in self._calls.values() if not c.outer.done()]
        for c in lost:
            c.inner = None  # what the old pool says of them now is not heard
        _stop_pool(self._pool, kill=True)
        self.restarts += 1
        self._pool = self._new_pool()
        if any(c.tries >= MAX_TRIES for c in lost):
            err = ExecutorError(
                f"a worker process died ({cause}) each of the {MAX_TRIES} times this call "
                "was being computed (the out-of-memory killer ends a worker with SIGKILL)")
            for c in lost:
                c.outer.set_exception(err)
            return
        for c in lost:
            self._start(c)

    def share(self, obj: Any) -> Any:
        return None  # the set-up gave it to every worker

    def wait_first(self, futures: Iterable[Any]) -> None:
        cf_wait(list(futures), return_when=FIRST_COMPLETED)

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            pool, calls = self._pool, list(self._calls.values())
        for c in calls:
            c.outer.cancel()
        self._wake.set()
        self._watch.join()
        _stop_pool(pool, kill=False)
        if self._setup_path is not None:
            from sea3d.io.worker_setup import remove_worker_setup

            remove_worker_setup(self._setup_path)


def _stop_pool(pool: ProcessPoolExecutor, *, kill: bool) -> None:
    """Shut ``pool`` down without waiting forever: its workers are killed at once (``kill``,
    without waiting for the pool's threads) or after :data:`CLOSE_GRACE_S` if they have not
    ended by then.

    Two ways a pool whose worker died never ends by itself (the interpreter's exit waits
    for it): its clean-up joins every worker, and a worker it started while breaking never
    gets its stop request; and a worker killed while sending a result leaves half a message
    that the pool's thread waits to read to the end, forever, since this process holds the
    pipe's other end too. So the workers get SIGKILL and that end is closed: the read sees
    the end of the pipe. ``pool``'s futures still pending fail with ``BrokenProcessPool`` or
    are cancelled."""
    # the pool's own objects, kept: shutdown drops its references to them
    procs = getattr(pool, "_processes", None) or {}  # a dict that may still grow
    manager = getattr(pool, "_executor_manager_thread", None)
    results = getattr(pool, "_result_queue", None)

    def kill_all() -> None:
        for proc in list(procs.values()):
            with contextlib.suppress(OSError, ValueError, AttributeError):
                proc.kill()
        writer = getattr(results, "_writer", None)  # workers write results, never we
        if writer is not None:
            with contextlib.suppress(OSError):
                writer.close()

    if kill:
        kill_all()
    pool.shutdown(wait=False, cancel_futures=True)
    if kill or manager is None:
        return  # (the manager thread may be waiting for the caller's lock: not joined)
    manager.join(CLOSE_GRACE_S)
    while manager.is_alive():
        kill_all()
        manager.join(WATCH_POLL_S)


CONNECT_TIMEOUT_S = 5.0
"""Seconds a Dask scheduler has to accept the connection and answer Dask's handshake."""
NO_WORKER_TIMEOUT_S = 120.0
"""Seconds a run waits while its Dask cluster has no worker (or no scheduler) at all."""
RETRY_PAUSE_S = 1.0
"""Seconds between two tries to hand a call to a Dask cluster that refused it."""


def _check_scheduler(address: str, timeout_s: float) -> None:
    """Connect to ``address``, do Dask's handshake and ask the scheduler who it is, all within
    ``timeout_s``: a port that is not Dask's, or that accepts and never answers, would
    otherwise keep ``distributed.Client`` waiting forever.

    Raises:
        ConfigError: not an address, nothing listening, or no Dask scheduler answering.
    """
    import asyncio

    from distributed.comm import connect

    async def ask() -> Any:
        comm = await connect(address, timeout=timeout_s)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    try:
        ident = asyncio.run(asyncio.wait_for(ask(), timeout_s))
    except ValueError as err:
        raise ConfigError(f"{address!r} is not a Dask scheduler address of the form "
                          f"tcp://HOST:PORT ({err})") from err
    except TimeoutError as err:
        raise ConfigError(f"cannot reach the Dask scheduler {address}: no Dask scheduler "
                          f"answered there within {timeout_s:g} s (nothing listening, or "
                          "not Dask)") from err
    except (OSError, EOFError) as err:
        raise ConfigError(f"cannot reach the Dask scheduler {address}: {err}") from err
    except Exception as err:  # a reply that is not Dask's protocol
        raise ConfigError(f"cannot reach the Dask scheduler {address}: what answered there "
                          f"is not a Dask scheduler ({type(err).__name__}: {err})") from err
    if not isinstance(ident, dict) or ident.get("type") != "Scheduler":
        raise ConfigError(f"cannot reach the Dask scheduler {address}: what answered there "
                          f"is not a Dask scheduler ({str(ident)[:80]!r})")


class _Shared:
    """``DaskExecutor.share``'s handle: the object, and its copies on the workers (sent
    again when the workers that held them are gone)."""

    def __init__(self, obj: Any, future: Any) -> None:
        self.obj, self.future = obj, future


class DaskExecutor:
    """The per-frame stage on a Dask ``distributed`` cluster.

    A call whose worker is lost (killed, or stopped cleanly with the call's scattered arrays
    on it) is submitted again, arrays scattered again, up to :data:`MAX_TRIES` times; Dask's
    own retries cover a call whose worker died while running it (after which it raises
    ``KilledWorker``). Whatever the cluster cannot do in the end reaches the caller as an
    :class:`~sea3d.errors.ExecutorError`, never a Dask exception; a cluster without any
    worker (or without its scheduler) for ``no_worker_timeout_s`` ends the wait.

    Args:
        scheduler: ``tcp://HOST:PORT`` of a running scheduler, or a ``distributed.Client``
            (which the caller keeps and closes).
        timeout_s: seconds to connect and hear the scheduler's handshake.
        no_worker_timeout_s: see above.

    Raises:
        ConfigError: not a scheduler address, or no Dask scheduler answers there in time.
    """

    name = "dask"

    def __init__(self, scheduler: str | Any, *, timeout_s: float = CONNECT_TIMEOUT_S,
                 no_worker_timeout_s: float = NO_WORKER_TIMEOUT_S) -> None:
        import distributed

        self._own = isinstance(scheduler, str)
        self.no_worker_timeout_s = no_worker_timeout_s
        self.client: Any
        if self._own:
            _check_scheduler(scheduler, timeout_s)
            try:
                self.client = distributed.Client(scheduler, timeout=timeout_s,
                                                 set_as_default=False)
            except (OSError, TimeoutError, ValueError) as err:
                raise ConfigError(f"cannot reach the Dask scheduler {scheduler}: {err}") from err
        else:
            self.client = scheduler
        self._distributed = distributed
        info = self.client.scheduler_info()
        self.workers = len(info.get("workers", {}))
        self.address = str(getattr(getattr(self.client, "scheduler", None), "address", "?"))
        self.resubmitted = 0
        """Calls submitted again after their worker was lost."""
        self._calls: set[_Call] = set()  # not done yet
        self._closed = False
        if self.workers == 0:
            log.warning("the Dask cluster at %s has no workers yet; frames wait for one "
                        "(at most %g s)", self.address, no_worker_timeout_s)

    def _args(self, args: tuple[Any, ...]) -> tuple[Any, ...]:
        """``args`` as sent: shared objects as their (re-sent if lost) copies on the workers,
        big arrays scattered straight to a worker (not through the scheduler)."""
        import numpy as np

        out = list(args)
        for i, a in enumerate(args):
            if isinstance(a, _Shared):
                if a.future.status != "finished":  # the workers that held it are gone
                    a.future = self.client.scatter(a.obj, broadcast=True,
                                                   timeout=self.no_worker_timeout_s)
                out[i] = a.future
        big = [i for i, a in enumerate(args) if isinstance(a, np.ndarray) and a.nbytes > 1 << 16]
        if big:
            scattered = self.client.scatter([args[i] for i in big], direct=True,
                                            timeout=self.no_worker_timeout_s)
            for i, f in zip(big, scattered, strict=True):
                out[i] = f
        return tuple(out)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        call = _Call(fn, args)
        self._calls.add(call)
        call.outer.add_done_callback(functools.partial(self._forget, call))
        self._start(call)
        return call.outer

    def _scheduler_lost(self) -> bool:
        """The client gave up on its scheduler (it reconnects for a while first). Its
        connection pool is closed a moment before its own status says so, and a call made in
        that moment fails with the pool's ``CommClosedError``: both are looked at."""
        gone = ("closing", "closed", "Status.closing", "Status.closed")
        pool = getattr(self.client, "rpc", None)
        return (str(getattr(self.client, "status", "running")) in gone
                or str(getattr(pool, "status", "running")) in gone)

    def _start(self, call: _Call) -> None:
        while True:
            call.tries += 1
            if self._closed:
                call.outer.cancel()
                return
            if self._scheduler_lost():
                call.outer.set_exception(ExecutorError(
                    f"the Dask cluster at {self.address} lost its scheduler"))
                return
            try:
                inner = self.client.submit(call.fn, *self._args(call.args), pure=False)
                break
            except Exception as err:  # scatter or submit failed: a worker gone, say
                timed_out = isinstance(err, TimeoutError | self._distributed.TimeoutError)
                if self._scheduler_lost():
                    call.outer.set_exception(ExecutorError(
                        f"the Dask cluster at {self.address} lost its scheduler"))
                    return
                if timed_out or call.tries >= MAX_TRIES:
                    call.outer.set_exception(self._error(err))
                    return
                log.warning("the Dask cluster at %s did not take a call (%s: %s); trying "
                            "again", self.address, type(err).__name__, err)
                time.sleep(RETRY_PAUSE_S)  # for the scheduler to notice a lost worker
        call.inner = inner
        inner.add_done_callback(functools.partial(self._on_inner_done, call))

    def _error(self, err: BaseException, what: str = "") -> ExecutorError:
        if isinstance(err, TimeoutError | self._distributed.TimeoutError):
            return ExecutorError(f"the Dask cluster at {self.address} had no worker for "
                                 f"{self.no_worker_timeout_s:g} s")
        return ExecutorError(f"the Dask cluster at {self.address} {what or 'failed'} "
                             f"({type(err).__name__}: {err})")

    def _on_inner_done(self, call: _Call, inner: Any) -> None:
        """(Dask's callback thread.)"""
        with contextlib.suppress(InvalidStateError):  # cancelled meanwhile (close)
            self._settle(call, inner)

    def _settle(self, call: _Call, inner: Any) -> None:
        if call.inner is not inner or call.outer.done() or self._closed:
            return
        status = inner.status
        err: BaseException | None = None
        if status == "finished":
            try:
                call.outer.set_result(inner.result())
                return
            except BaseException as got:  # its result could not be fetched (worker lost)
                err = got
        elif status == "error":
            err = inner.exception()
            if not isinstance(err, self._distributed.KilledWorker):
                call.outer.set_exception(err)  # the call's own error
                return
            call.outer.set_exception(self._error(
                err, "lost the workers that ran this call each time Dask tried it"))
            return
        # cancelled or lost: its worker (with its arrays) is gone, or it never got one, or
        # the client gave up on the scheduler
        if self._scheduler_lost():
            call.outer.set_exception(ExecutorError(
                f"the Dask cluster at {self.address} lost its scheduler"))
            return
        if call.tries >= MAX_TRIES:
            call.outer.set_exception(self._error(
                err or RuntimeError(f"status {status}"),
                f"lost this call's worker each of the {MAX_TRIES} times it was submitted"))
            return
        log.warning("a Dask worker was lost with a call (%s); submitting it again", status)
        self.resubmitted += 1
        self._start(call)

    def _forget(self, call: _Call, outer: Future[Any]) -> None:
        self._calls.discard(call)
        if outer.cancelled() and call.inner is not None:
            with contextlib.suppress(Exception):  # a cluster already gone
                call.inner.cancel()

    def share(self, obj: Any) -> Any:
        try:
            return _Shared(obj, self.client.scatter(obj, broadcast=True,
                                                    timeout=self.no_worker_timeout_s))
        except Exception as err:
            raise self._error(err) from err

    def wait_first(self, futures: Iterable[Any]) -> None:
        fs = list(futures)
        without_workers_since: float | None = None
        while fs:
            done, _ = cf_wait(fs, timeout=1.0, return_when=FIRST_COMPLETED)
            if done:
                return
            try:
                running = self.client.status == "running"
                n = len(self.client.scheduler_info().get("workers", {})) if running else 0
            except Exception:  # the scheduler is gone: as good as no workers
                n = 0
            if n:
                without_workers_since = None
                continue
            now = time.monotonic()
            without_workers_since = without_workers_since or now
            if now - without_workers_since > self.no_worker_timeout_s:
                raise ExecutorError(
                    f"the Dask cluster at {self.address} has had no worker "
                    f"{'' if running else 'and no scheduler '}for "
                    f"{self.no_worker_timeout_s:g} s; {len(fs)} calls wait")

    def close(self) -> None:
        self._closed = True  # calls lost from now on are not submitted again
        for call in list(self._calls):
            call.outer.cancel()
        if self._own:
            with contextlib.suppress(Exception):
                self.client.close(timeout=CONNECT_TIMEOUT_S)


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
