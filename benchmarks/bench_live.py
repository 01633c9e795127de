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
        [--repeat 3]
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


def one_run(mode: str, session: Path, work: Path, extra: str = "") -> dict:
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
                          env={**os.environ, "PYTHONPATH": str(ROOT / "src")}, check=False)
    wall, cpu = time.perf_counter() - t0, _cpu_children() - c0
    if proc.returncode != 0:
        raise SystemExit(f"{mode}: exit {proc.returncode}: {proc.stderr[-2000:]}")
    s = json.loads(proc.stdout)
    live = s["live"]
    return {"mode": mode, "frames": live["frames"], "tracked": live["fraction_tracked"],
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
            "stop": live["stop_reason"]}


def _fmt(v: object, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def _line(r: dict) -> str:
    return (f"{r['mode']:<8} {r['frames']:>4} {r['tracked']:>7.1%} {r['fused']:>6.1%} "
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
                    "'--depth-max-backlog 0' (the policy before newest-first)")
    args = ap.parse_args()
    session = args.out / f"session_{args.frames}_{args.size}"
    simulate(session, args.frames, args.size)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print("mode     frms tracked  fused drops lat50  lat99  mesh50 mesh99 loopCPU runCPU  wall")
    rows = []
    for _ in range(args.repeat):
        for mode in args.runs.split(","):
            r = one_run(mode, session, args.out / f"run_{mode}", args.extra)
            rows.append(r)
            print(_line(r), f"(imu-only {r['imu_only']}, lost {r['lost']}, warm-up "
                  f"{_fmt(r['warmup_s'], '.1f')} s, backlog {r['backlog_max']}, stale "
                  f"{r['stale']}, odometry before own depth {r['late']}; wait p50/p99 "
                  f"{_fmt(r['wait_p50'], '.2f')}/"
                  f"{_fmt(r['wait_p99'], '.2f')} s, fused frames' depth p50 "
                  f"{_fmt(r['depth_p50'], '.2f')} s, then to fusion p50 "
                  f"{_fmt(r['hold_p50'], '.2f')} s; {r['stop']})", flush=True)
    print("medians:")
    for mode in args.runs.split(","):
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
        print(_line(med))
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
