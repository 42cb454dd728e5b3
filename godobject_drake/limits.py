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
