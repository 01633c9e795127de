"""``sea3d process`` throughput, memory and accuracy on a simulated survey.

A lawnmower survey of the lake scene in coastal water through the paper's dome-port rig is
simulated once (kept in ``out/bench_process/``) and processed from scratch (``--fresh``) with
the per-frame stage

- ``inline``: in the client process;
- ``procs1``, ``procs2``: one or two local worker processes (``--workers N``);
- ``dask2``: a ``distributed.LocalCluster`` of two single-threaded worker processes on
  loopback TCP (``--scheduler``), as a user would run it across machines;
- ``procs2-auto``, ``procs2-3``...: two local workers with ``--depth-rate auto`` or every 3rd
  frame (any run name followed by ``-RATE``); a run name given twice runs twice, and the
  medians per run name close the table;
- ``paper``: the paper's chain from the reference libraries, on the same dive and the same
  rectification: OpenCV ``StereoSGBM`` (``MODE_SGBM_3WAY``) depth ``z = f B / d``, Open3D
  frame-to-frame RGB-D odometry (``rgbd_odometry_multi_scale``, Hybrid), Open3D
  ``VoxelBlockGrid`` TSDF at the same voxel size, one mesh at the end.

Meshes are placed by their first pose (``T_gt[0] @ T_est[0]^-1``) for the ``mesh 1st``
column, for sea3d and the paper's chain alike; ``mesh acc`` is sea3d's own figure (its poses
aligned to the ground truth). The last line gives the ratio of frames per second.

Each run is a fresh subprocess, so its peak memory is its own: ``peak_rss_mb`` of the client
and of the largest worker (``ru_maxrss``). Printed per run: frames per second of the frame
loop (reading, per-frame stage, odometry, fusion; merge, outputs and evaluation after it
listed apart), wall time, CPU time (client and workers, whole run), peak memory, and the
mesh's accuracy and completeness against the scene (median and 90th percentile, mm) with the
ATE. On a shared machine wall times depend on the load; CPU seconds much less. CPU per frame
comes three ways: the whole subprocess (``CPU s/fr``: imports, set-up and this script's
evaluation too), the run alone (``run s/fr``: sea3d's ``run_process``, the paper's chain from
rectification to mesh, with the libraries both use imported before), and the frame loop's
steady state (``loop s/fr``: from the first frame to the last, client and local workers; no
one-off costs, what a long dive pays per frame; not counted for Dask workers).

Poses: ``--odometry real`` (sea3d's stereo-inertial odometry, default) or ``gt`` (the
simulator's). ``--integrate keyframes`` compares fusing only
keyframes with every trusted frame on the cached per-frame results.

    python benchmarks/bench_process.py [--frames 60] [--size 640x360] [--runs inline,procs2,dask2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

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


def _first_pose_mesh_mm(session: Path, t_ns: np.ndarray, T_world_left: np.ndarray,
                        vertices: np.ndarray, triangles: np.ndarray) -> list[float]:
    """Mesh accuracy (median, p90, mm) against the scene, the mesh placed by its first pose."""
    from sea3d.eval.surface import surface_metrics
    from sea3d.io.mesh_files import read_mesh
    from sea3d.io.trajectory_files import read_trajectory

    gt = read_trajectory(session / "gt" / "poses_left.tum")
    i0 = int(np.searchsorted(gt.t_ns, t_ns[0]))
    S = gt.T_world_x[i0] @ np.linalg.inv(T_world_left[0])
    v = vertices @ S[:3, :3].T + S[:3, 3]
    ref = read_mesh(session / "gt" / "scene.ply")
    m = surface_metrics(v, triangles, ref.vertices, ref.triangles, samples=100_000)
    return [1000 * m.accuracy_m.median, 1000 * m.accuracy_m.p90]


def paper_run(session: Path, frames: int | None, voxel_m: float = 0.02,
              depth_range_m: tuple[float, float] = (0.5, 4.0)) -> dict:
    """The paper's chain (see the module docstring), timed frame by frame in this process."""
    import cv2
    import open3d as o3d
    import open3d.core as o3c

    from sea3d.eval.trajectory import evaluate_trajectory
    from sea3d.io.rig_file import rig_from_yaml
    from sea3d.io.session import open_session
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.rectify import rectify_images, rectify_rig
    from sea3d.stereo.depth import max_disparity_for_depth

    c_run = time.process_time()  # its run: rectification to mesh, as sea3d's run_cpu_s
    with open_session(session) as s:
        rig = rig_from_yaml(s.rig_yaml, "the session's rig")
        maps = rectify_rig(rig, depth_range_m=depth_range_m)
        match = s.match_pairs()
        stamps = s.stamps("left")
        n = len(match) if frames is None else min(frames, len(match))
        nd = max_disparity_for_depth(maps, depth_range_m[0]) + 1
        sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd, blockSize=5,
                                     P1=8 * 5 * 5, P2=32 * 5 * 5, uniquenessRatio=10,
                                     speckleWindowSize=100, speckleRange=2,
                                     mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
        K = np.asarray(maps.P_left[:3, :3], np.float64)
        Kt = o3c.Tensor(K, dtype=o3c.float64)
        fb = maps.focal_px * maps.baseline_m
        vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)), voxel_size=voxel_m, block_resolution=8,
            block_count=50_000, device=o3c.Device("CPU:0"))
        T_rect = [np.eye(4)]
        prev = None
        marks: list[float] = []  # CPU after the first and the latest frame
        w0, c0 = time.perf_counter(), time.process_time()
        for i in range(n):
            left = s.image("left", int(match.left_index[i]), by="index")
            right = s.image("right", int(match.right_index[i]), by="index")
            rl, rr = rectify_images(maps, left, right)
            gl = cv2.cvtColor(rl, cv2.COLOR_RGB2GRAY) if rl.ndim == 3 else rl
            gr = cv2.cvtColor(rr, cv2.COLOR_RGB2GRAY) if rr.ndim == 3 else rr
            d = sgbm.compute(gl, gr).astype(np.float32) / 16.0
            with np.errstate(divide="ignore"):
                z = np.where(d > 0, fb / d, 0.0).astype(np.float32)
            z[(z < depth_range_m[0]) | (z > depth_range_m[1])] = 0.0
            colour = np.ascontiguousarray(rl if rl.ndim == 3 else np.repeat(rl[..., None], 3, 2))
            cur = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(colour),
                                           o3d.t.geometry.Image(z))
            if prev is not None:
                try:
                    r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                        cur, prev, Kt, o3c.Tensor(np.eye(4)), 1.0, depth_range_m[1],
                        method=o3d.t.pipelines.odometry.Method.Hybrid)
                    step = r.transformation.numpy()
                except RuntimeError:
                    step = np.eye(4)
                T_rect.append(T_rect[-1] @ step)
            prev = cur
            ext = o3c.Tensor(np.linalg.inv(T_rect[-1]), dtype=o3c.float64)
            dimg = o3d.t.geometry.Image(z)
            blocks = vbg.compute_unique_block_coordinates(dimg, Kt, ext, 1.0, depth_range_m[1])
            vbg.integrate(blocks, dimg, o3d.t.geometry.Image(colour.astype(np.float32) / 255.0),
                          Kt, Kt, ext, 1.0, depth_range_m[1])
            marks = [marks[0] if marks else time.process_time(), time.process_time()]
        mesh = vbg.extract_triangle_mesh(weight_threshold=1.0).to_legacy()
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        run_cpu = time.process_time() - c_run
    R1 = np.eye(4)
    R1[:3, :3] = maps.R_rect_left_left
    T_left = np.stack(T_rect) @ R1
    t = np.asarray(stamps[match.left_index[:n]], np.int64)
    gt = read_trajectory(session / "gt" / "poses_left.tum")
    ate = evaluate_trajectory(t, T_left, gt.t_ns, gt.T_world_x, align="se3", max_diff_s=0.001)
    acc = _first_pose_mesh_mm(session, t, T_left, np.asarray(mesh.vertices),
                              np.asarray(mesh.triangles))
    return {"kind": "paper", "frames": n, "wall_s": wall, "fps": n / wall,
            "frame_loop_s": wall, "cpu_client_s": cpu, "cpu_workers_s": 0.0,
            "run_cpu_s": run_cpu,
            "loop_cpu_per_frame_s": {"client": (marks[1] - marks[0]) / max(n - 1, 1),
                                     "workers": 0.0},
            "peak_rss_client_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "peak_rss_worker_mb": 0.0, "mesh_accuracy_mm": None, "mesh_first_pose_mm": acc,
            "mesh_completeness_mm": None, "ate_rmse_mm": 1000 * ate.ate_m.rmse,
            "odometry": "Open3D f2f RGB-D", "path_length_m": float("nan"),
            "after_loop_s": {}, "one_off_s": {}, "worker_timings_s": {}, "frames_fused": n,
            "fusion_s": 0.0, "active_submap_peak_mb": 0.0}


def _status_mb(pid: str, key: str) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def _children() -> list[str]:
    kids: list[str] = []
    for task in Path("/proc/self/task").iterdir():
        try:
            kids += (task / "children").read_text().split()
        except OSError:
            continue
    return kids


def _du_mb(folder: Path) -> float:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) / 2**20


class RssRecorder:
    """A progress factory for ``run_process`` that samples memory every ``every`` frames of
    the odometry bar: the client's resident and peak memory, the local workers' resident
    memory (summed) and the largest one's peak, and the output folder's size on disk (MB).
    Each row is also appended to ``log`` (JSON lines) as it is taken, so a long run that is
    stopped keeps its figures so far."""

    def __init__(self, every: int, out: Path, log: Path | None = None) -> None:
        self.every, self.out, self.frames, self.rows = every, out, 0, []
        self.log, self.t0 = log, time.perf_counter()
        if log is not None:
            log.write_text("")

    def __call__(self, stage: str, total: int) -> RssRecorder._Bar:
        return RssRecorder._Bar(self if stage == "odometry" else None)

    def sample(self) -> None:
        self.rows.append({
            "frames": self.frames, "client_rss_mb": _status_mb("self", "VmRSS"),
            "client_hwm_mb": _status_mb("self", "VmHWM"),
            "workers_rss_mb": sum(_status_mb(k, "VmRSS") for k in _children()),
            "worker_hwm_mb": max((_status_mb(k, "VmHWM") for k in _children()), default=0.0),
            "out_mb": _du_mb(self.out) if self.out.is_dir() else 0.0,
            "wall_s": time.perf_counter() - self.t0,
            "cpu_client_s": _cpu(resource.RUSAGE_SELF),
            "cpu_workers_s": sum(_proc_cpu_s(k) for k in _children())})
        if self.log is not None:
            with self.log.open("a") as f:
                f.write(json.dumps(self.rows[-1]) + "\n")

    class _Bar:
        def __init__(self, rec: RssRecorder | None) -> None:
            self.rec = rec

        def update(self, n: int = 1) -> None:
            if self.rec is None:
                return
            for _ in range(n):
                self.rec.frames += 1
                if self.rec.frames % self.rec.every == 0:
                    self.rec.sample()

        def close(self) -> None:
            return None


def _proc_cpu_s(pid: str) -> float:
    """CPU seconds (user + system) of a live process, from ``/proc/PID/stat``."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class LoopCpu:
    """A progress factory for ``run_process`` that measures the steady-state CPU of the frame
    loop: the client's CPU from its first odometry frame to its last, and the local workers'
    CPU (summed, from ``/proc``) from the first depth result to the last, each over the
    frames in between. One-off costs (imports, kernel loading, rectification maps, the
    workers' start) fall before the first frame and the merge after the last, so they are
    left out; :func:`paper_run` measures its loop the same way. ``inner`` (an
    :class:`RssRecorder` or None) gets the same calls."""

    def __init__(self, inner: RssRecorder | None = None) -> None:
        self.inner = inner
        self.marks: dict[str, list[float]] = {"odometry": [], "depth": []}
        self.counts = {"odometry": 0, "depth": 0}

    def __call__(self, stage: str, total: int) -> LoopCpu._Bar:
        return LoopCpu._Bar(self, stage, self.inner(stage, total) if self.inner else None)

    def _mark(self, stage: str) -> None:
        self.counts[stage] += 1
        cpu = (time.process_time() if stage == "odometry"
               else sum(_proc_cpu_s(k) for k in _children()))
        m = self.marks[stage]
        m[:] = [cpu] if not m else [m[0], cpu]

    def per_frame_s(self) -> dict[str, float]:
        """Client and workers' CPU per frame between their first and last frames."""
        out = {}
        for stage, who in (("odometry", "client"), ("depth", "workers")):
            m, n = self.marks[stage], self.counts[stage]
            out[who] = (m[1] - m[0]) / (n - 1) if len(m) == 2 and n > 1 else 0.0
        return out

    class _Bar:
        def __init__(self, rec: LoopCpu, stage: str, inner: Any) -> None:
            self.rec, self.stage, self.inner = rec, stage, inner

        def update(self, n: int = 1) -> None:
            if self.stage in self.rec.marks:
                for _ in range(n):
                    self.rec._mark(self.stage)
            if self.inner is not None:
                self.inner.update(n)

        def close(self) -> None:
            if self.inner is not None:
                self.inner.close()


def one_run(kind: str, session: Path, out: Path, odometry: str, integrate: str,
            fresh: bool, rss_every: int = 0, min_observations: int = 2,
            max_frames: int | None = None) -> dict:
    """Process once in this process and return the figures (run in a subprocess)."""
    from sea3d.pipeline.process import (
        ExecutorConfig,
        MapConfig,
        PoseConfig,
        ProcessConfig,
        run_process,
    )
    from sea3d.stereo.recipe import DepthConfig

    if kind == "paper":
        return paper_run(session, max_frames)
    kind, _, depth_rate = kind.partition("-")
    use_gt = odometry == "gt"
    poses = session / "gt" / "poses_left.tum" if use_gt else None
    # The depth range of the paper's chain below, so both fuse the same slab of the scene.
    ex: dict = {}
    cluster = client = None
    if kind == "inline":
        ex["workers"] = 0
    elif kind.startswith("procs"):
        ex["workers"] = int(kind[5:])
    elif kind.startswith("dask"):
        import distributed

        n = int(kind[4:])
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           protocol="tcp", host="127.0.0.1",
                                           dashboard_address=None)
        client = distributed.Client(cluster)
        ex["scheduler"] = client
    config = ProcessConfig(out_dir=out, poses=PoseConfig(poses_path=poses), fresh=fresh,
                           map=MapConfig(integrate=integrate, min_observations=min_observations),
                           report=False,
                           depth=DepthConfig(min_depth_m=0.5, max_depth_m=4.0),
                           executor=ExecutorConfig(**ex), depth_rate=depth_rate or "all",
                           max_frames=max_frames)
    rec = (RssRecorder(rss_every, out, out.parent / f"rss_{out.name}.jsonl")
           if rss_every > 0 else None)
    loop_cpu = LoopCpu(rec)
    # the libraries both chains use, imported before either is timed (paper_run's too)
    import cv2  # noqa: F401
    import gtsam  # noqa: F401
    import open3d  # noqa: F401

    t0, c0 = time.perf_counter(), _cpu(resource.RUSAGE_SELF)
    try:
        res = run_process(session, config, progress=loop_cpu)
        run_cpu_client = _cpu(resource.RUSAGE_SELF) - c0
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    wall = time.perf_counter() - t0
    s = res.summary
    first_pose = _first_pose_mesh_mm(session, res.t_ns, res.T_world_left, res.mesh.vertices,
                                     res.mesh.triangles)
    mv, tv = s.get("mesh_vs_gt", {}), s.get("trajectory_vs_gt", {})
    return {
        "kind": kind + (f"-{depth_rate}" if depth_rate else ""),
        "frames": s["frames"],
        "frames_with_depth": s.get("frames_with_depth", s["frames"]),
        "wall_s": wall,
        "fps": s["frames_per_second"],
        "frame_loop_s": s["timings_s"]["frame_loop_wall_s"],
        "after_loop_s": {k: s["timings_s"].get(k, 0.0) for k in ("merge_s", "cloud_s",
                                                               "write_s", "evaluate_s")},
        "one_off_s": s["one_off_s"],
        "cpu_client_s": _cpu(resource.RUSAGE_SELF),
        "cpu_workers_s": _cpu(resource.RUSAGE_CHILDREN),
        # run_process alone (client, and the workers, which have ended by now; Dask's are
        # not counted), and the frame loop's steady state per frame (LoopCpu)
        "run_cpu_s": run_cpu_client + _cpu(resource.RUSAGE_CHILDREN),
        "loop_cpu_per_frame_s": loop_cpu.per_frame_s(),
        "peak_rss_client_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "peak_rss_worker_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
        "active_submap_peak_mb": s["active_submap_peak_mb"],
        "odometry": s["odometry"],
        "integrate": integrate,
        "frames_fused": s["frames_fused"],
        "fusion_s": s["timings_s"].get("fusion_s", 0.0),
        "mesh_accuracy_mm": [1000 * mv["accuracy_m"]["median"], 1000 * mv["accuracy_m"]["p90"]]
        if "accuracy_m" in mv else None,
        "mesh_first_pose_mm": first_pose,
        "mesh_completeness_mm": [1000 * mv["completeness_m"]["median"],
                                 1000 * mv["completeness_m"]["p90"]]
        if "completeness_m" in mv else None,
        "ate_rmse_mm": 1000 * tv["ate_m"]["rmse"] if "ate_m" in tv else None,
        "path_length_m": s["path_length_m"],
        "worker_timings_s": s["worker_timings_s"],
        "rss_rows": rec.rows if rec is not None else [],
    }


def _loop(r: dict) -> float:
    """The frame loop's steady-state CPU per frame, client and workers."""
    return float(sum(r["loop_cpu_per_frame_s"].values()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--runs", default="inline,procs2,dask2,paper")
    ap.add_argument("--odometry", choices=["gt", "real"], default="real")
    ap.add_argument("--integrate", choices=["trusted", "keyframes", "both"], default="trusted")
    ap.add_argument("--rss-every", type=int, default=0, metavar="N",
                    help="sample the client's and workers' memory and the output folder's "
                    "size every N frames (a table per run)")
    ap.add_argument("--min-observations", type=int, default=2,
                    help="MapConfig.min_observations of sea3d's runs (1 keeps voxels seen once)")
    ap.add_argument("--cached", action="store_true",
                    help="reuse each run's cached per-frame results (odometry, fusion and the "
                    "merge only)")
    ap.add_argument("--session", help="process the first --frames frames of this existing "
                    "session (a longer simulated survey) instead of simulating one")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--no-fresh", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    base = ROOT / "out" / "bench_process"
    session = base / f"lake_{args.size}_{args.frames}"
    if args.session is not None:  # the first --frames frames of a longer survey
        session = Path(args.session)
    if args.one:
        policy = args.integrate if args.integrate != "both" else "trusted"
        r = one_run(args.one, session, base / f"run_{args.one}_{args.frames}", args.odometry,
                    policy, fresh=not args.no_fresh, rss_every=args.rss_every,
                    min_observations=args.min_observations,
                    max_frames=args.frames if args.session is not None else None)
        print("RESULT " + json.dumps(r))
        return
    if args.session is None:
        simulate(session, args.frames, args.size)
    print(f"lake, {args.frames} frames at {args.size}, coastal water, dome ports; each run in a "
          "fresh process, per-frame results recomputed")
    print(f"{'run':10} {'fps':>6} {'loop s':>7} {'wall s':>7} {'CPU s':>7} {'client MB':>10} "
          f"{'worker MB':>10} {'mesh acc mm (med/p90)':>22} {'compl mm':>12} {'ATE mm':>7} "
          f"{'CPU s/fr':>8} {'mesh 1st mm':>14} {'run s/fr':>8} {'loop s/fr':>9}")
    results = []
    for kind in args.runs.split(","):
        policies = ["trusted", "keyframes"] if args.integrate == "both" else [args.integrate]
        for i, policy in enumerate(policies):
            cmd = [sys.executable, __file__, "--one", kind, "--frames", str(args.frames),
                   "--size", args.size, "--odometry", args.odometry, "--integrate", policy,
                   "--rss-every", str(args.rss_every),
                   "--min-observations", str(args.min_observations)]
            if args.session is not None:
                cmd += ["--session", str(args.session)]
            if i > 0 or args.cached:
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
                  f"{r['ate_rmse_mm'] if r['ate_rmse_mm'] is not None else float('nan'):7.2f} "
                  f"{cpu / r['frames']:8.3f} "
                  f"{r['mesh_first_pose_mm'][0]:6.1f} / {r['mesh_first_pose_mm'][1]:5.1f} "
                  f"{r['run_cpu_s'] / r['frames']:8.3f} {_loop(r):9.3f}")
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
    for x in results:
        if x.get("rss_rows"):
            print(f"memory of {x['kind']} (MB) against frames: frames, client RSS, client peak, "
                  "workers RSS (sum), largest worker's peak, output folder on disk")
            for row in x["rss_rows"]:
                print(f"  {row['frames']:6d} {row['client_rss_mb']:8.0f} "
                      f"{row['client_hwm_mb']:8.0f} {row['workers_rss_mb']:8.0f} "
                      f"{row.get('worker_hwm_mb', 0.0):8.0f} {row['out_mb']:8.1f}")
            print(f"  after the loop: client peak {x['peak_rss_client_mb']:.0f} MB (merge "
                  f"{x['after_loop_s'].get('merge_s', 0.0):.1f} s, evaluation "
                  f"{x['after_loop_s'].get('evaluate_s', 0.0):.1f} s)")
    print("CPU s/fr: the whole subprocess (imports, set-up, merge and this script's evaluation "
          "included); run s/fr: the run alone (sea3d's run_process, the paper's chain from "
          "rectification to mesh), libraries imported before; loop s/fr: the frame loop's steady "
          "state (client and workers, first frame to last)")
    print("medians per run: frames with depth, fps, CPU-s per frame (whole / run / loop), "
          "ATE mm, mesh 1st mm")
    for kind in dict.fromkeys(x["kind"] for x in results):
        rs = [x for x in results if x["kind"] == kind]
        cpu = [(x["cpu_client_s"] + x["cpu_workers_s"]) / x["frames"] for x in rs]
        ate = [x["ate_rmse_mm"] for x in rs if x["ate_rmse_mm"] is not None]
        m1 = np.array([x["mesh_first_pose_mm"] for x in rs])
        nd = int(np.median([x.get("frames_with_depth", x["frames"]) for x in rs]))
        run = np.median([x["run_cpu_s"] / x["frames"] for x in rs])
        loop = np.median([_loop(x) for x in rs])
        print(f"  {kind:14} n={len(rs)} depth {nd}/{rs[0]['frames']} "
              f"fps {np.median([x['fps'] for x in rs]):.2f} CPU {np.median(cpu):.3f} / "
              f"{run:.3f} / {loop:.3f} "
              f"ATE {np.median(ate) if ate else float('nan'):.2f} (range "
              f"{min(ate) if ate else float('nan'):.2f}-{max(ate) if ate else float('nan'):.2f}) "
              f"mesh {np.median(m1[:, 0]):.1f} / {np.median(m1[:, 1]):.1f} (medians range "
              f"{m1[:, 0].min():.1f}-{m1[:, 0].max():.1f})")
    paper = [x for x in results if x["kind"] == "paper"]
    ours = [x for x in results if x["kind"] != "paper"]
    if paper and ours:
        p, o = paper[0], ours[0]
        p_cpu = (p["cpu_client_s"] + p["cpu_workers_s"]) / p["frames"]
        o_cpu = (o["cpu_client_s"] + o["cpu_workers_s"]) / o["frames"]
        print(f"ratio sea3d ({o['kind']}) / paper's chain: frames/s {o['fps'] / p['fps']:.2f}, "
              f"CPU-s per frame {o_cpu / p_cpu:.2f} (paper {p_cpu:.3f}, sea3d {o_cpu:.3f}), "
              f"run {o['run_cpu_s'] / p['run_cpu_s']:.2f}, loop {_loop(o) / _loop(p):.2f}")
    (base / "last_results.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
