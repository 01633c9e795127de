"""``sea3d process --scheduler`` on loopback with 1 and 2 workers started as separate processes.

As a user runs it: ``dask scheduler`` and ``dask worker --nworkers N --nthreads 1`` as their own
processes, the client a third (``sea3d process SESSION --scheduler tcp://127.0.0.1:PORT``).
Poses are the simulator's (``--poses``) so the figure is the per-frame stage's. Printed per
worker count: frames/s of the frame loop, wall, CPU seconds (client; the workers' from
``/proc``), and the bytes that cross the network per frame (the pickled raw pair out, the
pickled per-frame result back, as Dask sends them).

    python benchmarks/bench_dask_processes.py [--frames 30] [--workers 1,2] [--session DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cpu_s(pid: int) -> float:
    """utime + stime of one running process (seconds)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _tree(pid: int) -> list[int]:
    """A process and all its descendants (the worker command, its nannies, their workers)."""
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):  # children of every thread
        try:
            kids += [int(p) for p in (task / "children").read_text().split()]
        except OSError:
            continue
    return [pid] + [q for k in kids for q in _tree(k)]


def run(session: Path, frames: int, workers: int) -> dict:
    import distributed

    from sea3d.pipeline.process import ExecutorConfig, PoseConfig, ProcessConfig, run_process

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host",
                               "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)]
    procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address,
                                   "--nworkers", str(workers), "--nthreads", "1",
                                   "--no-dashboard"], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL, env=env))
    try:
        with distributed.Client(address, timeout=30, set_as_default=False) as c:
            c.wait_for_workers(workers, timeout=60)
        out = ROOT / "out" / "bench_dask" / f"w{workers}"
        c0, w0 = time.process_time(), time.perf_counter()
        res = run_process(session, ProcessConfig(
            out_dir=out, executor=ExecutorConfig(scheduler=address),
            poses=PoseConfig(poses_path=session / "gt" / "poses_left.tum"),
            max_frames=frames, fresh=True, report=False, evaluate=False))
        wall = time.perf_counter() - w0
        cpu_client = time.process_time() - c0
        cpu_workers = sum(_cpu_s(p) for p in _tree(procs[1].pid))
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=20)
    return {"workers": workers, "frames": res.summary["frames"],
            "fps": res.summary["frames_per_second"], "wall_s": wall,
            "cpu_client_s": cpu_client, "cpu_workers_s": cpu_workers}


def bytes_per_frame(session: Path, frames_dir: Path) -> tuple[int, int]:
    """Pickled sizes of one raw pair (client -> worker) and one result (worker -> client)."""
    from sea3d.io.result_cache import FrameCache
    from sea3d.io.session import open_session
    from sea3d.pipeline.frame_stage import FrameResult

    with open_session(session) as s:
        m = s.match_pairs()
        left = s.image("left", int(m.left_index[0]), by="index")
        right = s.image("right", int(m.right_index[0]), by="index")
    cache = FrameCache(frames_dir, {})
    t = sorted(cache.stamps())[0]
    got = cache.get(t)
    assert got is not None
    res = FrameResult.from_cache(t, *got)
    return (len(pickle.dumps(left, protocol=5)) + len(pickle.dumps(right, protocol=5)),
            len(pickle.dumps(res, protocol=5)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--session", type=Path, default=ROOT / "out" / "bench_process" /
                    "lake_640x360_80")
    ap.add_argument("--workers", default="1,2")
    args = ap.parse_args()
    rows = [run(args.session, args.frames, int(n)) for n in args.workers.split(",")]
    sent, back = bytes_per_frame(args.session, ROOT / "out" / "bench_dask" / "w1" / "cache")
    print(f"{'workers':>7} {'fps':>6} {'wall s':>7} {'CPU client s':>12} {'CPU workers s':>13}")
    for r in rows:
        print(f"{r['workers']:7d} {r['fps']:6.2f} {r['wall_s']:7.1f} {r['cpu_client_s']:12.1f} "
              f"{r['cpu_workers_s']:13.1f}")
    print(f"per frame over the network: {sent / 1e6:.2f} MB raw pair to a worker, "
          f"{back / 1e6:.2f} MB result back")
    print("RESULT " + json.dumps({"rows": rows, "bytes_sent": sent, "bytes_back": back}))


if __name__ == "__main__":
    main()
