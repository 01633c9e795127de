"""``sea3d process --scheduler`` against a scheduler and a worker started as separate
processes, as a user starts them (``dask scheduler`` and ``dask worker``): no client of the
test's own, nothing shared in memory, frames and results over loopback TCP."""

from __future__ import annotations

import json
import os
import signal
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


CLI = "import sys; from sea3d.cli import main; sys.exit(main())"
GUARD_S = 120.0  # a run that has not ended by then hangs


def _cli_in_child(*argv: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    return subprocess.run([sys.executable, "-c", CLI, *argv], capture_output=True, text=True,
                          env=env, timeout=GUARD_S, check=False)


def test_a_scheduler_port_that_is_not_dask_fails_in_one_line(sim_session, tmp_path):
    port = _free_port()
    web = subprocess.Popen([sys.executable, "-m", "http.server", str(port), "--bind",
                            "127.0.0.1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           cwd=tmp_path)
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:  # until it listens
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        got = _cli_in_child("process", str(sim_session), "-o", str(tmp_path / "out"),
                            "--scheduler", f"tcp://127.0.0.1:{port}")
    finally:
        _stop(web)
    assert got.returncode == 2
    assert got.stderr.count("\n") == 1, got.stderr
    assert f"cannot reach the Dask scheduler tcp://127.0.0.1:{port}: no Dask scheduler " \
           "answered there within 5 s" in got.stderr


def test_a_scheduler_port_that_accepts_and_never_answers_fails_in_time():
    pytest.importorskip("distributed")
    from sea3d.errors import ConfigError
    from sea3d.pipeline.executors import DaskExecutor

    with socket.socket() as silent:  # the kernel accepts; nobody ever reads or writes
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        with pytest.raises(ConfigError, match=r"no Dask scheduler answered there within 1 s"):
            DaskExecutor(address, timeout_s=1.0)


def test_a_scheduler_that_is_not_an_address_is_one_line(sim_session, tmp_path, capsys):
    pytest.importorskip("distributed")
    assert main(["process", str(sim_session), "-o", str(tmp_path / "out"),
                 "--scheduler", "notanaddress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "'notanaddress' is not a Dask scheduler address of the form tcp://HOST:PORT" in err


def _sum_later(values, seconds, shared=None):
    time.sleep(seconds)
    return float(values.sum()) + (0.0 if shared is None else float(shared.sum()))


@pytest.mark.cluster
def test_calls_of_a_lost_dask_worker_are_submitted_again(dask_processes):
    import cloudpickle

    from sea3d.pipeline.executors import DaskExecutor

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import us
    ex = DaskExecutor(dask_processes)
    try:
        values = np.ones(100_000)  # scattered straight to the worker, lost with it
        shared = ex.share(np.full(10, 0.5))  # on every worker: lost with the only one
        futures = [ex.submit(_sum_later, values, 2.0, shared) for _ in range(3)]
        time.sleep(1.0)
        for pid in ex.client.run(os.getpid).values():  # its nanny starts a fresh worker
            os.kill(pid, signal.SIGKILL)
        assert [f.result(timeout=GUARD_S) for f in futures] == [100_005.0] * 3
        assert ex.resubmitted >= 1
    finally:
        ex.close()


@pytest.mark.cluster
def test_a_cluster_left_without_workers_ends_in_one_error(dask_processes):
    import cloudpickle

    from sea3d.errors import ExecutorError
    from sea3d.pipeline.executors import DaskExecutor

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ex = DaskExecutor(dask_processes, no_worker_timeout_s=2.0)
    try:
        pids = list(ex.client.run(os.getpid).values())
        nannies = [int(p) for p in subprocess.run(
            ["ps", "-o", "ppid=", "-p", ",".join(map(str, pids))], capture_output=True,
            text=True, check=True).stdout.split()]
        for pid in nannies + pids:
            os.kill(pid, signal.SIGKILL)
        with pytest.raises(ExecutorError, match=r"had no worker for 2 s"):
            fut = ex.submit(_sum_later, np.ones(100_000), 0.0)
            ex.wait_first([fut])
            fut.result(timeout=GUARD_S)
    finally:
        ex.close()


@pytest.mark.cluster
@pytest.mark.slow
def test_process_goes_on_when_its_dask_worker_is_killed(sim_session, dask_processes, tmp_path):
    import distributed

    gt = sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    run = subprocess.Popen(
        [sys.executable, "-c", CLI, "-q", "process", str(sim_session), "-o", str(out),
         "--poses", str(gt), "--max-frames", "12", "--no-report", "--json",
         "--scheduler", dask_processes],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        frames = out / "cache" / "frames"
        deadline = time.monotonic() + GUARD_S
        while run.poll() is None and time.monotonic() < deadline:
            if frames.is_dir() and any(frames.glob("*.s3c")):
                break  # the worker has frames in hand
            time.sleep(0.05)
        with distributed.Client(dask_processes, timeout=5, set_as_default=False) as c:
            for pid in c.run(os.getpid).values():  # its nanny starts a fresh worker
                os.kill(pid, signal.SIGKILL)
        stdout, stderr = run.communicate(timeout=GUARD_S)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait(10)
    assert run.returncode == 0, stderr
    assert "a Dask worker was lost with a call" in stderr  # and its frames sent again
    assert json.loads(stdout)["frames"] == 12


@pytest.mark.cluster
def test_a_lost_scheduler_ends_the_calls_in_one_error(dask_processes):
    import cloudpickle

    from sea3d.errors import ExecutorError
    from sea3d.pipeline.executors import DaskExecutor

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ex = DaskExecutor(dask_processes)
    try:
        futures = [ex.submit(_sum_later, np.ones(100_000), 2.0) for _ in range(2)]
        time.sleep(1.0)
        os.kill(ex.client.run_on_scheduler(os.getpid), signal.SIGKILL)
        with pytest.raises(ExecutorError, match=r"^the Dask cluster at tcp://\S+ lost its "
                                                r"scheduler$"):
            while not all(f.done() for f in futures):
                ex.wait_first([f for f in futures if not f.done()])
            for f in futures:
                f.result(timeout=GUARD_S)
    finally:
        ex.close()
