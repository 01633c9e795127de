"""``eval trajectory`` on files as real tools write them: repeated stamps, and paths too short,
too still or too straight for the rotation error or the RPE to mean anything."""

import json
from pathlib import Path

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


def _wavy_reference(tmp_path, n):
    """A 20 Hz reference along a wave, written to ``gt.tum``; returns the file's lines."""
    t = np.arange(n, dtype=np.int64) * 50_000_000
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = np.linspace(0, 3, n)
    T[:, 1, 3] = np.sin(np.linspace(0, 3, n))
    write_tum(tmp_path / "gt.tum", t, T)
    return (tmp_path / "gt.tum").read_text().splitlines()


def test_cli_repeated_stamps_are_counted_and_the_first_kept(tmp_path, rng, capsys):
    n = 60
    lines = _wavy_reference(tmp_path, n)
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
    # the estimate is the longer trajectory: evo pairs each reference pose with the first
    # estimated pose of its stamp, so the far-off repeats are never used
    assert d["duplicates_kept"] == {"estimate": 4, "reference": 0}
    assert d["matched"] == n and d["ate_rmse_m"] == pytest.approx(0.0, abs=1e-8)
    assert "4 pose(s) repeat an earlier stamp; kept" in cap.err


def test_cli_says_each_repair_once(tmp_path):
    """Run as a user runs it (its own process, its own log handler): the repeated stamps are
    reported in one line, not once by the reader's log and again by the command."""
    import os
    import subprocess
    import sys

    lines = _wavy_reference(tmp_path, 40)
    (tmp_path / "est.tum").write_text("\n".join(lines + [lines[5], lines[20]]) + "\n")
    src = str(Path(__file__).resolve().parents[2] / "src")
    env = {**os.environ, "PYTHONPATH": src + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run(
        [sys.executable, "-m", "sea3d", "eval", "trajectory", str(tmp_path / "est.tum"),
         str(tmp_path / "gt.tum")],
        capture_output=True, text=True, env=env, check=False,
    )
    assert out.returncode == 0, out.stderr
    assert out.stderr.count("repeat an earlier stamp") == 1, out.stderr
    assert "2 pose(s) repeat an earlier stamp; kept" in out.stderr


def _kabsch_ate(P, Q):
    """ATE RMSE after the least-squares rotation and translation of P onto Q, computed with
    scipy's Kabsch (independent of sea3d's Umeyama)."""
    from scipy.spatial.transform import Rotation

    pc, qc = P.mean(axis=0), Q.mean(axis=0)
    rot, _ = Rotation.align_vectors(Q - qc, P - pc)
    err = rot.apply(P - pc) + qc - Q
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def test_repeated_stamps_in_the_shorter_estimate_give_evos_figure(tmp_path, rng, capsys):
    """An estimate at 20 Hz against a 200 Hz reference with 4 stamps written twice (a VIO's
    re-initialisation): evo pairs every estimated pose, the repeats included, with the nearest
    reference pose; sea3d must give that figure, not the one with the repeats dropped."""
    n_ref = 2000
    t_ref = np.arange(n_ref, dtype=np.int64) * 5_000_000
    s = np.linspace(0, 2 * np.pi, n_ref)
    T_ref = np.tile(np.eye(4), (n_ref, 1, 1))
    T_ref[:, :3, 3] = np.stack([3 * np.cos(s), 2 * np.sin(s), 0.3 * np.sin(3 * s)], 1)
    T_ref[:, :3, :3] = rotvec_to_R(np.stack([0 * s, 0 * s, s], 1))
    idx = np.arange(0, n_ref, 10)
    rows = [(int(t_ref[i]), T_ref[i][:3, 3] + rng.normal(0, 0.05, 3)) for i in idx]
    for k in (150, 90, 41, 40):  # the same stamp again, with a pose 0.3 m off
        rows.insert(k + 1, (rows[k][0], rows[k][1] + [0.3, -0.2, 0.1]))
    t_est = np.array([r[0] for r in rows], np.int64)
    P = np.stack([r[1] for r in rows])
    T_est = np.tile(np.eye(4), (len(rows), 1, 1))
    T_est[:, :3, 3] = P
    write_tum(tmp_path / "est.tum", t_est, T_est)
    write_tum(tmp_path / "gt.tum", t_ref, T_ref)
    Q = T_ref[t_est // 5_000_000, :3, 3]  # each estimated stamp falls on a reference stamp
    want_all = _kabsch_ate(P, Q)
    first = np.concatenate([[True], np.diff(t_est) != 0])
    want_dropped = _kabsch_ate(P[first], Q[first])
    assert abs(want_all - want_dropped) > 1e-3  # the two rules give different figures
    argv = ["eval", "trajectory", str(tmp_path / "est.tum"), str(tmp_path / "gt.tum"), "--json"]
    assert main(argv) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["matched"] == len(rows) == 204
    assert d["duplicates_kept"] == {"estimate": 4, "reference": 0}
    assert d["ate_rmse_m"] == pytest.approx(want_all, rel=1e-9)
    # the library on files read with the first pose of each stamp gives the dropped figure
    est1 = read_trajectory(tmp_path / "est.tum")
    ref1 = read_trajectory(tmp_path / "gt.tum")
    m1 = evaluate_trajectory(est1.t_ns, est1.T_world_x, ref1.t_ns, ref1.T_world_x)
    assert est1.duplicates_dropped == 4
    assert m1.ate_rmse_m == pytest.approx(want_dropped, rel=1e-9)
