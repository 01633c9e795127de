"""rig.yaml round trips, OpenCV/MATLAB imports, exports, and clear errors for bad files."""

import copy

import cv2
import numpy as np
import pytest
import yaml

from sea3d.errors import RigFileError
from sea3d.geometry.rig import StereoRig
from sea3d.io.rig_file import (
    load_rig,
    rig_from_dict,
    rig_to_colmap,
    rig_to_dict,
    rig_to_yaml,
    save_rig,
)
from sea3d.refraction import DomePortCamera, FlatPortCamera
from sea3d.refraction.presets import paper_rig


@pytest.mark.parametrize("port", ["dome", "flat", "none"])
def test_yaml_round_trip_is_exact(port, tmp_path, rng):
    rig = paper_rig(port)
    path = save_rig(rig, tmp_path / "rig.yaml")
    back = load_rig(path)
    assert rig_to_dict(back) == rig_to_dict(rig)
    pts = np.c_[rng.uniform(-1, 1, (50, 2)), rng.uniform(0.5, 5, 50)]
    np.testing.assert_array_equal(back.left.project(pts)[0], rig.left.project(pts)[0])


def test_json_round_trip(tmp_path):
    rig = paper_rig("flat")
    back = load_rig(save_rig(rig, tmp_path / "rig.json"))
    assert rig_to_dict(back) == rig_to_dict(rig)


def test_paper_preset_has_the_papers_figures():
    rig = paper_rig("dome")
    assert (rig.width, rig.height) == (1920, 1080)
    assert rig.baseline_m == pytest.approx(0.107)
    assert isinstance(rig.left, DomePortCamera)
    port = rig.left.port
    np.testing.assert_allclose(port.center_m, [-0.54e-3, 0.58e-3, 2.10e-3])
    assert port.inner_radius_m == pytest.approx(0.03125)
    assert port.thickness_m == pytest.approx(0.0031)
    assert (port.n_air, port.n_glass, port.n_water) == (1.000292, 1.492, 1.333)
    assert rig.left.pinhole.fx == pytest.approx(1082.4)


@pytest.mark.data
def test_imports_matlab_export_in_millimetres(data_dir):
    path = data_dir / "calib/sea3d_yaml/in_air_stereo.yml"
    rig = load_rig(path, image_size=(1920, 1080))
    # T = [-107.166011, 0.054609, 1.497043] mm maps left into right: the baseline is ~107.18 mm.
    assert rig.baseline_m == pytest.approx(
        np.linalg.norm([-107.166011, 0.054609, 1.497043]) * 1e-3, rel=1e-4
    )
    assert rig.left.fx == pytest.approx(1157.6193)
    np.testing.assert_allclose(rig.left.dist, [0.043977, -0.008485, 0.0, 0.0, 0.0])
    # The right camera sits at +x in the left frame.
    assert rig.T_left_right[0, 3] == pytest.approx(0.10716, abs=1e-4)


@pytest.mark.data
def test_imports_in_water_file_with_extreme_rational_distortion(data_dir):
    rig = load_rig(data_dir / "calib/sea3d_yaml/in_water_field_test.yml", image_size=(1920, 1080))
    assert rig.left.dist.size == 8
    assert rig.right.dist[4] == pytest.approx(17971.6)
    # The model survives: the image centre still unprojects and projects back.
    uv = np.array([[960.0, 540.0], [700.0, 400.0]])
    rays = rig.left.unproject(uv)
    assert rays.valid.all()
    back, ok = rig.left.project(rays.directions)
    assert ok.all()
    np.testing.assert_allclose(back, uv, atol=1e-6)


@pytest.mark.data
def test_opencv_stereo_calib_intrinsics_need_extrinsics(data_dir, tmp_path):
    intr = data_dir / "calib/opencv_9x6/opencv_reference_intrinsics.yml"
    with pytest.raises(RigFileError, match="extrinsics"):
        load_rig(intr)
    ext = tmp_path / "extrinsics.yml"
    fs = cv2.FileStorage(str(ext), cv2.FILE_STORAGE_WRITE)
    fs.write("R", np.eye(3))
    fs.write("T", np.array([[-3.33], [0.0], [0.0]]))
    fs.release()
    rig = load_rig(intr, extrinsics=ext, translation_scale=0.025)
    assert (rig.width, rig.height) == (640, 480)
    assert rig.baseline_m == pytest.approx(3.33 * 0.025)
    assert rig.left.fx == pytest.approx(534.80326845051309)


def test_opencv_export_then_import(tmp_path):
    rig = paper_rig("none")
    path = save_rig(rig, tmp_path / "cv.yml", format="opencv")
    back = load_rig(path)
    np.testing.assert_allclose(back.T_left_right, rig.T_left_right, atol=1e-12)
    np.testing.assert_allclose(back.left.K, rig.left.K)
    assert (back.width, back.height) == (1920, 1080)


def test_colmap_export_lines():
    text = rig_to_colmap(paper_rig("dome"))
    lines = [ln for ln in text.splitlines() if not ln.startswith("#")]
    assert lines[0].startswith("1 OPENCV 1920 1080 1082.4 1074.4 949.5 535.7")
    fields = lines[1].split()
    assert fields[:2] == ["1", "DOMEPORT"]
    np.testing.assert_allclose(
        [float(f) for f in fields[2:]],
        [-0.00054, 0.00058, 0.0021, 0.03125, 0.0031, 1.000292, 1.492, 1.333],
    )
    flat = rig_to_colmap(paper_rig("flat"))
    assert "1 FLATPORT 0 0 1 0.01 0.01 1.000292 1.492 1.333" in flat


def _good() -> dict:
    return rig_to_dict(paper_rig("dome"))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["left"].pop("fx_px"), "left.fx_px': missing"),
        (
            lambda d: d.__setitem__("T_left_right", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
            "T_left_right': expected shape",
        ),
        (
            lambda d: d["left"]["port"].__setitem__("inner_radius_m", -0.01),
            "inner_radius_m': must be > 0",
        ),
        (
            lambda d: d["right"]["port"].__setitem__("center_m", [0.0, 0.0, 0.05]),
            "outside the dome",
        ),
        (lambda d: d["left"].__setitem__("distortion", [0.1, 0.2, 0.3]), "left.distortion'"),
        (
            lambda d: d["left"]["port"].__setitem__("type", "cylinder"),
            "expected none, dome or flat",
        ),
        (lambda d: d["left"].__setitem__("fy_px", "big"), "left.fy_px': expected a number"),
        (lambda d: d.__setitem__("format", "other"), "format'"),
    ],
)
def test_bad_rig_files_name_file_key_and_value(edit, message, tmp_path):
    data = copy.deepcopy(_good())
    edit(data)
    path = tmp_path / "bad_rig.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(RigFileError) as info:
        load_rig(path)
    assert "bad_rig.yaml" in str(info.value)
    assert message in str(info.value)


def test_missing_and_garbage_files(tmp_path):
    with pytest.raises(RigFileError, match="not found"):
        load_rig(tmp_path / "nope.yaml")
    bad = tmp_path / "garbage.yaml"
    bad.write_text("left: [unclosed\n")
    with pytest.raises(RigFileError, match=r"garbage\.yaml: not valid YAML"):
        load_rig(bad)


def test_a_rig_is_never_half_loaded():
    data = _good()
    data["right"]["port"]["n_water"] = 0.5
    with pytest.raises(RigFileError, match="n_water"):
        rig_from_dict(data, "x.yaml")


def test_save_is_atomic_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "rig.yaml"
    save_rig(paper_rig("dome"), path)
    before = path.read_text()

    def boom(rig):
        raise RuntimeError("disk full")

    monkeypatch.setattr("sea3d.io.rig_file.rig_to_yaml", boom)
    with pytest.raises(RuntimeError):
        save_rig(paper_rig("flat"), path)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["rig.yaml"]


def test_yaml_text_has_units_in_keys():
    text = rig_to_yaml(paper_rig("flat"))
    for key in ("image_width_px", "fx_px", "distance_m", "thickness_m", "T_left_right"):
        assert key in text
    assert isinstance(rig_from_dict(yaml.safe_load(text)).left, FlatPortCamera)
    assert isinstance(paper_rig("none"), StereoRig)
