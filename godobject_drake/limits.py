"""Stability limits of the explicit coupling, in plain numpy (no python-control).

What the coupling and the articulated coupling check when they are built:
Drake's discrete plant applies a LeafSystem's force explicitly, so a coupled
body is integrated by symplectic Euler (docs/theory.md §1). The full
python-control models of the loop are in :mod:`godobject_drake.studies.stability`,
which re-exports them.
"""

from __future__ import annotations

import math

import numpy as np


def explicit_limit_omega_h(zeta: float) -> float:
    """Largest stable ``ωn h`` of symplectic Euler with explicit spring-damper.

    From the characteristic polynomial ``z² − (2 − κ − β) z + (1 − β)`` with
    ``κ = (ωn h)²`` and ``β = 2 ζ ωn h``: stable iff ``κ + 2β < 4`` and
    ``β < 2``, i.e. ``ωn h < 2(√(1+ζ²) − ζ)`` (≈ 1.04 at ζ = 0.7, 0.83 at ζ = 1).
    """
    return 2.0 * (math.sqrt(1.0 + zeta * zeta) - zeta)


def symplectic_euler_matrix(M, K, D, time_step: float) -> np.ndarray:
    """One step of Drake's explicit coupling in joint space: ``[q; v]⁺ = A [q; v]``.

    ``M v̇ = −K q − D v`` integrated as ``v⁺ = v + h M⁻¹(−K q − D v)``,
    ``q⁺ = q + h v⁺`` (the discrete plant with an explicit force). For a
    scalar ``M = m, K = m ωn², D = 2 ζ m ωn`` its eigenvalues are the roots
    of docs/theory.md §1's symplectic Euler polynomial.
    """
    M, K, D = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (M, K, D))
    n, h = M.shape[0], float(time_step)
    MK, MD = np.linalg.solve(M, K), np.linalg.solve(M, D)
    eye = np.eye(n)
    return np.block([[eye - h * h * MK, h * (eye - h * MD)], [-h * MK, eye - h * MD]])


def symplectic_euler_radius(M, K, D, time_step: float) -> float:
    """Spectral radius of :func:`symplectic_euler_matrix` (< 1: the explicit loop is stable)."""
    return float(np.max(np.abs(np.linalg.eigvals(symplectic_euler_matrix(M, K, D, time_step)))))


def semi_implicit_matrix(M, K, D, K_i, D_i, time_step: float) -> np.ndarray:
    """:func:`symplectic_euler_matrix` with implicit terms beside the explicit coupling: a spring
    ``K_i`` and damper ``D_i`` that the plant integrates at the step's end (SAP's contact, a FEM
    body pressed by the tool, docs/theory.md §8)::

        (M + h D_i + h² K_i) v⁺ = M v − h (K + K_i) q − h D v,   q⁺ = q + h v⁺

    With ``K_i = D_i = 0`` it is :func:`symplectic_euler_matrix`.
    """
    M, K, D, K_i, D_i = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (M, K, D, K_i, D_i))
    n, h = M.shape[0], float(time_step)
    A_hat = M + h * D_i + h * h * K_i
    S, R = np.linalg.solve(A_hat, K + K_i), np.linalg.solve(A_hat, M - h * D)
    return np.block([[np.eye(n) - h * h * S, h * R], [-h * S, R]])


def zoh_mass_damper(mass: float, damping: float, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact one-period map of ``m ẍ + b ẋ = f`` with ``f`` held: ``[x, v]⁺ = A [x, v] + B f``.

    Closed form (``a = b/m``, ``e = exp(−a T)``): ``A = [[1, (1−e)/a], [0, e]]``,
    ``B = [[(T − (1−e)/a)/b], [(1−e)/b]]``; ``b = 0`` gives ``[[T²/2m], [T/m]]``.
    """
    if not (math.isfinite(mass) and mass > 0):
        raise ValueError(f"device mass={mass!r} kg must be > 0")
    if not (math.isfinite(damping) and damping >= 0):
        raise ValueError(f"device damping={damping!r} N·s/m must be ≥ 0 (a physical damper)")
    if not (math.isfinite(period_s) and period_s > 0):
        raise ValueError(f"device period_s={period_s!r} s must be > 0")
    a = damping / mass
    if a * period_s < 1e-9:
        return np.array([[1.0, period_s], [0.0, 1.0]]), np.array([period_s**2 / (2 * mass), period_s / mass])
    e = math.exp(-a * period_s)
    one_minus_e_over_a = -math.expm1(-a * period_s) / a
    A = np.array([[1.0, one_minus_e_over_a], [0.0, e]])
    B = np.array([(period_s - one_minus_e_over_a) / damping, one_minus_e_over_a * a / damping])
    return A, B


def device_wall_matrix(
    mass: float,
    damping: float,
    period_s: float,
    kd: float,
    gamma_d: float,
    hand_k: float = 0.0,
    hand_b: float = 0.0,
) -> np.ndarray:
    """One servo period of an impedance haptic device pressing a god-object held still.

    The worst case the feedback port gives the device: the god-object stopped by a rigid
    obstacle, so the device feels ``F = −kd x − γd (x_k − x_{k−1})/T`` (the feedback port's
    spring and damper on the sampled position and its backward difference), held for one
    period ``T`` with the hand's ``−k_h x − b_h v`` on the handle (a simulated hand, 0 for
    a hand that lets go). The handle is the exact zero-order-hold map of
    ``m ẍ + b ẋ = f`` (:func:`zoh_mass_damper`). State ``[x, v, x_prev]``.
    """
    A, B = zoh_mass_damper(mass, damping, period_s)
    # the held force u = −c·[x, v, x_prev]
    c = np.array([kd + gamma_d / period_s + hand_k, hand_b, -gamma_d / period_s])
    M = np.zeros((3, 3))
    M[0, :2], M[1, :2] = A[0], A[1]
    M[:2, :] -= np.outer(B, c)
    M[2, 0] = 1.0
    return M


def device_wall_radius(mass, damping, period_s, kd, gamma_d, hand_k=0.0, hand_b=0.0) -> float:
    """Spectral radius of :func:`device_wall_matrix` (< 1: the device is stable against a wall)."""
    M = device_wall_matrix(mass, damping, period_s, kd, gamma_d, hand_k, hand_b)
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def device_wall_limit(mass, damping, period_s, gamma_d, hand_k=0.0, hand_b=0.0, rel_tol=1e-6) -> float:
    """Largest feedback stiffness ``kd`` (N/m) for which :func:`device_wall_radius` < 1.

    Bisection on ``kd > 0`` (without a hand, ``kd = 0`` leaves the free handle's marginal
    pole at 1); 0 when even a vanishing ``kd`` is unstable (``γd`` past its own limit). Near
    ``2 (b + γd)/T`` without a hand (docs/theory.md §2); the hand's damping adds to ``b``.
    """

    def stable(kd: float) -> bool:
        return device_wall_radius(mass, damping, period_s, kd, gamma_d, hand_k, hand_b) < 1.0

    lo = 1e-6 * mass / period_s**2  # far below any limit: 1e-6 of the handle's own m/T²
    if not stable(lo):
        return 0.0
    hi = 2.0 * lo
    while stable(hi):
        lo, hi = hi, 2.0 * hi
        if hi > 1e18:
            return math.inf
    while hi - lo > rel_tol * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return lo
