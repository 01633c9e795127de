"""``sea3d live`` on a simulated dive at its recorded rate: how much it keeps up with.

A lawnmower survey of the lake scene in coastal water through the paper's dome-port rig
(10 fps) is simulated once (kept in ``out/bench_live/``) and run live, each run a fresh
``sea3d live`` subprocess with sea3d's stereo-inertial odometry:

- ``replay``: ``sea3d live --replay SESSION`` (the session at its recorded rate);
- ``cameras``: ``sea3d live --record REC --left session:SESSION#left --right ...#right --imu
  ...#imu`` (the session's streams as camera sources paced at real time, recorded by the
  recorder while the live loop takes them through its listener hook), with ``--monitor`` so
  the growing mesh is meshed and published while it runs (frame to mesh update latency).

Printed per run, and the medians per mode: frames, the fraction tracked (trusted pose) and
fused, depth frames dropped, latency from a frame's arrival to its fusion (p50, p99) and to
the published mesh update that holds it, the live loop's CPU per frame (the client:
odometry, rectification of dropped frames, fusion, meshing) and the whole run's CPU per frame
(client, depth worker and finish, ``RUSAGE_CHILDREN``), wall time. On a shared machine wall
times and latencies depend on the load; say so when quoting them.

    python benchmarks/bench_live.py [--frames 80] [--size 640x360] [--runs replay,cameras]
        [--repeat 3] [--src 'before=OTHER/src,after=src,lag1=src|--depth-max-lag 1']

``--src`` interleaves builds in one run (each mode, then each build, repeated). Besides the
latencies, the load-independent figures: CPU per frame of the loop's thread and of its
read-ahead thread, the depth worker's CPU per depth frame, and from them whether an idle
2-core machine keeps up at 10 fps and how many depth frames a second it affords.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
from bench_process import simulate  # noqa: E402  (the same simulated dive)


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def one_run(mode: str, session: Path, work: Path, extra: str = "", src: Path = ROOT / "src",
            label: str = "") -> dict:
    out = work / "out"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    cmd = [sys.executable, "-m", "sea3d", "live", "-o", str(out), "--json"]
    if mode == "replay":
        cmd += ["--replay", str(session)]
    elif mode == "cameras":
        cmd += ["--record", str(work / "rec.mcap"), "--left", f"session:{session}#left",
                "--right", f"session:{session}#right", "--imu", f"session:{session}#imu",
                "--replay-speed", "1", "--monitor", "127.0.0.1:0"]
    else:
        raise SystemExit(f"unknown mode {mode!r}")
    cmd += shlex.split(extra)
    c0, t0 = _cpu_children(), time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(src)}, check=False)
    wall, cpu = time.perf_counter() - t0, _cpu_children() - c0
    if proc.returncode != 0:
        raise SystemExit(f"{mode}: exit {proc.returncode}: {proc.stderr[-2000:]}")
    s = json.loads(proc.stdout)
    live = s["live"]
    return {"mode": mode + label, "frames": live["frames"], "tracked": live["fraction_tracked"],
            "fused": live["fraction_fused"], "dropped": live["depth_dropped"],
            "lat_p50": live["latency_s"]["p50"], "lat_p99": live["latency_s"]["p99"],
            "mesh_p50": live["mesh_latency_s"]["p50"], "mesh_p99": live["mesh_latency_s"]["p99"],
            "loop_cpu": live["cpu_s_per_frame"], "run_cpu": cpu / max(live["frames"], 1),
            "wall_s": wall, "imu_only": s["frames_imu_only"], "lost": s["frames_lost"],
            "warmup_s": live.get("warmup_s"), "backlog_max": live.get("backlog_max"),
            "stale": live.get("depth_stale"), "late": live.get("depth_after_odometry"),
            "wait_p50": (live.get("wait_s") or {}).get("p50"),
            "wait_p99": (live.get("wait_s") or {}).get("p99"),
            "depth_p50": (live.get("depth_s") or {}).get("p50"),
            "hold_p50": (live.get("hold_s") or {}).get("p50"),
            "pose_p50": (live.get("pose_latency_s") or {}).get("p50"),
            "pose_p99": (live.get("pose_latency_s") or {}).get("p99"),
            "thread_cpu": live.get("loop_thread_cpu_s_per_frame"),
            "read_cpu": live.get("read_cpu_s_per_frame"),
            "depth_cpu": live.get("depth_cpu_s_per_depth_frame"),
            "depth_frames": live.get("depth_frames"),
            "stop": live["stop_reason"]}


def idle_estimate(r: dict, fps: float = 10.0, cores: int = 2) -> str:
    """Whether an idle machine of ``cores`` keeps up, from the load-independent CPU figures:
    the loop's thread must fit in one core (it is one thread), the loop's process (its thread
    and the read-ahead's) and the depth worker (one process, one frame at a time: at most one
    core) in ``cores``; the depth frames a second it could then afford."""
    if r.get("thread_cpu") is None or not r.get("depth_cpu"):
        return "idle estimate: - (no per-thread or worker CPU in this build's summary)"
    thread = r["thread_cpu"] * fps  # cores
    loop = r["loop_cpu"] * fps
    depth_fps = min(1.0, cores - loop) / r["depth_cpu"] if loop < cores else 0.0
    keeps = thread < 1.0 and loop < cores
    return (f"idle {cores}-core estimate at {fps:g} fps: loop thread {thread:.2f} core, loop "
            f"process {loop:.2f} core -> {'keeps up' if keeps else 'does NOT keep up'}; depth "
            f"{r['depth_cpu']:.3f} CPU-s a frame -> {depth_fps:.1f} depth frames/s "
            f"({min(1.0, depth_fps / fps):.0%} fused)")


def _fmt(v: object, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def _line(r: dict) -> str:
    return (f"{r['mode']:<15} {r['frames']:>4} {r['tracked']:>7.1%} {r['fused']:>6.1%} "
            f"{r['dropped']:>5} {_fmt(r['lat_p50'], '6.2f')} {_fmt(r['lat_p99'], '6.2f')} "
            f"{_fmt(r['mesh_p50'], '6.2f')} {_fmt(r['mesh_p99'], '6.2f')} "
            f"{r['loop_cpu']:>6.3f} {r['run_cpu']:>6.3f} {r['wall_s']:>6.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=80)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--runs", default="replay,cameras")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench_live")
    ap.add_argument("--extra", default="", help="more arguments for sea3d live, e.g. "
                    "'--depth-pick in-order' (the policy before newest-first)")
    ap.add_argument("--src", default="", help="builds to interleave, LABEL=SRC_DIR[|ARGS],...: "
                    "each run's sea3d from that src folder, with more arguments ARGS (default: "
                    "this checkout's)")
    args = ap.parse_args()
    builds = []  # (label, src, extra arguments of that build's runs)
    for b in (b for b in args.src.split(",") if b):
        label, rest = b.split("=", 1)
        src, _, more = rest.partition("|")
        builds.append((f"-{label}", Path(src).resolve(), f"{args.extra} {more}".strip()))
    builds = builds or [("", ROOT / "src", args.extra)]
    session = args.out / f"session_{args.frames}_{args.size}"
    simulate(session, args.frames, args.size)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print("mode            frms tracked  fused drops lat50  lat99  mesh50 mesh99 loopCPU "
          "runCPU  wall")
    rows = []
    for _ in range(args.repeat):
        for mode, (label, src, extra) in ((m, b) for m in args.runs.split(",") for b in builds):
            r = one_run(mode, session, args.out / f"run_{mode}", extra, src, label)
            rows.append(r)
            print(_line(r), f"(imu-only {r['imu_only']}, lost {r['lost']}, warm-up "
                  f"{_fmt(r['warmup_s'], '.1f')} s, backlog {r['backlog_max']}, stale "
                  f"{r['stale']}, odometry before own depth {r['late']}; wait p50/p99 "
                  f"{_fmt(r['wait_p50'], '.2f')}/"
                  f"{_fmt(r['wait_p99'], '.2f')} s, fused frames' depth p50 "
                  f"{_fmt(r['depth_p50'], '.2f')} s, then to fusion p50 "
                  f"{_fmt(r['hold_p50'], '.2f')} s; frame to pose p50/p99 "
                  f"{_fmt(r['pose_p50'], '.2f')}/{_fmt(r['pose_p99'], '.2f')} s; CPU/frame "
                  f"loop thread {_fmt(r['thread_cpu'], '.3f')} read-ahead "
                  f"{_fmt(r['read_cpu'], '.3f')}, worker per depth frame "
                  f"{_fmt(r['depth_cpu'], '.3f')} ({r['depth_frames']} depth frames); "
                  f"load {os.getloadavg()[0]:.1f}; {r['stop']})", flush=True)
    print("medians:")
    for mode in (m + label for m in args.runs.split(",") for label, _, _ in builds):
        mine = [r for r in rows if r["mode"] == mode]
        med = {"mode": mode}
        for key in mine[0]:
            vals = [r[key] for r in mine]
            if key != "mode" and all(isinstance(v, int | float) for v in vals):
                med[key] = float(np.median(vals))
            elif key != "mode":
                med[key] = vals[0]
        med["frames"] = int(med["frames"])
        med["dropped"] = int(med["dropped"])
        print(_line(med), f"pose p50/p99 {_fmt(med.get('pose_p50'), '.2f')}/"
              f"{_fmt(med.get('pose_p99'), '.2f')} s, wait p50 "
              f"{_fmt(med.get('wait_p50'), '.2f')} s")
        print("   ", idle_estimate(med))
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
