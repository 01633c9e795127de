"""``sea3d process`` throughput, memory and accuracy on a simulated survey.

A lawnmower survey of the lake scene in coastal water through the paper's dome-port rig is
simulated once (kept in ``out/bench_process/``) and processed from scratch (``--fresh``) with
the per-frame stage

- ``inline``: in the client process;
- ``procs1``, ``procs2``: one or two local worker processes (``--workers N``);
- ``dask2``: a ``distributed.LocalCluster`` of two single-threaded worker processes on
  loopback TCP (``--scheduler``), as a user would run it across machines.

Each run is a fresh subprocess, so its peak memory is its own: ``peak_rss_mb`` of the client
and of the largest worker (``ru_maxrss``). Printed per run: frames per second of the frame
loop (reading, per-frame stage, odometry, fusion; merge, outputs and evaluation after it
listed apart), wall time, CPU time (client and workers, whole run), peak memory, and the
mesh's accuracy and completeness against the scene (median and 90th percentile, mm) with the
ATE. On a shared machine wall times depend on the load; CPU seconds much less.

Poses: ``--odometry gt`` (the simulator's, default while this build has no odometry),
``real`` (sea3d's, once merged) or ``auto``. ``--integrate keyframes`` compares fusing only
keyframes with every trusted frame on the cached per-frame results.

    python benchmarks/bench_process.py [--frames 60] [--size 640x360] [--runs inline,procs2,dask2]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def simulate(session: Path, frames: int, size: str) -> None:
    from sea3d.cli import main

    if (session / "session.json").is_file():
        return
    code = main(["-q", "sim", "--scene", "lake", "--frames", str(frames), "--size", size,
                 "--water", "coastal", "--format", "folder", "--out", str(session)])
    if code != 0:
        raise SystemExit(f"simulation failed ({code})")


def _cpu(who: int) -> float:
    r = resource.getrusage(who)
    return float(r.ru_utime + r.ru_stime)


def one_run(kind: str, session: Path, out: Path, odometry: str, integrate: str,
            fresh: bool) -> dict:
    """Process once in this process and return the figures (run in a subprocess)."""
    from sea3d.pipeline.process import ProcessConfig, odometry_available, run_process

    use_gt = odometry == "gt" or (odometry == "auto" and not odometry_available())
    poses = session / "gt" / "poses_left.tum" if use_gt else None
    kw: dict = {"out_dir": out, "poses_path": poses, "fresh": fresh, "integrate": integrate,
                "report": False}
    cluster = client = None
    if kind == "inline":
        kw["workers"] = 0
    elif kind.startswith("procs"):
        kw["workers"] = int(kind[5:])
    elif kind.startswith("dask"):
        import distributed

        n = int(kind[4:])
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           protocol="tcp", host="127.0.0.1",
                                           dashboard_address=None)
        client = distributed.Client(cluster)
        kw["scheduler"] = client
    t0 = time.perf_counter()
    try:
        res = run_process(session, ProcessConfig(**kw))
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    wall = time.perf_counter() - t0
    s = res.summary
    mv, tv = s.get("mesh_vs_gt", {}), s.get("trajectory_vs_gt", {})
    return {
        "kind": kind,
        "frames": s["frames"],
        "wall_s": wall,
        "fps": s["frames_per_second"],
        "frame_loop_s": s["timings_s"]["frame_loop_wall_s"],
        "after_loop_s": {k: s["timings_s"].get(k, 0.0) for k in ("merge_s", "cloud_s",
                                                               "write_s", "evaluate_s")},
        "one_off_s": s["one_off_s"],
        "cpu_client_s": _cpu(resource.RUSAGE_SELF),
        "cpu_workers_s": _cpu(resource.RUSAGE_CHILDREN),
        "peak_rss_client_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "peak_rss_worker_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
        "active_submap_peak_mb": s["active_submap_peak_mb"],
        "odometry": s["odometry"],
        "integrate": integrate,
        "frames_fused": s["frames_fused"],
        "fusion_s": s["timings_s"].get("fusion_s", 0.0),
        "mesh_accuracy_mm": [1000 * mv["accuracy_m"]["median"], 1000 * mv["accuracy_m"]["p90"]]
        if "accuracy_m" in mv else None,
        "mesh_completeness_mm": [1000 * mv["completeness_m"]["median"],
                                 1000 * mv["completeness_m"]["p90"]]
        if "completeness_m" in mv else None,
        "ate_rmse_mm": 1000 * tv["ate_m"]["rmse"] if "ate_m" in tv else None,
        "path_length_m": s["path_length_m"],
        "worker_timings_s": s["worker_timings_s"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--runs", default="inline,procs1,procs2,dask2")
    ap.add_argument("--odometry", choices=["auto", "gt", "real"], default="auto")
    ap.add_argument("--integrate", choices=["trusted", "keyframes", "both"], default="trusted")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--no-fresh", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    base = ROOT / "out" / "bench_process"
    session = base / f"lake_{args.size}_{args.frames}"
    if args.one:
        policy = args.integrate if args.integrate != "both" else "trusted"
        r = one_run(args.one, session, base / f"run_{args.one}", args.odometry,
                    policy, fresh=not args.no_fresh)
        print("RESULT " + json.dumps(r))
        return
    simulate(session, args.frames, args.size)
    print(f"lake, {args.frames} frames at {args.size}, coastal water, dome ports; each run in a "
          "fresh process, per-frame results recomputed")
    print(f"{'run':10} {'fps':>6} {'loop s':>7} {'wall s':>7} {'CPU s':>7} {'client MB':>10} "
          f"{'worker MB':>10} {'mesh acc mm (med/p90)':>22} {'compl mm':>12} {'ATE mm':>7}")
    results = []
    for kind in args.runs.split(","):
        policies = ["trusted", "keyframes"] if args.integrate == "both" else [args.integrate]
        for i, policy in enumerate(policies):
            cmd = [sys.executable, __file__, "--one", kind, "--frames", str(args.frames),
                   "--size", args.size, "--odometry", args.odometry, "--integrate", policy]
            if i > 0:
                cmd.append("--no-fresh")
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
            if proc.returncode != 0 or not line:
                print(f"{kind}: failed\n{proc.stderr[-2000:]}")
                continue
            r = json.loads(line[0][7:])
            r["integrate"] = policy
            results.append(r)
            acc = r["mesh_accuracy_mm"] or [float("nan")] * 2
            comp = r["mesh_completeness_mm"] or [float("nan")] * 2
            name = kind if len(policies) == 1 else f"{kind}/{policy[:3]}"
            cpu = r["cpu_client_s"] + r["cpu_workers_s"]
            print(f"{name:10} {r['fps']:6.2f} {r['frame_loop_s']:7.1f} {r['wall_s']:7.1f} "
                  f"{cpu:7.1f} "
                  f"{r['peak_rss_client_mb']:10.0f} {r['peak_rss_worker_mb']:10.0f} "
                  f"{acc[0]:10.1f} / {acc[1]:7.1f} {comp[0]:5.1f} / {comp[1]:4.1f} "
                  f"{r['ate_rmse_mm'] if r['ate_rmse_mm'] is not None else float('nan'):7.2f}")
    if results:
        r = results[0]
        print(f"poses: {r['odometry']}; path {r['path_length_m']:.2f} m; after the frame loop "
              f"(first run): " + ", ".join(f"{k} {v:.1f}" for k, v in r["after_loop_s"].items())
              + f"; one-off: {r['one_off_s']}")
        print("per-frame stage, summed over workers (first run): " + ", ".join(
            f"{k} {v:.1f}" for k, v in r["worker_timings_s"].items()
            if not k.startswith("pyramid")))
        for x in results:
            if x["integrate"] == "keyframes" or args.integrate == "both":
                print(f"  {x['kind']} integrate={x['integrate']}: {x['frames_fused']} frames "
                      f"fused in {x['fusion_s']:.1f} s, active submap peak "
                      f"{x['active_submap_peak_mb']:.0f} MB")
    (base / "last_results.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
