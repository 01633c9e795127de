"""``sea3d rig`` end to end through the CLI entry point."""

import json

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.io.rig_file import load_rig


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("sea3d ")


def test_create_preset_and_show_json(tmp_path, capsys):
    rig = tmp_path / "rig.yaml"
    assert main(["rig", "create", "--preset", "sea3d-paper", "-o", str(rig)]) == 0
    capsys.readouterr()
    assert main(["rig", "show", str(rig), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["left"]["model"] == "dome-port"
    assert data["left"]["K"][0][0] == pytest.approx(1082.4)
    assert data["left"]["image_size_px"] == [1920, 1080]
    np.testing.assert_allclose(data["left"]["port"]["center_m"], [-0.00054, 0.00058, 0.0021])
    np.testing.assert_allclose(np.array(data["T_left_right"])[0, 3], 0.107)
    assert main(["rig", "show", str(rig)]) == 0
    text = capsys.readouterr().out
    assert "baseline 107.00 mm" in text and "dome: centre (-0.540, 0.580, 2.100) mm" in text


def test_create_with_overrides(tmp_path):
    rig_path = tmp_path / "rig.yaml"
    args = [
        "rig",
        "create",
        "--preset",
        "sea3d-paper",
        "--port",
        "flat",
        "--size",
        "960x540",
        "--fx",
        "600",
        "--baseline-mm",
        "150",
        "--thickness-mm",
        "12",
        "-o",
        str(rig_path),
    ]
    assert main(args) == 0
    rig = load_rig(rig_path)
    assert (rig.width, rig.height) == (960, 540)
    assert rig.left.pinhole.fx == pytest.approx(600.0)
    assert rig.baseline_m == pytest.approx(0.150)
    assert rig.left.port.thickness_m == pytest.approx(0.012)


def test_create_dome_with_centres(tmp_path):
    rig_path = tmp_path / "rig.yaml"
    args = [
        "rig",
        "create",
        "--preset",
        "sea3d-paper",
        "--dome-center-left-mm",
        "1",
        "2",
        "3",
        "--dome-center-right-mm",
        "-1",
        "0",
        "0.5",
        "--inner-radius-mm",
        "50",
        "-o",
        str(rig_path),
    ]
    assert main(args) == 0
    rig = load_rig(rig_path)
    np.testing.assert_allclose(rig.left.port.center_m, [1e-3, 2e-3, 3e-3])
    np.testing.assert_allclose(rig.right.port.center_m, [-1e-3, 0.0, 0.5e-3])
    assert rig.left.port.inner_radius_m == pytest.approx(0.05)


@pytest.mark.data
def test_create_from_matlab_export_adds_domes(tmp_path, data_dir):
    rig_path = tmp_path / "rig.yaml"
    src = data_dir / "calib/sea3d_yaml/in_air_stereo.yml"
    args = [
        "rig",
        "create",
        "--from",
        str(src),
        "--port",
        "dome",
        "--size",
        "1920x1080",
        "-o",
        str(rig_path),
    ]
    assert main(args) == 0
    rig = load_rig(rig_path)
    assert rig.left.pinhole.fx == pytest.approx(1157.6193)
    assert rig.left.port.inner_radius_m == pytest.approx(0.03125)


def test_unproject_and_project_csv(tmp_path):
    rig_path = tmp_path / "rig.yaml"
    main(["rig", "create", "--preset", "sea3d-paper", "-o", str(rig_path)])
    px = tmp_path / "px.csv"
    px.write_text("u,v\n0,0\n959.5,539.5\n1919,1079\n")
    rays_csv = tmp_path / "rays.csv"
    assert main(["rig", "unproject", str(rig_path), "--pixels", str(px), "-o", str(rays_csv)]) == 0
    rays = np.genfromtxt(rays_csv, delimiter=",", names=True)
    assert rays.dtype.names == ("u", "v", "ox", "oy", "oz", "dx", "dy", "dz")
    # Points 2 m along each ray project back to the same pixels.
    pts = (
        np.c_[rays["ox"], rays["oy"], rays["oz"]] + 2.0 * np.c_[rays["dx"], rays["dy"], rays["dz"]]
    )
    pts_csv = tmp_path / "pts.csv"
    np.savetxt(pts_csv, pts, delimiter=",", header="x,y,z", comments="")
    uv_csv = tmp_path / "uv.csv"
    assert main(["rig", "project", str(rig_path), "--points", str(pts_csv), "-o", str(uv_csv)]) == 0
    out = np.genfromtxt(uv_csv, delimiter=",", names=True)
    np.testing.assert_allclose(
        np.c_[out["u"], out["v"]], [[0, 0], [959.5, 539.5], [1919, 1079]], atol=1e-4
    )
    assert out["valid"].tolist() == [1, 1, 1]


def test_bad_csv_gives_a_clear_error(tmp_path, capsys):
    rig_path = tmp_path / "rig.yaml"
    main(["rig", "create", "--preset", "sea3d-paper", "-o", str(rig_path)])
    bad = tmp_path / "bad.csv"
    bad.write_text("u,w\n1,2\n")
    code = main(
        ["rig", "unproject", str(rig_path), "--pixels", str(bad), "-o", str(tmp_path / "o.csv")]
    )
    assert code == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and "missing column(s) ['v']" in err
    bad.write_text("x,y,z\n1,2,oops\n")
    code = main(
        ["rig", "project", str(rig_path), "--points", str(bad), "-o", str(tmp_path / "o.csv")]
    )
    assert code == 2
    assert "line 2, column 'z': not a number" in capsys.readouterr().err


def test_convert_to_colmap_and_back_to_yaml(tmp_path):
    rig_path = tmp_path / "rig.yaml"
    main(["rig", "create", "--preset", "sea3d-paper", "-o", str(rig_path)])
    assert main(["rig", "convert", str(rig_path), str(tmp_path / "cams.txt")]) == 0
    assert "DOMEPORT" in (tmp_path / "cams.txt").read_text()
    assert (
        main(["rig", "convert", str(rig_path), str(tmp_path / "cv.yml"), "--format", "opencv"]) == 0
    )
    assert main(["rig", "convert", str(tmp_path / "cv.yml"), str(tmp_path / "back.yaml")]) == 0
    np.testing.assert_allclose(
        load_rig(tmp_path / "back.yaml").left.K, load_rig(rig_path).left.pinhole.K
    )


def test_bad_rig_file_is_reported_not_a_traceback(tmp_path, capsys):
    bad = tmp_path / "rig.yaml"
    bad.write_text("format: sea3d-rig\nversion: 1\n")
    assert main(["rig", "show", str(bad)]) == 2
    assert "rig.yaml: key 'image_width_px': missing" in capsys.readouterr().err


def test_python_dash_m_runs_the_same_command():
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-m", "sea3d", "--version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.startswith("sea3d ")
