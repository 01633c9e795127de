"""Surface accuracy and completeness: known offsets, partial surfaces, point clouds, CLI."""

import json

import numpy as np
import open3d as o3d
import pytest

from sea3d.cli import main
from sea3d.errors import ReconError
from sea3d.eval.surface import surface_metrics
from sea3d.geometry.mesh import Mesh
from sea3d.io.mesh_files import read_mesh, write_mesh

# Distances are exact point-to-triangle distances, so a known offset comes back to float32
# rounding of the Open3D query (micrometres).
OFFSET_TOL_M = 1e-5


def _grid(n=20, size=1.0, z=0.0, x_max=None):
    x_max = size if x_max is None else x_max
    xs = np.linspace(0, x_max, n)
    ys = np.linspace(0, size, n)
    xx, yy = np.meshgrid(xs, ys)
    v = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)], axis=1)
    f = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            f += [[a, a + 1, a + n], [a + 1, a + n + 1, a + n]]
    return Mesh(vertices=v, triangles=np.asarray(f, np.int64))


def test_identical_surfaces_score_zero_and_full_fscore():
    m = _grid()
    s = surface_metrics(m.vertices, m.triangles, m.vertices, m.triangles, samples=5000)
    assert s.accuracy_m.max < OFFSET_TOL_M and s.completeness_m.max < OFFSET_TOL_M
    assert s.fscore == (1.0, 1.0, 1.0)
    assert s.reference_outside == 0.0


def test_a_lifted_surface_is_off_by_its_lift():
    ref, est = _grid(), _grid(z=0.015)
    s = surface_metrics(est.vertices, est.triangles, ref.vertices, ref.triangles, samples=5000)
    assert s.accuracy_m.median == pytest.approx(0.015, abs=OFFSET_TOL_M)
    assert s.completeness_m.median == pytest.approx(0.015, abs=OFFSET_TOL_M)
    # 15 mm: outside 10 mm, inside 20 mm.
    assert s.precision[0] == 0.0 and s.precision[1] == 1.0


def test_half_a_surface_is_accurate_but_incomplete():
    ref, est = _grid(), _grid(x_max=0.5)
    s = surface_metrics(est.vertices, est.triangles, ref.vertices, ref.triangles, samples=8000)
    assert s.accuracy_m.p90 < OFFSET_TOL_M
    # Half the reference is farther than 5 cm from the estimate; its median is on the edge.
    assert s.recall[2] == pytest.approx(0.55, abs=0.03)
    assert s.reference_outside == pytest.approx(0.5, abs=0.03)  # x > 0.5 of the reference
    cropped = surface_metrics(est.vertices, est.triangles, ref.vertices, ref.triangles,
                              samples=8000, crop_margin_m=0.0)
    assert cropped.recall[0] > 0.99


def test_point_clouds_are_accepted_on_either_side():
    ref = _grid(n=60)
    est_pts = ref.vertices + [0.0, 0.0, 0.004]
    s = surface_metrics(est_pts, None, ref.vertices, ref.triangles)
    assert s.accuracy_m.median == pytest.approx(0.004, abs=OFFSET_TOL_M)
    # Completeness to a cloud is a nearest-neighbour distance: at most half the spacing away.
    assert s.completeness_m.max < 0.004 + 1.0 / 59


def test_empty_input():
    with pytest.raises(ReconError):
        surface_metrics(np.zeros((0, 3)), None, _grid().vertices, _grid().triangles)


def test_cli_eval_surface_on_mesh_files(tmp_path, capsys):
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    ref = Mesh(vertices=np.asarray(box.vertices), triangles=np.asarray(box.triangles))
    write_mesh(tmp_path / "ref.ply", ref)
    write_mesh(tmp_path / "est.ply", ref.transformed(np.diag([1.0, 1.0, 1.0, 1.0]) + np.array(
        [[0, 0, 0, 0.0], [0, 0, 0, 0.0], [0, 0, 0, 0.008], [0, 0, 0, 0]])))
    assert read_mesh(tmp_path / "est.ply").triangles.shape == (12, 3)
    assert main(["eval", "surface", str(tmp_path / "est.ply"), str(tmp_path / "ref.ply"),
                 "--json", "--samples", "4000"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["accuracy_m"]["max"] <= 0.008 + OFFSET_TOL_M
    assert d["accuracy_m"]["median"] < 0.008
    assert main(["eval", "surface", str(tmp_path / "nope.ply"), str(tmp_path / "ref.ply")]) == 2
    assert "nope.ply does not exist" in capsys.readouterr().err


def test_cli_says_when_completeness_mostly_measures_unseen_reference(tmp_path, capsys):
    ref, est = _grid(), _grid(x_max=0.5)
    write_mesh(tmp_path / "ref.ply", ref)
    write_mesh(tmp_path / "est.ply", est)
    argv = ["eval", "surface", str(tmp_path / "est.ply"), str(tmp_path / "ref.ply"),
            "--samples", "4000", "--align", "none"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "of the reference surface lies outside the mesh's bounding box" in err
    assert "--crop-margin-m" in err
    assert main(argv + ["--crop-margin-m", "0"]) == 0
    assert "outside the mesh's bounding box" not in capsys.readouterr().err
    write_mesh(tmp_path / "same.ply", ref)
    assert main(["eval", "surface", str(tmp_path / "same.ply"), str(tmp_path / "ref.ply"),
                 "--samples", "4000", "--align", "none"]) == 0
    assert "outside the mesh's bounding box" not in capsys.readouterr().err
