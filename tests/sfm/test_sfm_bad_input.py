"""``sea3d sfm`` refuses bad input with one line naming the file and what was wrong."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.cli import main
from sea3d.errors import ConfigError, SfmError
from sea3d.sfm import SfmConfig, SfmFrame, run_sfm


def _err(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("sea3d: error: ")
    return err


def test_too_few_images(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for i in range(2):
        cv2.imwrite(str(tmp_path / f"{i}.png"), np.zeros((60, 80), np.uint8))
    err = _err(capsys, ["sfm", str(tmp_path / "*.png"), "-o", str(tmp_path / "out")])
    assert "2 frame(s)" in err and "at least 3" in err and str(tmp_path) in err
    err = _err(capsys, ["sfm", str(tmp_path / "*.jpg"), "-o", str(tmp_path / "out")])
    assert "matches no image files" in err


def test_mixed_sizes_name_the_odd_file(orbit_session: Callable[..., Path], tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    session = orbit_session()
    files = sorted((session / "left").glob("*.png"))[:4]
    for f in files:
        shutil.copy(f, tmp_path / f.name)
    odd = tmp_path / files[2].name
    cv2.imwrite(str(odd), cv2.resize(cv2.imread(str(odd)), (160, 90)))
    err = _err(capsys, ["sfm", str(tmp_path / "*.png"), "-o", str(tmp_path / "out")])
    assert odd.name in err and "160x90" in err and "320x180" in err


def test_no_overlap_is_an_error_and_keeps_the_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(0)
    for i in range(4):  # independent noise: features, but no geometry between the images
        img = cv2.GaussianBlur(rng.uniform(0, 255, (120, 160)).astype(np.uint8), (3, 3), 0)
        cv2.imwrite(str(tmp_path / f"{i}.png"), img)
    out = tmp_path / "out"
    err = _err(capsys, ["sfm", str(tmp_path / "*.png"), "-o", str(out), "--matcher",
                        "exhaustive"])
    assert "no model" in err and "overlap" in err and str(tmp_path) in err
    assert '"status": "failed"' in (out / "summary.json").read_text()


def test_stereo_needs_a_right_camera_and_a_rig(orbit_session: Callable[..., Path], tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    session = orbit_session()
    mono = tmp_path / "mono"
    shutil.copytree(session / "left", mono / "left")
    shutil.copy(session / "rig.yaml", mono / "rig.yaml")
    err = _err(capsys, ["sfm", str(mono), "--camera", "stereo", "-o", str(tmp_path / "o")])
    assert str(mono) in err and "no right camera" in err
    err = _err(capsys, ["sfm", str(session / "left" / "*.png"), "--camera", "stereo",
                        "-o", str(tmp_path / "o")])
    assert "image glob" in err and "session" in err
    frames = [SfmFrame(name=str(i), t_s=float(i), left=np.zeros((9, 9), np.uint8),
                       right=np.zeros((9, 9), np.uint8), source=f"f{i}") for i in range(3)]
    with pytest.raises(SfmError, match="needs the rig"):
        run_sfm(frames, SfmConfig(camera="stereo"))


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="camera"):
        SfmConfig(camera="middle")
    with pytest.raises(ConfigError, match="matcher"):
        SfmConfig(matcher="vocabtree")
    with pytest.raises(ConfigError, match="depth_range_m"):
        SfmConfig(depth_range_m=(2.0, 1.0))


def test_pose_priors_must_be_a_stamped_trajectory(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    # the priors are read before the input is opened, so any input will do
    session = tmp_path
    kitti = tmp_path / "poses.txt"  # KITTI: 12 values a line, no stamps
    kitti.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    out = str(tmp_path / "o")
    err = _err(capsys, ["sfm", str(session), "-o", out, "--pose-priors", str(kitti)])
    assert str(kitti) in err and "--pose-priors-times" in err
    bad = tmp_path / "bad.tum"
    bad.write_text("0.0 1 2 3 0 0 0\n")
    err = _err(capsys, ["sfm", str(session), "-o", out, "--pose-priors", str(bad),
                        "--pose-priors-format", "tum"])
    assert str(bad) in err and "expected 8" in err
