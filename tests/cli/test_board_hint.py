"""A wrong --board size: the hint names the size most images hold, and the camera of each file."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.calib.targets import parse_board, render_board
from sea3d.cli import main


def _views(out: Path, side: str, n: int) -> None:
    """9x6 boards seen at varied tilts; the first has its right part covered (a smaller count)."""
    board = render_board(parse_board("checkerboard:9x6:40mm"), px_per_m=900, margin_m=0.03)
    h, w = board.shape
    (out / side).mkdir(parents=True)
    for i in range(n):
        a = 0.06 * (i - n / 2)
        src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
        dst = np.float32([[60 + 40 * a, 50], [580, 50 + 60 * a], [580 - 30 * a, 430],
                          [60, 430 - 40 * a]])
        img = cv2.warpPerspective(board, cv2.getPerspectiveTransform(src, dst), (640, 480),
                                  borderValue=255)
        if i == 0:
            img[:, 330:] = 255  # covers the right half: only part of the board shows
        cv2.imwrite(str(out / side / f"{i:02d}.png"), img)


@pytest.fixture(scope="module")
def boards(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("boards")
    for side in ("left", "right"):
        _views(root, side, 5)
    return root


def test_the_hint_is_the_size_most_images_hold(boards: Path, capsys) -> None:
    code = main(["-q", "calibrate", "stereo", "--left", str(boards / "left" / "*.png"),
                 "--right", str(boards / "right" / "*.png"), "--board", "checkerboard:8x6:40mm",
                 "-o", str(boards / "rig.yaml"), "--detector", "classic"])
    err = capsys.readouterr().err
    assert code == 2
    assert "did you mean --board checkerboard:9x6:40mm?" in err
    # each camera's files are listed under its name
    assert "not found in left: 00.png, 01.png, 02.png, 03.png and 1 more; right: 00.png" in err
