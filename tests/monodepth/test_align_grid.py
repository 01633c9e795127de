"""Mono-depth alignment reads the grid sidecar of the metric depth it aligns to: raw-view depth
is taken as it is, rectified-view depth is resampled with the rig or refused in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sea3d.errors import MonoDepthError
from sea3d.geometry.rig import StereoRig
from sea3d.io.depth_files import DepthGrid, rig_identity, write_depth
from sea3d.io.rig_file import rig_to_yaml
from sea3d.monodepth.align import read_alignment_depth
from sea3d.refraction.presets import paper_rig
from sea3d.stereo.recipe import StereoDepth

W, H = 160, 90
PLANE_Z_M = 2.0
# nearest-pixel resampling of a fronto-parallel plane: the raw depth is the plane's own
PLANE_TOL_M = 1e-4


def _rotated_rig() -> StereoRig:
    """A pinhole rig whose right camera is turned 3 deg and sits 1 cm low, so rectification
    rotates the left view: the rectified grid is not the raw one."""
    base = paper_rig("none", size_px=(W, H))
    T = base.T_left_right.copy()
    T[:3, :3] = Rotation.from_euler("xz", [2.0, 3.0], degrees=True).as_matrix()
    T[1, 3] = 0.01
    return StereoRig(left=base.left, right=base.right, T_left_right=T)


def _grid(kind: str, K: np.ndarray, rig: StereoRig) -> DepthGrid:
    return DepthGrid(kind=kind, width_px=W, height_px=H,  # type: ignore[arg-type]
                     K=tuple(tuple(float(x) for x in r) for r in K),
                     rig_id=rig_identity(rig_to_yaml(rig)))


def _rectified_plane(rig: StereoRig) -> tuple[np.ndarray, np.ndarray]:
    """Rectified-left depth of the plane ``z_raw = PLANE_Z_M`` and the rectified K."""
    maps = StereoDepth(rig).maps
    K = np.asarray(maps.P_left[:3, :3], dtype=np.float64)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.linalg.solve(K, np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))
    d_raw = maps.R_rect_left_left.T @ rays  # rectified ray (z = 1) in the raw left frame
    z_rect = PLANE_Z_M / d_raw[2]  # ray length factor = depth along the rectified z axis
    return z_rect.reshape(H, W).astype(np.float32), K


def test_raw_depth_is_taken_as_it_is_and_a_size_mismatch_names_the_file(tmp_path: Path) -> None:
    rig = _rotated_rig()
    z = np.full((H, W), 1.5, np.float32)
    pin = rig.left.lens
    K = np.array([[pin.fx, 0, pin.cx], [0, pin.fy, pin.cy], [0, 0, 1.0]])
    write_depth(tmp_path / "raw.npy", z, _grid("raw-left", K, rig))
    np.testing.assert_array_equal(read_alignment_depth(tmp_path / "raw.npy", W, H), z)
    np.save(tmp_path / "bare.npy", z[:, :-2])  # no sidecar: only the size is known
    with pytest.raises(MonoDepthError, match=r"bare\.npy.*158x90.*160x90"):
        read_alignment_depth(tmp_path / "bare.npy", W, H)


def test_rectified_depth_is_resampled_with_its_rig_or_refused(tmp_path: Path) -> None:
    rig = _rotated_rig()
    z_rect, K = _rectified_plane(rig)
    path = tmp_path / "rect.npy"
    write_depth(path, z_rect, _grid("rectified-left", K, rig))
    # the rectified map itself is not the plane's raw depth: taking it as is would be wrong
    assert np.nanmax(np.abs(z_rect - PLANE_Z_M)) > 0.005
    with pytest.raises(MonoDepthError, match=r"rect\.npy.*rectified-left.*give the rig"):
        read_alignment_depth(path, W, H)
    raw = read_alignment_depth(path, W, H, rig=rig)
    assert raw.shape == (H, W)
    covered = np.isfinite(raw)
    assert covered.mean() > 0.5  # the rolled, zoomed rectified view misses the raw corners
    np.testing.assert_allclose(raw[covered], PLANE_Z_M, atol=PLANE_TOL_M)
    other = paper_rig("none", size_px=(W, H))  # another calibration: another rig identity
    with pytest.raises(MonoDepthError, match=r"rect\.npy came from another rig"):
        read_alignment_depth(path, W, H, rig=other)


def test_cli_refuses_rectified_depth_without_a_rig(make_net: object, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    import cv2

    from sea3d.cli import main

    rig = _rotated_rig()
    z_rect, K = _rectified_plane(rig)
    write_depth(tmp_path / "rect.npy", z_rect, _grid("rectified-left", K, rig))
    img = tmp_path / "img.png"
    cv2.imwrite(str(img), np.full((H, W, 3), 100, np.uint8))
    net = make_net("mean", H, W)  # type: ignore[operator]
    assert main(["mono-depth", str(img), "--model", str(net), "-o", str(tmp_path / "o.npy"),
                 "--align-depth", str(tmp_path / "rect.npy")]) == 2
    err = capsys.readouterr().err.strip()
    assert "rect.npy" in err and "rectified-left" in err and len(err.splitlines()) == 1
