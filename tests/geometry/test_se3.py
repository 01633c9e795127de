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


def test_check_T_accepts_rounding_and_refuses_what_is_not_rigid(rng):
    T = _random_T(rng)
    # Rounding of a few 1e-9 (a transform read from text, composed a few times) is fine ...
    noisy = T + np.r_[rng.normal(0.0, 2e-9, (3, 4)), np.zeros((1, 4))]
    np.testing.assert_array_equal(check_T(noisy, "T_a_b"), noisy)
    assert check_T(T.tolist()).dtype == np.float64
    # ... a mirror, a scaled rotation, a bad last row, NaN are not, and the message says which.
    mirror = T.copy()
    mirror[:3, 0] *= -1.0
    with pytest.raises(GeometryError, match="T_a_b's rotation block is not a proper rotation"):
        check_T(mirror, "T_a_b")
    with pytest.raises(GeometryError, match="rotation"):
        check_T(make_T(1.001 * T[:3, :3], T[:3, 3]))
    last = T.copy()
    last[3, 2] = 0.1
    with pytest.raises(GeometryError, match=r"T must end with the row \[0, 0, 0, 1\], got"):
        check_T(last)
    bad = T.copy()
    bad[1, 3] = np.nan
    with pytest.raises(GeometryError, match="T has non-finite values"):
        check_T(bad)


def test_make_T_places_R_and_t_and_refuses_other_shapes():
    R = rotvec_to_R([0.1, -0.2, 0.3])
    T = make_T(R, [[1.0], [2.0], [3.0]])
    np.testing.assert_array_equal(T[:3, :3], R)
    np.testing.assert_array_equal(T[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(GeometryError, match=r"make_T needs R \(3, 3\) and t \(3,\)"):
        make_T(R, [1.0, 2.0])
    with pytest.raises(GeometryError, match="make_T needs"):
        make_T(np.eye(2), [1.0, 2.0, 3.0])
    with pytest.raises(GeometryError, match="invert_T needs a 4x4 matrix"):
        invert_T(np.eye(3))


def test_compose_of_none_one_and_three_transforms(rng):
    A, B, C = (_random_T(rng) for _ in range(3))
    np.testing.assert_array_equal(compose(), np.eye(4))
    np.testing.assert_allclose(compose(A), A, atol=0)
    np.testing.assert_allclose(compose(A.tolist(), B, C), A @ B @ C, atol=1e-12)
    np.testing.assert_allclose(invert_T(compose(A, B)), invert_T(B) @ invert_T(A), atol=1e-12)


# Conversions through scipy and one 3x3 product: float64 rounding, a few 1e-16 per element.
ROUNDING = 1e-12
# check_T's stated tolerance (se3._ORTHO_TOL, its docstring): 1e-6 on the last row and on R^T R.
CHECK_T_TOL = 1e-6


def test_quaternions_of_many_rotations_are_unit_with_nonnegative_w_and_batch_safe():
    # scipy returns w < 0 for about 40 % of rotations: every one must be flipped to w >= 0,
    # stay unit length, and map back to its rotation, in a batch as one by one.
    R = rotvec_to_R(np.random.default_rng(7).normal(size=(200, 3)))
    q = R_to_quat_wxyz(R)
    assert q.shape == (200, 4) and (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=ROUNDING)
    np.testing.assert_allclose(quat_wxyz_to_R(q), R, atol=ROUNDING)
    np.testing.assert_allclose(R_to_quat_wxyz(R[17]), q[17], atol=ROUNDING)
    np.testing.assert_allclose(quat_wxyz_to_R(q[17]), R[17], atol=ROUNDING)
    # Known answers: 180 degrees about x is (0, 1, 0, 0) (w = 0 exactly: not flipped), and
    # a quaternion is normalised before use.
    np.testing.assert_allclose(R_to_quat_wxyz(np.diag([1.0, -1.0, -1.0])), [0.0, 1.0, 0.0, 0.0],
                               atol=ROUNDING)
    np.testing.assert_allclose(quat_wxyz_to_R([2.0, 0.0, 0.0, 0.0]), np.eye(3), atol=ROUNDING)


def test_quaternion_errors_name_the_problem_per_row():
    # One zero quaternion in a batch of good ones is refused (not hidden by the batch's norm).
    with pytest.raises(GeometryError, match=r"^quaternion must be finite and non-zero$"):
        quat_wxyz_to_R([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    with pytest.raises(GeometryError, match="finite"):
        quat_wxyz_to_R([np.nan, 0.0, 0.0, 1.0])
    with pytest.raises(GeometryError, match=r"^a wxyz quaternion needs 4 values, got shape \(3,\)"):
        quat_wxyz_to_R([1.0, 0.0, 0.0])


def test_look_at_is_a_rotation_for_any_distance_and_accepts_column_vectors():
    from sea3d.geometry.se3 import look_at

    # 7 m away and off-axis: the x axis must be normalised after the cross product.
    T = look_at([[3.0], [-6.0], [2.0]], [[0.5], [0.5], [0.0]], up=[[0.0], [0.0], [1.0]])
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=ROUNDING)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=ROUNDING)
    np.testing.assert_allclose(T[:3, 3], [3.0, -6.0, 2.0], atol=0)
    z = np.array([0.5 - 3.0, 0.5 + 6.0, -2.0])
    np.testing.assert_allclose(R[:, 2], z / np.linalg.norm(z), atol=ROUNDING)
    with pytest.raises(GeometryError, match=r"^look_at: eye and target coincide$"):
        look_at([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    with pytest.raises(GeometryError, match=r"^look_at: view direction is parallel to up$"):
        look_at([0.0, 0.0, 0.0], [0.0, 0.0, -2.0])


def test_check_T_tolerance_is_the_documented_one(rng):
    T = _random_T(rng)
    # Inside 1e-6 (half of it) on the last row and on R^T R: accepted; four times it: refused.
    for scale, ok in ((0.5, True), (4.0, False)):
        row = T.copy()
        row[3, 0] = scale * CHECK_T_TOL
        skew = T.copy()
        E = np.zeros((3, 3))
        E[0, 1] = E[1, 0] = 0.5 * scale * CHECK_T_TOL
        skew[:3, :3] = T[:3, :3] @ (np.eye(3) + 0.5 * E)  # R^T R = I + E + E^2 / 4
        for M, what in ((row, "row"), (skew, "rotation")):
            if ok:
                np.testing.assert_array_equal(check_T(M), M)
            else:
                with pytest.raises(GeometryError, match=what):
                    check_T(M)


def test_transform_points_refuses_a_3x4_transform():
    # A 3x4 [R | t] would slice fine and give plausible numbers: it must be refused.
    with pytest.raises(GeometryError, match=r"T \(4, 4\) and points \(N, 3\), got \(3, 4\)"):
        transform_points(np.eye(4)[:3], np.zeros((5, 3)))
    with pytest.raises(GeometryError, match="transform_points needs"):
        transform_points(np.eye(4), np.zeros(3))
