"""Quaternion and rigid-motion math on plain numpy arrays.

The only module with quaternion and rotation formulas. The coupling runs once
per simulation step, so its math avoids pydrake objects (each call into the
bindings costs microseconds) and, on 3- and 4-vectors, numpy too: the
formulas are written once in plain arithmetic (:func:`quat_product`,
:func:`rotation_entries`, :func:`quat_of_rotation_entries`), which takes
Python floats on the hot path and arrays for logs; the numpy-returning
functions wrap them. Conventions follow Drake: quaternions are ``[w, x, y,
z]``, spatial vectors are ``[rotational; translational]`` and a free body's
positions are ``[qw, qx, qy, qz, x, y, z]``.
"""

from __future__ import annotations

import math

import numpy as np


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` for 3-vectors (1.1 µs; ``np.cross`` takes 16 µs on 3-vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def cross_rows(a, b) -> np.ndarray:
    """``np.cross(a, b)`` for 3-vectors or rows of them (``(..., 3)``, broadcast): the same
    products and differences, so the same bits, without ``np.cross``'s axis handling (16 µs a
    call; the implicit coupling made ~5 a step)."""
    a, b = np.asarray(a), np.asarray(b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def quat_product(a, b) -> tuple:
    """Hamilton product ``a ⊗ b`` of ``[w, x, y, z]`` quaternions, as a 4-tuple.

    Plain arithmetic, so it takes Python floats (the coupling's hot path: one
    numpy call on a 4-vector costs as much as the whole product) or equal-length
    arrays (one product per element).
    """
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_multiply(a, b) -> np.ndarray:
    """:func:`quat_product` as a numpy 4-vector."""
    return np.array(quat_product(a, b))


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion)."""
    return np.array([q[0], -q[1], -q[2], -q[3]])


def rotation_entries(w, x, y, z) -> tuple:
    """The rotation matrix of the unit quaternion ``[w, x, y, z]``, row-major, as a 9-tuple.

    Floats (the hot path) or arrays of quaternions (one matrix per element, for logs).
    """
    return (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )  # fmt: skip


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``[w, x, y, z]``."""
    return np.array(rotation_entries(*q)).reshape(3, 3)


def quats_to_rotations(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` of unit quaternions ``(N, 4)`` ``[w, x, y, z]``."""
    q = np.asarray(q, dtype=float)
    return np.stack(rotation_entries(*q.T), axis=-1).reshape(len(q), 3, 3)


def rotation_vector_between(q_target, q_current) -> tuple:
    """``α u`` of ``q_target ⊗ q_current⁻¹`` on float 4-tuples (the coupling's hot path).

    Same definition as :func:`rotation_error`, in Python floats. The two agree to the
    last bit or two: ``math.atan2`` and ``numpy.arctan2`` round differently for about
    one input in twenty. Each caller keeps the one it has always used, so no
    trajectory changes in its last bits.
    """
    qT, qG = q_target, q_current
    e = quat_product(qT, (qG[0], -qG[1], -qG[2], -qG[3]))
    if e[0] < 0.0:
        e = (-e[0], -e[1], -e[2], -e[3])
    s = math.sqrt(e[1] * e[1] + e[2] * e[2] + e[3] * e[3])
    k = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, e[0]) / s
    return (k * e[1], k * e[2], k * e[3])


def rotation_error(q_target: np.ndarray, q_current: np.ndarray) -> np.ndarray:
    """Axis-angle vector ``α u`` of ``q_target ⊗ q_current⁻¹`` (paper Eq. 2).

    The error is taken the short way, ``α ∈ [0, π]``, and is expressed in the
    frame the quaternions are measured in (the world, for poses ``R_WB``).
    Near ``α = π`` the axis flips with the sign of the error's scalar part,
    so a 179° error and a 181° error turn opposite ways.
    """
    e = quat_multiply(q_target, quat_conjugate(q_current))
    if e[0] < 0.0:
        e = -e
    s = np.sqrt(e[1] * e[1] + e[2] * e[2] + e[3] * e[3])
    if s < 1e-12:
        # α ≈ 2 s, u ≈ v / s, so α u ≈ 2 v (exact to O(s³)).
        return 2.0 * e[1:]
    alpha = 2.0 * np.arctan2(s, e[0])
    return (alpha / s) * e[1:]


def normalized_quaternion(q, *, what: str, tolerance: float = 1e-3) -> np.ndarray:
    """Return ``q / |q|``; raise if ``q`` is not finite or not near unit norm.

    Parameters
    ----------
    q : array_like
        Quaternion ``[w, x, y, z]``.
    what : str
        Where the quaternion came from, quoted in the error.
    tolerance : float
        Allowed ``| |q| - 1 |`` before refusing, dimensionless.
    """
    q = np.asarray(q, dtype=float).reshape(4)
    norm = float(np.linalg.norm(q))
    if not np.all(np.isfinite(q)) or abs(norm - 1.0) > tolerance:
        raise ValueError(
            f"{what}: quaternion {q.tolist()} has norm {norm:.6g}; expected 1 within "
            f"{tolerance:g}. Give a unit quaternion [qw, qx, qy, qz] (normalise it)."
        )
    return q / norm


def quat_of_rotation_entries(R) -> tuple:
    """``[w, x, y, z]`` (w ≥ 0) of a row-major 9-tuple rotation, as a 4-tuple (Shepperd's method)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R
    tr = r00 + r11 + r22
    if tr > 0.0:
        t = 2.0 * math.sqrt(1.0 + tr)
        q = (0.25 * t, (r21 - r12) / t, (r02 - r20) / t, (r10 - r01) / t)
    elif r00 > r11 and r00 > r22:
        t = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        q = ((r21 - r12) / t, 0.25 * t, (r01 + r10) / t, (r02 + r20) / t)
    elif r11 > r22:
        t = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        q = ((r02 - r20) / t, (r01 + r10) / t, 0.25 * t, (r12 + r21) / t)
    else:
        t = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        q = ((r10 - r01) / t, (r02 + r20) / t, (r12 + r21) / t, 0.25 * t)
    return q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def rotation_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[w,x,y,z]`` (w ≥ 0) of a rotation matrix (Shepperd's method)."""
    return np.array(quat_of_rotation_entries(np.asarray(R, dtype=float).ravel().tolist()))


def pose_arrays(X) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(q [w,x,y,z], p, R)`` of a ``RigidTransform`` with one binding call."""
    M = X.GetAsMatrix34()
    R = M[:, :3]
    return rotation_to_quat(R), M[:, 3].copy(), R


def pose_from_array(x: np.ndarray):
    """A ``RigidTransform`` from ``[qw qx qy qz x y z]`` (the logged pose layout)."""
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RigidTransform

    return RigidTransform(Quaternion(x[:4] / np.linalg.norm(x[:4])), x[4:])
