"""Second methods the tests hold the library against: closed forms and bisections of the theory
(docs/theory.md) that the package itself does not need, and the metrics of whole logs at once.

Each is an independent way to the number a library function computes; a test compares the two.
"""

import dataclasses
import math

import control as ct
import numpy as np

from godobject_drake.limits import explicit_limit_omega_h
from godobject_drake.metrics import SceneMetrics
from godobject_drake.studies.stability import (
    SCHEMES,
    BodyLoop,
    DeviceParams,
    bisect,
    body_spectral_radius,
    device_stiffness_limit,
    pipeline_impedance,
    spectral_radius,
)
from godobject_drake.studies.validation import HapticScenario


def stable_by_table(kappa, beta, scheme: str) -> np.ndarray:
    """Jury's conditions for each scheme, in closed form (a second method to the roots).

    docs/theory.md §1's table. Symplectic Euler needs ``β > 0`` as well as ``β < 2``
    (``|1 − β| < 1``): negative damping makes the root product ``1 − β`` exceed 1.
    """
    k, b = np.broadcast_arrays(np.asarray(kappa, float), np.asarray(beta, float))
    if scheme == "symplectic_euler":
        return (k > 0) & (b > 0) & (b < 2) & (k + 2 * b < 4)
    if scheme == "symplectic_implicit_damping":
        return (k > 0) & (b > 0) & (k < 4 + 2 * b)
    if scheme == "implicit_euler":
        return (k > 0) & (k + b > 0)
    if scheme == "explicit_euler":
        return (k > 0) & (k < b) & (b < 2 + k / 2)
    if scheme == "first_order":
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = k / b
        return (ratio > 0) & (ratio < 2)
    raise ValueError(f"unknown scheme {scheme!r}; choose one of {sorted(SCHEMES)}")


def explicit_k_crit(mass: float, zeta: float, time_step: float) -> float:
    """Coupling stiffness (N/m) at the explicit limit for gains by bandwidth ``k = m ωn², γ = 2ζ m ωn``."""
    return mass * (explicit_limit_omega_h(zeta) / time_step) ** 2


def k_crit_from_poles(mass: float, zeta: float, time_step: float, rel_tol: float = 1e-6) -> float:
    """The explicit stiffness limit found by bisection on the ``"drake"`` model's poles (free space)."""

    def stable(k: float) -> bool:
        omega = math.sqrt(k / mass)
        return body_spectral_radius(BodyLoop.by_bandwidth(mass, omega, zeta, time_step)) < 1.0

    guess = explicit_k_crit(mass, zeta, time_step)
    return bisect(stable, 0.5 * guess, 2.0 * guess, rel_tol)


def stiffness_limit_approx(dev: DeviceParams, B: float) -> float:
    """docs/theory.md's approximations: ``2(b_d+B)/T`` (no delay), ``(b_d+B)/(T(d+½))`` (delay d)."""
    if dev.delay == 0:
        return 2 * (dev.damping + B) / dev.period_s
    return (dev.damping + B) / (dev.period_s * (dev.delay + 0.5))


def rendered_impedance(
    mass: float, k: float, gamma: float, k_w: float, b_w: float, kd: float, gamma_d: float
):
    """Continuous impedance the device feels, god-object in contact: ``Zd (m s + Zw)/(m s + Zc + Zw)``.

    ``Zw = b_w + k_w/s``. Returned as a python-control transfer function
    (velocity → force); it has a pole at ``s = 0`` (the feedback spring).
    """
    s = ct.tf("s")
    Zd = (gamma_d * s + kd) / s
    return ct.minreal(
        Zd * (mass * s * s + b_w * s + k_w) / (mass * s * s + (gamma + b_w) * s + k + k_w), verbose=False
    )


def re_rendered_impedance_gamma_d0(mass, k, gamma, k_w, kd, omega) -> np.ndarray:
    """docs/theory.md's closed form of ``Re Z_env(jω)`` for ``γd = 0``, ``b_w = 0``."""
    w2 = np.asarray(omega, float) ** 2
    return -kd * gamma * (k_w - mass * w2) / (gamma**2 * w2 + (k + k_w - mass * w2) ** 2)


def max_explicit_wall_stiffness(scheme: str, mass: float, k: float, gamma: float, time_step: float) -> float:
    """Stiffest wall (N/m) the coupled body survives when the wall is integrated like the coupling.

    ``inf`` when no wall stiffness destabilises the scheme (implicit Euler;
    Drake's SAP, where contact is implicit). Found by bisection on
    :func:`spectral_radius` with ``K = k + k_w``, ``B = γ``.
    """
    m, h = mass, time_step

    def stable(k_w: float) -> bool:
        return bool(spectral_radius((k + k_w) * h * h / m, gamma * h / m, scheme) < 1.0)

    if scheme in ("implicit_euler", "drake"):
        return math.inf
    if not stable(0.0):
        return 0.0
    hi = 1.0
    while stable(hi):
        hi *= 10.0
        if hi > 1e15:
            return math.inf
    return bisect(stable, 0.0, hi, 1e-6)


def predicted_device_k_max(sc: HapticScenario, probe_mass: float = 1.0) -> float:
    """The analysis' largest stable ``kd`` (N/m) for ``sc`` (bisection on the pipeline model's poles)."""
    return device_stiffness_limit(
        sc.device, lambda kd: pipeline_impedance(dataclasses.replace(sc, kd=kd).pipeline(probe_mass))
    )


def scene_metrics(station, data: dict) -> dict:
    """:class:`SceneMetrics` of whole logs at once."""
    acc = SceneMetrics(station)
    acc.update(data)
    return acc.result()
