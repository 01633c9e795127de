"""Depth files say which pixel grid they live on (``<file>.grid.json``), consumers check it,
and rectified depth resamples onto the raw left grid with the rig."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.cli import main as sea3d_main
from sea3d.errors import StereoError
from sea3d.io.depth_files import (
    DepthGrid,
    check_depth_grid,
    read_depth,
    read_depth_grid,
    rig_identity,
    write_depth,
)
from sea3d.io.rig_file import rig_to_yaml
from sea3d.rectify import rectify_rig
from sea3d.rectify.depth_grid import rectified_depth_to_raw
from sea3d.refraction.presets import paper_rig

SIZE = (160, 90)
# A plane 2 m ahead in the rectified frame, resampled onto the raw grid: every raw pixel's 3D
# point lies on it to 2 mm (nearest-pixel splatting of a 1.5 mm/px plane).
PLANE_TOL_M = 2e-3
# Range varies across the plane: a point up to half a pixel (f = 100 px here) from the raw
# pixel's centre changes it by up to r tan(theta) / (2 f) = 2.9 * 0.75 / 200 = 11 mm.
RANGE_TOL_M = 1.1e-2


def _grid(kind: str = "rectified-left", rig_id: str = "ab" * 8) -> DepthGrid:
    return DepthGrid(kind=kind, width_px=SIZE[0], height_px=SIZE[1],  # type: ignore[arg-type]
                     K=((100.0, 0.0, 80.0), (0.0, 100.0, 45.0), (0.0, 0.0, 1.0)), rig_id=rig_id)


def test_depth_grid_sidecar_round_trips_and_checks_refuse_another_grid(tmp_path: Path) -> None:
    depth = np.full(SIZE[::-1], 2.0, np.float32)
    p = tmp_path / "d.tiff"
    write_depth(p, depth, _grid())
    assert read_depth_grid(p) == _grid()
    assert json.loads((tmp_path / "d.tiff.grid.json").read_text())["kind"] == "rectified-left"
    got = check_depth_grid(p, read_depth(p).shape, kind="rectified-left", width_px=SIZE[0],
                           height_px=SIZE[1], rig_id="ab" * 8)
    assert got == _grid()
    with pytest.raises(StereoError, match=r"lives on the rectified-left 160x90 .*raw grid"):
        check_depth_grid(p, depth.shape, kind="raw-left", width_px=SIZE[0], height_px=SIZE[1])
    with pytest.raises(StereoError, match="another rig"):
        check_depth_grid(p, depth.shape, kind="rectified-left", width_px=SIZE[0],
                         height_px=SIZE[1], rig_id="cd" * 8)
    bare = tmp_path / "bare.npy"
    write_depth(bare, depth)
    assert read_depth_grid(bare) is None
    with pytest.raises(StereoError, match="is 160x90 but"):
        check_depth_grid(bare, depth.shape, kind="raw-left", width_px=80, height_px=45)
    with pytest.raises(StereoError, match="its grid says"):
        write_depth(tmp_path / "x.npy", depth[:, :-1], _grid())
    (tmp_path / "bad.npy.grid.json").write_text("{not json")
    with pytest.raises(StereoError, match="not a depth grid sidecar"):
        read_depth_grid(tmp_path / "bad.npy")
    with pytest.raises(StereoError):
        DepthGrid(kind="left", width_px=1, height_px=1, K=((1, 0, 0), (0, 1, 0), (0, 0, 1)))  # type: ignore[arg-type]


def test_rectified_depth_resamples_onto_the_raw_grid_with_the_rig() -> None:
    rig = paper_rig("none", size_px=SIZE)
    maps = rectify_rig(rig, depth_range_m=(0.5, 10.0))
    K = maps.P_left[:3, :3]
    depth_rect = np.full(SIZE[::-1], 2.0, np.float32)
    raw = rectified_depth_to_raw(depth_rect, K, maps.R_rect_left_left, rig.left)
    assert raw.shape == SIZE[::-1] and np.isfinite(raw).mean() > 0.8
    v, u = np.nonzero(np.isfinite(raw))
    rays = rig.left.unproject(np.stack([u, v], axis=1).astype(np.float64))
    d = rays.directions / rays.directions[:, 2:3]
    p_left = rays.origins + d * raw[v, u][:, None]
    z_rect = (p_left @ maps.R_rect_left_left.T)[:, 2]
    assert np.abs(z_rect - 2.0).max() < PLANE_TOL_M
    rng = rectified_depth_to_raw(depth_rect, K, maps.R_rect_left_left, rig.left,
                                 quantity="range")
    np.testing.assert_allclose(rng[v, u], np.linalg.norm(p_left, axis=1), atol=RANGE_TOL_M)


def test_enhance_refuses_rectified_depth_without_a_rig_and_resamples_with_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = paper_rig("none", size_px=SIZE)
    rig_path = tmp_path / "rig.yaml"
    rig_path.write_text(rig_to_yaml(rig))
    maps = rectify_rig(rig, depth_range_m=(0.5, 10.0))
    img = np.random.default_rng(0).integers(30, 220, (SIZE[1], SIZE[0], 3), dtype=np.uint8)
    img_path = tmp_path / "in.png"
    cv2.imwrite(str(img_path), img)
    ramp = np.linspace(1.0, 5.0, SIZE[1], dtype=np.float32)[:, None] * np.ones((1, SIZE[0]))
    grid = DepthGrid(kind="rectified-left", width_px=SIZE[0], height_px=SIZE[1],
                     K=tuple(tuple(float(x) for x in r) for r in maps.P_left[:3, :3]),
                     rig_id=rig_identity(rig_to_yaml(rig)))
    dpath = tmp_path / "depth.tiff"
    write_depth(dpath, ramp.astype(np.float32), grid)
    out = tmp_path / "out.png"
    rc = sea3d_main(["enhance", str(img_path), "-o", str(out), "--depth", str(dpath)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "rectified-left" in err and "--grid raw" in err
    assert not out.exists()
    rc = sea3d_main(["enhance", str(img_path), "-o", str(out), "--depth", str(dpath),
                     "--rig", str(rig_path)])
    assert rc == 0 and out.exists()
    other = tmp_path / "other.tiff"
    write_depth(other, ramp.astype(np.float32),
                DepthGrid(kind=grid.kind, width_px=grid.width_px, height_px=grid.height_px,
                          K=grid.K, rig_id="00" * 8))
    rc = sea3d_main(["enhance", str(img_path), "-o", str(tmp_path / "o2.png"), "--depth",
                     str(other), "--rig", str(rig_path)])
    assert rc == 2 and "another rig" in capsys.readouterr().err


def test_sea3d_depth_writes_raw_view_depth_that_enhance_takes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sea3d.geometry.se3 import look_at
    from sea3d.sim.reference import simulate_pair_with_reference

    rig = paper_rig("none", size_px=SIZE)
    (tmp_path / "rig.yaml").write_text(rig_to_yaml(rig))
    p = simulate_pair_with_reference(rig, "lake", look_at((0.35, -1.6, 0.9), (0.0, 0.0, 0.1)),
                                     "coastal", seed=1, supersample=1)
    for name, img in (("L.png", p.left), ("R.png", p.right)):
        cv2.imwrite(str(tmp_path / name), img[..., ::-1])
    args = ["depth", "--rig", str(tmp_path / "rig.yaml"), "--left", str(tmp_path / "L.png"),
            "--right", str(tmp_path / "R.png")]
    assert sea3d_main([*args, "-o", str(tmp_path / "raw.tiff"), "--grid", "raw"]) == 0
    assert sea3d_main([*args, "-o", str(tmp_path / "rect.tiff")]) == 0
    raw_grid = read_depth_grid(tmp_path / "raw.tiff")
    assert raw_grid is not None and raw_grid.kind == "raw-left"
    assert raw_grid.rig_id == rig_identity(rig_to_yaml(rig))
    rect_grid = read_depth_grid(tmp_path / "rect.tiff")
    assert rect_grid is not None and rect_grid.kind == "rectified-left"
    raw = read_depth(tmp_path / "raw.tiff")
    both = np.isfinite(raw) & np.isfinite(p.gt.depth_m)
    assert both.mean() > 0.5
    # Raw-view depth against the simulator's true depth of the raw left view: 5 % median.
    assert np.median(np.abs(raw[both] / p.gt.depth_m[both] - 1.0)) < 0.05
    capsys.readouterr()
    out = tmp_path / "out.png"
    assert sea3d_main(["enhance", str(tmp_path / "L.png"), "-o", str(out), "--depth",
                       str(tmp_path / "raw.tiff"), "--rig", str(tmp_path / "rig.yaml")]) == 0
    assert out.exists()


def test_enhance_resamples_a_dome_rigs_rectified_depth_without_a_depth_range(
    tmp_path: Path,
) -> None:
    # Without --min-depth/--max-depth the rectification is the one sea3d depth uses with the
    # rig's own range (it used to pass (None, None) to the virtual-pinhole fit and crash).
    from sea3d.pipeline.enhance_image import range_for_image
    from sea3d.stereo.recipe import StereoDepth

    rig = paper_rig("dome", size_px=SIZE)
    rig_path = tmp_path / "rig.yaml"
    rig_path.write_text(rig_to_yaml(rig))
    maps = StereoDepth(rig).maps
    grid = DepthGrid(kind="rectified-left", width_px=maps.width, height_px=maps.height,
                     K=tuple(tuple(float(x) for x in r) for r in maps.P_left[:3, :3]),
                     rig_id=rig_identity(rig_to_yaml(rig)))
    dpath = tmp_path / "depth.tiff"
    write_depth(dpath, np.full((maps.height, maps.width), 2.0, np.float32), grid)
    rng = range_for_image(dpath, (SIZE[1], SIZE[0]), image_name="in.png", rig_path=rig_path)
    ok = np.isfinite(rng)
    assert rng.shape == (SIZE[1], SIZE[0]) and ok.mean() > 0.5
    # range along a ray to a plane 2 m ahead is at least 2 m (to the plane's splatting error)
    assert rng[ok].min() > 2.0 - PLANE_TOL_M
