"""``sea3d calibrate`` end to end through the CLI entry point."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.calib.synthetic import BoardRenderer, board_poses
from sea3d.calib.targets import parse_board
from sea3d.cli import main
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.io.rig_file import load_rig, save_rig
from sea3d.refraction import DomePortCamera
from sea3d.refraction.presets import paper_rig

PAPER_CENTER_M = np.array([-0.54e-3, 0.58e-3, 2.10e-3])
# Seven rendered views at 800x450: a looser check than tests/calib/test_port.py (the CLI is
# what is tested here, the accuracy there).
CLI_DOME_CENTER_TOL_M = 0.5e-3


def test_board_pdf_and_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pdf = tmp_path / "board.pdf"
    assert main(["calibrate", "board", "checkerboard:9x6:95mm", "--paper", "A0", "-o",
                 str(pdf)]) == 0
    assert pdf.read_bytes().startswith(b"%PDF-1.4")
    assert "950.0 x 665.0 mm" in capsys.readouterr().out
    png = tmp_path / "board.png"
    assert main(["calibrate", "board", "checkerboard:4x3:10mm", "--dpi", "254", "-o",
                 str(png)]) == 0
    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    # 254 dpi = 10 px/mm: 5x4 squares of 10 mm plus a 10 mm margin on each side.
    assert img.shape == (600, 700)
    assert main(["calibrate", "board", "checkerboard:9x6:95mm", "--paper", "A4", "-o",
                 str(pdf)]) == 2
    assert "does not fit on A4" in capsys.readouterr().err


def test_stereo_bad_input_is_a_one_line_error(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    blank = np.full((120, 160), 128, np.uint8)
    for name in ("left01.png", "left02.png", "right01.png"):
        cv2.imwrite(str(tmp_path / name), blank)
    args = ["calibrate", "stereo", "--left", str(tmp_path / "left*.png"), "--right",
            str(tmp_path / "right*.png"), "--board", "checkerboard:9x6:25mm", "-o",
            str(tmp_path / "rig.yaml")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "2 left and 1 right" in err and "left02.png" in err
    cv2.imwrite(str(tmp_path / "right02.png"), blank)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "found in 0 of 2 left" in err and "left01.png" in err
    assert main([*args[:2], "--left", str(tmp_path / "nothing*.png"), *args[4:]]) == 2
    assert "matches no files" in capsys.readouterr().err
    assert not (tmp_path / "rig.yaml").exists()


def test_wrong_board_size_is_named_in_the_error(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    from sea3d.calib.targets import render_board

    img = render_board(parse_board("checkerboard:7x5:20mm"), px_per_m=1500.0, margin_m=0.02)
    for side in ("left", "right"):
        cv2.imwrite(str(tmp_path / f"{side}01.png"), img)
    assert main(["calibrate", "stereo", "--left", str(tmp_path / "left*.png"), "--right",
                 str(tmp_path / "right*.png"), "--board", "checkerboard:9x6:20mm", "-o",
                 str(tmp_path / "rig.yaml")]) == 2
    assert "did you mean --board checkerboard:7x5:20mm" in capsys.readouterr().err


@pytest.mark.data
def test_stereo_on_opencv_9x6_with_json_and_report(tmp_path: Path, data_dir: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    folder = data_dir / "calib" / "opencv_9x6"
    rig_path, report = tmp_path / "rig.yaml", tmp_path / "report.html"
    assert main(["calibrate", "stereo", "--left", str(folder / "left*.jpg"), "--right",
                 str(folder / "right*.jpg"), "--board", "checkerboard:9x6:25mm", "-o",
                 str(rig_path), "--json", "--report", str(report)]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("rms_px", "holdout_px", "baseline_m", "views_used", "views_rejected"):
        assert key in out
    assert out["left"]["rms_px"] > 0 and out["right"]["rms_px"] > 0
    assert out["rms_px"] < 0.45  # README: plain OpenCV stereoCalibrate gives 0.45 px
    assert out["views_used"] + len(out["views_rejected"]) == 13
    # Every detector was tried; the one kept has the lowest holdout error on common pairs
    # (measured: sector+subpix 0.193 px, classic 0.197, sector 0.283; benchmarks/
    # bench_calib_accuracy.py).
    trials = {t["detector"]: t for t in out["detector"]["trials"]}
    assert set(trials) == {"sector", "sector+subpix", "classic"}
    assert out["detector"]["chosen"] == min(trials, key=lambda n: trials[n]["common_holdout_px"])
    assert out["holdout_px"] < 0.25
    rig = load_rig(rig_path)
    assert rig.baseline_m == pytest.approx(out["baseline_m"])
    assert isinstance(rig.left, PinholeCamera) and rig.left.fx == pytest.approx(
        out["left"]["fx"])
    html = report.read_text()
    assert "Rectified pair" in html and html.count("data:image/png;base64,") == 5
    assert "Corner detector" in html


def test_port_cli_on_rendered_in_water_images(tmp_path: Path, rng: np.random.Generator,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    size = (800, 450)
    rig = paper_rig("dome", size_px=size, dome_center_left_m=tuple(PAPER_CENTER_M),
                    dome_center_right_m=tuple(PAPER_CENTER_M))
    board = parse_board("checkerboard:9x6:60mm")
    poses = board_poses(rig.left, board, 7, rng, distance_range_m=(0.6, 1.4),
                        max_tilt_deg=35, also_inside=[(rig.right, rig.T_right_left)])
    for side, cam, T_cl in (("left", rig.left, np.eye(4)), ("right", rig.right,
                                                             rig.T_right_left)):
        renderer = BoardRenderer(cam, board, texture_px_per_m=2500.0, supersample=1)
        for k, T in enumerate(poses):
            cv2.imwrite(str(tmp_path / f"{side}{k:02d}.png"), renderer.render(T_cl @ T,
                                                                             blur_px=0.7))
    # One pair with an unreadable left image, one whose right image holds no board: both must
    # be listed with their reasons (the JSON's top-level list was empty, the text said nothing).
    (tmp_path / "left07.png").write_bytes(b"not a png")
    cv2.imwrite(str(tmp_path / "right07.png"), np.full(size[::-1], 200, np.uint8))
    cv2.imwrite(str(tmp_path / "left08.png"), np.full(size[::-1], 200, np.uint8))
    cv2.imwrite(str(tmp_path / "right08.png"), np.full(size[::-1], 200, np.uint8))
    air = tmp_path / "air.yaml"
    save_rig(paper_rig("none", size_px=size), air)
    out_rig = tmp_path / "water.yaml"
    argv = ["calibrate", "port", "--rig", str(air), "--port", "dome",
            "--inner-radius-mm", "31.25", "--thickness-mm", "3.1", "--n-glass", "1.492",
            "--left", str(tmp_path / "left*.png"), "--right", str(tmp_path / "right*.png"),
            "--board", "checkerboard:9x6:60mm", "-o", str(out_rig)]
    report = tmp_path / "port.html"
    assert main([*argv, "--report", str(report)]) == 0
    text = capsys.readouterr().out
    assert "rejected left07.png / right07.png: left image: unreadable" in text
    assert "rejected left08.png / right08.png: left image: not_found" in text
    assert "verdict:" in text
    page = report.read_text()
    for section in ("Verdict", "Ports", "dome centre", "standard deviation", "Per-view errors",
                    "Rejected views", "Residual vectors through the port"):
        assert section in page, section
    assert page.count("data:image/png;base64,") == 2
    assert main([*argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {(v["left"], v["right"]) for v in out["views_rejected"]} >= {
        ("left07.png", "right07.png"), ("left08.png", "right08.png")}
    assert len(out["views"]) == out["views_used"] == 7
    assert out["rms_px"] < 0.5
    for side in ("left", "right"):
        centre = np.asarray(out[side]["dome_center_m"])
        assert np.all(np.abs(centre - PAPER_CENTER_M) < CLI_DOME_CENTER_TOL_M), (side, centre)
        assert len(out[side]["dome_center_std_m"]) == 3
    water = load_rig(out_rig)
    assert isinstance(water.left, DomePortCamera)
    np.testing.assert_allclose(water.left.port.center_m, out["left"]["dome_center_m"])
    assert water.baseline_m == pytest.approx(0.107, abs=1e-3)


def test_image_arguments_take_a_glob_or_a_folder_in_natural_order(tmp_path) -> None:
    from sea3d.cli.calibrate import _expand
    from sea3d.errors import CalibrationError

    for name in ("left10.png", "left2.png", "left1.png", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    want = [tmp_path / n for n in ("left1.png", "left2.png", "left10.png")]
    assert _expand(str(tmp_path / "left*.png"), "left") == want
    assert _expand(str(tmp_path), "left") == want  # a folder: its images
    with pytest.raises(CalibrationError, match=r"--left .* matches no files"):
        _expand(str(tmp_path / "right*.png"), "left")
