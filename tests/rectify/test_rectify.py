"""Rectification of pinhole and refractive rigs, and metric depth through it.

Independent references: OpenCV's undistortPoints for pinhole geometry, and scenes rendered by
ray casting through each camera model (pixels unprojected, refracted by the ports, intersected
with a textured plane of known depth) for the refractive pipeline.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from _textures import grain_over_blobs, textured_plane_view
from sea3d.errors import RectifyError, StereoError
from sea3d.geometry import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import make_T, rotvec_to_R
from sea3d.io.depth_files import read_depth_png_mm, write_depth_png_mm, write_ply
from sea3d.rectify import fit_virtual_pinhole, rectify_images, rectify_rig
from sea3d.refraction.presets import paper_rig
from sea3d.stereo import SgmConfig
from sea3d.stereo.depth import (
    compute_depth,
    depth_to_disparity,
    disparity_to_depth,
    max_disparity_for_depth,
)

ROW_ALIGN_PX = 0.02  # rectified rows of one point agree (undistortPoints iterates)
POINT_ROUNDTRIP_M = 1e-6
DEPTH_REL_PINHOLE = 0.01  # median |dz| / z on rendered planes
DEPTH_REL_REFRACTIVE = 0.01  # the target for dome ports at 1-5 m


def _distorted_rig(width: int = 320, height: int = 240) -> StereoRig:
    left = PinholeCamera(fx=300.0, fy=302.0, cx=158.0, cy=121.0, width=width, height=height,
                         dist=(-0.12, 0.05, 0.001, -0.0005, 0.0))
    right = PinholeCamera(fx=298.0, fy=299.0, cx=162.0, cy=118.0, width=width, height=height,
                          dist=(-0.10, 0.03, -0.0008, 0.0004, 0.0))
    T_left_right = make_T(
        rotvec_to_R(np.array([0.01, -0.02, 0.005])), np.array([0.12, 0.003, 0.002])
    )
    return StereoRig(left=left, right=right, T_left_right=T_left_right)


def test_pinhole_rectification_aligns_rows_and_gives_depth_f_b_over_d() -> None:
    rng = np.random.default_rng(0)
    rig = _distorted_rig()
    maps = rectify_rig(rig)
    points_left = np.column_stack([rng.uniform(-0.5, 0.5, 200), rng.uniform(-0.4, 0.4, 200),
                                   rng.uniform(1.0, 4.0, 200)])
    T_right_left = rig.T_right_left
    points_right = points_left @ T_right_left[:3, :3].T + T_right_left[:3, 3]
    uv_l, ok_l = rig.left.project(points_left)
    uv_r, ok_r = rig.right.project(points_right)
    assert ok_l.all() and ok_r.all()
    # reference: OpenCV's own point mapping into the rectified views (R1/P1, R2/P2)
    rect_l = cv2.undistortPoints(uv_l.reshape(-1, 1, 2), rig.left.K, rig.left.dist,
                                 R=maps.R_rect_left_left, P=maps.P_left).reshape(-1, 2)
    rect_r = cv2.undistortPoints(uv_r.reshape(-1, 1, 2), rig.right.K, rig.right.dist,
                                 R=maps.R_rect_right_right, P=maps.P_right).reshape(-1, 2)
    assert np.max(np.abs(rect_l[:, 1] - rect_r[:, 1])) < ROW_ALIGN_PX
    d = rect_l[:, 0] - rect_r[:, 0]
    z_rect = (points_left @ maps.R_rect_left_left.T)[:, 2]
    np.testing.assert_allclose(disparity_to_depth(d, maps.focal_px, maps.baseline_m), z_rect,
                               rtol=1e-3)
    np.testing.assert_allclose(depth_to_disparity(z_rect, maps.focal_px, maps.baseline_m), d,
                               rtol=1e-3)
    # the remap table sends the rectified pixel back to the raw one
    u, v = np.round(rect_l).astype(int).T
    inside = (u >= 0) & (u < rig.width) & (v >= 0) & (v < rig.height)
    back = np.column_stack([maps.map_left_x[v[inside], u[inside]],
                            maps.map_left_y[v[inside], u[inside]]])
    expected = cv2.projectPoints(
        (np.column_stack([(u[inside] - maps.cx_px) / maps.focal_px,
                          (v[inside] - maps.cy_px) / maps.focal_px,
                          np.ones(inside.sum())]) @ maps.R_rect_left_left),
        np.zeros(3), np.zeros(3), rig.left.K, rig.left.dist)[0].reshape(-1, 2)
    np.testing.assert_allclose(back, expected, atol=0.01)


def test_rectify_bad_input() -> None:
    rig = _distorted_rig()
    maps = rectify_rig(rig)
    img = np.zeros((100, 100), np.uint8)
    with pytest.raises(RectifyError, match="rig is 320x240"):
        rectify_images(maps, img, img)
    vertical = StereoRig(left=rig.left, right=rig.right,
                         T_left_right=make_T(np.eye(3), np.array([0.0, 0.1, 0.0])))
    with pytest.raises(RectifyError, match="side by side"):
        rectify_rig(vertical)
    with pytest.raises(StereoError):
        disparity_to_depth(np.ones((2, 2)), 0.0, 0.1)


def _plane_depth_error(rig: StereoRig, depth_m: float, maps: object, rng: np.random.Generator,
                       pinhole_baseline: bool = False) -> tuple[float, float]:
    tex = grain_over_blobs(rng)
    half = 1.2 * depth_m
    left = textured_plane_view(rig.left, np.eye(4), depth_m, tex, half)
    right = textured_plane_view(rig.right, rig.T_left_right, depth_m, tex, half)
    cfg = SgmConfig(max_disparity_px=max_disparity_for_depth(maps, 0.8))  # type: ignore[arg-type]
    res = compute_depth(maps, left, right, cfg)  # type: ignore[arg-type]
    z = res.depth_m
    h, w = z.shape
    inner = np.zeros_like(z, dtype=bool)
    inner[h // 8 : -h // 8, w // 4 : -w // 8] = True
    # true depth along the rectified left z axis of the plane z_left = depth_m
    valid = np.isfinite(z) & inner
    pts = res.points_left
    rel = np.abs(pts[:, 2] - depth_m) / depth_m  # plane is z_left = depth_m
    density = valid.sum() / inner.sum()
    return float(np.median(rel)), float(density)


@pytest.mark.parametrize("depth_m", [1.5, 4.0])
def test_pinhole_rig_plane_depth_and_points_in_left_frame(depth_m: float) -> None:
    rng = np.random.default_rng(0)
    rig = paper_rig(port="none", size_px=(480, 270))
    maps = rectify_rig(rig)
    med, density = _plane_depth_error(rig, depth_m, maps, rng)
    assert density > 0.8
    assert med < DEPTH_REL_PINHOLE


@pytest.mark.parametrize("depth_m", [1.5, 4.0])
def test_dome_port_depth_is_refraction_corrected(depth_m: float) -> None:
    rng = np.random.default_rng(0)
    rig = paper_rig(port="dome", size_px=(480, 270))
    maps = rectify_rig(rig, depth_range_m=(1.0, 5.0))
    assert maps.refractive and maps.report_left is not None
    assert maps.report_left.max_px < 2.0  # the virtual pinhole is close for a dome
    med, density = _plane_depth_error(rig, depth_m, maps, rng)
    assert density > 0.8
    assert med < DEPTH_REL_REFRACTIVE


def test_flat_port_virtual_pinhole_report_and_depth() -> None:
    rng = np.random.default_rng(0)
    rig = paper_rig(port="flat", size_px=(480, 270))
    virtual, report = fit_virtual_pinhole(rig.left, (1.0, 5.0))
    # a flat port magnifies by about n_water / n_air
    assert 1.25 < virtual.fx / rig.left.pinhole.fx < 1.40  # type: ignore[attr-defined]
    assert len(report.rms_by_depth_px) == 6 and report.max_px >= report.rms_px
    maps = rectify_rig(rig, depth_range_m=(1.0, 5.0))
    med, _ = _plane_depth_error(rig, 2.0, maps, rng)
    assert med < DEPTH_REL_REFRACTIVE


def test_depth_png_and_ply_files(tmp_path: Path) -> None:
    z = np.array([[1.2345, np.nan], [70.0, 0.5]], np.float32)
    write_depth_png_mm(tmp_path / "d.png", z)
    back = read_depth_png_mm(tmp_path / "d.png")
    assert back[0, 0] == pytest.approx(1.234, abs=1e-3) or back[0, 0] == pytest.approx(1.235)
    assert np.isnan(back[0, 1]) and np.isnan(back[1, 0])  # NaN and > 65.535 m are invalid
    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw[1, 1] == 500
    pts = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]])
    cols = np.array([[255, 0, 0], [0, 255, 0]], np.uint8)
    write_ply(tmp_path / "c.ply", pts, cols)
    data = (tmp_path / "c.ply").read_bytes()
    head, body = data.split(b"end_header\n")
    assert b"element vertex 2" in head and b"property uchar red" in head
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                     ("r", "u1"), ("g", "u1"), ("b", "u1")])
    np.testing.assert_allclose(np.column_stack([rec["x"], rec["y"], rec["z"]]), pts,
                               atol=POINT_ROUNDTRIP_M)
    assert rec["r"][0] == 255 and rec["g"][1] == 255
