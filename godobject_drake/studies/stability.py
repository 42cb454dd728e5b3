"""Stability and passivity of the god-object loop (python-control models).

Two halves, as in ``docs/theory.md``:

*Simulation side* — the coupled body. One degree of freedom of the held body
(mass ``m``) is pulled to its target by the coupling ``(k, γ)`` and pushed by
a wall ``(k_w, b_w)``; a discrete integrator at step ``h`` advances it. With
``K = k + k_w``, ``B = γ + b_w``, ``κ = K h²/m`` and ``β = B h/m`` each scheme
has a quadratic characteristic polynomial (:func:`characteristic_polynomial`).
:func:`coupled_body_model` builds the same schemes as python-control state
space models with an explicit/implicit split of the forces; the one Drake
runs is ``"drake"``: the coupling explicit (a LeafSystem's force into
``applied_spatial_force``), SAP contact implicit.

*Device side* — the haptic loop. A device of mass ``m_d`` and physical damping
``b_d`` is sampled at period ``T`` and driven by a zero-order-held force
(:func:`device_model`, exact ZOH). The virtual side is a position→force map
``H(z)`` (a wall, :func:`wall_impedance`, or the whole pipeline device →
god-object → wall → feedback port, :func:`pipeline_impedance`). On it:
Colgate's required device damping (:func:`colgate_required_damping`), the
closed-loop poles and the stiffness limit (:func:`device_closed_loop`,
:func:`device_stiffness_limit`), the human-port admittance and python-control's
passivity test (:func:`human_port_admittance`, :func:`passivity_check`), and
Llewellyn's absolute stability of the continuous two-port
(:func:`llewellyn_eta`).

Sign conventions: ``H`` gives the force that *resists* the device,
``m_d ẍ + b_d ẋ = F_h − H x``; the feedback port's ``F_Do_W`` is ``−H x``.
All quantities SI.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import control as ct
import numpy as np

from godobject_drake.limits import explicit_limit_omega_h as explicit_limit_omega_h
from godobject_drake.limits import symplectic_euler_matrix as symplectic_euler_matrix
from godobject_drake.limits import symplectic_euler_radius as symplectic_euler_radius

# -- simulation side -------------------------------------------------------------------------------------

SCHEMES = {
    "symplectic_euler": "symplectic Euler, forces explicit (Drake discrete plant + external force)",
    "symplectic_implicit_damping": "symplectic Euler, damping implicit",
    "implicit_euler": "backward (implicit) Euler (the paper's integrator)",
    "explicit_euler": "explicit Euler",
    "first_order": "first-order (kinematic) coupling, explicit Euler (the paper's rejected footnote)",
}


def characteristic_polynomial(kappa, beta, scheme: str) -> np.ndarray:
    """Coefficients ``[a2, a1, a0]`` of the coupled body's characteristic polynomial.

    ``kappa = K h²/m``, ``beta = B h/m`` (arrays broadcast). For
    ``"first_order"`` (``m_v ẋ = F`` with the damping γ as the viscous mass,
    explicit Euler: ``x⁺ = x − (K h/B) x``) the polynomial is ``z − (1 − κ/β)``,
    returned as ``[0, 1, −(1 − κ/β)]``.
    """
    kappa, beta = np.broadcast_arrays(np.asarray(kappa, float), np.asarray(beta, float))
    one, zero = np.ones_like(kappa), np.zeros_like(kappa)
    if scheme == "symplectic_euler":
        coeffs = (one, -(2 - kappa - beta), 1 - beta)
    elif scheme == "symplectic_implicit_damping":
        coeffs = (1 + beta, -(2 + beta - kappa), one)
    elif scheme == "implicit_euler":
        coeffs = (1 + beta + kappa, -(2 + beta), one)
    elif scheme == "explicit_euler":
        coeffs = (one, -(2 - beta), 1 - beta + kappa)
    elif scheme == "first_order":
        with np.errstate(divide="ignore", invalid="ignore"):
            coeffs = (zero, one, -(1 - kappa / beta))
    else:
        raise ValueError(f"unknown scheme {scheme!r}; choose one of {sorted(SCHEMES)}")
    return np.stack(coeffs, axis=-1)


def spectral_radius(kappa, beta, scheme: str) -> np.ndarray:
    """Largest root modulus of :func:`characteristic_polynomial` (vectorised, closed-form roots)."""
    c = characteristic_polynomial(kappa, beta, scheme)
    a2, a1, a0 = c[..., 0], c[..., 1], c[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        if scheme == "first_order":
            return np.abs(-a0 / a1)
        disc = np.sqrt((a1 * a1 - 4 * a2 * a0).astype(complex))
        r1, r2 = (-a1 + disc) / (2 * a2), (-a1 - disc) / (2 * a2)
    return np.maximum(np.abs(r1), np.abs(r2))


def explicit_h_max(mass: float, K: float, B: float) -> float:
    """Largest step (s) for symplectic Euler with explicit ``(K, B)``: ``(√(B² + 4mK) − B)/K``.

    Also needs ``β = B h/m < 2``; the returned step satisfies it whenever it
    satisfies ``κ + 2β < 4``.
    """
    _positive(mass=mass, K=K)
    return (math.sqrt(B * B + 4 * mass * K) - B) / K


def explicit_min_mass(K: float, B: float, time_step: float) -> float:
    """Smallest mass (kg) that symplectic Euler integrates stably with explicit ``(K, B)`` at ``h``.

    ``m > (K h² + 2 B h)/4`` (from ``κ + 2β < 4``; ``β < 2`` then holds too).
    """
    return (K * time_step**2 + 2 * B * time_step) / 4.0


def _positive(**values: float) -> None:
    for name, v in values.items():
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name}={v!r} must be a positive finite number (SI units)")


@dataclasses.dataclass(frozen=True)
class BodyLoop:
    """One degree of freedom of a held body: coupling, wall and integration split.

    Attributes
    ----------
    mass : float
        Body mass (kg), or the inertia (kg·m²) for a rotational degree of freedom.
    k, gamma : float
        Coupling stiffness (N/m) and damping (N·s/m).
    k_w, b_w : float
        Wall (contact) stiffness (N/m) and damping (N·s/m); 0 in free space.
    time_step : float
        Integration step h (s).
    scheme : str
        ``"drake"`` (coupling explicit, contact implicit: SAP), or one of
        :data:`SCHEMES` except ``"first_order"`` (then coupling and wall share it).
    """

    mass: float
    k: float
    gamma: float
    time_step: float
    k_w: float = 0.0
    b_w: float = 0.0
    scheme: str = "drake"

    @classmethod
    def by_bandwidth(cls, mass: float, omega_n: float, zeta: float, time_step: float, **kw) -> BodyLoop:
        """The coupling of
        :class:`~godobject_drake.config.gains.CouplingGains`: ``k = m ωn²``, ``γ = 2ζmωn``."""
        return cls(mass, mass * omega_n**2, 2 * zeta * mass * omega_n, time_step, **kw)

    def split(self) -> tuple[float, float, float, float]:
        """``(K_explicit, B_explicit, K_implicit, B_implicit)`` for this scheme."""
        K, B = self.k + self.k_w, self.gamma + self.b_w
        return {
            "drake": (self.k, self.gamma, self.k_w, self.b_w),
            "symplectic_euler": (K, B, 0.0, 0.0),
            "symplectic_implicit_damping": (K, 0.0, 0.0, B),
            "implicit_euler": (0.0, 0.0, K, B),
        }[self.scheme]


def coupled_body_matrices(loop: BodyLoop) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of one step, state ``[x, v]``, input ``[x_t, v_t]`` (target position and velocity).

    Semi-implicit step: explicit forces ``−K_e x − B_e v`` at ``n``, implicit
    ones ``−K_i x⁺ − B_i v⁺`` at ``n+1``, ``x⁺ = x + h v⁺`` (:meth:`BodyLoop.split`)::

        (m + h B_i + h² K_i) v⁺ = m v − h (K_e + K_i) x − h B_e v + h (k x_t + γ v_t)

    The target is held over the step, so its terms are the same at ``n`` and
    ``n+1``. For ``"drake"`` this is SAP's point-contact law (measured:
    ``f = k_w x⁺ + k_w τ v⁺`` with ``b_w = k_w τ``, outside SAP's near-rigid
    regime). Explicit Euler (``x⁺ = x + h v``) is handled apart.
    """
    m, h = loop.mass, loop.time_step
    _positive(mass=m, time_step=h)
    K, B = loop.k + loop.k_w, loop.gamma + loop.b_w
    if loop.scheme == "explicit_euler":
        A = np.array([[1.0, h], [-h * K / m, 1.0 - h * B / m]])
        Bu = np.array([[0.0, 0.0], [h * loop.k / m, h * loop.gamma / m]])
        return A, Bu
    if loop.scheme not in ("drake", "symplectic_euler", "symplectic_implicit_damping", "implicit_euler"):
        raise ValueError(
            f"scheme {loop.scheme!r} has no second-order body model; use 'drake' or one of "
            f"{sorted(set(SCHEMES) - {'first_order'})}"
        )
    Ke, Be, Ki, Bi = loop.split()
    den = m + h * Bi + h * h * Ki
    a_vx = -h * (Ke + Ki) / den
    a_vv = (m - h * Be) / den
    b_vx, b_vv = h * loop.k / den, h * loop.gamma / den
    A = np.array([[1.0 + h * a_vx, h * a_vv], [a_vx, a_vv]])
    Bu = np.array([[h * b_vx, h * b_vv], [b_vx, b_vv]])
    return A, Bu


def coupled_body_model(loop: BodyLoop) -> ct.StateSpace:
    """python-control model (``dt = h``): target ``[x_t, v_t]`` → body ``[x, v]``."""
    A, Bu = coupled_body_matrices(loop)
    return ct.ss(A, Bu, np.eye(2), np.zeros((2, 2)), dt=loop.time_step, name=f"body_{loop.scheme}")


def body_spectral_radius(loop: BodyLoop) -> float:
    """Largest pole modulus of :func:`coupled_body_model` (< 1: stable)."""
    return float(np.max(np.abs(coupled_body_model(loop).poles())))


def bisect(is_stable: Callable[[float], bool], lo: float, hi: float, rel_tol: float = 1e-4) -> float:
    """Boundary of a monotone stability predicate: ``is_stable(lo)`` and not ``is_stable(hi)``."""
    if not is_stable(lo):
        raise ValueError(f"bisection needs a stable lower bound; {lo:g} is already unstable")
    if is_stable(hi):
        raise ValueError(f"bisection needs an unstable upper bound; {hi:g} is still stable")
    while hi - lo > rel_tol * hi:
        mid = math.sqrt(lo * hi) if lo > 0 else 0.5 * (lo + hi)
        if is_stable(mid):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclasses.dataclass(frozen=True)
class GainRecommendation:
    """Recommended coupling gains for one body at one step (see :func:`recommend_gains`)."""

    body: str
    mass: float
    inertia: tuple[float, float, float]
    time_step: float
    zeta: float
    omega_n_max: float
    omega_n: float
    k: float
    gamma: float
    omega_n_rot: float
    k_rot: tuple[float, float, float]
    gamma_rot: tuple[float, float, float]
    min_mass_explicit_contact: float

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def recommend_gains(
    body: str,
    mass: float,
    inertia: tuple[float, float, float],
    time_step: float,
    zeta: float = 1.0,
    safety: float = 0.5,
    rot_ratio: float = 3.0,
    device_rate_hz: float | None = 60.0,
    contact_stiffness: float = 0.0,
) -> GainRecommendation:
    """Gains for a body: a ``safety`` fraction of the explicit limit, no faster than the device.

    Rule: the rotational bandwidth is ``rot_ratio`` times the translational
    one (the brick scene's choice: the issue-2 note measured less tumbling at
    ``3ωn``); the faster of the two stays below ``safety · 2(√(1+ζ²)−ζ)/h``;
    the translational one also stays below the device's Nyquist rate
    ``π f`` (rad/s), past which the god-object only follows the sampling steps.
    The gains do not depend on the mass (they scale with it), so every body
    gets the same ``ωn``; ``k``, ``γ``, ``k_rot``, ``γ_rot`` are per body.
    ``min_mass_explicit_contact`` is the mass below which the scene's
    ``contact_stiffness`` would be unstable if contact were explicit
    (``K h²/4``): it is why SAP's implicit contact matters for light bodies.
    """
    limit = explicit_limit_omega_h(zeta) / time_step
    w_cap = safety * limit
    w = w_cap / max(rot_ratio, 1.0)
    if device_rate_hz:
        w = min(w, math.pi * device_rate_hz)
    w_rot = rot_ratio * w
    inertia = tuple(float(i) for i in inertia)
    return GainRecommendation(
        body=body,
        mass=mass,
        inertia=inertia,
        time_step=time_step,
        zeta=zeta,
        omega_n_max=limit,
        omega_n=w,
        k=mass * w * w,
        gamma=2 * zeta * mass * w,
        omega_n_rot=w_rot,
        k_rot=tuple(i * w_rot**2 for i in inertia),
        gamma_rot=tuple(2 * zeta * i * w_rot for i in inertia),
        min_mass_explicit_contact=explicit_min_mass(contact_stiffness, 0.0, time_step),
    )


# -- device side -----------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DeviceParams:
    """A 1-DoF impedance-type haptic device (per axis).

    Attributes
    ----------
    mass : float
        Moving mass m_d (kg).
    damping : float
        Physical (viscous) damping b_d (N·s/m).
    period_s : float
        Servo period T (s): position sampled, force zero-order held.
    delay : int
        Force delay in samples d.
    """

    mass: float = 0.1
    damping: float = 1.0
    period_s: float = 1e-3
    delay: int = 0

    def __post_init__(self):
        _positive(mass=self.mass, period_s=self.period_s)
        if not (math.isfinite(self.damping) and self.damping >= 0):
            raise ValueError(f"device damping={self.damping!r} N·s/m must be ≥ 0")
        if int(self.delay) != self.delay or self.delay < 0:
            raise ValueError(f"device delay={self.delay!r} must be a whole number of samples ≥ 0")


def device_model(dev: DeviceParams) -> ct.StateSpace:
    """Exact ZOH discretisation (``c2d``) of ``1/(m_d s² + b_d s)``: held force → sampled position.

    State ``[x, v]``, ``dt = T``. The delay is not included (it sits in ``H``).
    """
    sys_c = ct.ss([[0.0, 1.0], [0.0, -dev.damping / dev.mass]], [[0.0], [1.0 / dev.mass]], [[1.0, 0.0]], 0.0)
    return ct.c2d(sys_c, dev.period_s, method="zoh")


def delay_tf(d: int, dt: float) -> ct.TransferFunction:
    """``z^−d`` as a discrete transfer function."""
    return ct.tf([1.0], [1.0] + [0.0] * int(d), dt)


def wall_impedance(K: float, B: float, T: float, delay: int = 0) -> ct.TransferFunction:
    """A virtual wall ``H(z) = (K + B (1 − z⁻¹)/T) z^−d`` (position → resisting force)."""
    H = ct.tf([K + B / T, -B / T], [1.0, 0.0], T)
    return H * delay_tf(delay, T) if delay else H


@dataclasses.dataclass(frozen=True)
class Pipeline:
    """The virtual side a device feels: feedback port on a god-object held by a wall.

    The god-object (``body``, integrated as Drake does at ``body.time_step``)
    follows the device's sampled position ``x_k`` and its backward-difference
    velocity; the feedback port gives ``F = kd (x_g − x_d) + γd (v_g − v_d)``
    at each device sample; the device holds it for ``T`` after ``delay``
    samples. ``T`` must be a whole multiple of ``h`` (the god-object takes
    ``T/h`` steps per device sample, target held).

    ``reads_post_step``: which god-object state the device's update sees.
    Measured in Drake 1.51.1: with ``MultibodyPlantConfig.use_sampled_output_ports``
    true (the default), a discrete system that reads the plant's state at a
    plant step time sees the state *after* that step (``x_g`` one step of
    ``h`` later); with it false, the state before. The coupling's force, a
    feedthrough into the plant, always sees the state before.
    """

    body: BodyLoop
    kd: float
    gamma_d: float
    period_s: float
    delay: int = 0
    reads_post_step: bool = True

    def substeps(self) -> int:
        n = self.period_s / self.body.time_step
        if abs(n - round(n)) > 1e-9 * n or round(n) < 1:
            raise ValueError(
                f"device period {self.period_s:g} s is not a whole multiple of the simulation step "
                f"{self.body.time_step:g} s; choose T = n·h"
            )
        return round(n)


def pipeline_impedance(p: Pipeline) -> ct.StateSpace:
    """``H(z)`` of :class:`Pipeline`: device position ``x_k`` → resisting force (``dt = T``).

    Lifted model: state ``S = [x_g, v_g, x_prev]``; per device sample the
    body takes ``n = T/h`` steps of :func:`coupled_body_matrices` with the
    target ``[x_k, (x_k − x_prev)/T]`` held. The force is read from the body
    state before the sample's first step, or after it (``reads_post_step``).
    """
    n, T = p.substeps(), p.period_s
    A1, B1 = coupled_body_matrices(p.body)
    An = np.linalg.matrix_power(A1, n)
    Bn = sum(np.linalg.matrix_power(A1, j) for j in range(n)) @ B1
    E = np.array([[1.0, 0, 0], [0, 1.0, 0]])  # body part of S
    Mx = np.array([[0, 0, 0], [0, 0, -1.0 / T]])  # target [x_t, v_t] = Mx S + Mu x_k
    Mu = np.array([[1.0], [1.0 / T]])
    A = np.zeros((3, 3))
    A[:2, :] = An @ E + Bn @ Mx
    Bm = np.zeros((3, 1))
    Bm[:2] = Bn @ Mu
    Bm[2, 0] = 1.0
    # resisting force −F = c·(target − body), c = [kd, γd]
    c = np.array([[p.kd, p.gamma_d]])
    if p.reads_post_step:
        C = c @ Mx - c @ (A1 @ E + B1 @ Mx)
        D = c @ Mu - c @ B1 @ Mu
    else:
        C = c @ Mx - c @ E
        D = c @ Mu
    H = ct.ss(A, Bm, C, D, dt=T, name="pipeline")
    return ct.series(H, ct.ss(delay_tf(p.delay, T))) if p.delay else H


def device_closed_loop(dev: DeviceParams, H) -> ct.StateSpace:
    """Human force (held) → device position, with the virtual side ``H`` in negative feedback."""
    return ct.feedback(device_model(dev), H, sign=-1)


def closed_loop_radius(dev: DeviceParams, H) -> float:
    """Largest closed-loop pole modulus (< 1: the device is stable)."""
    return float(np.max(np.abs(device_closed_loop(dev, H).poles())))


def device_stiffness_limit(
    dev: DeviceParams, H_of_k: Callable[[float], object], k_hi: float | None = None, rel_tol: float = 1e-5
) -> float:
    """Largest virtual stiffness for which the device loop is stable (bisection on the poles)."""
    k_hi = k_hi or 100.0 * dev.mass / dev.period_s**2
    return bisect(lambda k: closed_loop_radius(dev, H_of_k(k)) < 1.0, 1e-9 * k_hi, k_hi, rel_tol)


@dataclasses.dataclass(frozen=True)
class ColgateResult:
    """Required device damping over frequency (Colgate & Schenkel 1997)."""

    omega: np.ndarray
    required_b_curve: np.ndarray
    required_b: float
    omega_at_max: float

    def margin(self, b_d: float) -> float:
        """Passivity margin ``b_d − required_b`` (N·s/m); ≥ 0 is passive."""
        return b_d - self.required_b


def evaluate(sys, z: np.ndarray) -> np.ndarray:
    """A SISO system's transfer function at the complex points ``z`` (batched ``C (zI − A)⁻¹ B + D``)."""
    sys = ct.ss(sys)
    A, B, C, D = (np.asarray(M, float) for M in (sys.A, sys.B, sys.C, sys.D))
    z = np.asarray(z, complex)
    if A.shape[0] == 0:
        return np.full(z.shape, D[0, 0], complex)
    M = z[:, None, None] * np.eye(A.shape[0]) - A
    return (C @ np.linalg.solve(M, np.broadcast_to(B, (len(z), *B.shape))))[:, 0, 0] + D[0, 0]


def colgate_required_damping(H, T: float, n: int = 4000, refine: bool = True) -> ColgateResult:
    """``sup_ω (T/2) Re[(1 − e^{−jωT}) H(e^{jωT})] / (1 − cos ωT)`` over ω ∈ (0, π/T].

    Evaluated as ``(T/2)[Re H − cot(θ/2) Im H]`` (θ = ωT), the same quantity
    without the ``1 − cos θ`` cancellation near θ → 0. The grid is geometric
    near 0 and linear up to and including ``π/T`` (a damped wall's supremum
    sits at the Nyquist end, an undelayed negative damping's at θ → 0); the
    largest grid value is then refined by a bounded search between its
    neighbours.
    """
    from scipy.optimize import minimize_scalar

    theta = np.unique(np.concatenate([np.geomspace(1e-7, 0.1, n // 4), np.linspace(0.1, math.pi, n)]))

    def b_of(th):
        th = np.atleast_1d(th)
        Hz = evaluate(H, np.exp(1j * th))
        return 0.5 * T * (Hz.real - Hz.imag / np.tan(0.5 * th))

    curve = b_of(theta)
    i = int(np.argmax(curve))
    th_best, b_best = theta[i], curve[i]
    if refine and 0 < i < len(theta) - 1:
        r = minimize_scalar(
            lambda t: -b_of(t)[0],
            bounds=(theta[i - 1], theta[i + 1]),
            method="bounded",
            options={"xatol": 1e-12},
        )
        if -r.fun > b_best:
            th_best, b_best = float(r.x), float(-r.fun)
    return ColgateResult(theta / T, curve, float(b_best), float(th_best / T))


def human_port_admittance(dev: DeviceParams, H) -> ct.StateSpace:
    """Held human force ``F_k`` → mean velocity over the hold ``(x_{k+1} − x_k)/T`` (discrete).

    ``T Σ F_k y_k`` is the exact work the human does on the device, so
    discrete passivity of this map (``ispassive``) is passivity of the
    sampled device against a held force.
    """
    G = device_closed_loop(dev, H)
    A, B, C = (np.asarray(M) for M in (G.A, G.B, G.C))
    T = dev.period_s
    # y_k = (x_{k+1} − x_k)/T = (C A s_k + C B u_k − C s_k)/T; the device has no feedthrough (G.D = 0).
    return ct.ss(A, B, (C @ A - C) / T, (C @ B) / T, dt=T, name="human_admittance")


@dataclasses.dataclass(frozen=True)
class PassivityCheck:
    """python-control's passivity verdicts on a square system."""

    passive: bool
    output_feedback_index: float
    input_feedforward_index: float


def passivity_check(sys: ct.StateSpace) -> PassivityCheck:
    """``ct.ispassive`` and the passivity indices (needs cvxopt)."""
    try:
        import cvxopt  # noqa: F401
    except ImportError as e:  # pragma: no cover - cvxopt is a dependency
        raise ImportError(
            "passivity_check needs cvxopt (pip install cvxopt), python-control's LMI solver"
        ) from e
    return PassivityCheck(
        passive=bool(ct.ispassive(sys)),
        output_feedback_index=float(_index_or_nan(ct.get_output_fb_index, sys)),
        input_feedforward_index=float(_index_or_nan(ct.get_input_ff_index, sys)),
    )


def _index_or_nan(fn, sys) -> float:
    try:
        return fn(sys)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError, RuntimeError):
        return float("nan")  # RuntimeError: python-control's "LMI passivity problem is infeasible"


# -- continuous two-port (Llewellyn) -----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TwoPort:
    """The god-object two-port: port 1 ``v_d → F_fb``, port 2 ``F_e → −v_g``.

    ``Zc = γ + k/s`` (coupling), ``Zd = γd + kd/s`` (feedback), ``D = m s + Zc``.
    """

    mass: float
    k: float
    gamma: float
    kd: float
    gamma_d: float

    def h(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        s = 1j * np.asarray(omega, float)
        Zc = self.gamma + self.k / s
        Zd = self.gamma_d + self.kd / s
        D = self.mass * s + Zc
        return Zd * self.mass * s / D, Zd / D, -Zc / D, 1.0 / D


@dataclasses.dataclass(frozen=True)
class LlewellynResult:
    omega: np.ndarray
    eta: np.ndarray
    eta_min: float
    omega_at_min: float
    re_h11_min: float
    re_h22_min: float

    @property
    def absolutely_stable(self) -> bool:
        return self.eta_min >= 1.0 - 1e-9 and self.re_h11_min >= -1e-12 and self.re_h22_min >= -1e-12


def llewellyn_eta(tp: TwoPort, omega: np.ndarray | None = None) -> LlewellynResult:
    """``η(ω) = 2 Re h11 Re h22/|h12 h21| − Re(h12 h21)/|h12 h21|`` and its minimum."""
    if omega is None:
        wn = math.sqrt(tp.k / tp.mass) if tp.k > 0 else 1.0
        omega = np.geomspace(1e-3 * wn, 1e3 * wn, 4001)
    h11, h12, h21, h22 = tp.h(omega)
    p = h12 * h21
    eta = 2 * h11.real * h22.real / np.abs(p) - p.real / np.abs(p)
    i = int(np.argmin(eta))
    return LlewellynResult(
        omega, eta, float(eta[i]), float(omega[i]), float(h11.real.min()), float(h22.real.min())
    )
