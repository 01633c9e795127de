"""A local worker process that dies (the out-of-memory killer, ``kill -9``, a native crash)
never leaves ``sea3d process`` waiting: its calls are redone on a fresh worker, and a call
that kills its worker every time fails with one :class:`ExecutorError`.

Every child process is bounded in time and killed on failure.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sea3d.errors import ExecutorError
from sea3d.pipeline.executors import MAX_TRIES, ProcessExecutor

RESULT_TIMEOUT_S = 60.0  # a worker's spawn and imports on a loaded machine; never reached
RUN_TIMEOUT_S = 300.0
FRAMES = 12


def _workers(ex: ProcessExecutor) -> list[int]:
    return list(ex._pool._processes)


def test_calls_of_a_killed_worker_are_redone_on_a_fresh_one():
    ex = ProcessExecutor(2)
    try:
        futures = [ex.submit(time.sleep, 1.0) for _ in range(4)]
        deadline = time.monotonic() + RESULT_TIMEOUT_S
        while len(_workers(ex)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        os.kill(_workers(ex)[0], signal.SIGKILL)
        assert [f.result(timeout=RESULT_TIMEOUT_S) for f in futures] == [None] * 4
        assert ex.restarts == 1
        assert ex.submit(divmod, 7, 2).result(timeout=RESULT_TIMEOUT_S) == (3, 1)
    finally:
        ex.close()


def test_a_call_that_kills_its_worker_every_time_fails_in_one_error():
    ex = ProcessExecutor(1)
    try:
        with pytest.raises(ExecutorError, match=rf"signal SIGABRT\) each of the {MAX_TRIES} "):
            ex.submit(os.abort).result(timeout=RESULT_TIMEOUT_S)
        assert ex.restarts == MAX_TRIES
        # the executor goes on with a fresh worker
        assert ex.submit(divmod, 7, 2).result(timeout=RESULT_TIMEOUT_S) == (3, 1)
    finally:
        ex.close()


def test_close_returns_while_a_call_still_runs():
    ex = ProcessExecutor(1)
    fut = ex.submit(time.sleep, 600)
    deadline = time.monotonic() + RESULT_TIMEOUT_S
    while not _workers(ex) and time.monotonic() < deadline:
        time.sleep(0.05)
    t0 = time.monotonic()
    ex.close()
    assert fut.cancelled()
    assert time.monotonic() - t0 < RESULT_TIMEOUT_S


def _spawned_children() -> list[int]:
    """This process's worker processes now (``spawn_main`` in their command line)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            cmd = (stat.parent / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == os.getpid() and b"spawn_main" in cmd:
            found.append(int(stat.parent.name))
    return found


def test_a_worker_killed_while_it_starts_does_not_block_the_caller():
    """Spawn writes a worker's start-up data while holding the pipe's read end too: data
    larger than the pipe (the set-up's maps, when they were sent that way) blocked the
    caller forever when the worker died before reading it all."""
    killed: list[int] = []

    def kill_the_first_worker() -> None:
        deadline = time.monotonic() + RESULT_TIMEOUT_S
        while not killed and time.monotonic() < deadline:
            for pid in _spawned_children():
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                break

    ex = ProcessExecutor(1, setup=(np.sum, (np.zeros(4_000_000),)))  # 32 MB
    try:
        killer = threading.Thread(target=kill_the_first_worker, daemon=True)
        killer.start()
        got: list[Any] = []
        caller = threading.Thread(target=lambda: got.append(ex.submit(divmod, 7, 2)),
                                  daemon=True)
        caller.start()
        caller.join(RESULT_TIMEOUT_S)
        assert not caller.is_alive(), "submit blocked by a worker killed at its start"
        killer.join(RESULT_TIMEOUT_S)
        assert killed
        assert got[0].result(timeout=RESULT_TIMEOUT_S) == (3, 1)
    finally:
        ex.close()


def _children(pid: int) -> list[tuple[int, str]]:
    out = subprocess.run(["ps", "-ww", "--ppid", str(pid), "-o", "pid=,args="], capture_output=True,
                         text=True, check=False).stdout
    return [(int(line.split(None, 1)[0]), line.split(None, 1)[1])
            for line in out.splitlines() if line.strip()]


@pytest.mark.slow
def test_process_finishes_when_a_worker_is_sigkilled_mid_run(sim_session, tmp_path):
    gt = sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"
    out = tmp_path / "out"
    code = "import sys; from sea3d.cli import main; sys.exit(main())"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "-q", "process", str(sim_session), "-o", str(out),
         "--poses", str(gt), "--workers", "2", "--max-frames", str(FRAMES), "--no-report",
         "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        frames = out / "cache" / "frames"
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while proc.poll() is None and time.monotonic() < deadline:
            if frames.is_dir() and any(frames.glob("*.s3c")):
                break  # the workers have started and compute frames
            time.sleep(0.05)
        workers = [pid for pid, args in _children(proc.pid) if "spawn_main" in args]
        assert workers, f"no worker process found (exit {proc.poll()})"
        os.kill(workers[0], signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=RUN_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0, stderr
    assert "a worker process died" in stderr and "signal SIGKILL" in stderr
    summary = json.loads(stdout)
    assert summary["frames"] == FRAMES


def test_the_scheduler_names_the_frames_a_lost_worker_took_with_it():
    from sea3d.pipeline.depth_scheduler import DepthScheduler, StageTimer

    class Lost:
        """An executor whose every call failed for good."""

        name, workers = "lost", 1

        def submit(self, fn, *args):
            from concurrent.futures import Future

            f: Future = Future()
            f.set_exception(ExecutorError("a worker process died (pid 1, signal SIGKILL)"))
            return f

        def wait_first(self, futures):
            return None

    class Pair:
        def __init__(self, t_ns: int) -> None:
            self.t_ns = t_ns

    class Source:
        def __init__(self) -> None:
            self.pairs = [Pair(10), Pair(20), Pair(30)]

        def read(self, pair):
            return None, None

    class Cache:
        def stamps(self):
            return set()

    sched = DepthScheduler(Source(), Lost(), None, None, Cache(), window=3,
                           timer=StageTimer())
    with pytest.raises(ExecutorError, match=r"^frames t_ns=10, 20, 30 were not computed: a "
                                            r"worker process died \(pid 1, signal SIGKILL\)"):
        list(sched.results())
