"""``sea3d process`` holds its output folder, and its workers die with it.

Every child process is bounded in time and killed on failure.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from sea3d.errors import OutputInUseError
from sea3d.pipeline.lock import LOCK_NAME, output_lock

STARTUP_S = 30.0


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().split()[2] == "Z")


def test_a_second_run_into_the_same_folder_is_refused_in_one_line(tmp_path):
    out = tmp_path / "out"
    with output_lock(out):
        assert (out / LOCK_NAME).is_file()
        with pytest.raises(OutputInUseError, match=rf"{out} is in use by another sea3d run \(pid "):
            with output_lock(out):
                pass
    assert not (out / LOCK_NAME).exists()  # released, and the folder left as it was
    with output_lock(out):  # and free again
        pass


def test_a_lock_left_by_a_killed_process_does_not_block(tmp_path):
    out = tmp_path / "out"
    code = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(Path(__file__).parents[2] / "src")!r})
        from sea3d.pipeline.lock import output_lock
        with output_lock({str(out)!r}):
            print("held", flush=True)
            time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
        with pytest.raises(OutputInUseError, match=rf"pid {proc.pid}"):
            with output_lock(out):
                pass
        proc.kill()
        proc.wait(10)
        assert (out / LOCK_NAME).is_file()  # the stale file stays: the kernel freed the lock
        with output_lock(out):
            pass
    finally:
        if proc.poll() is None:
            proc.kill()


def test_run_process_is_locked(tmp_path):
    from sea3d.pipeline.process import ProcessConfig, run_process

    out = tmp_path / "out"
    with output_lock(out), pytest.raises(OutputInUseError):
        run_process(tmp_path / "no_such_session.mcap", ProcessConfig(out_dir=out))


def test_workers_and_the_resource_tracker_die_when_the_parent_is_sigkilled(tmp_path):
    code = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(Path(__file__).parents[2] / "src")!r})
        from multiprocessing import resource_tracker
        from sea3d.pipeline.executors import ProcessExecutor
        ex = ProcessExecutor(2)
        futs = [ex.submit(time.sleep, 60) for _ in range(2)]
        time.sleep(1.0)
        pids = list(ex._pool._processes)
        print(" ".join(map(str, pids)), resource_tracker._resource_tracker._pid, flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    children: list[int] = []
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        children = [int(p) for p in line if p != "None"]
        assert len(children) >= 2, line
        assert all(_alive(p) for p in children)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        end = time.monotonic() + 10
        while any(_alive(p) for p in children) and time.monotonic() < end:
            time.sleep(0.1)
        left = [p for p in children if _alive(p)]
        assert not left, f"still running after the parent's SIGKILL: {left}"
    finally:
        for p in children:
            try:
                os.kill(p, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if proc.poll() is None:
            proc.kill()


def test_the_cli_refuses_a_second_process_in_one_line(tmp_path, capsys):
    from sea3d.cli import main

    out = tmp_path / "out"
    with output_lock(out):
        rc = main(["process", str(tmp_path / "dive.mcap"), "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1 and "is in use by another sea3d run (pid" in err[0], err


def test_live_takes_the_folder_lock_as_process_does(tmp_path):
    from sea3d.pipeline.live import run_live_cameras, run_live_replay
    from sea3d.pipeline.process import ProcessConfig

    out = tmp_path / "out"
    config = ProcessConfig(out_dir=out)
    with output_lock(out):
        with pytest.raises(OutputInUseError):
            run_live_replay(tmp_path / "no_such_session.mcap", config)
        with pytest.raises(OutputInUseError):
            run_live_cameras(object(), config)  # refused before the recorder is touched


@pytest.mark.slow
def test_a_second_live_or_process_into_a_running_live_folder_is_refused(sim_session, tmp_path,
                                                                        capsys):
    from sea3d.cli import main

    gt = sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    code = "import sys; from sea3d.cli import main; sys.exit(main())"
    first = subprocess.Popen(
        [sys.executable, "-c", code, "-q", "live", "--replay", str(sim_session), "-o",
         str(out), "--poses", str(gt), "--max-frames", "12", "--rate", "0.5"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + STARTUP_S
        while not (out / LOCK_NAME).is_file() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert first.poll() is None
        for argv in (["live", "--replay", str(sim_session)], ["process", str(sim_session)]):
            assert main([*argv, "-o", str(out), "--poses", str(gt), "--max-frames", "2"]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and f"is in use by another sea3d run (pid {first.pid}" in err[0]
        assert first.poll() is None  # the first run goes on, untouched
    finally:
        first.kill()
        first.wait(30)
