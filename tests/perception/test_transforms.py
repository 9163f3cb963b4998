"""perception.transforms: the rigid-transform check and the device pose formats, against exact values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perception.transforms import (
    TransformError,
    X_from_ur_pose,
    X_from_xyzquat,
    X_from_xyzwpr_mm_deg,
    check_X,
    invert_X,
    look_at_X,
    make_X,
    rotate_vectors,
    rotation_angle_rad,
    transform_points,
    ur_pose_from_X,
    xyzquat_from_X,
    xyzwpr_mm_deg_from_X,
)

RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def test_check_x_accepts_a_rigid_transform_and_names_what_is_wrong() -> None:
    X = make_X(RZ90, [0.1, 0.2, 0.3])
    assert check_X(X.tolist()).dtype == np.float64 and np.array_equal(check_X(X), X)
    cases = [
        (np.eye(3), "X_a_b: expected shape (4, 4), got (3, 3)"),
        (make_X(RZ90, [np.nan, 0.0, np.inf]), "X_a_b: contains NaN or inf at [0, 3], [2, 3]"),
        (np.vstack([X[:3], [0.0, 0.0, 0.1, 1.0]]), "X_a_b: last row must be [0, 0, 0, 1], got [0.0, 0.0, 0.1, 1.0]"),
        (
            make_X(np.diag([1.0, 1.0, -1.0]), np.zeros(3)),
            "X_a_b: rotation part is a reflection (det = -1.000, must be +1)",
        ),
    ]
    for bad, message in cases:
        with pytest.raises(TransformError) as info:
            check_X(bad, name="X_a_b")
        assert str(info.value) == message
    with pytest.raises(
        TransformError, match=r"rotation part is not orthonormal \(max \|R\^T R - I\| = 2.00e-03, limit 1e-04\)"
    ):
        check_X(make_X(np.diag([1.0, 1.0, 1.001]), np.zeros(3)), name="X_a_b")
    with pytest.raises(TransformError, match="not a numeric 4x4 matrix"):
        check_X([["a"]])


def test_compose_invert_and_map_points() -> None:
    X_a_b = make_X(RZ90, [1.0, 2.0, 3.0])
    p_b = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(transform_points(X_a_b, p_b), [[1.0, 3.0, 3.0], [1.0, 2.0, 4.0]])
    np.testing.assert_array_equal(rotate_vectors(X_a_b, p_b), [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(invert_X(X_a_b) @ X_a_b, np.eye(4), atol=1e-15)
    np.testing.assert_array_equal(invert_X(X_a_b)[:3, 3], [-2.0, 1.0, -3.0])


def test_quaternions_are_scalar_last_with_a_non_negative_w() -> None:
    X = make_X(RZ90, [0.5, -0.25, 1.0])
    v = xyzquat_from_X(X)
    h = math.sqrt(0.5)
    np.testing.assert_allclose(v, [0.5, -0.25, 1.0, 0.0, 0.0, h, h], atol=1e-15)
    np.testing.assert_allclose(X_from_xyzquat(v), X, atol=1e-15)
    # the same rotation with the other sign of the quaternion gives the same pose, and w >= 0 on the way out
    np.testing.assert_allclose(X_from_xyzquat([0.5, -0.25, 1.0, 0.0, 0.0, -2 * h, -2 * h]), X, atol=1e-15)
    for R in Rotation.random(20, random_state=3).as_matrix():
        q = xyzquat_from_X(make_X(R, np.zeros(3)))[3:]
        assert q[3] >= 0.0 and np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
        np.testing.assert_allclose(X_from_xyzquat([0, 0, 0, *q])[:3, :3], R, atol=1e-15)


def test_ur_pose_is_metres_and_a_rotation_vector() -> None:
    X = make_X(RZ90, [0.4, 0.0, 0.2])
    np.testing.assert_allclose(ur_pose_from_X(X), [0.4, 0.0, 0.2, 0.0, 0.0, math.pi / 2], atol=1e-15)
    np.testing.assert_allclose(X_from_ur_pose([0.4, 0.0, 0.2, 0.0, 0.0, math.pi / 2]), X, atol=1e-15)


def test_fanuc_xyzwpr_is_millimetres_and_fixed_axis_degrees() -> None:
    # R = Rz(r) Ry(p) Rx(w): w = 90 deg alone turns y into z
    X = X_from_xyzwpr_mm_deg([100.0, -50.0, 250.0, 90.0, 0.0, 0.0])
    np.testing.assert_allclose(X[:3, 3], [0.1, -0.05, 0.25], atol=1e-15)
    np.testing.assert_allclose(X[:3, :3] @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(xyzwpr_mm_deg_from_X(make_X(RZ90, [0.001, 0, 0])), [1.0, 0, 0, 0, 0, 90.0], atol=1e-12)
    v = np.array([12.5, -3.0, 400.0, 10.0, -20.0, 30.0])
    np.testing.assert_allclose(xyzwpr_mm_deg_from_X(X_from_xyzwpr_mm_deg(v)), v, atol=1e-12)


def test_look_at_points_the_optical_axis_at_the_target_with_up_upward() -> None:
    X = look_at_X([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    np.testing.assert_allclose(X[:3, 2], [0.0, 0.0, -1.0], atol=1e-15)  # z forward, at the target
    np.testing.assert_allclose(X[:3, 1], [0.0, -1.0, 0.0], atol=1e-15)  # image y (down) is world -up
    check_X(X)
    with pytest.raises(TransformError, match="eye and target coincide"):
        look_at_X([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])
    with pytest.raises(TransformError, match="parallel to 'up'"):
        look_at_X([0.0, 0.0, 1.0], [0.0, 0.0, 0.0])


def test_rotation_angle_is_exact_near_zero_and_at_large_angles() -> None:
    assert rotation_angle_rad(np.eye(3), RZ90) == pytest.approx(math.pi / 2, abs=1e-15)
    tiny = X_from_ur_pose([0.0, 0.0, 0.0, 1e-9, 0.0, 0.0])
    assert rotation_angle_rad(np.eye(4), tiny) == pytest.approx(1e-9, rel=1e-9)
