"""RGB-D odometry benchmark: frame-to-model and frame-to-keyframe tracking, loop closure, beside
Open3D frame-to-frame in the same run.

Sequences:

1. **7-Scenes chess** (``$SEA3D_TEST_DATA/rgbd/7scenes_chess``, 60 frames, Kinect v1 depth) at
   frame steps 1, 2, 5 and 10 (every k-th frame);
2. **chess there and back** (``return``): all 60 frames in order, then back in reverse to the
   first (119 frames): a path that returns, where drift shows in the end error;
3. **TUM RGB-D excerpts** under ``$SEA3D_REAL_DATA`` (default ``~/.cache/sea3d/real``), each
   ``tum_<name>/`` in the TUM layout (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, depth
   16-bit at 5000 per metre; fr1 intrinsics 517.3 516.5 318.6 255.3); skipped when absent.

Columns: Open3D's frame-to-frame ``rgbd_odometry_multi_scale`` (Hybrid, as in Open3D's RGB-D
odometry example; the reference), sea3d ``keyframe`` (frame-to-keyframe dense tracking, the
default), sea3d ``model`` (frame-to-model against the TSDF ray-cast,
``DenseRgbdConfig(tracking="model")``) and, with ``--loops``, both with loop closure. ATE RMSE
after an SE3 alignment and the end error (the last pose relative to the first, against the
ground truth's), centimetres; the loops found; wall and CPU seconds of each run (one run each:
the machine is shared and loaded; accuracy does not depend on it). Run:

    python benchmarks/bench_rgbd.py [--only chess|return|tum] [--steps 1 2 5 10] [--loops]
                                    [--voxel-px 1.25]
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DATA = Path(os.environ.get("SEA3D_TEST_DATA", Path(__file__).resolve().parents[1] / ".." /
                           "shared" / "data"))
REAL = Path(os.environ.get("SEA3D_REAL_DATA", Path.home() / ".cache" / "sea3d" / "real"))
CHESS_K = (585.0, 585.0, 320.0, 240.0)
TUM_FR1_K = (517.3, 516.5, 318.6, 255.3)


@dataclass
class Sequence:
    name: str
    frames: list  # (rgb (H, W, 3) uint8, depth (H, W) float32 metres, NaN invalid)
    gt: np.ndarray  # (N, 4, 4) T_world_cam
    K: tuple[float, float, float, float]


def _mat(K: tuple[float, float, float, float]) -> np.ndarray:
    return np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1.0]])


def errors_cm(T: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """ATE RMSE (SE3 alignment, poses paired by index) and end error, centimetres."""
    from sea3d.eval.trajectory import evaluate_trajectory

    t = np.arange(len(gt), dtype=np.int64) * 10**9
    m = evaluate_trajectory(t, T, t, gt, align="se3", max_diff_s=0.001, rpe_deltas_m=[])
    rel_T = np.linalg.inv(T[0]) @ T[-1]
    rel_g = np.linalg.inv(gt[0]) @ gt[-1]
    return 100.0 * m.ate_rmse_m, 100.0 * float(np.linalg.norm(rel_T[:3, 3] - rel_g[:3, 3]))


def chess(indices: list[int]) -> Sequence | None:
    from sea3d.pipeline.odometry import read_rgbd_frame

    root = DATA / "rgbd" / "7scenes_chess"
    if not root.is_dir():
        return None
    cache = {i: read_rgbd_frame(root / f"frame-{i:06d}.color.jpg",
                                root / f"frame-{i:06d}.depth.png", 1000.0)
             for i in set(indices)}
    gt = np.stack([np.loadtxt(root / f"frame-{i:06d}.pose.txt") for i in indices])
    return Sequence("", [cache[i] for i in indices], gt, CHESS_K)


def there_and_back(n: int = 60) -> list[int]:
    """Frames ``0 .. n-1`` then back to 0: ``2 n - 1`` frames."""
    return [*range(n), *range(n - 2, -1, -1)]


def _tum_list(path: Path) -> tuple[np.ndarray, list[list[str]]]:
    rows = [ln.split() for ln in path.read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    return np.array([float(r[0]) for r in rows]), [r[1:] for r in rows]


def tum(folder: Path, max_frames: int) -> Sequence:
    """A TUM RGB-D folder: colour and depth associated by nearest stamp (within 20 ms), and
    ground truth interpolated-free: the nearest pose within 10 ms."""
    from scipy.spatial.transform import Rotation

    from sea3d.pipeline.odometry import read_rgbd_frame

    t_rgb, rgb = _tum_list(folder / "rgb.txt")
    t_dep, dep = _tum_list(folder / "depth.txt")
    t_gt, gt = _tum_list(folder / "groundtruth.txt")
    gt_v = np.array(gt, float)
    frames, poses = [], []
    for i, t in enumerate(t_rgb):
        j = int(np.argmin(np.abs(t_dep - t)))
        g = int(np.argmin(np.abs(t_gt - t)))
        if abs(t_dep[j] - t) > 0.02 or abs(t_gt[g] - t) > 0.01:
            continue
        frames.append(read_rgbd_frame(folder / rgb[i][0], folder / dep[j][0], 5000.0))
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(gt_v[g, 3:7]).as_matrix()
        T[:3, 3] = gt_v[g, :3]
        poses.append(T)
        if len(frames) >= max_frames:
            break
    return Sequence(folder.name, frames, np.stack(poses), TUM_FR1_K)


def open3d_frame_to_frame(seq: Sequence) -> np.ndarray:
    import open3d as o3d

    Kt = o3d.core.Tensor(_mat(seq.K), dtype=o3d.core.Dtype.Float64)
    imgs = [o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(np.ascontiguousarray(rgb)),
                                     o3d.t.geometry.Image(np.nan_to_num(z, nan=0.0)))
            for rgb, z in seq.frames]
    T = [np.eye(4)]
    for i in range(1, len(imgs)):
        r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
            imgs[i], imgs[i - 1], Kt, o3d.core.Tensor(np.eye(4)), 1.0, 3.0,
            method=o3d.t.pipelines.odometry.Method.Hybrid)
        T.append(T[-1] @ r.transformation.numpy())
    return np.stack(T)


def sea3d_dense(seq: Sequence, **config) -> tuple[np.ndarray, dict]:
    from sea3d.odometry.rgbd_dense import DenseRgbdConfig, DenseRgbdOdometry
    from sea3d.odometry.types import FrameObservation, TrackingStatus

    K = _mat(seq.K)
    odo = DenseRgbdOdometry(K, DenseRgbdConfig(**config))
    lost = 0
    for k, (rgb, z) in enumerate(seq.frames):
        e = odo.step(FrameObservation(t_ns=k * 10**9, rect_left=rgb, rect_right=rgb, depth_m=z,
                                      K_rect=K, baseline_m=0.0, R_rect_left_left=np.eye(3)))
        lost += e.status is TrackingStatus.LOST
    loops = list(odo._loops.loops) if odo._loops is not None else []
    return odo.trajectory()[1], {"lost": lost, "keyframes": odo.keyframe_count,
                                 "model_frames": odo.model_frames, "loops": loops}


def _timed(fn, *args, **kw):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kw)
    return out, time.perf_counter() - w0, time.process_time() - c0


def run_sequence(seq: Sequence, loops: bool, voxel_px: float | None = None) -> dict:
    model = {"tracking": "model"} | ({"voxel_px": voxel_px} if voxel_px else {})
    runs = {"keyframe": {"loop_closure": False}, "model": model | {"loop_closure": False}}
    if loops:
        runs["keyframe+loops"] = {"loop_closure": True}
        runs["model+loops"] = model | {"loop_closure": True}
    ref, w, c = _timed(open3d_frame_to_frame, seq)
    row = {"sequence": seq.name, "frames": len(seq.frames),
           "path_m": float(np.linalg.norm(np.diff(seq.gt[:, :3, 3], axis=0), axis=1).sum()),
           "Open3D f2f": (*errors_cm(ref, seq.gt), {}, w, c)}
    for name, cfg in runs.items():
        (T, info), w, c = _timed(sea3d_dense, seq, **cfg)
        row[name] = (*errors_cm(T, seq.gt), info, w, c)
    return row


def print_row(row: dict) -> None:
    print(f"{row['sequence']}: {row['frames']} frames, path {row['path_m']:.2f} m")
    for name, val in row.items():
        if not isinstance(val, tuple):
            continue
        ate, end, info, w, c = val
        extra = (f"lost {info['lost']}, keyframes {info['keyframes']}, model frames "
                 f"{info['model_frames']}, loops {info['loops']}" if info else "")
        print(f"  {name:>15}: ATE {ate:6.2f} cm  end {end:6.2f} cm  wall {w:6.1f} s  "
              f"CPU {c:6.1f} s  {extra}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", choices=["chess", "return", "tum"])
    p.add_argument("--steps", nargs="+", type=int, default=[1, 2, 5, 10])
    p.add_argument("--loops", action="store_true", help="also run with loop closure")
    p.add_argument("--tum-frames", type=int, default=200, help="frames read per TUM excerpt")
    p.add_argument("--voxel-px", type=float, help="model voxel in pixel footprints (default: "
                   "DenseRgbdConfig's)")
    args = p.parse_args(argv)
    if args.only in (None, "chess"):
        for s in args.steps:
            seq = chess(list(range(0, 60, s)))
            if seq is None:
                print("7-Scenes chess missing, skipped")
                break
            seq.name = f"chess step {s}"
            print_row(run_sequence(seq, args.loops, args.voxel_px))
    if args.only in (None, "return"):
        seq = chess(there_and_back())
        if seq is None:
            print("7-Scenes chess missing, skipped")
        else:
            seq.name = "chess there and back"
            print_row(run_sequence(seq, True, args.voxel_px))
    if args.only in (None, "tum"):
        folders = sorted(REAL.glob("tum_*")) if REAL.is_dir() else []
        if not folders:
            print(f"no TUM RGB-D excerpt under {REAL} (tum_<name>/), skipped")
        for f in folders:
            print_row(run_sequence(tum(f, args.tum_frames), args.loops, args.voxel_px))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
