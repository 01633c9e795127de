"""``sea3d process --scheduler`` against a scheduler and a worker started as separate
processes, as a user starts them (``dask scheduler`` and ``dask worker``): no client of the
test's own, nothing shared in memory, frames and results over loopback TCP."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.io.result_cache import FrameCache

START_TIMEOUT_S = 30.0
FRAMES = 4


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


@pytest.fixture
def dask_processes(tmp_path):
    """``tcp://127.0.0.1:PORT`` of a scheduler with one single-threaded worker, each its own
    process (torn down after the test)."""
    distributed = pytest.importorskip("distributed")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    log = open(tmp_path / "dask.log", "wb")
    procs: list[subprocess.Popen[bytes]] = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
             "--port", str(port), "--no-dashboard"], stdout=log, stderr=log, env=env))
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "1",
             "--nthreads", "1", "--no-dashboard"], stdout=log, stderr=log, env=env,
            cwd=tmp_path))
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            try:
                with distributed.Client(address, timeout=2, set_as_default=False) as c:
                    c.wait_for_workers(1, timeout=max(1.0, deadline - time.monotonic()))
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        yield address
    finally:
        for p in reversed(procs):
            _stop(p)
        log.close()


@pytest.mark.cluster
def test_process_on_separate_scheduler_and_worker_processes(sim_session, dask_processes,
                                                            tmp_path, capsys):
    gt = sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"
    common = [str(sim_session), "--poses", str(gt), "--max-frames", str(FRAMES), "--no-report",
              "--json"]
    assert main(["process", *common, "-o", str(tmp_path / "dask"),
                 "--scheduler", dask_processes]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["executor"]["kind"] == "dask" and s["executor"]["workers"] == 1
    assert s["frames"] == FRAMES
    assert main(["process", *common, "-o", str(tmp_path / "inline"), "--workers", "0"]) == 0
    a, b = FrameCache(tmp_path / "dask" / "cache", {}), FrameCache(tmp_path / "inline" / "cache",
                                                                     {})
    stamps = sorted(a.stamps())
    assert stamps == sorted(b.stamps()) and len(stamps) == FRAMES
    for t in stamps:
        ea, eb = a.get(t), b.get(t)
        assert ea is not None and eb is not None
        np.testing.assert_array_equal(ea[0]["depth_m"], eb[0]["depth_m"])
    assert Path(tmp_path / "dask" / "trajectory.tum").is_file()
