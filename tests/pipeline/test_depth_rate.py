"""Depth at the rate the scene needs (``--depth-rate``): fewer depth frames, a pose for every
frame, seeds moved to where the frame looks, and a mesh within the process tests' budget."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from sea3d.errors import ConfigError
from sea3d.pipeline.depth_rate import DepthRate, DepthRateConfig, parse_depth_rate, warp_depth
from sea3d.pipeline.process import (
    ExecutorConfig,
    MapConfig,
    PoseConfig,
    ProcessConfig,
    run_process,
)

# The budget of tests/pipeline/test_process.py (true poses, 320x180, 2 cm voxels).
MESH_MEDIAN_TOL_M = 0.008
MESH_P90_TOL_M = 0.025
K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 90.0], [0.0, 0.0, 1.0]])


def _translation(x_m: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x_m
    return T


def test_parse_depth_rate():
    assert parse_depth_rate("auto") == "auto" and parse_depth_rate("all") == "all"
    assert parse_depth_rate("3") == 3 and parse_depth_rate(4) == 4
    for bad in ("0", "-2", "fast", "1.5"):
        with pytest.raises(ConfigError, match="depth_rate"):
            parse_depth_rate(bad)
    with pytest.raises(ConfigError, match="depth_rate"):
        ProcessConfig(out_dir="x", depth_rate="sometimes")


def test_auto_rate_follows_the_predicted_flow():
    """Constant lateral motion of 1.2 cm a frame at 1.5 m (2.4 px of flow with f = 300 px):
    depth on the first two frames (no velocity yet), then whenever the flow since the last
    depth frame would pass width / min_views (320 / 4 = 80 px: 33 frames without depth, then
    one with), or after max_stride frames; every frame again once the odometry loses track."""
    rate = DepthRate("auto", K=K, width_px=320, config=DepthRateConfig(max_stride=100),
                     trusted=("ok",))
    depth = np.full((180, 320), 1.5, np.float32)
    got = []
    for i in range(100):
        own = rate.wants_depth(i)
        got.append(own)
        if own:
            rate.observe_depth(depth)
        rate.observe(i, "ok" if i < 90 else "lost", _translation(0.012 * i), own_depth=own)
    taken = np.flatnonzero(got)
    assert taken[:2].tolist() == [0, 1]  # no velocity yet
    strides = np.diff(taken[(taken >= 1) & (taken < 90)])
    assert strides.tolist() == [34, 34]
    assert all(got[91:])  # lost: no motion to predict from
    capped = DepthRate("auto", K=K, width_px=320, trusted=("ok",))
    taken = []
    for i in range(40):
        own = capped.wants_depth(i)
        if own:
            taken.append(i)
            capped.observe_depth(depth)
        capped.observe(i, "ok", _translation(0.012 * i), own_depth=own)
    assert taken == [0, 1, 9, 17, 25, 33]  # max_stride 8 bounds it
    fixed = DepthRate(3, K=K, width_px=320)
    assert [fixed.wants_depth(i) for i in range(7)] == [True, False, False, True, False,
                                                        False, True]


def test_warped_seed_matches_the_depth_seen_from_the_new_pose():
    """A tilted plane seen from a pose 3 cm to the side: the warped map is the plane's depth
    in the new camera (to the splat's rounding), where the unwarped one is off."""
    h, w = 180, 320
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    # plane n . X = 1.5 with n tilted 20 degrees about the camera's y axis
    n = np.array([np.sin(0.35), 0.0, np.cos(0.35)])

    def plane_depth(T_cam_world: np.ndarray) -> np.ndarray:
        R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
        rays_w = rays @ R  # R^T applied to each ray
        c = -R.T @ t
        s = (1.5 - c @ n) / (rays_w @ n)
        return s.astype(np.float32)  # z of a ray with z component 1

    T0 = np.eye(4)
    T1 = _translation(-0.03)  # world -> camera 1: the camera moved 3 cm along +x
    d0, d1 = plane_depth(T0), plane_depth(T1)
    warped = warp_depth(d0, K, T1 @ np.linalg.inv(T0))
    ok = np.isfinite(warped)
    assert ok.mean() > 0.9
    err = np.abs(warped[ok] - d1[ok])
    assert np.percentile(err, 90) < 0.01 * 1.5 and np.abs(d0 - d1).mean() > 4 * err.mean()


def _warp_reference(depth_m: np.ndarray, K: np.ndarray, T_cur_src: np.ndarray) -> np.ndarray:
    """warp_depth written as whole-array numpy (its form before the numba pass)."""
    h, w = depth_m.shape
    v, u = np.nonzero(np.isfinite(depth_m) & (depth_m > 0))
    z = depth_m[v, u].astype(np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    p = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z])
    q = T_cur_src[:3, :3] @ p + T_cur_src[:3, 3:4]
    out = np.full((h, w), np.inf, np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        uq = np.rint(fx * q[0] / q[2] + cx)
        vq = np.rint(fy * q[1] / q[2] + cy)
    ok = (q[2] > 1e-6) & (uq >= 0) & (uq < w) & (vq >= 0) & (vq < h)
    flat = vq[ok].astype(np.int64) * w + uq[ok].astype(np.int64)
    np.minimum.at(out.reshape(-1), flat, q[2][ok].astype(np.float32))
    out[~np.isfinite(out)] = np.nan
    return out


def test_warp_depth_equals_the_whole_array_form_with_occlusions_and_holes():
    """The one-pass kernel gives the whole-array form's map exactly: a box in front of a
    wall (pixels that collide, the nearest kept), invalid pixels, points that leave the
    image or fall behind the camera, under a turn and a move."""
    rng = np.random.default_rng(0)
    h, w = 180, 320
    depth = np.full((h, w), 2.5, np.float32) + rng.normal(0, 0.01, (h, w)).astype(np.float32)
    depth[60:120, 100:180] = 0.8
    depth[rng.random((h, w)) < 0.05] = np.nan
    depth[:5, :] = 0.0
    c, s = np.cos(0.08), np.sin(0.08)
    for t in ([0.06, -0.02, 0.01], [0.0, 0.0, -3.0], [0.3, 0.1, 0.05]):
        T = np.eye(4)
        T[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
        T[:3, 3] = t
        got, want = warp_depth(depth, K, T), _warp_reference(depth, K, T)
        assert np.array_equal(got, want, equal_nan=True)
        assert got.dtype == np.float32 and got.shape == (h, w)
    assert np.isfinite(warp_depth(depth, K, np.eye(4))).mean() > 0.9


FRAMES = 20


@pytest.fixture(scope="module")
def auto_run(sim_session, tmp_path_factory):
    """The session's first 20 frames with sea3d's stereo-inertial odometry and
    ``--depth-rate auto``."""
    out = tmp_path_factory.mktemp("depth_rate") / "auto"
    res = run_process(sim_session, ProcessConfig(
        out_dir=out, executor=ExecutorConfig(workers=0), depth_rate="auto",
        map=MapConfig(keyframes_per_submap=2), max_frames=FRAMES))
    return out, res


def test_auto_depth_rate_computes_fewer_depth_maps_and_tracks_every_frame(auto_run):
    """Fewer depth maps; every frame still gets a pose, tracked (its seeds warped from the
    last depth frame), and the frames without depth are not fused. (The mesh's budget is
    checked with true poses below: with the odometry's poses the mesh of this short dive is
    already at it with depth on every frame, 8.6 mm median in docs/evaluation.md.)"""
    out, res = auto_run
    s = res.summary
    assert s["depth_rate"] == "auto" and s["frames"] == FRAMES
    assert s["frames_with_depth"] <= FRAMES // 2
    assert s["frames_fused"] == s["frames_with_depth"]
    assert len(res.t_ns) == FRAMES and s["frames_lost"] == 0 and s["frames_imu_only"] == 0
    with open(out / "status.csv") as fh:
        rows = list(csv.DictReader(fh))
    seeded = [r for r in rows if r["depth"] == "seeded"]
    assert len(seeded) == FRAMES - s["frames_with_depth"]
    assert all(r["fusion"] == "no-depth" for r in seeded)
    assert all(r["status"] == "tracking" for r in rows[2:])
    assert s["trajectory_vs_gt"]["ate_m"]["rmse"] < 0.01


def test_auto_depth_rate_keeps_the_mesh_within_the_process_budget(sim_session, tmp_path):
    """With the true poses, the mesh of the depth frames alone stays within the budget of
    tests/pipeline/test_process.py."""
    res = run_process(sim_session, ProcessConfig(
        out_dir=tmp_path / "auto_gt", executor=ExecutorConfig(workers=0), depth_rate="auto",
        map=MapConfig(keyframes_per_submap=2), max_frames=FRAMES,
        poses=PoseConfig(
            poses_path=sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum")))
    s = res.summary
    assert s["frames_with_depth"] <= FRAMES // 2 and s["frames_fused"] == s["frames_with_depth"]
    acc = s["mesh_vs_gt"]["accuracy_m"]
    assert acc["median"] < MESH_MEDIAN_TOL_M and acc["p90"] < MESH_P90_TOL_M
