"""The real 7-Scenes chess frames shared by the RGB-D tests: loading, observations, ATE, and
the reference (Open3D's frame-to-frame ``rgbd_odometry_multi_scale``, Hybrid, the paper's
method) on the same frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sea3d.eval.trajectory import evaluate_trajectory
from sea3d.odometry.types import FrameObservation
from sea3d.pipeline.odometry import read_rgbd_frame

INTR = (585.0, 585.0, 320.0, 240.0)
K = np.array([[INTR[0], 0, INTR[2]], [0, INTR[1], INTR[3]], [0, 0, 1.0]])


def load_chess(data_dir: Path, n: int) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """The first ``n`` frames (colour, metric depth) and their ground-truth poses."""
    root = data_dir / "rgbd/7scenes_chess"
    frames = [read_rgbd_frame(root / f"frame-{i:06d}.color.jpg",
                              root / f"frame-{i:06d}.depth.png", 1000.0) for i in range(n)]
    gt = np.stack([np.loadtxt(root / f"frame-{i:06d}.pose.txt") for i in range(n)])
    return frames, gt


def obs(i: int, rgb: np.ndarray, z: np.ndarray) -> FrameObservation:
    return FrameObservation(t_ns=i * 10**9, rect_left=rgb, rect_right=rgb, depth_m=z, K_rect=K,
                            baseline_m=0.0, R_rect_left_left=np.eye(3))


def ate_m(T: np.ndarray, gt: np.ndarray) -> float:
    t = np.arange(len(gt), dtype=np.int64) * 10**9
    return evaluate_trajectory(t, T, t, gt, align="se3", max_diff_s=0.001,
                               rpe_deltas_m=[]).ate_rmse_m


def open3d_f2f(frames: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses chained from Open3D's frame-to-frame odometry."""
    import open3d as o3d

    Kt = o3d.core.Tensor(K, dtype=o3d.core.Dtype.Float64)
    imgs = [o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(np.ascontiguousarray(rgb)),
                                     o3d.t.geometry.Image(np.nan_to_num(z, nan=0.0)))
            for rgb, z in frames]
    T = [np.eye(4)]
    for i in range(1, len(imgs)):
        r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
            imgs[i], imgs[i - 1], Kt, o3d.core.Tensor(np.eye(4)), 1.0, 3.0,
            method=o3d.t.pipelines.odometry.Method.Hybrid)
        T.append(T[-1] @ r.transformation.numpy())
    return np.stack(T)
