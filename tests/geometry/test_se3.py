"""SE(3) helpers: invariants and known answers."""

import numpy as np
import pytest

from sea3d.errors import GeometryError
from sea3d.geometry.se3 import (
    R_to_quat_wxyz,
    R_to_rotvec,
    check_T,
    compose,
    invert_T,
    make_T,
    quat_wxyz_to_R,
    rotvec_to_R,
    transform_points,
)


def _random_T(rng: np.random.Generator) -> np.ndarray:
    return make_T(rotvec_to_R(rng.normal(size=3)), rng.normal(size=3))


def test_invert_times_T_is_identity(rng):
    for _ in range(20):
        T = _random_T(rng)
        np.testing.assert_allclose(invert_T(T) @ T, np.eye(4), atol=1e-12)


def test_compose_cancels_inner_frames(rng):
    T_a_b, T_b_c = _random_T(rng), _random_T(rng)
    p_c = rng.normal(size=(5, 3))
    np.testing.assert_allclose(
        transform_points(compose(T_a_b, T_b_c), p_c),
        transform_points(T_a_b, transform_points(T_b_c, p_c)),
        atol=1e-12,
    )


def test_quaternion_round_trip_is_wxyz_with_nonnegative_w(rng):
    R = rotvec_to_R(rng.normal(size=3))
    q = R_to_quat_wxyz(R)
    assert q[0] >= 0
    np.testing.assert_allclose(quat_wxyz_to_R(q), R, atol=1e-12)
    np.testing.assert_allclose(rotvec_to_R(R_to_rotvec(R)), R, atol=1e-12)


def test_quaternion_known_answer_90_deg_about_z():
    q = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(quat_wxyz_to_R(q) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)


def test_bad_transforms_are_rejected():
    with pytest.raises(GeometryError, match="4x4"):
        check_T(np.eye(3))
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(GeometryError, match="rotation"):
        check_T(bad)
    with pytest.raises(GeometryError, match="non-zero"):
        quat_wxyz_to_R([0.0, 0.0, 0.0, 0.0])
    with pytest.raises(GeometryError, match=r"\(N, 3\)"):
        transform_points(np.eye(4), np.zeros((3, 2)))


def test_look_at_points_z_at_the_target_and_y_down():
    from sea3d.geometry.se3 import look_at

    T = look_at([0.0, -2.0, 1.0], [0.0, 0.0, 1.0])
    check_T(T)
    # The target lies straight ahead on the camera's z axis, 2 m away.
    p_cam = transform_points(invert_T(T), np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(p_cam, [[0.0, 0.0, 2.0]], atol=1e-12)
    # World up (+z) appears as image up (-y).
    np.testing.assert_allclose(T[:3, 1], [0.0, 0.0, -1.0], atol=1e-12)
    with pytest.raises(GeometryError, match="parallel"):
        look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
