"""Frame-to-model RGB-D tracking (``sea3d.odometry.rgbd_model`` and
``DenseRgbdConfig(tracking="model")``) and RGB-D loop closure (``sea3d.odometry.rgbd_loop``) on
the real 7-Scenes chess frames, against ground truth and Open3D frame-to-frame."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from odometry._chess import K, ate_m, obs, open3d_f2f
from sea3d.errors import OdometryError
from sea3d.odometry import TrackingStatus
from sea3d.odometry.rgbd_dense import DenseRgbdConfig, DenseRgbdOdometry
from sea3d.odometry.rgbd_loop import RgbdLoopCloser
from sea3d.odometry.rgbd_model import TsdfModel, voxel_from_depth

pytestmark = pytest.mark.data


def test_voxel_from_depth_is_the_pixel_footprint_at_the_median_depth() -> None:
    z = np.full((4, 4), 2.0, np.float32)
    z[0, 0] = np.nan
    assert voxel_from_depth(z, 500.0, 1.25) == pytest.approx(2.0 * 1.25 / 500.0)
    with pytest.raises(OdometryError, match="no valid depth"):
        voxel_from_depth(np.full((4, 4), np.nan, np.float32), 500.0, 1.25)


RENDER_GAP_VOXELS = 0.35
"""Median signed gap between the ray-cast and the integrated frame, in voxels, at every
orientation (Open3D's half-voxel offset left uncorrected gives up to 0.78 voxel)."""


@pytest.mark.parametrize("rotvec", [(0, 0, 0), (0, np.pi / 2, 0), (-np.pi / 2, 0, 0)])
def test_the_model_renders_the_frame_it_integrated(chess, rotvec) -> None:
    frames, _ = chess
    rgb, z = frames[0]
    voxel = 0.008
    model = TsdfModel(K, 640, 480, voxel_m=voxel, trunc_voxels=4.0, min_depth_m=0.1,
                      max_depth_m=4.0)
    P = np.eye(4)
    P[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    P[:3, 3] = [0.3, -0.2, 0.5]
    zz = np.nan_to_num(z, nan=0.0).astype(np.float32)
    assert model.render(P) is None  # nothing fused yet
    model.integrate(rgb, zz, P)
    _, d = model.render(P)
    both = (d > 0) & (zz > 0)
    assert both.sum() > 0.9 * (zz > 0).sum()
    gap = np.median(d[both] - zz[both])
    assert abs(gap) < RENDER_GAP_VOXELS * voxel, gap


def test_model_tracking_falls_back_to_the_keyframe_when_the_raycast_is_too_sparse(chess) -> None:
    frames, _ = chess
    # a ray-cast never covers every pixel with depth: min_model_share 1 always falls back
    cfg = DenseRgbdConfig(tracking="model", min_model_share=1.0, voxel_px=4.0,
                          loop_closure=False)
    odo = DenseRgbdOdometry(K, cfg)
    ref = DenseRgbdOdometry(K, DenseRgbdConfig(loop_closure=False))
    for i in range(0, 12, 4):
        e = odo.step(obs(i, *frames[i]))
        ref.step(obs(i, *frames[i]))
        assert e.status is TrackingStatus.TRACKING
        assert i == 0 or e.info["model_share"] < 1.0
    assert odo.model_frames == 0
    # the same alignments (up to the rounding of Open3D's parallel reductions, 10 um)
    np.testing.assert_allclose(odo.trajectory()[1], ref.trajectory()[1], atol=1e-5)


def test_tracking_mode_is_checked() -> None:
    with pytest.raises(OdometryError, match="tracking must be"):
        DenseRgbdConfig(tracking="frame")


MODEL_MARGIN = 0.85
"""Frame-to-model ATE must be below this fraction of Open3D frame-to-frame's (step 5)."""


@pytest.mark.slow
def test_frame_to_model_beats_open3d_frame_to_frame_at_step_5(chess) -> None:
    frames, gt = chess
    idx = list(range(0, 60, 5))
    odo = DenseRgbdOdometry(K, DenseRgbdConfig(tracking="model"))
    est = [odo.step(obs(k, *frames[i])) for k, i in enumerate(idx)]
    assert all(e.status is TrackingStatus.TRACKING for e in est)
    assert odo.model_frames == len(idx) - 1  # every frame after the first, against the model
    ours = ate_m(odo.trajectory()[1], gt[idx])
    ref = ate_m(open3d_f2f([frames[i] for i in idx]), gt[idx])
    assert ours < MODEL_MARGIN * ref, (ours, ref)


# ---------------------------------------------------------------------------- loop closure
THERE_AND_BACK = [0, 10, 20, 30, 40, 50, 59, 45, 35, 25, 15, 5, 0]
"""Keyframes of a path that goes to the end of the clip and comes back to its first frame."""
DRIFT_M_PER_KF = 0.002
"""Odometry drift fed to the loop closer: this much more along x at every keyframe."""


def _grey(rgb: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def _feed(closer: RgbdLoopCloser, frames, gt, idx, drift: float) -> list[np.ndarray]:
    T0 = np.linalg.inv(gt[idx[0]])
    odom = []
    for k, i in enumerate(idx):
        T = T0 @ gt[i]
        T[0, 3] += drift * k
        odom.append(T)
        rgb, z = frames[i]
        closer.add_keyframe(k, 0, T, _grey(rgb), z)
    return odom


def test_a_return_closes_a_loop_and_removes_the_drift(chess) -> None:
    frames, gt = chess
    closer = RgbdLoopCloser(K)
    odom = _feed(closer, frames, gt, THERE_AND_BACK, DRIFT_M_PER_KF)
    assert closer.loop_closures >= 1
    n = len(THERE_AND_BACK)
    for a, b in closer.loops:  # only returns: a keyframe of the way out with one of the way back
        assert THERE_AND_BACK.index(59) > a and b > THERE_AND_BACK.index(59), closer.loops
    truth = np.linalg.inv(gt[0]) @ gt[0]
    before = np.linalg.norm(odom[-1][:3, 3] - truth[:3, 3])
    after = np.linalg.norm((closer.correction(n - 1) @ odom[-1])[:3, 3] - truth[:3, 3])
    assert before == pytest.approx(DRIFT_M_PER_KF * (n - 1))
    assert after < 0.25 * before, (before, after)


def test_a_path_that_goes_on_closes_no_loop(chess) -> None:
    frames, gt = chess
    closer = RgbdLoopCloser(K)
    _feed(closer, frames, gt, list(range(0, 60, 6)), DRIFT_M_PER_KF)
    assert closer.loop_closures == 0 and closer.loops == []
    np.testing.assert_array_equal(closer.correction(3), np.eye(4))


@pytest.mark.slow
def test_there_and_back_closes_a_loop_and_ends_nearer_its_start(chess) -> None:
    frames, _ = chess
    idx = [*range(60), *range(58, -1, -1)]  # out and back to the first frame
    end = {}
    for loops in (False, True):
        odo = DenseRgbdOdometry(K, DenseRgbdConfig(loop_closure=loops))
        est = [odo.step(obs(k, *frames[i])) for k, i in enumerate(idx)]
        assert all(e.status is TrackingStatus.TRACKING for e in est)
        T = odo.trajectory()[1]
        end[loops] = float(np.linalg.norm((np.linalg.inv(T[0]) @ T[-1])[:3, 3]))  # truth: 0
        assert (odo.loop_closures >= 1) if loops else (odo.loop_closures == 0)
    assert end[True] < 0.8 * end[False], end


@pytest.mark.slow
def test_cli_tracks_against_the_model_with_tracking_model(chess, data_dir, tmp_path,
                                                          capsys) -> None:
    import json
    import shutil

    from sea3d.cli import main as sea3d_main
    from sea3d.io.trajectory_files import read_trajectory

    frames, _ = chess
    src = data_dir / "rgbd/7scenes_chess"
    for i in range(4):
        for kind, ext in (("color", "jpg"), ("depth", "png")):
            name = f"frame-{i:06d}.{kind}.{ext}"
            shutil.copy(src / name, tmp_path / name)
    out = tmp_path / "t.tum"
    argv = ["odometry", "rgbd", "--color", str(tmp_path / "*.color.jpg"), "--depth",
            str(tmp_path / "*.depth.png"), "--intrinsics", "585", "585", "320", "240",
            "--tracking", "model", "-o", str(out), "--json"]
    assert sea3d_main(argv) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 4
    odo = DenseRgbdOdometry(K, DenseRgbdConfig(tracking="model", loop_closure=True))
    for i in range(4):
        odo.step(obs(i, *frames[i]))
    assert odo.model_frames == 3
    got = read_trajectory(out)
    np.testing.assert_allclose(got.T_world_x[:, :3, 3], odo.trajectory()[1][:, :3, 3], atol=1e-4)
