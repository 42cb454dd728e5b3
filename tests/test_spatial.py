"""Quaternion math against hand values and against Drake's own conversions."""

import numpy as np
import pytest
from pydrake.common.eigen_geometry import AngleAxis, Quaternion
from pydrake.math import RotationMatrix

from godobject_drake.spatial import (
    cross3,
    normalized_quaternion,
    pose_from_array,
    quat_multiply,
    quat_of_rotation_entries,
    quat_product,
    quat_to_rotation,
    quats_to_rotations,
    rotation_error,
    rotation_to_quat,
    rotation_vector_between,
)


def q_about_z(deg):
    a = np.radians(deg)
    return np.array([np.cos(a / 2), 0, 0, np.sin(a / 2)])


def test_ninety_degrees_about_z():
    np.testing.assert_allclose(rotation_error(q_about_z(90), [1, 0, 0, 0]), [0, 0, np.pi / 2], atol=1e-12)


def test_179_and_181_degrees_turn_opposite_ways():
    e179 = rotation_error(q_about_z(179), [1, 0, 0, 0])
    e181 = rotation_error(q_about_z(181), [1, 0, 0, 0])
    np.testing.assert_allclose(e179, [0, 0, np.radians(179)], atol=1e-12)
    np.testing.assert_allclose(e181, [0, 0, -np.radians(179)], atol=1e-12)  # short way: 179° about −z


def test_sign_of_quaternion_does_not_matter():
    q = q_about_z(120)
    np.testing.assert_allclose(rotation_error(q, [1, 0, 0, 0]), rotation_error(-q, [1, 0, 0, 0]), atol=1e-12)


def test_tiny_error_is_continuous():
    np.testing.assert_allclose(
        rotation_error(q_about_z(1e-9), [1, 0, 0, 0]), [0, 0, np.radians(1e-9)], rtol=1e-6
    )


@pytest.mark.parametrize("seed", range(5))
def test_against_drake(seed):
    rng = np.random.default_rng(seed)
    qa, qb = (q / np.linalg.norm(q) for q in rng.standard_normal((2, 4)))
    Ra, Rb = RotationMatrix(Quaternion(qa)), RotationMatrix(Quaternion(qb))
    np.testing.assert_allclose(quat_to_rotation(qa), Ra.matrix(), atol=1e-12)
    np.testing.assert_allclose(quat_to_rotation(quat_multiply(qa, qb)), Ra.multiply(Rb).matrix(), atol=1e-12)
    R_err = Ra.multiply(Rb.inverse())  # error expressed in the world, as the coupling uses it
    aa = AngleAxis(R_err.matrix())
    np.testing.assert_allclose(rotation_error(qa, qb), aa.angle() * aa.axis(), atol=1e-9)
    q = rotation_to_quat(Ra.matrix())
    np.testing.assert_allclose(q * np.sign(qa[0]), qa, atol=1e-12)


def test_cross3_matches_numpy():
    a, b = np.array([0.3, -1.2, 2.0]), np.array([-0.7, 0.1, 0.4])
    np.testing.assert_array_equal(cross3(a, b), np.cross(a, b))


def test_float_and_array_forms_are_the_same_formulas():
    """The hot path's float tuples, the numpy wrappers and the per-log arrays give the same numbers."""
    rng = np.random.default_rng(11)
    q = rng.standard_normal((500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = quats_to_rotations(q)
    for i in range(len(q)):
        np.testing.assert_array_equal(R[i], quat_to_rotation(q[i]))  # same expressions: bit for bit
        np.testing.assert_array_equal(rotation_to_quat(R[i]), quat_of_rotation_entries(R[i].ravel().tolist()))
        a, b = q[i].tolist(), q[i - 1].tolist()
        np.testing.assert_array_equal(quat_multiply(q[i], q[i - 1]), quat_product(a, b))
        # libm's atan2 and numpy's arctan2 may differ in the last bit: a few ulps of π at most.
        np.testing.assert_allclose(
            rotation_vector_between(a, b), rotation_error(q[i], q[i - 1]), rtol=0, atol=4e-15
        )


@pytest.mark.parametrize("axis", [[1, 0.2, -0.1], [0.1, -1, 0.3], [-0.2, 0.1, 1], [1, 1, 1]])
@pytest.mark.parametrize("degrees", [30, 120, 170, 180])
def test_rotation_to_quat_in_every_branch_of_shepperds_method(axis, degrees):
    """Past 90° or so the trace is ≤ 0 and the largest diagonal entry (x, y or z) picks the
    formula: each branch is checked against Drake's own conversion, with w ≥ 0."""
    R = RotationMatrix(AngleAxis(np.radians(degrees), np.array(axis) / np.linalg.norm(axis)))
    expected = R.ToQuaternion().wxyz()  # ± q: one rotation
    q = rotation_to_quat(R.matrix())
    assert q[0] >= 0.0
    np.testing.assert_allclose(q if np.dot(q, expected) >= 0 else -q, expected, atol=2e-15)
    np.testing.assert_allclose(quat_to_rotation(q), R.matrix(), atol=4e-15)


def test_a_half_turn_error_is_pi_about_the_vector_part():
    """q_target ⊗ q_current⁻¹ = (0, 0, 0, 1) exactly: s = 1, α = 2 atan2(1, 0) = π, about +z as
    given (a scalar part of exactly 0 is not flipped: only a negative one is)."""
    half_turn = np.array([0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(rotation_error(half_turn, [1, 0, 0, 0]), [0, 0, np.pi], atol=1e-15)
    np.testing.assert_allclose(rotation_vector_between(half_turn, (1, 0, 0, 0)), [0, 0, np.pi], atol=1e-15)


def test_an_error_below_the_tiny_threshold_is_twice_the_vector_part():
    """Below s = 1e-12 the error is 2 v (α ≈ 2 s): a 1e-13 rad turn gives 1e-13 rad, not 0 or 1.5e-13."""
    for f in (rotation_error, rotation_vector_between):
        np.testing.assert_allclose(
            f(q_about_z(np.degrees(1e-13)), (1.0, 0.0, 0.0, 0.0)), [0, 0, 1e-13], rtol=1e-9
        )


def test_normalized_quaternion_divides_by_the_norm_and_refuses_past_the_tolerance():
    np.testing.assert_allclose(
        normalized_quaternion([0, 0, 0, 1.0008], what="x"), [0, 0, 0, 1], rtol=0, atol=0
    )
    assert normalized_quaternion([[1.5, 0, 0, 0]], what="x", tolerance=0.5).shape == (
        4,
    )  # |q| − 1 = tolerance: ok
    with pytest.raises(
        ValueError,
        match=r"^waypoint 3: quaternion \[1\.002, 0\.0, 0\.0, 0\.0\] has norm 1\.002; "
        r"expected 1 within 0\.001\. Give a unit quaternion \[qw, qx, qy, qz\] \(normalise it\)\.$",
    ):
        normalized_quaternion([1.002, 0, 0, 0], what="waypoint 3")
    with pytest.raises(ValueError, match="norm nan"):
        normalized_quaternion([np.nan, 0, 0, 1], what="x")
    with pytest.raises(ValueError, match=r"has norm inf"):
        normalized_quaternion([np.inf, 0, 0, 0], what="x", tolerance=np.inf)


def test_pose_from_array_is_the_logged_pose():
    a = np.radians(40)
    X = pose_from_array(np.array([2 * np.cos(a / 2), 0, 2 * np.sin(a / 2), 0, 0.1, -0.2, 0.3]))
    np.testing.assert_allclose(X.rotation().matrix(), RotationMatrix.MakeYRotation(a).matrix(), atol=1e-15)
    np.testing.assert_array_equal(X.translation(), [0.1, -0.2, 0.3])


def test_cross_rows_is_numpys_cross_to_the_bit():
    """The implicit coupling's cross products (``cross_rows``) against ``np.cross`` (a second
    method): the same bits for 3-vectors, rows, and a vector broadcast against rows."""
    from godobject_drake.spatial import cross_rows

    rng = np.random.default_rng(7)
    for sa, sb in (((3,), (3,)), ((6, 3), (6, 3)), ((3,), (5, 3)), ((4, 3), (3,))):
        a, b = rng.normal(size=sa), rng.normal(size=sb)
        assert np.array_equal(cross_rows(a, b), np.cross(a, b))
