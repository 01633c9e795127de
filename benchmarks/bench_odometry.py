"""Odometry benchmark: accuracy and speed on simulated dives, 7-Scenes and EuRoC, beside the
reference in the same run.

1. Simulated dives (``benchmarks/odometry_sessions.py`` renders them once into the cache):
   a 3,000-frame lawnmower survey through the paper's dome ports (640x360, coastal water), a
   600-frame orbit, and 600 frames through flat ports. For each: sea3d with the IMU and
   visual-only, each with and without loop closure (frames, keyframes, lost, loops, ATE
   against the simulator's truth after an SE3 alignment, in metres and in per cent of the path,
   ms per frame wall and CPU, peak memory; the closures' precision and recall, a closure being
   right when its relative pose is within 3 cm and 1 degree of the truth),
   and beside it the paper's method: Open3D's frame-to-frame ``rgbd_odometry_multi_scale`` on
   the same rectified images and depth maps (``--no-reference`` skips it).
2. 7-Scenes chess (60 frames, ``../shared/data/rgbd/7scenes_chess``): sea3d's RGB-D mode
   beside Open3D's ``rgbd_odometry_multi_scale`` frame to frame (Hybrid), ATE and ms per frame
   (medians of ``--repeat`` runs).
3. EuRoC V1_01 micro (40 frames, the drone still on the ground): the IMU start-up (attitude
   error against the ground truth's gravity direction) and the drift while still.

Depth for the simulated dives is computed once per frame with ``sea3d.stereo.depth.
compute_depth`` (engine ``--engine``, default OpenCV SGBM for speed: the odometry only seeds
its left-right matches with the depth map and triangulates them itself) and cached as float16
next to the sessions. ATE (RMSE after an SE3 alignment) and RPE (drift per metre of path) come
from ``sea3d.eval.trajectory``. ``--frames N`` also accepts a session whose render was stopped
early, when it holds at least N frames (said in the output). Run (long: render the sessions
first, with ``nice``):

    nice python benchmarks/odometry_sessions.py
    nice python benchmarks/bench_odometry.py [--cache /tmp/sea3d_cache/odometry] [--only NAME]

4. **The odometry alone on any recorded session** (``--session DIR``, e.g. bench_process's
   80-frame lake dive): the frames' observations (rectified pair, depth from the rig's default
   :class:`~sea3d.odometry.observe.Observer`, the IMU chunk), as ``sea3d odometry`` makes them,
   are computed once and cached (``--obs-cache``); then the odometry alone runs over them
   ``--repeat`` times, each in a fresh process: CPU ms per frame (median), ATE against the
   session's ``gt/poses_left.tum`` (or ``--gt``), and with ``--stages`` the CPU ms per frame of
   each stage (cProfile, in one more run: KLT, right-image matching, PnP, the smoother, corner
   detection, loop-closure ORB, the rest). ``--compare SRC`` runs another source tree (e.g. the
   main branch's ``src``) in the same way, interleaved with this one (``ours, ref, ours, ...``),
   for a before/after on one machine under one load::

       python benchmarks/bench_odometry.py --session out/bench_process/lake_640x360_80 \
           --repeat 3 --stages --compare /work/main/src
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from odometry_sessions import DEFAULT_CACHE, SESSIONS, is_ready, session_dir

DATA = Path(os.environ.get("SEA3D_TEST_DATA", Path(__file__).resolve().parents[1] / ".." /
                           "shared" / "data"))


# ------------------------------------------------------------------------------ metrics
def metrics(t_ns: np.ndarray, T: np.ndarray, gt_t_ns: np.ndarray, gt_T: np.ndarray,
            rpe_m: float = 1.0) -> dict:
    """ATE (SE3 Umeyama alignment) and RPE per ``rpe_m`` of path, by ``sea3d.eval.trajectory``
    (its figures equal evo's on the stored res files)."""
    from sea3d.eval.trajectory import evaluate_trajectory

    m = evaluate_trajectory(np.asarray(t_ns, np.int64), T, np.asarray(gt_t_ns, np.int64), gt_T,
                            align="se3", max_diff_s=0.001, rpe_deltas_m=[rpe_m])
    rpe = m.rpe[0] if m.rpe else None
    return {
        "path_m": m.path_length_m, "ate_m": m.ate_rmse_m,
        "ate_pct": 100 * m.ate_rmse_m / m.path_length_m if m.path_length_m > 0 else float("nan"),
        "ate_max_m": m.ate_m.max,
        "rpe_pct": rpe.drift_pct if rpe else float("nan"),
        "rpe_deg": rpe.rotation_deg.rmse if rpe else float("nan"),
    }


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ------------------------------------------------------------------------------ sessions
def _depth_dir(cache: Path, name: str, engine: str) -> Path:
    return session_dir(cache, name) / f"depth_{engine}"


def rendered_frames(cache: Path, name: str) -> int:
    """Frames with both images in a (possibly unfinished) rendered session."""
    root = session_dir(cache, name) / "session"
    if not root.is_dir():
        return 0
    return min(len(list((root / side).glob("*.png"))) for side in ("left", "right"))


def prepare_depth(cache: Path, name: str, engine: str, limit: int | None = None) -> None:
    """Compute and cache the depth of every frame of a rendered session (resumable)."""
    from tqdm import tqdm

    from sea3d.io.rig_file import rig_from_yaml
    from sea3d.io.session import open_session
    from sea3d.odometry.observe import Observer
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    out = _depth_dir(cache, name, engine)
    out.mkdir(exist_ok=True)
    with open_session(session_dir(cache, name) / "session") as s:
        rig = rig_from_yaml(s.rig_yaml or "")
        observer = Observer(StereoDepth(rig, DepthConfig(engine=engine)))
        stamps = s.stamps("left")[:limit]
        todo = [t for t in stamps.tolist() if not (out / f"{t}.npy").is_file()]
        if not todo:
            return
        done = set(stamps.tolist()) - set(todo)
        want = set(stamps.tolist())
        for pair in tqdm(s.pairs(), total=len(stamps), desc=f"depth {name}", unit="frame"):
            if pair.t_ns not in want:
                break
            if pair.t_ns in done:
                continue
            obs = observer.observe(pair.t_ns, pair.left, pair.right)
            tmp = out / f".{pair.t_ns}.npy"
            np.save(tmp, obs.depth_m.astype(np.float16))
            os.replace(tmp, out / f"{pair.t_ns}.npy")


def _observations(cache: Path, name: str, engine: str, use_imu: bool, limit: int | None):
    """Frame observations of a cached session, built on the fly (rectified images + cached
    depth + IMU chunks), and the rig, maps, stamps and ground truth."""
    from sea3d.io.rig_file import rig_from_yaml
    from sea3d.io.session import open_session
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.odometry.observe import imu_chunks
    from sea3d.odometry.types import FrameObservation
    from sea3d.rectify import rectify_images
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    root = session_dir(cache, name)
    reader = open_session(root / "session")
    rig = rig_from_yaml(reader.rig_yaml or "")
    maps = StereoDepth(rig, DepthConfig(engine=engine)).maps  # those the cached depth used
    imu = reader.imu()
    stamps = reader.stamps("left")[:limit]
    chunks = imu_chunks(stamps, imu.t_ns, imu.accel_mps2, imu.gyro_radps)
    gt = read_trajectory(root / "gt" / "poses_left.tum")
    gt_t, gt_T = gt.t_ns, gt.T_world_x
    depth_dir = _depth_dir(cache, name, engine)
    K = np.asarray(maps.P_left[:3, :3], dtype=np.float64)

    def frames():
        for i, t in enumerate(stamps.tolist()):
            left = reader.image("left", t, by="stamp")
            right = reader.image("right", t, by="stamp")
            rl, rr = rectify_images(maps, left, right)
            depth = np.load(depth_dir / f"{t}.npy").astype(np.float32)
            yield FrameObservation(
                t_ns=int(t), rect_left=rl, rect_right=rr, depth_m=depth, K_rect=K,
                baseline_m=maps.baseline_m, R_rect_left_left=maps.R_rect_left_left,
                imu=chunks[i] if use_imu else None,
            )

    return rig, maps, stamps, gt_t, gt_T, frames, reader


# a closure is right when its relative pose is within these of the truth (as in the tests)
LOOP_RIGHT_M = 0.03
LOOP_RIGHT_DEG = 1.0


def loop_precision_recall(checks, maps, gt_t: np.ndarray, gt_T: np.ndarray) -> dict:
    """Each verified loop's relative pose against the ground truth: ``right`` when within
    ``LOOP_RIGHT_M`` and ``LOOP_RIGHT_DEG``. Precision: right among the accepted; recall:
    accepted among the right ones verified (what the consistency tests let through)."""
    from sea3d.geometry.se3 import R_to_rotvec

    gt = {int(t): T for t, T in zip(gt_t.tolist(), gt_T, strict=True)}
    T_left_rect = np.eye(4)
    T_left_rect[:3, :3] = np.asarray(maps.R_rect_left_left).T
    rows = []
    for rec in checks.verified_loops:
        if rec.t_query_ns not in gt or rec.t_candidate_ns not in gt:
            continue
        true = np.linalg.inv(gt[rec.t_candidate_ns] @ T_left_rect) @ (gt[rec.t_query_ns]
                                                                      @ T_left_rect)
        D = np.linalg.inv(true) @ rec.T_candidate_query
        err_m = float(np.linalg.norm(D[:3, 3]))
        err_deg = float(np.degrees(np.linalg.norm(R_to_rotvec(D[:3, :3]))))
        rows.append((rec.outcome == "accepted", err_m < LOOP_RIGHT_M and err_deg < LOOP_RIGHT_DEG,
                     err_m, err_deg))
    accepted = [r for r in rows if r[0]]
    right = [r for r in rows if r[1]]
    return {
        "loops_verified": len(rows), "loops_accepted": len(accepted),
        "loops_right_accepted": sum(r[1] for r in accepted),
        "loop_precision": (sum(r[1] for r in accepted) / len(accepted)) if accepted else None,
        "loop_recall": (sum(r[0] for r in right) / len(right)) if right else None,
        "loop_err_mm_max": max((1e3 * r[2] for r in accepted), default=None),
        "loop_err_deg_max": max((r[3] for r in accepted), default=None),
    }


def run_sea3d(cache: Path, name: str, engine: str, use_imu: bool, limit: int | None,
              loop_closure: bool = True) -> dict:
    """One run of sea3d's odometry on a cached session (in this process)."""
    from sea3d.odometry import OdometryConfig, TrackingStatus, create_odometry

    rig, maps, _, gt_t, gt_T, frames, reader = _observations(cache, name, engine, use_imu,
                                                                   limit)
    odo = create_odometry(rig, maps, use_imu=use_imu,
                          config=OdometryConfig(loop_closure=loop_closure))
    step_wall, step_cpu, statuses = [], [], []
    for obs in frames():
        w0, c0 = time.perf_counter(), time.process_time()
        est = odo.step(obs)
        step_wall.append(time.perf_counter() - w0)
        step_cpu.append(time.process_time() - c0)
        statuses.append(est.status)
    reader.close()
    t, T = odo.trajectory()
    n = len(statuses)
    q = max(n // 6, 1)
    return {
        "name": name, "method": "sea3d " + ("stereo+IMU" if use_imu else "stereo")
        + ("" if loop_closure else " no loops"),
        **loop_precision_recall(odo.loop_checks, maps, gt_t, gt_T),
        "frames": n, "keyframes": odo.keyframe_count,
        "lost": sum(s is TrackingStatus.LOST for s in statuses),
        "not_tracking": sum(s not in (TrackingStatus.TRACKING, TrackingStatus.RELOCALISED)
                            for s in statuses),
        "loops": odo.loop_closures, **metrics(t, T, gt_t, gt_T),
        "ms_wall": 1e3 * float(np.mean(step_wall)), "ms_cpu": 1e3 * float(np.mean(step_cpu)),
        "ms_cpu_first": 1e3 * float(np.mean(step_cpu[:q])),
        "ms_cpu_last": 1e3 * float(np.mean(step_cpu[-q:])),
        "ms_cpu_p95": 1e3 * float(np.percentile(step_cpu, 95)),
        "peak_rss_mb": peak_rss_mb(), "state_mb": odo.memory_bytes() / 2**20,
    }


def run_open3d(cache: Path, name: str, engine: str, limit: int | None) -> dict:
    """The paper's method: Open3D frame-to-frame RGB-D odometry on the same rectified left
    images and depth maps, poses chained."""
    import open3d as o3d

    from sea3d.odometry.frontend import to_grey

    _, maps, stamps, gt_t, gt_T, frames, reader = _observations(cache, name, engine, False,
                                                                   limit)
    K = o3d.core.Tensor(np.asarray(maps.P_left[:3, :3]), dtype=o3d.core.Dtype.Float64)
    T = [np.eye(4)]
    prev = None
    wall, cpu, fails = [], [], 0
    for obs in frames():
        depth = np.nan_to_num(obs.depth_m, nan=0.0).astype(np.float32)
        colour = np.ascontiguousarray(np.repeat(to_grey(obs.rect_left)[..., None], 3, axis=2))
        cur = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(colour),
                                       o3d.t.geometry.Image(depth))
        if prev is not None:
            w0, c0 = time.perf_counter(), time.process_time()
            try:
                r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                    cur, prev, K, o3d.core.Tensor(np.eye(4)), 1.0, 8.0,
                    method=o3d.t.pipelines.odometry.Method.Hybrid,
                )
                step = r.transformation.numpy()
            except RuntimeError:
                fails += 1
                step = np.eye(4)
            wall.append(time.perf_counter() - w0)
            cpu.append(time.process_time() - c0)
            T.append(T[-1] @ step)
        prev = cur
    reader.close()
    T_rect = np.stack(T)
    R1 = np.eye(4)
    R1[:3, :3] = maps.R_rect_left_left
    T_left = T_rect @ R1  # T_world_left = T_world_rect @ T_rect_left
    t = stamps[: len(T_left)]
    return {
        "name": name, "method": "Open3D f2f RGB-D", "frames": len(T_left), "keyframes": 0,
        "lost": fails, "not_tracking": fails, "loops": 0, **metrics(t, T_left, gt_t, gt_T),
        "ms_wall": 1e3 * float(np.mean(wall)),
        "ms_cpu": 1e3 * float(np.mean(cpu)), "peak_rss_mb": peak_rss_mb(),
    }


def _open3d_chain(greys: list, depths: list, K_rect: np.ndarray, R_rect_left_left: np.ndarray
                  ) -> np.ndarray:
    """Open3D frame-to-frame Hybrid RGB-D odometry chained over rectified frames: ``T_world_left``
    per frame (the paper's method)."""
    import open3d as o3d

    from sea3d.odometry.frontend import to_grey

    K = o3d.core.Tensor(np.asarray(K_rect, np.float64), dtype=o3d.core.Dtype.Float64)
    T = [np.eye(4)]
    prev = None
    for g, d in zip(greys, depths, strict=True):
        colour = np.ascontiguousarray(np.repeat(to_grey(g)[..., None], 3, axis=2))
        cur = o3d.t.geometry.RGBDImage(
            o3d.t.geometry.Image(colour),
            o3d.t.geometry.Image(np.nan_to_num(d, nan=0.0).astype(np.float32)))
        if prev is not None:
            try:
                r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                    cur, prev, K, o3d.core.Tensor(np.eye(4)), 1.0, 8.0,
                    method=o3d.t.pipelines.odometry.Method.Hybrid)
                step = r.transformation.numpy()
            except RuntimeError:
                step = np.eye(4)
            T.append(T[-1] @ step)
        prev = cur
    R1 = np.eye(4)
    R1[:3, :3] = R_rect_left_left
    return np.stack(T) @ R1


def _child(args: argparse.Namespace, what: str, name: str) -> dict:
    """Run one configuration in a fresh process, so each gets its own peak memory."""
    cmd = [sys.executable, __file__, "--child", what, "--only", name, "--cache", str(args.cache),
           "--engine", args.engine]
    if args.frames:
        cmd += ["--frames", str(args.frames)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _row(r: dict) -> None:
    print(
        f"  {r['method']:<20}{r['frames']:>7}{r['keyframes']:>6}{r['not_tracking']:>6}"
        f"{r['loops']:>6}{r['path_m']:>8.1f}{r['ate_m'] * 100:>9.2f}{r['ate_pct']:>8.3f}"
        f"{r['rpe_pct']:>8.2f}{r['rpe_deg']:>8.2f}{r['ms_wall']:>9.1f}{r['ms_cpu']:>8.1f}{r['peak_rss_mb']:>9.0f}"
    )


def bench_sessions(args: argparse.Namespace) -> None:
    names = [args.only] if args.only else list(SESSIONS)
    for name in names:
        rendered = rendered_frames(args.cache, name)
        partial = not is_ready(args.cache, name)
        if partial and not (args.frames and rendered >= args.frames):
            print(f"\n{name}: not rendered in {args.cache} ({rendered} frames there); run "
                  "benchmarks/odometry_sessions.py, or pass --frames N up to that")
            continue
        n_frames = args.frames or SESSIONS[name].frames
        prepare_depth(args.cache, name, args.engine, n_frames)
        note = f", first {n_frames} of a render stopped at {rendered}" if partial else ""
        print(f"\n{name} ({n_frames} frames, {SESSIONS[name].port} ports, depth "
              f"{args.engine}{note}):")
        print(f"  {'method':<20}{'frames':>7}{'kf':>6}{'!trk':>6}{'loops':>6}{'path m':>8}"
              f"{'ATE cm':>9}{'ATE %':>8}{'RPE %':>8}{'RPE deg':>8}{'ms wall':>9}{'ms cpu':>8}"
              f"{'peak MB':>9}")
        results = [_child(args, "vio", name), _child(args, "vo", name)]
        if not args.no_reference:
            results.append(_child(args, "open3d", name))
        plain = [_child(args, "vio-noloop", name), _child(args, "vo-noloop", name)]
        for r in results + plain:
            _row(r)
        for r, p in zip(results[:2], plain, strict=True):
            print(f"    {r['method']}: loop closures {r['loops_accepted']} of "
                  f"{r['loops_verified']} verified, right (within {LOOP_RIGHT_M * 100:.0f} cm "
                  f"and {LOOP_RIGHT_DEG:.0f} deg of the truth) {r['loops_right_accepted']}: "
                  f"precision {_pct(r['loop_precision'])}, recall {_pct(r['loop_recall'])}; "
                  f"ATE {r['ate_m'] * 100:.2f} cm with closures, {p['ate_m'] * 100:.2f} cm "
                  "without")
        for r in results[:2]:
            print(f"    {r['method']}: CPU ms per frame first sixth {r['ms_cpu_first']:.1f}, "
                  f"last sixth {r['ms_cpu_last']:.1f}, p95 {r['ms_cpu_p95']:.1f}; state held "
                  f"{r['state_mb']:.1f} MB")
        if not args.no_reference:
            o3d_r = results[2]
            ratio_vio = results[0]["ate_m"] / o3d_r["ate_m"]
            print(f"    ATE ratio sea3d/Open3D: stereo+IMU {ratio_vio:.3f}"
                  f", stereo {results[1]['ate_m'] / o3d_r['ate_m']:.3f}; CPU time ratio "
                  f"{results[0]['ms_cpu'] / o3d_r['ms_cpu']:.2f}")


# ------------------------------------------------------------------------------ 7-Scenes
def bench_chess(args: argparse.Namespace) -> None:
    import glob

    import open3d as o3d

    from sea3d.pipeline.odometry import rgbd_odometry

    root = DATA / "rgbd" / "7scenes_chess"
    if not root.is_dir():
        print(f"\n7-Scenes chess: {root} missing, skipped")
        return
    gt = np.stack([np.loadtxt(f) for f in sorted(glob.glob(str(root / "*.pose.txt")))])
    cols = sorted(glob.glob(str(root / "*.color.jpg")))
    deps = sorted(glob.glob(str(root / "*.depth.png")))
    intr = (585.0, 585.0, 320.0, 240.0)
    runs: dict[str, list] = {"dense": [], "features": []}
    res: dict = {}
    for _ in range(args.repeat):
        for method in runs:
            c0 = time.process_time()
            w0 = time.perf_counter()
            res[method] = rgbd_odometry(str(root / "*.color.jpg"), str(root / "*.depth.png"),
                                        intr, method=method)
            runs[method].append(((time.perf_counter() - w0) / len(cols),
                                 (time.process_time() - c0) / len(cols)))
    K = o3d.core.Tensor([[585.0, 0, 320], [0, 585, 240], [0, 0, 1]], dtype=o3d.core.Dtype.Float64)
    ref_t, ref = [], None
    for _ in range(args.repeat):
        imgs = [o3d.t.geometry.RGBDImage(o3d.t.io.read_image(c), o3d.t.io.read_image(d))
                for c, d in zip(cols, deps, strict=True)]
        w0, c0 = time.perf_counter(), time.process_time()
        T = [np.eye(4)]
        for i in range(1, len(imgs)):
            r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                imgs[i], imgs[i - 1], K, o3d.core.Tensor(np.eye(4)), 1000.0, 3.0,
                method=o3d.t.pipelines.odometry.Method.Hybrid,
            )
            T.append(T[-1] @ r.transformation.numpy())
        ref_t.append(((time.perf_counter() - w0) / len(cols), (time.process_time() - c0)
                      / len(cols)))
        ref = np.stack(T)
    assert ref is not None
    idx_t = np.arange(len(gt), dtype=np.int64) * 10**9  # frames paired by index
    m_ref = metrics(idx_t, ref, idx_t, gt, rpe_m=0.1)
    w_r, c_r = (statistics.median(x) for x in zip(*ref_t, strict=True))
    rows = []
    for method, label in (("dense", "sea3d RGB-D dense (default)"),
                          ("features", "sea3d RGB-D features")):
        m = metrics(idx_t, res[method].T_world_left, idx_t, gt, rpe_m=0.1)
        w, c = (statistics.median(x) for x in zip(*runs[method], strict=True))
        rows.append((label, m, w, c, res[method].summary))
    print(f"\n7-Scenes chess, {len(cols)} frames, path {m_ref['path_m']:.3f} m "
          f"(medians of {args.repeat} runs; RPE per 0.1 m):")
    print(f"  {'method':<34}{'ATE cm':>9}{'RPE %':>8}{'RPE deg':>8}{'ms wall':>9}{'ms cpu':>8}"
          f"{'kf':>5}{'lost':>6}")
    for label, m, w, c, summ in rows:
        print(f"  {label:<34}{m['ate_m'] * 100:>9.2f}{m['rpe_pct']:>8.2f}{m['rpe_deg']:>8.2f}"
              f"{w * 1e3:>9.1f}{c * 1e3:>8.1f}{summ.keyframes:>5}{summ.frames_lost:>6}")
    print(f"  {'Open3D rgbd_odometry_multi_scale':<34}{m_ref['ate_m'] * 100:>9.2f}"
          f"{m_ref['rpe_pct']:>8.2f}{m_ref['rpe_deg']:>8.2f}{w_r * 1e3:>9.1f}{c_r * 1e3:>8.1f}")
    for label, m, w, c, _ in rows:
        print(f"  ratio {label}/Open3D: ATE {m['ate_m'] / m_ref['ate_m']:.3f}, wall "
              f"{w / w_r:.2f}, CPU {c / c_r:.2f}")
    # both are causal, so the first n poses are what a run on the first n frames gives
    prefixes = [n for n in (20, 30, 40, 50) if n < len(gt)] + [len(gt)]
    dense_T = res["dense"].T_world_left
    parts = []
    for n in prefixes:
        a_d = metrics(idx_t[:n], dense_T[:n], idx_t[:n], gt[:n])["ate_m"]
        a_r = metrics(idx_t[:n], ref[:n], idx_t[:n], gt[:n])["ate_m"]
        parts.append(f"{n}: {a_d * 100:.2f} / {a_r * 100:.2f}")
    line = ", ".join(parts)
    print(f"  ATE cm on the first n frames, dense / Open3D: {line}")


# ------------------------------------------------------------------------------ EuRoC
def bench_euroc(args: argparse.Namespace) -> None:
    from sea3d.io.euroc import read_euroc
    from sea3d.odometry import create_odometry
    from sea3d.odometry.observe import Observer, imu_chunks
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    root = DATA / "vio" / "euroc_v101_micro"
    if not root.is_dir():
        print(f"\nEuRoC: {root} missing, skipped")
        return
    seq = read_euroc(root)
    observer = Observer(StereoDepth(seq.rig, DepthConfig(engine="opencv")))
    maps = observer.maps
    chunks = imu_chunks(seq.t_ns, seq.imu_t_ns, seq.accel_mps2, seq.gyro_radps)
    obs = [observer.observe(int(t), seq.image("left", i), seq.image("right", i), chunks[i])
           for i, t in enumerate(seq.t_ns)]
    gi = np.searchsorted(seq.gt_t_ns, seq.t_ns)
    G = seq.gt_T_world_body[gi]
    T_body_left = seq.rig.imu.T_imu_left if seq.rig.imu else np.eye(4)
    G_left = G @ T_body_left
    gt_move = np.linalg.inv(G_left[0]) @ G_left[-1]
    print(f"\nEuRoC V1_01 micro: {len(obs)} frames ({(seq.t_ns[-1] - seq.t_ns[0]) * 1e-9:.2f} s, "
          f"still); ground truth moves {np.linalg.norm(gt_move[:3, 3]) * 1e3:.2f} mm")
    print(f"  {'method':<20}{'ATE mm':>8}{'drift mm':>10}{'rel err mm':>12}{'rot err deg':>12}"
          f"{'tilt err deg':>13}{'ms cpu':>8}")
    for method in ("vio", "vo", "open3d"):
        use_imu = method == "vio"
        c0 = time.process_time()
        if method == "open3d":
            T = _open3d_chain([o.rect_left for o in obs], [o.depth_m for o in obs],
                              np.asarray(maps.P_left[:3, :3]), maps.R_rect_left_left)
        else:
            odo = create_odometry(seq.rig, maps, use_imu=use_imu)
            for o in obs:
                odo.step(o)
            _, T = odo.trajectory()
        cpu = (time.process_time() - c0) / len(obs)
        ate = metrics(seq.t_ns, T, seq.t_ns, G_left)["ate_m"]
        move = np.linalg.inv(T[0]) @ T[-1]
        err = np.linalg.inv(gt_move) @ move
        rot = np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1)))
        tilt = float("nan")
        if use_imu:
            # IMU start-up: gravity in the body frame, ours against the ground truth's
            g_ours = (T[0] @ seq.rig.imu.T_left_imu)[:3, :3].T @ np.array([0, 0, 1.0])
            g_gt = G[0, :3, :3].T @ np.array([0, 0, 1.0])
            tilt = np.degrees(np.arccos(np.clip(g_ours @ g_gt, -1, 1)))
        name = {"vio": "sea3d stereo+IMU", "vo": "sea3d stereo", "open3d": "Open3D f2f RGB-D"}[
            method]
        print(f"  {name:<20}{ate * 1e3:>8.2f}{np.linalg.norm(move[:3, 3]) * 1e3:>10.2f}"
              f"{np.linalg.norm(err[:3, 3]) * 1e3:>12.2f}{rot:>12.3f}{tilt:>13.2f}"
              f"{cpu * 1e3:>8.1f}")


# ------------------------------------------------------------------------------ odometry alone
STAGES = {
    "KLT": ("frontend.py", ("track_klt", "track_warped")),
    "right match": ("frontend.py", ("stereo_points",)),
    "PnP": ("frontend.py", ("solve_pnp",)),
    "smoother": ("backend.py", ("add_keyframe",)),
    "corners": ("frontend.py", ("detect_corners",)),
    "loop ORB": ("vio.py", ("_loop_closure", "_redetected_pose")),
}


def cache_observations(session: Path, obs_cache: Path) -> Path:
    """The observations ``sea3d odometry`` feeds its odometry, computed once into a pickle."""
    import pickle

    out = obs_cache / f"{session.resolve().name}.pkl"
    if out.is_file():
        return out
    from sea3d.odometry.config import OdometryConfig
    from sea3d.odometry.observe import Observer, imu_chunks
    from sea3d.pipeline.odometry import imu_decision, open_stereo_source
    from sea3d.stereo.recipe import StereoDepth

    src = open_stereo_source(session, None, imu=True)
    try:
        imu_ok, _ = imu_decision(True, src.rig.imu, src.t_ns, src.imu_t_ns,
                                 tolerance_s=OdometryConfig().imu_max_clock_offset_s)
        stereo = StereoDepth(src.rig, None)
        observer = Observer(stereo)
        n = src.t_ns.size
        chunks: list = [None] * n
        if imu_ok and src.rig.imu is not None:
            off = round(src.rig.imu.time_offset_s * 1e9)
            chunks = imu_chunks(src.t_ns + off, src.imu_t_ns, src.accel_mps2, src.gyro_radps)
        obs = []
        for i in range(n):
            left, right = src.load(i)
            obs.append(observer.observe(int(src.t_ns[i]), left, right, chunks[i]))
    finally:
        src.close()
    obs_cache.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".partial")
    with open(tmp, "wb") as f:
        pickle.dump({"obs": obs, "rig": src.rig, "maps": stereo.maps, "imu": imu_ok}, f,
                    protocol=4)
    tmp.replace(out)
    return out


def run_alone(obs_path: Path, gt_path: Path, stages: bool) -> dict:
    """One run of the odometry alone over cached observations (in this process)."""
    import cProfile
    import pickle
    import pstats

    import sea3d
    from sea3d.eval.trajectory import evaluate_trajectory
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.odometry import create_odometry

    with open(obs_path, "rb") as f:
        d = pickle.load(f)
    gt = read_trajectory(gt_path)
    odo = create_odometry(d["rig"], d["maps"], use_imu=d["imu"])
    prof = cProfile.Profile(timer=time.process_time) if stages else None
    c0 = time.process_time()
    if prof is not None:
        prof.enable()
    for obs in d["obs"]:
        odo.step(obs)
    if prof is not None:
        prof.disable()
    cpu = time.process_time() - c0
    n = len(d["obs"])
    t, T = odo.trajectory()
    m = evaluate_trajectory(t, T, gt.t_ns, gt.T_world_x, align="se3", max_diff_s=0.005,
                            rpe_deltas_m=[])
    r = {"src": str(Path(sea3d.__file__).parents[1]), "frames": n, "cpu_ms": 1e3 * cpu / n,
         "ate_mm": 1e3 * m.ate_rmse_m, "rot_deg": m.ate_rotation_deg.rmse,
         "keyframes": odo.keyframe_count, "lost": odo.frames_lost,
         "loops": odo.loop_closures}
    if prof is not None:
        st = pstats.Stats(prof).stats  # type: ignore[attr-defined]
        cum = {(Path(k[0]).name, k[2]): v[3] for k, v in st.items()}
        total = sum(v for (f, fn), v in cum.items() if f == "vio.py" and fn == "step")
        split = {name: sum(cum.get((f, fn), 0.0) for fn in fns)
                 for name, (f, fns) in STAGES.items()}
        split["rest"] = total - sum(split.values())
        r["stages_ms"] = {k: 1e3 * v / n for k, v in split.items()}
        r["profiled_total_ms"] = 1e3 * total / n
    return r


def bench_alone(args: argparse.Namespace) -> None:
    session = Path(args.session)
    gt = Path(args.gt) if args.gt else session / "gt" / "poses_left.tum"
    obs = cache_observations(session, args.obs_cache)
    trees: list[tuple[str, str | None]] = [("this tree", None)]
    if args.compare:
        trees.append((f"--compare {args.compare}", args.compare))

    def child(tree: str | None, stages: bool) -> dict:
        env = dict(os.environ)
        if tree is not None:
            env["PYTHONPATH"] = tree
        cmd = [sys.executable, __file__, "--child-alone", str(obs), "--gt", str(gt)]
        if stages:
            cmd.append("--stages")
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
        return json.loads(out.stdout.strip().splitlines()[-1])

    runs: dict[str, list[dict]] = {label: [] for label, _ in trees}
    for _ in range(args.repeat):
        for label, tree in trees:
            runs[label].append(child(tree, False))
    print(f"odometry alone over {session} ({runs[trees[0][0]][0]['frames']} frames, cached "
          f"observations {obs}); {args.repeat} runs each, interleaved; load average "
          f"{os.getloadavg()[0]:.1f}")
    print(f"  {'tree':<28}{'CPU ms/frame (median, runs)':<40}{'ATE mm':>8}{'rot deg':>8}"
          f"{'kf':>5}{'lost':>5}{'loops':>6}")
    for label, _ in trees:
        rs = runs[label]
        cpus = [r["cpu_ms"] for r in rs]
        ates = sorted({round(r["ate_mm"], 4) for r in rs})
        print(f"  {label:<28}{statistics.median(cpus):>7.1f}  "
              f"({', '.join(f'{c:.1f}' for c in cpus)}){'':<8}"
              f"{'/'.join(f'{a:.3f}' for a in ates):>10}{rs[0]['rot_deg']:>8.2f}"
              f"{rs[0]['keyframes']:>5}"
              f"{rs[0]['lost']:>5}{rs[0]['loops']:>6}   [{rs[0]['src']}]")
    if args.stages:
        print("  CPU ms per frame by stage (cProfile, one run each; its overhead falls in "
              "the rest):")
        for label, tree in trees:
            r = child(tree, True)
            parts = "  ".join(f"{k} {v:.1f}" for k, v in r["stages_ms"].items())
            print(f"    {label:<26} total {r['profiled_total_ms']:.1f}: {parts}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    p.add_argument("--only", help="one simulated session (or 'chess', 'euroc')")
    p.add_argument("--engine", default="opencv", help="depth engine for the simulated dives")
    p.add_argument("--frames", type=int, help="use only the first frames of each dive")
    p.add_argument("--repeat", type=int, default=3, help="timing repeats (7-Scenes)")
    p.add_argument("--no-reference", action="store_true", help="skip Open3D on the dives")
    p.add_argument("--session", help="the odometry alone on this recorded session (section 4)")
    p.add_argument("--gt", help="ground truth of --session (default SESSION/gt/poses_left.tum)")
    p.add_argument("--obs-cache", type=Path, default=DEFAULT_CACHE / "observations",
                   help="where --session's observations are cached")
    p.add_argument("--compare", help="another source tree (its src/) run beside this one")
    p.add_argument("--stages", action="store_true", help="CPU per stage of --session")
    p.add_argument("--child", help=argparse.SUPPRESS)
    p.add_argument("--child-alone", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child_alone:
        print(json.dumps(run_alone(args.child_alone, Path(args.gt), args.stages)))
        return 0
    if args.session:
        bench_alone(args)
        return 0
    if args.child:
        if args.child == "open3d":
            r = run_open3d(args.cache, args.only, args.engine, args.frames)
        else:
            what, _, loops = args.child.partition("-")
            r = run_sea3d(args.cache, args.only, args.engine, what == "vio", args.frames,
                          loop_closure=loops != "noloop")
        print(json.dumps(r))
        return 0
    print(f"sea3d odometry benchmark ({os.cpu_count()} CPUs; load average "
          f"{os.getloadavg()[0]:.1f})")
    if args.only in (None, "chess"):
        bench_chess(args)
    if args.only in (None, "euroc"):
        bench_euroc(args)
    if args.only not in ("chess", "euroc"):
        bench_sessions(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
