"""Aligning a mesh to its reference: from two trajectories (Umeyama) or ICP, residual stated."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sea3d.cli import main
from sea3d.errors import ReconError
from sea3d.eval.surface import align_by_icp, align_by_trajectories, surface_metrics
from sea3d.io.mesh_files import write_mesh
from sea3d.io.trajectory_files import write_tum
from sea3d.recon.types import Mesh


def _terrain(n=40, size=4.0):
    """A bumpy 4 m x 4 m seabed (no symmetry for ICP to slide along)."""
    xs = np.linspace(0, size, n)
    xx, yy = np.meshgrid(xs, xs)
    zz = 0.3 * np.sin(1.3 * xx) * np.cos(0.9 * yy) + 0.1 * xx
    v = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
    f = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            f += [[a, a + 1, a + n], [a + 1, a + n + 1, a + n]]
    return Mesh(vertices=v, triangles=np.asarray(f, np.int64))


def _straight_leg(n=30):
    """Cameras along one straight line 2 m above the seabed, looking down (a lawnmower leg)."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    T[:, 0, 3] = np.linspace(0.5, 3.5, n)
    T[:, 1, 3] = 2.0
    T[:, 2, 3] = 2.0
    t = np.arange(n, dtype=np.int64) * 100_000_000
    return t, T


def _se3(rx, ry, rz, t):
    S = np.eye(4)
    S[:3, :3] = Rotation.from_euler("xyz", [rx, ry, rz], degrees=True).as_matrix()
    S[:3, 3] = t
    return S


# The estimate's world is the reference's moved by a known rigid transform (the first camera).
T_REF_EST = _se3(170.0, 20.0, -35.0, [1.2, -0.4, 2.0])


def test_trajectories_recover_the_transform_even_on_a_straight_leg():
    t, T_ref = _straight_leg()
    T_est = np.linalg.inv(T_REF_EST)[None] @ T_ref
    a = align_by_trajectories(t, T_est, t, T_ref)
    assert a.method == "trajectory-se3" and a.pairs == len(t)
    np.testing.assert_allclose(a.T_ref_est, T_REF_EST, atol=1e-9)
    assert a.residual_m < 1e-9


def test_sim3_recovers_scale_and_the_residual_is_the_position_noise():
    rng = np.random.default_rng(0)
    t, T_ref = _straight_leg()
    T_est = np.linalg.inv(T_REF_EST)[None] @ T_ref
    T_est[:, :3, 3] *= 0.5  # an unscaled (monocular) estimate at half size
    noise = rng.normal(0.0, 0.01, (len(t), 3))
    T_est[:, :3, 3] += noise
    a = align_by_trajectories(t, T_est, t, T_ref, with_scale=True)
    assert a.scale == pytest.approx(2.0, rel=0.02)
    # Residual: 1 cm per axis of noise at half scale is 2 cm per axis after scaling, so about
    # 2 * sqrt(3) cm RMS in 3-D (less what the fit absorbs).
    assert 0.02 < a.residual_m < 0.04


def test_too_few_pairs_is_an_error():
    t, T = _straight_leg(5)
    with pytest.raises(ReconError, match="pair up"):
        align_by_trajectories(t, T, t + 10**9, T)


def test_icp_refines_a_close_start_and_states_its_residual():
    ref = _terrain()
    small = _se3(1.0, -1.5, 2.0, [0.03, -0.02, 0.04])
    est = ref.transformed(np.linalg.inv(small))
    off = surface_metrics(est.vertices, est.triangles, ref.vertices, ref.triangles,
                          samples=20_000)
    assert off.accuracy_m.median > 0.02
    a = align_by_icp(est.vertices, est.triangles, ref.vertices, ref.triangles,
                     max_distance_m=0.2, samples=20_000)
    assert a.method == "icp" and a.fitness > 0.95
    on = surface_metrics(a.apply(est.vertices), est.triangles, ref.vertices, ref.triangles,
                         samples=20_000)
    # Sampling density (about 3 mm between samples on this seabed) bounds what ICP resolves.
    assert on.accuracy_m.median < 0.003
    assert a.residual_m < 0.005


def _write_case(tmp_path):
    ref = _terrain()
    t, T_ref = _straight_leg()
    est = ref.transformed(np.linalg.inv(T_REF_EST))
    write_mesh(tmp_path / "ref.ply", ref)
    write_mesh(tmp_path / "est.ply", est)
    write_tum(tmp_path / "est.tum", t, np.linalg.inv(T_REF_EST)[None] @ T_ref)
    write_tum(tmp_path / "gt.tum", t, T_ref)
    return tmp_path / "est.ply", tmp_path / "ref.ply"


def test_cli_without_alignment_warns_and_with_trajectories_is_right(tmp_path, capsys, caplog):
    est, ref = _write_case(tmp_path)
    assert main(["eval", "surface", str(est), str(ref), "--samples", "5000", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["alignment"]["method"] == "none"
    assert d["accuracy_m"]["median"] > 0.5
    assert "nothing aligns" in caplog.text
    assert main(["eval", "surface", str(est), str(ref), "--samples", "5000", "--json",
                 "--trajectories", str(tmp_path / "est.tum"), str(tmp_path / "gt.tum")]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["alignment"]["method"] == "trajectory-se3"
    assert d["accuracy_m"]["median"] < 1e-4
    assert d["alignment"]["residual_m"] < 1e-6


def test_cli_finds_the_trajectories_of_a_process_folder(tmp_path, capsys):
    """The README's chain: ``process -o out`` then ``eval surface out/mesh.ply scene.ply``."""
    est, ref = _write_case(tmp_path)
    out = tmp_path / "out"
    gt = tmp_path / "dive_gt"
    out.mkdir()
    gt.mkdir()
    est.rename(out / "mesh.ply")
    (tmp_path / "est.tum").rename(out / "trajectory.tum")
    (tmp_path / "gt.tum").rename(gt / "poses_left.tum")
    (out / "summary.json").write_text(json.dumps({"ground_truth": str(gt)}))
    assert main(["eval", "surface", str(out / "mesh.ply"), str(ref), "--samples", "5000"]) == 0
    text = capsys.readouterr().out
    assert "aligned trajectory-se3 from" in text and "residual" in text
    median_mm = float(text.split("accuracy (estimate to reference): median ")[1].split()[0])
    assert median_mm < 0.1


def test_cli_pairs_in_frame_order_when_the_stamps_do_not_meet(tmp_path, capsys):
    """7-Scenes: RGB-D odometry stamps frames by index, the reference by camera clock; the same
    count pairs in frame order (as 'sea3d fuse' does)."""
    est, ref = _write_case(tmp_path)
    t, T_ref = _straight_leg()
    write_tum(tmp_path / "est.tum", np.arange(len(t)) * 1_000_000_000,
              np.linalg.inv(T_REF_EST)[None] @ T_ref)
    assert main(["eval", "surface", str(est), str(ref), "--samples", "5000", "--json",
                 "--trajectories", str(tmp_path / "est.tum"), str(tmp_path / "gt.tum")]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["alignment"]["pairs"] == len(t) and d["accuracy_m"]["median"] < 1e-4
