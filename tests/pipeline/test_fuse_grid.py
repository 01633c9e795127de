"""``fuse`` reads each depth file's grid sidecar: depth on a grid other than the intrinsics it
is given (or frames on two grids) is refused in one line naming the file, not fused wrong."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.errors import StereoError
from sea3d.io.depth_files import DepthGrid, write_depth
from sea3d.io.trajectory_files import read_trajectory, write_tum
from sea3d.pipeline.fuse import fuse_rgbd
from sea3d.recon.tsdf import TsdfConfig

W, H = 64, 48
K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])


def _grid(kind: str, k: np.ndarray) -> DepthGrid:
    return DepthGrid(kind=kind, width_px=W, height_px=H,  # type: ignore[arg-type]
                     K=tuple(tuple(float(x) for x in r) for r in k), rig_id="0123456789abcdef")


def _frames(tmp_path: Path, grids: list[DepthGrid | None]) -> tuple[list[Path], list[Path]]:
    tmp_path.mkdir(exist_ok=True)
    colors, depths = [], []
    for i, g in enumerate(grids):
        c, d = tmp_path / f"c{i}.png", tmp_path / f"d{i}.png"
        cv2.imwrite(str(c), np.full((H, W, 3), 120, np.uint8))
        write_depth(d, np.full((H, W), 1.0, np.float32), g)
        colors.append(c)
        depths.append(d)
    write_tum(tmp_path / "p.tum", np.arange(len(grids)) * 10**8,
              np.repeat(np.eye(4)[None], len(grids), axis=0))
    return colors, depths


CONFIG = TsdfConfig(voxel_m=0.05, trunc_voxels=4.0, min_depth_m=0.1, max_depth_m=5.0)


def test_depth_on_the_given_pinhole_grid_is_fused(tmp_path: Path) -> None:
    colors, depths = _frames(tmp_path, [_grid("raw-left", K), _grid("raw-left", K)])
    res = fuse_rgbd(colors, depths, read_trajectory(tmp_path / "p.tum"), K, CONFIG)
    assert res.frames == 2 and len(res.mesh.triangles) > 0


def test_depth_from_another_grid_is_refused_naming_the_file(tmp_path: Path) -> None:
    rect = K.copy()
    rect[0, 0] = rect[1, 1] = 66.0  # a rectified view's virtual pinhole: another focal length
    colors, depths = _frames(tmp_path, [_grid("rectified-left", rect)])
    with pytest.raises(StereoError, match=r"d0\.png lives on the rectified-left 64x48 \(fx "
                                          r"66\.0.*fuse was given 60\.00"):
        fuse_rgbd(colors, depths, read_trajectory(tmp_path / "p.tum"), K, CONFIG)


def test_frames_on_two_grids_are_refused(tmp_path: Path) -> None:
    colors, depths = _frames(tmp_path, [_grid("raw-left", K), _grid("rectified-left", K)])
    with pytest.raises(StereoError, match=r"d1\.png lives on the rectified-left.*first depth "
                                          r"file on the raw-left"):
        fuse_rgbd(colors, depths, read_trajectory(tmp_path / "p.tum"), K, CONFIG)
    colors, depths = _frames(tmp_path / "bare", [_grid("raw-left", K), None])
    with pytest.raises(StereoError, match=r"d1\.png has no grid sidecar"):
        fuse_rgbd(colors, depths, read_trajectory(tmp_path / "bare" / "p.tum"), K, CONFIG)
