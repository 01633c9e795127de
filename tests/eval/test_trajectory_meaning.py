"""``eval trajectory`` on files as real tools write them: repeated stamps, and paths too short,
too still or too straight for the rotation error or the RPE to mean anything (issue 21)."""

import json

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.eval.trajectory import evaluate_trajectory
from sea3d.geometry.se3 import rotvec_to_R
from sea3d.io.trajectory_files import read_trajectory, write_tum


def _still(rng, n=200, jitter_m=0.003):
    """A camera at rest (a drone on the ground) with a reference that jitters by millimetres."""
    t = np.arange(n, dtype=np.int64) * 50_000_000
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = rng.normal(0, jitter_m, (n, 3))
    return t, T


def test_still_path_warns_that_rotation_and_rpe_mean_nothing(rng):
    t, T_ref = _still(rng)
    T_est = np.tile(np.eye(4), (len(t), 1, 1))
    T_est[:, :3, 3] = rng.normal(0, 0.003, (len(t), 3))
    T_est[:, :3, :3] = rotvec_to_R(rng.normal(0, 0.002, (len(t), 3)))
    m = evaluate_trajectory(t, T_est, t, T_ref)
    assert not m.rotation_meaningful
    assert any("rotation error" in w and "means nothing" in w for w in m.warnings)
    assert m.rpe and any(w.startswith("RPE over") and "still point" in w for w in m.warnings)
    # With no alignment the rotation error is the estimate's own and stays meaningful
    assert evaluate_trajectory(t, T_est, t, T_ref, align="none").rotation_meaningful


def test_a_real_motion_gives_no_warning(data_dir):
    d = data_dir / "trajectories"
    est = read_trajectory(d / "freiburg1_xyz-rgbdslam.txt")
    gt = read_trajectory(d / "freiburg1_xyz-groundtruth.txt")
    m = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x, max_diff_s=0.02)
    assert m.warnings == [] and m.rotation_meaningful
    kitti = read_trajectory(d / "KITTI_00_ORB.txt"), read_trajectory(d / "KITTI_00_gt.txt")
    k = evaluate_trajectory(kitti[0].t_ns, kitti[0].T_world_x, kitti[1].t_ns,
                            kitti[1].T_world_x, by_index=True)
    assert k.warnings == []


def test_cli_still_path_marks_the_figures(tmp_path, rng, capsys):
    t, T = _still(rng)
    noisy = T.copy()
    noisy[:, :3, 3] += rng.normal(0, 0.003, (len(t), 3))
    write_tum(tmp_path / "gt.tum", t, T)
    write_tum(tmp_path / "est.tum", t, noisy)
    assert main(["eval", "trajectory", str(tmp_path / "est.tum"), str(tmp_path / "gt.tum")]) == 0
    cap = capsys.readouterr()
    assert "deg (meaningless: see the warning)" in cap.out
    assert "sea3d: warning:" in cap.err and "means nothing" in cap.err


def test_cli_repeated_stamps_are_counted_and_the_first_kept(tmp_path, rng, capsys):
    n = 60
    t = np.arange(n, dtype=np.int64) * 50_000_000
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = np.linspace(0, 3, n)
    T[:, 1, 3] = np.sin(np.linspace(0, 3, n))
    write_tum(tmp_path / "gt.tum", t, T)
    lines = (tmp_path / "gt.tum").read_text().splitlines()
    # an estimator that writes a stamp twice (re-initialisation): the second pose is far off
    est_lines = list(lines)
    for k in (10, 30, 31, 50):
        stamp = lines[k + 1].split()[0]
        est_lines.insert(len(est_lines), f"{stamp} 9 9 9 0 0 0 1")
    (tmp_path / "est.tum").write_text("\n".join(est_lines) + "\n")
    argv = ["eval", "trajectory", str(tmp_path / "est.tum"), str(tmp_path / "gt.tum"), "--json"]
    assert main(argv) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["duplicates_dropped"] == {"estimate": 4, "reference": 0}
    assert d["matched"] == n and d["ate_rmse_m"] == pytest.approx(0.0, abs=1e-8)
    assert "4 pose(s) with a repeated stamp dropped" in cap.err
