"""Renderer validation: geometry against analytic answers and OpenCV, water model, determinism."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sea3d.calib.targets import parse_board
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.refraction.presets import paper_rig
from sea3d.sim.materials import SandMaterial
from sea3d.sim.optics import WATER_PRESETS, Imaging
from sea3d.sim.render import Renderer
from sea3d.sim.scene import Scene, SceneObject, builtin_scene, plane_mesh
from sea3d.sim.survey import render_calibration_set, simulate_pair

SIZE_PX = (640, 360)
CORNER_RMS_TOL_PX = 0.1  # issue: detected corners within 0.1 px RMS of the projected 3D corners
DEPTH_REL_TOL = 2e-6  # float32 ray distances from Open3D: a few ulp of the range
WATER_EXACT_TOL = 1e-6


def _plane_scene(T_world_plane: np.ndarray) -> Scene:
    scene = Scene(name="plane")
    mesh = plane_mesh(-20, 20, -20, 20)
    mesh.transform(T_world_plane)
    mesh.compute_triangle_normals()
    scene.add(
        SceneObject(name="plane", mesh=mesh, material=SandMaterial(), T_world_object=T_world_plane)
    )
    return scene


@pytest.mark.parametrize("port", ["none", "dome", "flat"])
def test_rendered_depth_of_a_plane_matches_the_analytic_plane(port: str) -> None:
    rig = paper_rig(port, size_px=(160, 90))
    cam = rig.left
    # A plane tilted 30 deg about x, 1.5 m in front of the camera (world = camera frame).
    th = np.deg2rad(30.0)
    T_plane = np.eye(4)
    T_plane[:3, :3] = np.array(
        [[1, 0, 0], [0, np.cos(th), -np.sin(th)], [0, np.sin(th), np.cos(th)]]
    )
    T_plane[:3, 3] = (0.1, -0.05, 1.5)
    view = Renderer(_plane_scene(T_plane), supersample=1).render(cam, np.eye(4))
    vv, uu = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    rays = cam.unproject(np.stack([uu.ravel(), vv.ravel()], axis=1))
    n = T_plane[:3, 2]
    t = ((T_plane[:3, 3] - rays.origins) @ n) / (rays.directions @ n)
    z_expected = rays.at(t)[:, 2].reshape(cam.height, cam.width)
    depth = view.gt.depth_m.astype(np.float64)
    assert np.isfinite(depth).all()
    np.testing.assert_allclose(depth, z_expected, rtol=DEPTH_REL_TOL)
    r_expected = np.linalg.norm(rays.at(t), axis=1).reshape(cam.height, cam.width)
    np.testing.assert_allclose(view.gt.range_m, r_expected, rtol=DEPTH_REL_TOL)
    normals = view.gt.normals_cam.reshape(-1, 3)
    np.testing.assert_allclose(np.abs(normals @ n), 1.0, atol=1e-5)


def _corner_errors(rig, port_cam, spec, cal) -> np.ndarray:
    errors = []
    for img, T in zip(cal.lefts, cal.T_left_board, strict=True):
        gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        ok, corners = cv2.findChessboardCorners(gray, spec.corner_grid)
        assert ok, "OpenCV did not find the rendered checkerboard"
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), crit).reshape(-1, 2)
        _ids, pts_board = spec.object_points()  # x fastest, as OpenCV orders them
        pts = pts_board @ T[:3, :3].T + T[:3, 3]
        uv, valid = port_cam.project(pts)
        assert valid.all()
        d = corners[:, None, :] - uv[None, :, :]
        nearest = np.linalg.norm(d, axis=2).argmin(axis=1)
        assert len(set(nearest.tolist())) == len(nearest), "corner matching is not one-to-one"
        errors.append(d[np.arange(len(nearest)), nearest])
    return np.concatenate(errors)


@pytest.mark.parametrize("port", ["none", "dome"])
def test_detected_checkerboard_corners_land_on_projected_board_corners(port: str) -> None:
    rig = paper_rig(port, size_px=SIZE_PX)
    spec = parse_board("checkerboard:9x6:40mm")
    cal = render_calibration_set(
        rig, spec, 3, "water", seed=1, distance_range_m=(0.5, 0.9), supersample=6
    )
    err = _corner_errors(rig, rig.left, spec, cal)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    assert rms < CORNER_RMS_TOL_PX, rms


def test_calibration_boards_are_fully_inside_both_images_and_poses_are_rigid() -> None:
    rig = paper_rig("dome", size_px=(320, 180))
    cal = render_calibration_set(
        rig, "checkerboard:9x6:40mm", 2, "air", seed=3, distance_range_m=(0.8, 1.5), supersample=1
    )
    for T in cal.T_left_board:
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
        assert 0.6 < np.linalg.norm(T[:3, 3]) < 1.8
    assert all(
        img.shape == (180, 320, 3) and img.dtype == np.uint8 for img in cal.lefts + cal.rights
    )


def test_same_seed_and_no_water_gives_identical_images() -> None:
    rig = paper_rig("none", size_px=(160, 90))
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down
    T[:3, 3] = (0.0, 0.0, 1.2)
    a = simulate_pair(rig, "lake", T, None, seed=5)
    b = simulate_pair(rig, "lake", T, None, seed=5)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    # With noise on, the seed decides the image.
    c = simulate_pair(rig, "lake", T, "coastal", seed=5)
    d = simulate_pair(rig, "lake", T, "coastal", seed=5)
    e = simulate_pair(rig, "lake", T, "coastal", seed=6)
    assert np.array_equal(c[0], d[0]) and not np.array_equal(c[0], e[0])


def test_water_model_is_the_akkaynak_treibitz_equation() -> None:
    water = WATER_PRESETS["coastal"]
    imaging = Imaging(water=water)
    J = np.array([[0.5, 0.4, 0.3], [0.5, 0.4, 0.3], [0.2, 0.2, 0.2]])
    z = np.array([0.0, 2.0, np.inf])
    out = imaging.through_water(J, z)
    bD, bB, Binf = (
        np.asarray(v) for v in (water.beta_D_per_m, water.beta_B_per_m, water.B_inf_rgb)
    )
    np.testing.assert_allclose(out[0], J[0], atol=WATER_EXACT_TOL)
    np.testing.assert_allclose(
        out[1], J[1] * np.exp(-bD * 2.0) + Binf * (1 - np.exp(-bB * 2.0)), atol=WATER_EXACT_TOL
    )
    np.testing.assert_allclose(out[2], Binf, atol=WATER_EXACT_TOL)


def test_water_darkens_and_tints_with_distance() -> None:
    rig = paper_rig("none", size_px=(160, 90))
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (0.0, 0.0, 1.0)
    clean = simulate_pair(rig, "lake", T, None)[0].astype(float)
    turbid = simulate_pair(rig, "lake", T, Imaging(water=WATER_PRESETS["turbid"]))[0].astype(float)
    # Turbid water: less contrast and a colour cast towards the veiling light.
    assert turbid.std() < clean.std()
    assert turbid[..., 1].mean() > turbid[..., 0].mean()


def test_ground_truth_marks_misses_and_ranges_exceed_depths() -> None:
    cam = PinholeCamera(fx=100.0, fy=100.0, cx=79.5, cy=44.5, width=160, height=90)
    scene = builtin_scene("lake")
    T = np.eye(4)  # above the floor, looking along world +z (up): it sees nothing
    T[:3, 3] = (0.0, 0.0, 1.0)
    view = Renderer(scene, supersample=1).render(cam, T)
    assert np.isnan(view.gt.depth_m).all() and (view.gt.object_id == -1).all()
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (0.0, 0.0, 1.5)
    view = Renderer(scene, supersample=1).render(cam, T)
    hit = view.gt.object_id >= 0
    assert hit.all()
    assert (view.gt.range_m[hit] >= view.gt.depth_m[hit] - 1e-6).all()
    cube_id = next(k for k, o in enumerate(scene.objects) if o.name == "aruco_cube")
    assert (view.gt.object_id == cube_id).sum() > 50


def test_aruco_markers_on_the_rendered_cube_are_detected_with_their_ids() -> None:
    scene = builtin_scene("tank")
    cube = next(o for o in scene.objects if o.name == "aruco_cube")
    c = cube.T_world_object[:3, 3]
    cam = PinholeCamera(fx=500.0, fy=500.0, cx=319.5, cy=179.5, width=640, height=360)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # straight down onto the top face (+z, marker id 4)
    T[:3, 3] = (c[0], c[1], c[2] + 0.45)
    view = Renderer(scene, supersample=2).render(cam, T, Imaging(ambient=1.0))
    gray = cv2.cvtColor(view.image, cv2.COLOR_RGB2GRAY)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    _, ids, _ = detector.detectMarkers(gray)
    assert ids is not None and 4 in ids.ravel().tolist()


CHARUCO_BIAS_TOL_PX = 0.1
CHARUCO_RMS_TOL_PX = 0.4  # small squares (~30 px) with markers inside the cornerSubPix window


def test_charuco_corners_match_the_board_frame_convention() -> None:
    """OpenCV's ChArUco corner k lands on the calib board's object point with id k (frame at the
    first inner corner), for OpenCV's own board built from the spec's square counts.

    OpenCV's CharucoDetector alone returns corners offset by about +0.5 px in x and y (seen here
    on exact renders); after cornerSubPix the offset is gone, so the test refines first.
    """
    rig = paper_rig("none", size_px=SIZE_PX)
    spec = parse_board("charuco:7x5:50mm:37mm:DICT_4X4_50")
    lefts, _rights, poses = render_calibration_set(
        rig, spec, 2, "air", seed=0, distance_range_m=(0.55, 0.75)
    )
    board = cv2.aruco.CharucoBoard(
        (spec.cols, spec.rows),  # calib counts ChArUco squares, as OpenCV does
        spec.square_m,
        spec.marker_m,
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
    )
    detector = cv2.aruco.CharucoDetector(board)
    all_ids, pts_board = spec.object_points()
    assert np.array_equal(all_ids, np.arange(len(all_ids)))
    errors = []
    for img, T in zip(lefts, poses, strict=True):
        gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        corners, ids, _, _ = detector.detectBoard(gray)
        assert ids is not None and len(ids) >= 10
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
        corners = cv2.cornerSubPix(gray, corners, (4, 4), (-1, -1), crit).reshape(-1, 2)
        pts = pts_board[ids.ravel()] @ T[:3, :3].T + T[:3, 3]
        uv, _ = rig.left.project(pts)
        errors.append(corners - uv)
    err = np.concatenate(errors)
    assert np.all(np.abs(err.mean(axis=0)) < CHARUCO_BIAS_TOL_PX), err.mean(axis=0)
    assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < CHARUCO_RMS_TOL_PX


ADAPTIVE_MEAN_DIFF_DN = 0.5  # 8-bit levels, whole image


def test_adaptive_supersampling_matches_full_supersampling() -> None:
    rig = paper_rig("dome", size_px=(320, 180))
    scene = builtin_scene("lake")
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (0.1, 0.1, 0.9)
    adaptive = Renderer(scene, supersample=2)
    full = Renderer(scene, supersample=2, adaptive=False)
    a = adaptive.render(rig.left, T).image.astype(float)
    f = full.render(rig.left, T).image.astype(float)
    assert 0.0 < adaptive.last_supersampled_fraction < 0.2
    assert np.abs(a - f).mean() < ADAPTIVE_MEAN_DIFF_DN


STEREO_CONSISTENCY_TOL_M = 2e-4  # bilinear interpolation of a tilted plane's depth, 160x90


@pytest.mark.parametrize("port", ["none", "dome"])
def test_right_view_ground_truth_agrees_with_the_left_through_the_rig(port: str) -> None:
    rig = paper_rig(port, size_px=(160, 90))
    th = np.deg2rad(20.0)
    T_plane = np.eye(4)
    T_plane[:3, :3] = np.array(
        [[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]]
    )
    T_plane[:3, 3] = (0.0, 0.0, 1.2)
    renderer = Renderer(_plane_scene(T_plane), supersample=1)
    left = renderer.render(rig.left, np.eye(4)).gt
    right = renderer.render(rig.right, rig.T_left_right).gt
    p_right = right.points_cam.reshape(-1, 3).astype(np.float64)[::7]
    p_left = p_right @ rig.T_left_right[:3, :3].T + rig.T_left_right[:3, 3]
    uv, ok = rig.left.project(p_left)
    inside = ok & (uv[:, 0] > 1) & (uv[:, 0] < 158) & (uv[:, 1] > 1) & (uv[:, 1] < 88)
    z = cv2.remap(
        left.depth_m,
        uv[inside, 0].astype(np.float32).reshape(-1, 1),
        uv[inside, 1].astype(np.float32).reshape(-1, 1),
        cv2.INTER_LINEAR,
    ).ravel()
    assert inside.sum() > 500
    np.testing.assert_allclose(z, p_left[inside, 2], atol=STEREO_CONSISTENCY_TOL_M)


def _fused_and_reference(scene, T: np.ndarray, imaging: Imaging):
    rig = paper_rig("dome", size_px=(240, 135))
    views = []
    for fused in (True, False):
        renderer = Renderer(scene, supersample=2, fused=fused)
        views.append(
            renderer.render(rig.left, T, imaging, time_s=0.7, rng=np.random.default_rng(0))
        )
    return views


def test_fused_shading_gives_the_reference_path_images_bit_for_bit() -> None:
    # The fast path (whole-image numba passes, lattice-cached noise) must not change any number:
    # lake scene (sand, rocks, the ArUco cube, the bottle) in coastal water with every effect on.
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (-0.3, 0.2, 1.1)
    fast, ref = _fused_and_reference(builtin_scene("lake"), T, Imaging.underwater("coastal"))
    np.testing.assert_array_equal(fast.image, ref.image)
    np.testing.assert_array_equal(fast.radiance, ref.radiance)
    for key in ("depth_m", "range_m", "points_cam", "normals_cam", "object_id"):
        np.testing.assert_array_equal(getattr(fast.gt, key), getattr(ref.gt, key), err_msg=key)


def test_fused_shading_handles_a_posed_sand_object_and_clean_imaging() -> None:
    T_plane = np.eye(4)
    T_plane[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T_plane[:3, 3] = (0.3, -0.2, 1.4)
    fast, ref = _fused_and_reference(_plane_scene(T_plane), np.eye(4), Imaging.clean())
    np.testing.assert_array_equal(fast.image, ref.image)
    np.testing.assert_array_equal(fast.radiance, ref.radiance)
