"""Pinhole camera against OpenCV: projectPoints and a converged undistortPointsIter."""

import cv2
import numpy as np
import pytest

from sea3d.errors import CameraModelError, GeometryError
from sea3d.geometry import PinholeCamera
from tolerances import PIXEL_EXACT_PX


def _camera(n_coeffs: int, rng: np.random.Generator) -> PinholeCamera:
    dist = rng.normal(0.0, 0.02, n_coeffs)
    if n_coeffs >= 8:
        dist[5:8] = rng.normal(0.0, 0.01, 3)
    if n_coeffs == 14:
        dist[12:] = [0.01, -0.02]
    return PinholeCamera(1100.0, 1090.0, 958.3, 541.2, 1920, 1080, dist)


@pytest.mark.parametrize("n_coeffs", [0, 4, 5, 8, 12, 14])
def test_project_matches_cv2_project_points(n_coeffs, rng):
    cam = _camera(n_coeffs, rng)
    pts = np.c_[rng.uniform(-1.5, 1.5, (2000, 2)), rng.uniform(0.5, 10.0, 2000)]
    uv, valid = cam.project(pts)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, cam.dist if n_coeffs else None)
    assert valid.all()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=PIXEL_EXACT_PX)


@pytest.mark.parametrize("n_coeffs", [0, 4, 5, 8, 12, 14])
def test_unproject_matches_converged_cv2_undistort_over_whole_image(n_coeffs, rng):
    cam = _camera(n_coeffs, rng)
    uv = cam.pixel_grid(step=7)
    rays = cam.unproject(uv)
    np.testing.assert_array_equal(rays.origins, 0.0)
    np.testing.assert_allclose(np.linalg.norm(rays.directions, axis=1), 1.0, atol=1e-12)
    xy = rays.directions[:, :2] / rays.directions[:, 2:]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ref = cv2.undistortPointsIter(
        uv.reshape(-1, 1, 2), cam.K, cam.dist if n_coeffs else None, None, None, criteria
    ).reshape(-1, 2)
    # Compare in pixels: normalised difference times the focal length.
    assert np.abs(xy - ref).max() * cam.fx < PIXEL_EXACT_PX


@pytest.mark.parametrize("n_coeffs", [0, 5, 8, 14])
def test_project_then_unproject_round_trip(n_coeffs, rng):
    cam = _camera(n_coeffs, rng)
    uv = cam.pixel_grid(step=5)
    back, valid = cam.project(cam.unproject(uv).directions * 3.0)
    assert valid.all()
    np.testing.assert_allclose(back, uv, atol=PIXEL_EXACT_PX)


def test_points_behind_camera_are_invalid():
    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    uv, valid = cam.project(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
    assert valid.tolist() == [False, True]
    assert np.isnan(uv[0]).all()
    np.testing.assert_allclose(uv[1], [320.0, 240.0])


def test_bad_parameters_raise_clear_errors():
    with pytest.raises(CameraModelError, match="coefficients"):
        PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480, np.zeros(6))
    with pytest.raises(CameraModelError, match="focal"):
        PinholeCamera(-1.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(CameraModelError, match="size"):
        PinholeCamera(500.0, 500.0, 320.0, 240.0, 0, 480)
    with pytest.raises(CameraModelError, match="skew"):
        PinholeCamera.from_K([[500, 1, 320], [0, 500, 240], [0, 0, 1]], 640, 480)
    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(GeometryError, match=r"\(N, 3\)"):
        cam.project(np.zeros((4, 2)))
    with pytest.raises(GeometryError, match=r"\(N, 2\)"):
        cam.unproject(np.zeros((4, 3)))


def test_from_K_and_with_dist_keep_every_parameter():
    K = [[1100.0, 0.0, 958.3], [0.0, 1090.0, 541.2], [0.0, 0.0, 1.0]]
    dist = [-0.1, 0.02, 1e-4, -2e-4, 0.003]
    cam = PinholeCamera.from_K(K, 1920, 1080, dist)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (1100.0, 1090.0, 958.3, 541.2)
    assert (cam.width, cam.height) == (1920, 1080)
    np.testing.assert_array_equal(cam.K, K)
    np.testing.assert_array_equal(cam.dist, dist)
    assert PinholeCamera.from_K(K, 1920, 1080).dist.size == 0
    other = cam.with_dist([0.05, -0.01, 0.0, 0.0])
    assert (other.fx, other.fy, other.cx, other.cy, other.width, other.height) == (
        1100.0, 1090.0, 958.3, 541.2, 1920, 1080)
    np.testing.assert_array_equal(other.dist, [0.05, -0.01, 0.0, 0.0])
    np.testing.assert_array_equal(cam.dist, dist)  # the original is unchanged
    with pytest.raises(CameraModelError, match=r"camera matrix must be 3x3, got shape \(2, 3\)"):
        PinholeCamera.from_K(np.zeros((2, 3)), 640, 480)
    for bad_row in ([0.0, 0.0, 2.0], [1e-3, 0.0, 1.0], [0.0, 1e-3, 1.0]):
        with pytest.raises(CameraModelError, match=r"last row \[0, 0, 1\]"):
            PinholeCamera.from_K([K[0], K[1], bad_row], 1920, 1080)


def test_rays_at_distances_per_ray_or_one_for_all():
    from sea3d.geometry.camera import Rays

    rays = Rays(origins=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
                directions=np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8]]))
    np.testing.assert_allclose(rays.at(np.array([2.0, 5.0])), [[0.0, 0.0, 2.0], [1.0, 3.0, 4.0]])
    np.testing.assert_allclose(rays.at(5.0), [[0.0, 0.0, 5.0], [1.0, 3.0, 4.0]])
    np.testing.assert_allclose(rays.at([1, 1]), [[0.0, 0.0, 1.0], [1.0, 0.6, 0.8]])
