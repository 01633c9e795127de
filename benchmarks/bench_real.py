"""Real-data benchmark: every real sequence we can read, beside plain references in the same run.

1. **7-Scenes chess** (``$SEA3D_TEST_DATA/rgbd/7scenes_chess``, 60 frames, Kinect v1 depth) at
   frame steps 1, 2, 5 and 10 (every k-th frame: larger motion between the frames tracked):
   sea3d's RGB-D odometry (``dense``, the default, and ``features``) beside Open3D's
   frame-to-frame ``rgbd_odometry_multi_scale`` (Hybrid, as in Open3D's own RGB-D odometry
   example) on the same frames and depth, and the patterns ``jerk`` (the speed changes tenfold
   twice) and ``jump`` (12 cm in one step after ten slow frames). ATE after an SE3 alignment,
   centimetres.
2. **EuRoC V1_01 micro** (``$SEA3D_TEST_DATA/vio/euroc_v101_micro``, 40 frames, the drone still
   on the ground): ``sea3d odometry`` with its defaults beside the plain OpenCV SGBM + KLT +
   PnP-RANSAC frame-to-frame odometry (``opencv_pnp_baseline.py``): the drift while still.
3. **Fetched sequences** under ``$SEA3D_REAL_DATA`` (default ``~/.cache/sea3d/real``; their
   licences forbid copying them into the repository, so each is skipped when absent):
   ``kitti_<seq>/`` (KITTI odometry layout: ``image_0``, ``image_1``, ``calib.txt``,
   ``times.txt``, ``poses.txt``) and ``euroc_<name>/`` (EuRoC layout with
   ``state_groundtruth_estimate0``), each beside the OpenCV baseline.
4. **Trajectory files as real tools write them** (``--only files``): ``$SEA3D_REAL_DATA/evo_v102/``
   holds evo's test files for EuRoC V1_02 (an open VIO's estimate ``V102.txt`` with 4 repeated
   stamps, and ``V102_groundtruth.csv``; from github.com/MichaelGrupp/evo ``test/data/``, kept out
   of this repository). ``sea3d eval trajectory`` on them, beside evo's figures quoted in issue
   21 (evo is GPL: not run here, its figures are only compared): the ATE with the repeats kept
   and paired as evo pairs them, and with the first pose of each stamp kept.

ATE from :func:`sea3d.eval.trajectory.evaluate_trajectory` (equal to evo's on the stored
files). Wall and CPU seconds are per sequence (one run each: the machine is shared and loaded;
accuracy does not depend on it). Run:

    python benchmarks/bench_real.py [--only chess|euroc|fetched] [--patterns 1 2 5 10 jerk]
        [--strides 1 2 3]

``--strides`` takes every k-th frame of each fetched KITTI excerpt (at its real stamps: 1.2 m
per frame at stride 1, 2.4 and 3.6 m at strides 2 and 3, real large inter-frame motion); sea3d
and the OpenCV baseline run on the same frames in the same run.
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

DATA = Path(os.environ.get("SEA3D_TEST_DATA", Path(__file__).resolve().parents[1] / ".." /
                           "shared" / "data"))
REAL = Path(os.environ.get("SEA3D_REAL_DATA", Path.home() / ".cache" / "sea3d" / "real"))
CHESS_K = (585.0, 585.0, 320.0, 240.0)


def ate_cm(T: np.ndarray, gt: np.ndarray) -> float:
    """ATE RMSE (SE3 alignment) of poses paired by index, centimetres."""
    from sea3d.eval.trajectory import evaluate_trajectory

    t = np.arange(len(gt), dtype=np.int64) * 10**9
    m = evaluate_trajectory(t, T, t, gt, align="se3", max_diff_s=0.001, rpe_deltas_m=[])
    return 100.0 * m.ate_rmse_m


def _timed(fn, *args):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, time.perf_counter() - w0, time.process_time() - c0


# ------------------------------------------------------------------------------ 7-Scenes
# every k-th frame, and a "jerk": 20 frames at walking pace, three 10-frame jumps, then walking
# pace again (the speed changes tenfold twice, as when frames are dropped)
JERK = [*range(0, 21), 30, 40, 50, *range(51, 60)]
# ten frames, a jump of 36 frames (about 12 cm and 8 deg), ten frames
JUMP = [*range(0, 10), *range(45, 55)]


def chess_frames(root: Path, pattern: int | str):
    """Colour and depth paths and ground-truth poses of the chess frames of a pattern: a step
    ``k`` (every k-th frame), ``"jerk"`` (:data:`JERK`) or ``"jump"`` (:data:`JUMP`)."""
    named = {"jerk": JERK, "jump": JUMP}
    idx = named[pattern] if pattern in named else list(range(0, 60, int(pattern)))
    cols = sorted(glob.glob(str(root / "*.color.jpg")))
    deps = sorted(glob.glob(str(root / "*.depth.png")))
    poses = sorted(glob.glob(str(root / "*.pose.txt")))
    gt = np.stack([np.loadtxt(poses[i]) for i in idx])
    return [cols[i] for i in idx], [deps[i] for i in idx], gt


def open3d_frame_to_frame(cols: list[str], deps: list[str], K: tuple) -> np.ndarray:
    """Open3D's multi-scale RGB-D odometry chained frame to frame (Hybrid, depth in mm)."""
    import open3d as o3d

    fx, fy, cx, cy = K
    Kt = o3d.core.Tensor([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=o3d.core.Dtype.Float64)
    imgs = [o3d.t.geometry.RGBDImage(o3d.t.io.read_image(c), o3d.t.io.read_image(d))
            for c, d in zip(cols, deps, strict=True)]
    T = [np.eye(4)]
    for i in range(1, len(imgs)):
        r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
            imgs[i], imgs[i - 1], Kt, o3d.core.Tensor(np.eye(4)), 1000.0, 3.0,
            method=o3d.t.pipelines.odometry.Method.Hybrid)
        T.append(T[-1] @ r.transformation.numpy())
    return np.stack(T)


def sea3d_rgbd(cols: list[str], deps: list[str], K: tuple, method: str, tmp: Path):
    """sea3d's RGB-D odometry on these files (linked into one folder so the glob finds them);
    method ``dense``, ``features`` or ``dense-nofeat`` (dense without the feature pose)."""
    from sea3d.odometry.rgbd_dense import DenseRgbdConfig
    from sea3d.pipeline.odometry import rgbd_odometry

    tmp.mkdir(parents=True, exist_ok=True)
    for p in tmp.iterdir():
        p.unlink()
    for k, (c, d) in enumerate(zip(cols, deps, strict=True)):
        os.symlink(c, tmp / f"f{k:05d}.color.jpg")
        os.symlink(d, tmp / f"f{k:05d}.depth.png")
    cfg = DenseRgbdConfig(feature_init=False) if method == "dense-nofeat" else None
    return rgbd_odometry(str(tmp / "*.color.jpg"), str(tmp / "*.depth.png"), K,
                         method=method.split("-")[0], dense_config=cfg)


def bench_chess(patterns: list) -> list[dict]:
    import tempfile

    root = DATA / "rgbd" / "7scenes_chess"
    if not root.is_dir():
        print(f"7-Scenes chess: {root} missing, skipped")
        return []
    rows = []
    methods = ("dense", "dense-nofeat", "features")
    print("7-Scenes chess (60 frames), every k-th frame, the 'jerk' or the 'jump' pattern; ATE "
          "cm (SE3) and lost frames; wall s of sea3d dense / Open3D:")
    print(f"  {'frames':>10} {'n':>3} {'path m':>7} {'dense':>7} {'lost':>4} {'no-feat':>8} "
          f"{'features':>9} {'Open3D':>7} {'dense/O3D':>9} {'wall s':>12}")
    with tempfile.TemporaryDirectory() as td:
        for pat in patterns:
            cols, deps, gt = chess_frames(root, pat)
            path = float(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum())
            ref, w_r, _ = _timed(open3d_frame_to_frame, cols, deps, CHESS_K)
            out = {}
            for method in methods:
                run, w, c = _timed(sea3d_rgbd, cols, deps, CHESS_K, method, Path(td) / "f")
                out[method] = (ate_cm(run.T_world_left, gt), run.summary.frames_lost, w, c)
            a_ref = ate_cm(ref, gt)
            d, n, f = out["dense"], out["dense-nofeat"], out["features"]
            label = pat if isinstance(pat, str) else f"step {pat}"
            print(f"  {label:>10} {len(cols):>3} {path:>7.2f} {d[0]:>7.2f} {d[1]:>4} {n[0]:>8.2f} "
                  f"{f[0]:>9.2f} {a_ref:>7.2f} {d[0] / a_ref:>9.2f} {d[2]:>5.1f} / {w_r:<5.1f}")
            rows.append({"pattern": pat, "frames": len(cols), "dense_cm": d[0],
                         "nofeat_cm": n[0], "features_cm": f[0], "open3d_cm": a_ref})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", choices=["chess", "euroc", "fetched", "files"])
    p.add_argument("--patterns", nargs="+", default=["1", "2", "5", "10", "jerk", "jump"],
                   help="chess frame steps, or 'jerk', 'jump'")
    p.add_argument("--strides", nargs="+", type=int, default=[1, 2, 3],
                   help="KITTI frame strides (every k-th frame)")
    args = p.parse_args(argv)
    if args.only in (None, "chess"):
        bench_chess([p if p in ("jerk", "jump") else int(p) for p in args.patterns])
    if args.only in (None, "euroc"):
        bench_euroc()
    if args.only in (None, "fetched"):
        bench_fetched(args.strides)
    if args.only in (None, "files"):
        bench_files()
    return 0


# evo's ATE RMSE (SE3) on evo's own V1_02 test files, as quoted there (evo 1.x, default
# association: 0.01 s): the repeats kept, and the first pose of each repeated stamp kept
EVO_V102_ATE_M = {"keep": 0.091727, "first": 0.091747}


def bench_files() -> None:
    """``eval trajectory``'s reading and pairing on real files beside evo's figures."""
    import logging

    from sea3d.eval.trajectory import evaluate_trajectory
    from sea3d.io.trajectory_files import read_trajectory

    d = REAL / "evo_v102"
    if not (d / "V102.txt").is_file():
        print(f"trajectory files: {d} missing, skipped")
        return
    logging.getLogger("sea3d.io.trajectory_files").setLevel(logging.ERROR)
    print("EuRoC V1_02, an open VIO's estimate (evo's test files): ATE RMSE m, SE3")
    for rule in ("keep", "first"):
        est = read_trajectory(d / "V102.txt", duplicates=rule)
        ref = read_trajectory(d / "V102_groundtruth.csv", duplicates=rule)
        m = evaluate_trajectory(est.t_ns, est.T_world_x, ref.t_ns, ref.T_world_x)
        evo = EVO_V102_ATE_M[rule]
        print(f"  repeats {rule:5s}  {m.ate_rmse_m:.6f} ({m.matched} pairs)  evo {evo:.6f}  "
              f"difference {m.ate_rmse_m - evo:+.1e} m")


# ------------------------------------------------------------------------------ EuRoC / KITTI
def bench_euroc() -> None:
    root = DATA / "vio" / "euroc_v101_micro"
    if not root.is_dir():
        print(f"EuRoC micro: {root} missing, skipped")
        return
    _stereo_row("EuRoC V1_01 micro (still)", root)


def bench_fetched(strides: list[int]) -> None:
    found = sorted(REAL.glob("kitti_*")) + sorted(REAL.glob("euroc_*")) if REAL.is_dir() else []
    if not found:
        print(f"fetched sequences: none under {REAL} (SEA3D_REAL_DATA), skipped")
        return
    import tempfile

    for d in found:
        if d.name.startswith("kitti_"):
            for k in strides:
                with tempfile.TemporaryDirectory() as td:
                    _stereo_row(f"{d.name} stride {k}", kitti_as_euroc(d, Path(td), stride=k))
        else:
            _stereo_row(d.name, d)


def kitti_as_euroc(src: Path, dst: Path, rate_hz: float = 10.0, stride: int = 1) -> Path:
    """Present a KITTI odometry excerpt (``image_0``/``image_1`` rectified grey pairs,
    ``calib.txt`` with the ``P0``/``P1`` rows, ``poses.txt`` of ``T_world_left`` rows, optional
    ``times.txt``) as an EuRoC folder under ``dst`` (images linked, not copied): the body frame
    is the left camera, no IMU, no distortion, the right camera ``B = -P1[0, 3] / P1[0, 0]`` to
    the right; ``stride`` keeps every k-th frame (at its own stamp). Returns the folder for
    :func:`sea3d.io.euroc.read_euroc`."""
    import cv2
    from scipy.spatial.transform import Rotation

    rows = []
    for line in (src / "calib.txt").read_text().splitlines():
        vals = line.split(":")[-1].split()
        if len(vals) == 12:
            rows.append(np.asarray(vals, dtype=np.float64).reshape(3, 4))
    P0, P1 = rows[0], rows[1]
    baseline = float(-P1[0, 3] / P1[0, 0])
    left = sorted((src / "image_0").glob("*.png"))
    right = sorted((src / "image_1").glob("*.png"))
    poses = np.loadtxt(src / "poses.txt").reshape(-1, 3, 4)
    n = min(len(left), len(right), len(poses))
    times = (np.loadtxt(src / "times.txt")[:n] if (src / "times.txt").is_file()
             else np.arange(n) / rate_hz)
    t_ns = (1_000_000_000 + np.round(np.asarray(times) * 1e9)).astype(np.int64)
    keep = np.arange(0, n, int(stride))
    left, right, poses, t_ns = ([left[i] for i in keep], [right[i] for i in keep], poses[keep],
                                t_ns[keep])
    n = keep.size
    h, w = cv2.imread(str(left[0]), cv2.IMREAD_GRAYSCALE).shape
    mav0 = dst / "mav0"
    for cam, files, tx in (("cam0", left, 0.0), ("cam1", right, baseline)):
        (mav0 / cam / "data").mkdir(parents=True)
        for t, f in zip(t_ns, files[:n], strict=True):
            os.symlink(f.resolve(), mav0 / cam / "data" / f"{t}.png")
        (mav0 / cam / "data.csv").write_text(
            "#timestamp [ns],filename\n" + "".join(f"{t},{t}.png\n" for t in t_ns))
        T = [1, 0, 0, tx, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
        (mav0 / cam / "sensor.yaml").write_text(
            f"T_BS:\n  rows: 4\n  cols: 4\n  data: {T}\nrate_hz: {rate_hz / stride}\n"
            f"resolution: [{w}, {h}]\ncamera_model: pinhole\n"
            f"intrinsics: {[float(v) for v in (P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2])]}\n"
            "distortion_model: radial-tangential\ndistortion_coefficients: [0, 0, 0, 0]\n")
    gt = mav0 / "state_groundtruth_estimate0"
    gt.mkdir()
    q = Rotation.from_matrix(poses[:n, :, :3]).as_quat()  # x y z w
    lines = [f"{t},{p[0, 3]},{p[1, 3]},{p[2, 3]},{qq[3]},{qq[0]},{qq[1]},{qq[2]}\n"
             for t, p, qq in zip(t_ns, poses[:n], q, strict=True)]
    (gt / "data.csv").write_text("#timestamp,px,py,pz,qw,qx,qy,qz\n" + "".join(lines))
    return dst


def _stereo_row(name: str, root: Path) -> None:
    """sea3d odometry (defaults) and the OpenCV baseline on one stereo sequence with GT."""
    from opencv_pnp_baseline import load_stereo_sequence, pnp_baseline

    from sea3d.eval.trajectory import evaluate_trajectory
    from sea3d.pipeline.odometry import session_odometry

    seq = load_stereo_sequence(root)
    gt_t, gt_T = seq["gt_t_ns"], seq["gt_T_world_left"]
    base, w_b, c_b = _timed(pnp_baseline, seq)
    run, w, c = _timed(session_odometry, seq["session"])

    def ate(t, T):
        m = evaluate_trajectory(t, T, gt_t, gt_T, align="se3", max_diff_s=0.005, rpe_deltas_m=[])
        return m.ate_rmse_m, m.path_length_m

    def moved_mm(T):  # displacement from the first to the last frame
        return 1e3 * float(np.linalg.norm(T[-1, :3, 3] - T[0, :3, 3]))

    a_s, path = ate(run.t_ns, run.T_world_left)
    a_b, _ = ate(seq["t_ns"], base)
    gt_moved = moved_mm(gt_T[(gt_t >= seq["t_ns"][0]) & (gt_t <= seq["t_ns"][-1])])
    print(f"{name}: {len(seq['t_ns'])} frames, path {path:.2f} m (ground truth moves "
          f"{gt_moved:.1f} mm start to end); ATE m (SE3) and start-to-end displacement mm:")
    print(f"  sea3d odometry (defaults)      {a_s:.4f}  {moved_mm(run.T_world_left):7.1f} mm  "
          f"lost {run.summary.frames_lost}  {w:.0f} s wall {c:.0f} s CPU")
    print(f"  OpenCV SGBM + KLT + PnP f2f    {a_b:.4f}  {moved_mm(base):7.1f} mm  "
          f"        {w_b:.0f} s wall {c_b:.0f} s CPU")


if __name__ == "__main__":
    raise SystemExit(main())
