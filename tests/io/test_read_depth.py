"""read_depth: float metres or 16-bit millimetres in, float32 metres with NaN out."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.errors import StereoError
from sea3d.io.depth_files import read_depth, write_depth

MM_TOL_M = 5e-4  # half a millimetre: the PNG stores whole millimetres


@pytest.mark.parametrize("suffix", [".npy", ".tiff", ".pfm", ".png"])
def test_write_then_read_keeps_metres_and_invalid(tmp_path: Path, suffix: str) -> None:
    z = np.linspace(0.3, 9.0, 48, dtype=np.float32).reshape(6, 8)
    z[0, 0] = np.nan
    z[1, 1] = -1.0  # invalid too
    path = tmp_path / f"d{suffix}"
    write_depth(path, z)
    back = read_depth(path)
    assert back.dtype == np.float32 and back.shape == z.shape
    assert np.isnan(back[0, 0]) and np.isnan(back[1, 1])
    ok = np.isfinite(z) & (z > 0)
    np.testing.assert_allclose(back[ok], z[ok], atol=MM_TOL_M if suffix == ".png" else 1e-6)


def test_depth_that_is_not_depth_is_refused(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "d8.png"), np.full((4, 4), 200, dtype=np.uint8))
    with pytest.raises(StereoError, match="8-bit"):
        read_depth(tmp_path / "d8.png")
    np.save(tmp_path / "int.npy", np.ones((4, 4), dtype=np.int32))
    with pytest.raises(StereoError, match="float metres"):
        read_depth(tmp_path / "int.npy")
    np.save(tmp_path / "rgb.npy", np.ones((4, 4, 3), dtype=np.float32))
    with pytest.raises(StereoError, match="one-channel"):
        read_depth(tmp_path / "rgb.npy")
    with pytest.raises(StereoError, match="not found"):
        read_depth(tmp_path / "missing.npy")
    (tmp_path / "d.txt").write_text("1 2 3")
    with pytest.raises(StereoError, match="unknown depth file type"):
        read_depth(tmp_path / "d.txt")
