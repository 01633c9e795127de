"""``sea3d sfm`` end to end on a simulated session, against the simulator's ground truth.

Expected values: the ground-truth poses ``gt/poses_left.tum`` of the simulator. At 320x180 the
stereo disparities are a few pixels, so the metric scale is only good to about 1.5 % here
(measured 1.3-1.5 %, at 640x360 0.05 %: ``benchmarks/bench_sfm.py``); the tolerances below
leave room for the machine's thread timing changing COLMAP's choices, not for a wrong model
(a rig with its extrinsics refined, or ignored, is off by far more).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.eval.trajectory import umeyama
from sea3d.geometry.se3 import R_to_quat_wxyz
from sea3d.io.trajectory_files import read_trajectory
from sea3d.refraction.presets import PAPER_BASELINE_M

STEREO_SCALE_REL = 0.03  # metric scale of --camera stereo at 320x180 (measured 1.5 %)
STEREO_ATE_M = 0.01  # SE(3)-aligned (no scale) ATE of the stereo model (measured 2.5 mm)
PRIOR_POSITION_M = 0.01  # pose priors from ground truth: positions with no alignment (2 mm)
SELFCAL_ATE_M = 0.02  # Sim(3)-aligned ATE of a self-calibrated monocular model (5 mm)
BASELINE_M = 1e-9  # the rig's baseline in rigs.bin, held fixed


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    tr = read_trajectory(path, "tum")
    return tr.t_ns.astype(np.float64) * 1e-9, tr.T_world_x


def ate_rmse(est: np.ndarray, gt: np.ndarray, with_scale: bool) -> tuple[float, float]:
    R, t, s = umeyama(est, gt, with_scale=with_scale)
    err = s * est @ R.T + t - gt
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1)))), s


def _gt_positions(session: Path, t_s: np.ndarray) -> np.ndarray:
    t_gt, T_gt = read_tum(session / "gt" / "poses_left.tum")
    idx = np.array([int(np.argmin(np.abs(t_gt - t))) for t in t_s])
    assert np.all(np.abs(t_gt[idx] - t_s) < 1e-6)
    return T_gt[idx][:, :3, 3]


def test_stereo_session_gives_a_metric_model_and_all_files(
    orbit_session: Callable[..., Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import pycolmap

    session = orbit_session()
    out = tmp_path / "out"
    assert main(["sfm", str(session), "--camera", "stereo", "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary == json.loads((out / "summary.json").read_text())
    for key in ("images", "registered", "points3d", "mean_reprojection_error_px", "metric",
                "timings_s"):
        assert key in summary
    assert summary["metric"] is True and summary["images"] == 20
    assert summary["registered"] == 20 and summary["mean_reprojection_error_px"] < 1.0
    for name in ("cameras", "images", "points3D", "rigs", "frames"):
        assert (out / "sparse" / f"{name}.bin").is_file()
        assert (out / "sparse" / f"{name}.txt").is_file()
    assert (out / "points.ply").read_bytes().startswith(b"ply")
    # The dome cameras went in as virtual pinholes with a tiny residual over the range.
    assert summary["virtual_pinhole"]["left"]["max_px"] < 0.01
    t, T = read_tum(out / "trajectory.tum")
    np.testing.assert_allclose(t, np.arange(10) * 0.1, atol=1e-9)  # the session's seconds
    gt = _gt_positions(session, t)
    _, scale = ate_rmse(T[:, :3, 3], gt, with_scale=True)
    assert abs(scale - 1.0) < STEREO_SCALE_REL
    ate_se3, _ = ate_rmse(T[:, :3, 3], gt, with_scale=False)
    assert ate_se3 < STEREO_ATE_M
    # The calibrated extrinsics were held fixed: COLMAP's rig still has the baseline.
    rec = pycolmap.Reconstruction(str(out / "sparse"))
    assert rec.num_points3D() == summary["points3d"]
    rig = rec.rigs[1]
    ((_, right_from_left),) = rig.non_ref_sensors.items()
    assert right_from_left is not None
    c = right_from_left.inverse().translation  # right virtual camera in the left virtual frame
    assert abs(float(np.linalg.norm(c)) - PAPER_BASELINE_M) < BASELINE_M


def test_monocular_with_pose_priors_lands_in_the_priors_world(
    orbit_session: Callable[..., Path], tmp_path: Path
) -> None:
    session = orbit_session()
    # the priors as a EuRoC CSV (stamps in ns, quaternion w first): any trajectory file works
    tr = read_trajectory(session / "gt" / "poses_left.tum")
    euroc = tmp_path / "priors.csv"
    rows = ["#timestamp [ns],p_x,p_y,p_z,q_w,q_x,q_y,q_z"]
    for t_ns, T in zip(tr.t_ns, tr.T_world_x, strict=True):
        q = R_to_quat_wxyz(T[:3, :3])
        rows.append(",".join([str(int(t_ns))] + [f"{v:.9f}" for v in (*T[:3, 3], *q)]))
    euroc.write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    assert main(["-q", "sfm", str(session), "-o", str(out), "--pose-priors",
                 str(euroc)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["metric"] is True and summary["metric_source"] == "pose_priors"
    t, T = read_tum(out / "trajectory.tum")
    err = np.linalg.norm(T[:, :3, 3] - _gt_positions(session, t), axis=1)
    assert len(t) == 10 and float(err.max()) < PRIOR_POSITION_M


def test_image_glob_is_self_calibrated_and_indexed(
    orbit_session: Callable[..., Path], tmp_path: Path
) -> None:
    # A clip that turns enough for the focal length to be observable: the orbit at 4 Hz, 2.5 s
    # of it (see conftest).
    session = orbit_session(fps=4.0)
    out = tmp_path / "out"
    pattern = str(session / "left" / "*.png")
    assert main(["-q", "sfm", pattern, "-o", str(out), "--matcher", "exhaustive"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["metric"] is False and summary["intrinsics"] == "self-calibrated"
    assert summary["registered"] == 10
    t, T = read_tum(out / "trajectory.tum")
    np.testing.assert_array_equal(t, np.arange(10.0))  # 0-based index in sorted order
    t_gt, _ = read_tum(session / "gt" / "poses_left.tum")
    gt = _gt_positions(session, t_gt[t.astype(int)])  # frame index -> its stamp
    ate, _ = ate_rmse(T[:, :3, 3], gt, with_scale=True)
    assert ate < SELFCAL_ATE_M
    # the self-calibrated focal length is near the dome camera's virtual pinhole: a least-squares
    # pinhole fit to the dome camera's projection gives fx = 177.0-177.1 px at 0.5-5 m
    f = summary["cameras"]["left"]["params"][0]
    assert 0.9 * 177.3 < f < 1.1 * 177.3


def test_imu_scale_is_reported_and_applied_only_when_trustworthy(
    orbit_session: Callable[..., Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = orbit_session()
    # One second of a slow orbit: far too little acceleration for the IMU to fix the scale;
    # the run must say so and leave the model up to scale.
    out = tmp_path / "out"
    assert main(["-q", "sfm", str(session), "-o", str(out), "--imu-scale",
                 "--imu-extrinsics", str(session / "gt" / "sim.json")]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["imu_scale"]["status"] in ("weak", "failed")
    assert summary["imu_scale"]["applied"] is False and summary["metric"] is False
    assert main(["sfm", str(session), "-o", str(out), "--imu-scale"]) == 2
    assert "--imu-extrinsics" in capsys.readouterr().err
