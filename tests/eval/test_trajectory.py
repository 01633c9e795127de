"""Trajectory metrics: evo's stored statistics as golden values, alignment and association."""

import json
import zipfile

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.errors import OdometryError
from sea3d.eval.trajectory import associate, evaluate_trajectory, umeyama
from sea3d.geometry.se3 import rotvec_to_R
from sea3d.io.trajectory_files import read_trajectory, write_tum

# evo stores its statistics as float64 JSON; ours are computed from the same poses with the
# same definitions, so they agree to float64 rounding accumulated over 4541 poses.
EVO_REL_TOL = 1e-9
# Umeyama on exact synthetic data recovers the transform to float64 rounding.
ALIGN_TOL = 1e-9


def _evo(data_dir, name):
    with zipfile.ZipFile(data_dir / "trajectories" / "res_files" / f"{name}.zip") as z:
        stats = json.loads(z.read("stats.json"))
        info = json.loads(z.read("info.json"))
        with z.open("error_array.npz") as fh:
            errors = np.load(fh)
            errors = np.asarray(errors)
    return stats, info, errors


@pytest.fixture(scope="module")
def kitti(data_dir):
    d = data_dir / "trajectories"
    return read_trajectory(d / "KITTI_00_ORB.txt"), read_trajectory(d / "KITTI_00_gt.txt")


def _check_stats(ours, evo):
    for key in ("rmse", "mean", "median", "std", "min", "max", "sse"):
        assert getattr(ours, key) == pytest.approx(evo[key], rel=EVO_REL_TOL), key


@pytest.mark.data
def test_ate_equals_evo_ape_with_se3_alignment_on_kitti_00(data_dir, kitti):
    stats, info, errors = _evo(data_dir, "orb_ape")
    assert "SE(3) Umeyama" in info["title"]
    est, gt = kitti
    m = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x, by_index=True,
                            align="se3", rpe_deltas_m=[])
    assert m.ate_m.count == len(errors) == 4541
    _check_stats(m.ate_m, stats)
    assert m.as_dict()["ate_rmse_m"] == pytest.approx(stats["rmse"], rel=EVO_REL_TOL)


@pytest.mark.data
def test_rpe_per_10_m_equals_evo_element_by_element(data_dir, kitti):
    stats, info, errors = _evo(data_dir, "orb_rpe")
    assert "delta = 10.0 (m)" in info["title"] and "not aligned" in info["title"]
    est, gt = kitti
    m = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x, by_index=True,
                            align="none", rpe_deltas_m=[10.0])
    r = m.rpe[0]
    _check_stats(r.translation_m, stats)
    assert r.translation_m.count == len(errors) == 353
    # Pairs chosen along the reference's path give other pairs (356): the option is real.
    other = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x,
                                by_index=True, align="none", rpe_deltas_m=[10.0],
                                rpe_along="reference")
    assert other.rpe[0].translation_m.count != 353


@pytest.mark.data
def test_rpe_is_unchanged_by_a_rigid_alignment(data_dir, kitti):
    est, gt = kitti
    a = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x, by_index=True,
                            align="none", rpe_deltas_m=[100.0])
    b = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x, by_index=True,
                            align="se3", rpe_deltas_m=[100.0])
    assert a.rpe[0].translation_m.rmse == pytest.approx(b.rpe[0].translation_m.rmse, rel=1e-9)
    assert a.ate_m.rmse > 5 * b.ate_m.rmse  # but the ATE is not (7.8 m against 1.3 m)


@pytest.mark.data
def test_tum_fr1_xyz_pairs_by_time(data_dir):
    d = data_dir / "trajectories"
    est = read_trajectory(d / "freiburg1_xyz-rgbdslam.txt")
    gt = read_trajectory(d / "freiburg1_xyz-groundtruth.txt")
    m = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x, max_diff_s=0.02)
    # 788 estimated poses, the 2 outside the ground truth's span find no partner.
    assert m.matched == 786
    # RGB-D SLAM on fr1/xyz: about 1.4 cm ATE RMSE (Endres et al. 2014 report 0.014 m).
    assert 0.010 < m.ate_rmse_m < 0.018
    tight = evaluate_trajectory(est.t_ns, est.T_world_x, gt.t_ns, gt.T_world_x,
                                max_diff_s=0.0001)
    assert tight.matched < m.matched


def _random_traj(rng, n=60):
    t = np.arange(n, dtype=np.int64) * 50_000_000
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    T[:, :3, :3] = rotvec_to_R(rng.normal(0, 0.3, (n, 3)))
    return t, T


def test_sim3_alignment_recovers_a_scaled_rotated_copy(rng):
    t, T = _random_traj(rng)
    S_R = rotvec_to_R(np.array([0.3, -0.2, 1.1]))
    s, shift = 2.5, np.array([1.0, -2.0, 0.5])
    est = T.copy()
    est[:, :3, :3] = S_R.T @ T[:, :3, :3]
    est[:, :3, 3] = ((T[:, :3, 3] - shift) @ S_R) / s  # so that gt = s R est + shift
    m = evaluate_trajectory(t, est, t, T, align="sim3")
    assert m.scale == pytest.approx(s, rel=ALIGN_TOL)
    assert m.ate_m.max < 1e-9 and m.ate_rotation_deg.max < 1e-6
    se3 = evaluate_trajectory(t, est, t, T, align="se3")
    assert se3.ate_m.rmse > 0.01  # a wrong scale cannot be aligned away rigidly
    none = evaluate_trajectory(t, est, t, T, align="none")
    assert none.ate_m.rmse > se3.ate_m.rmse


def test_umeyama_returns_a_proper_rotation_for_reflected_data(rng):
    x = rng.normal(size=(20, 3))
    y = x * np.array([1.0, 1.0, -1.0])  # a mirror image: the best rotation has det +1
    R, _, _ = umeyama(x, y, with_scale=False)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_association_pairs_the_shorter_trajectory_as_evo_does():
    est = np.array([0, 100, 105, 300, 1000], np.int64)
    ref = np.array([1, 102, 290, 2000], np.int64)
    i, j = associate(est, ref, max_diff_ns=10)
    # the reference is shorter: each of its stamps takes its nearest estimated one (102 -> 100,
    # 2 ns off); 2000 finds nothing within 10 ns.
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == [(0, 0), (1, 1), (3, 2)]
    # the estimate shorter: both 100 and 105 take 102; a repeated stamp is paired twice
    i, j = associate(np.array([100, 105, 105]), np.array([1, 102, 290, 2000]), max_diff_ns=10)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == [(0, 1), (1, 1), (2, 1)]
    # a repeated stamp of the longer one: the first of the run; a tie: the earlier stamp
    i, j = associate(np.array([10, 55]), np.array([0, 10, 10, 50, 60, 70]), max_diff_ns=10)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == [(0, 1), (1, 3)]


def test_too_few_matches_is_a_clear_error(rng):
    t, T = _random_traj(rng, 10)
    with pytest.raises(OdometryError, match="have a reference pose within"):
        evaluate_trajectory(t, T, t + 10**9, T)


def test_cli_eval_trajectory_json(tmp_path, rng, capsys):
    t, T = _random_traj(rng)
    noisy = T.copy()
    noisy[:, :3, 3] += rng.normal(0, 0.01, (len(T), 3))
    write_tum(tmp_path / "gt.tum", t, T)
    write_tum(tmp_path / "est.tum", t, noisy)
    assert main(["eval", "trajectory", str(tmp_path / "est.tum"), str(tmp_path / "gt.tum"),
                 "--json", "--rpe-delta-m", "0.5"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["paired_by"] == "time" and d["matched"] == len(t)
    assert 0.005 < d["ate_rmse_m"] < 0.02
    assert d["rpe"][0]["delta_m"] == 0.5


def test_cli_eval_trajectory_bad_file_is_one_line(tmp_path, capsys):
    (tmp_path / "bad.tum").write_text("0 1 2 3 0 0 0 1\n1 2 3\n")
    assert main(["eval", "trajectory", str(tmp_path / "bad.tum"), str(tmp_path / "bad.tum")]) == 2
    err = capsys.readouterr().err
    assert "bad.tum:2" in err and err.count("\n") == 1
