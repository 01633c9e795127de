"""``sea3d stereo`` and ``sea3d depth`` end to end on small rendered pairs."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from _textures import grain_over_blobs, textured_plane_view
from sea3d.cli import main
from sea3d.io.depth_files import read_depth_png_mm, read_disparity
from sea3d.io.rig_file import save_rig
from sea3d.refraction.presets import paper_rig

PLANE_DEPTH_REL = 0.01


def _shifted_pair(tmp_path: Path, rng: np.random.Generator) -> tuple[Path, Path]:
    tex = cv2.GaussianBlur((rng.random((80, 200)) * 255).astype(np.float32), (0, 0), 1.0)
    left = tex[:, 20:180]
    right = tex[:, 32:192]  # d = 12 px everywhere
    for name, img in (("l.png", left), ("r.png", right)):
        cv2.imwrite(str(tmp_path / name), np.clip(img, 0, 255).astype(np.uint8))
    return tmp_path / "l.png", tmp_path / "r.png"


@pytest.mark.parametrize("suffix", [".pfm", ".npy", ".tiff"])
def test_stereo_cli_writes_disparity_and_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], suffix: str
) -> None:
    rng = np.random.default_rng(0)
    left, right = _shifted_pair(tmp_path, rng)
    out = tmp_path / f"d{suffix}"
    assert main(["stereo", str(left), str(right), "--max-disparity", "31", "-o", str(out),
                 "--json", "--filters", "median,speckle"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["match_s"] > 0 and 0.7 < info["valid_fraction"] <= 1.0
    d = read_disparity(out)
    assert abs(float(np.nanmedian(d)) - 12.0) < 0.05


def test_stereo_cli_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(0)
    left, _ = _shifted_pair(tmp_path, rng)
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((10, 10), np.uint8))
    assert main(["stereo", str(left), str(small), "--max-disparity", "15", "-o",
                 str(tmp_path / "x.pfm")]) == 2
    assert "differ in size" in capsys.readouterr().err
    assert main(["stereo", str(left), str(left), "--max-disparity", "500", "-o",
                 str(tmp_path / "x.pfm")]) == 2
    assert "--max-disparity 500 is too wide" in capsys.readouterr().err
    assert main(["stereo", str(left), str(tmp_path / "missing.png"), "--max-disparity", "15",
                 "-o", str(tmp_path / "x.pfm")]) == 2


def test_depth_cli_dome_rig_png_and_ply(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(0)
    rig = paper_rig(port="dome", size_px=(480, 270))
    save_rig(rig, tmp_path / "rig.yaml")
    tex = grain_over_blobs(rng)
    z0 = 2.0
    left = textured_plane_view(rig.left, np.eye(4), z0, tex, 1.2 * z0)
    right = textured_plane_view(rig.right, rig.T_left_right, z0, tex, 1.2 * z0)
    cv2.imwrite(str(tmp_path / "L.png"), left)
    cv2.imwrite(str(tmp_path / "R.png"), right)
    args = ["depth", "--rig", str(tmp_path / "rig.yaml"), "--left", str(tmp_path / "L.png"),
            "--right", str(tmp_path / "R.png"), "-o", str(tmp_path / "depth.png"),
            "--points", str(tmp_path / "cloud.ply"), "--min-depth", "1", "--max-depth", "5",
            "--json"]
    assert main(args) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["refractive"] and info["n_points"] > 1000
    assert abs(info["median_depth_m"] - z0) / z0 < PLANE_DEPTH_REL
    z = read_depth_png_mm(tmp_path / "depth.png")
    assert abs(float(np.nanmedian(z)) - z0) / z0 < PLANE_DEPTH_REL
    assert (tmp_path / "cloud.ply").read_bytes().startswith(b"ply\n")
    # a rig that does not match the images
    save_rig(paper_rig(port="dome", size_px=(640, 360)), tmp_path / "big.yaml")
    args[2] = str(tmp_path / "big.yaml")
    assert main(args) == 2
    assert "640x360" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "-3", "x"])
def test_bad_max_disparity_is_refused_up_front_naming_the_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str
) -> None:
    rng = np.random.default_rng(0)
    left, right = _shifted_pair(tmp_path, rng)
    # refused by the argument parser (exit 2), before the rig or the images are read
    with pytest.raises(SystemExit) as stop:
        main(["depth", "--rig", str(tmp_path / "no_such_rig.yaml"), "--left", str(left),
              "--right", str(right), "-o", str(tmp_path / "d.png"), "--max-disparity", value])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--max-disparity" in err and "no_such_rig" not in err
    with pytest.raises(SystemExit) as stop:
        main(["stereo", str(left), str(right), "--max-disparity", value, "-o",
              str(tmp_path / "d.pfm")])
    assert stop.value.code == 2
    assert "--max-disparity" in capsys.readouterr().err
    assert not (tmp_path / "d.pfm").exists() and not (tmp_path / "d.png").exists()


def test_too_wide_max_disparity_names_the_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(0)
    left, right = _shifted_pair(tmp_path, rng)  # 160 px wide
    for engine, top in (("sea3d", 159), ("opencv-3way", 143)):
        assert main(["stereo", str(left), str(right), "--max-disparity", str(top + 1), "-o",
                     str(tmp_path / "d.pfm"), "--engine", engine]) == 2
        err = capsys.readouterr().err
        assert "--max-disparity" in err and "max_disparity_px" not in err
        assert f"at most {top}" in err
    save_rig(paper_rig(port="none", size_px=(160, 80)), tmp_path / "rig.yaml")
    assert main(["depth", "--rig", str(tmp_path / "rig.yaml"), "--left", str(left), "--right",
                 str(right), "-o", str(tmp_path / "d.png"), "--max-disparity", "400"]) == 2
    assert "--max-disparity 400 is too wide" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["depth", "--rig", str(tmp_path / "rig.yaml"), "--left", str(left), "--right",
              str(right), "-o", str(tmp_path / "d.png"), "--min-depth", "-1"])
    assert "--min-depth" in capsys.readouterr().err
