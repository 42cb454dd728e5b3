"""A simulated impedance-type haptic device: position out, force in.

The device is a mass ``m_d`` with physical damping ``b_d`` on each of its
1 or 3 translational axes. Its servo loop runs at period ``T``: it samples the
position, and holds the commanded force (the feedback port's ``F_Do_W``,
optionally ``d`` samples late) plus the user's force for one period. Between
samples the mechanics are integrated exactly (zero-order-hold discretisation
of ``m_d ẍ + b_d ẋ = f``), so the simulated device is the sampled-data system
Colgate's passivity analysis describes, with no integrator error of its own.

It plugs into the god-object loop where a :class:`~godobject_drake.devices.DeviceSource`
would: it outputs ``X_WD``, ``V_WD`` (backward difference of the last two
samples, as a device's encoder-based velocity) and ``grasp``. It also
integrates the exact work of each held force over each hold interval,
``W += f_k · (x_{k+1} − x_k)``: ``work[0]`` by the user, ``work[1]`` by the
feedback. ``−work[0]`` is the energy the device has given to the user; a
passive device never makes it positive (from rest).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector, LeafSystem


def zoh_mass_damper(mass: float, damping: float, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact one-period map of ``m ẍ + b ẋ = f`` with ``f`` held: ``[x, v]⁺ = A [x, v] + B f``.

    Closed form (``a = b/m``, ``e = exp(−a T)``): ``A = [[1, (1−e)/a], [0, e]]``,
    ``B = [[(T − (1−e)/a)/b], [(1−e)/b]]``; ``b = 0`` gives ``[[T²/2m], [T/m]]``.
    """
    if not (math.isfinite(mass) and mass > 0):
        raise ValueError(f"device mass={mass!r} kg must be > 0")
    if not (math.isfinite(damping) and damping >= 0):
        raise ValueError(f"device damping={damping!r} N·s/m must be ≥ 0 (a physical damper)")
    if not (math.isfinite(period) and period > 0):
        raise ValueError(f"device period={period!r} s must be > 0")
    a = damping / mass
    if a * period < 1e-9:
        return np.array([[1.0, period], [0.0, 1.0]]), np.array([period**2 / (2 * mass), period / mass])
    e = math.exp(-a * period)
    one_minus_e_over_a = -math.expm1(-a * period) / a
    A = np.array([[1.0, one_minus_e_over_a], [0.0, e]])
    B = np.array([(period - one_minus_e_over_a) / damping, one_minus_e_over_a * a / damping])
    return A, B


AXES = {"x": [[1, 0, 0]], "y": [[0, 1, 0]], "z": [[0, 0, 1]], "xyz": np.eye(3).tolist()}


class HapticDevice(LeafSystem):
    """A sampled, force-controlled haptic device (impedance causality).

    .. pydrake_system::

        name: HapticDevice
        input_ports:
        - F_Do_W
        - human_force (optional)
        output_ports:
        - X_WD
        - V_WD
        - grasp
        - device_state
        - work

    ``F_Do_W`` is the feedback wrench ``[τ; f]`` (N·m, N) from
    :class:`~godobject_drake.feedback.FeedbackPort`; only the force along the
    device's axes acts. ``human_force`` (N, one entry per axis) is the user's
    force, zero when unconnected. ``X_WD`` is the home pose moved by the
    device's displacement ``x`` along its axes; ``V_WD`` is ``[0; v̂]`` with
    ``v̂ = (x_k − x_{k−1})/T``, from the samples. ``device_state`` is the
    mechanical ``[x; v]`` (m, m/s; the true velocity) as of the last update,
    ``work`` is ``[W_user, W_feedback]`` (J).

    Timing: at ``kT`` the device reads the feedback computed from its sample
    ``x_k`` and advances its mechanics to ``(k+1)T``; the new sample is
    published ``1e-6·T`` before ``(k+1)T``, so a plant stepping faster than
    the device sees ``x_k`` until the next sample, never a future one.

    Parameters
    ----------
    mass : float
        Moving mass per axis m_d (kg).
    damping : float
        Physical damping per axis b_d (N·s/m).
    period : float
        Servo period T (s).
    delay : int
        Samples between the feedback force being computed and being applied.
    axes : str
        ``"x"``, ``"y"``, ``"z"`` (1-DoF) or ``"xyz"`` (3-DoF), in W.
    X_WD_home : RigidTransform
        Device pose at zero displacement.
    grasp : str
        Body the device holds (the ``grasp`` output, constant).
    """

    def __init__(
        self,
        mass: float = 0.1,
        damping: float = 1.0,
        period: float = 1e-3,
        delay: int = 0,
        axes: str = "z",
        X_WD_home: RigidTransform | None = None,
        grasp: str = "",
    ):
        super().__init__()
        if axes not in AXES:
            raise ValueError(f"axes={axes!r}; choose one of {sorted(AXES)}")
        if int(delay) != delay or delay < 0:
            raise ValueError(f"delay={delay!r} must be a whole number of samples ≥ 0")
        self.mass, self.damping, self.period, self.delay = mass, damping, period, int(delay)
        self._A, self._B = zoh_mass_damper(mass, damping, period)
        self._E = np.array(AXES[axes], float)  # (n, 3): rows are the axes in W
        n = self.num_axes = len(self._E)
        self._X_home = X_WD_home or RigidTransform()
        self._grasp = grasp

        self._F_port = self.DeclareVectorInputPort("F_Do_W", 6)
        self._h_port = self.DeclareVectorInputPort("human_force", n)
        # [x_sample (n), x_sample_prev (n), x (n), v (n), delayed feedback forces (d·n, oldest first),
        #  W_user, W_feedback]
        self._n_state = 4 * n + self.delay * n + 2
        self._state = self.DeclareDiscreteState(self._n_state)
        # The mechanics advance at kT with the force computed from the sample x_k; the sample
        # x_{k+1} is published just before (k+1)T, so plant steps between samples see x_k.
        self.sample_lead_s = 1e-6 * period
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._advance)
        self.DeclarePeriodicDiscreteUpdateEvent(period, period - self.sample_lead_s, self._sample)

        self.DeclareAbstractOutputPort(
            "X_WD", lambda: AbstractValue.Make(RigidTransform()), self._calc_X_WD, {self.xd_ticket()}
        )
        self.DeclareVectorOutputPort("V_WD", 6, self._calc_V_WD, {self.xd_ticket()})
        self.DeclareAbstractOutputPort(
            "grasp", lambda: AbstractValue.Make(""), self._calc_grasp, {self.nothing_ticket()}
        )
        self.DeclareVectorOutputPort(
            "device_state",
            2 * n,
            lambda c, o: o.SetFromVector(c.get_discrete_state_vector().value()[2 * n : 4 * n]),
            {self.xd_ticket()},
        )
        self.DeclareVectorOutputPort(
            "work",
            2,
            lambda c, o: o.SetFromVector(c.get_discrete_state_vector().value()[-2:]),
            {self.xd_ticket()},
        )

    def set_initial_state(self, context, x=None, v=None) -> None:
        """Displacement ``x`` (m) and velocity ``v`` (m/s) per axis at t = 0; both samples are ``x``."""
        n = self.num_axes
        s = np.zeros(self._n_state)
        x = np.zeros(n) if x is None else np.asarray(x, float)
        s[:n] = s[n : 2 * n] = s[2 * n : 3 * n] = x
        s[3 * n : 4 * n] = np.zeros(n) if v is None else v
        context.SetDiscreteState(self._state, s)

    def _advance(self, context, discrete_state):
        n, d = self.num_axes, self.delay
        s = context.get_discrete_state_vector().value().copy()
        x, v = s[2 * n : 3 * n], s[3 * n : 4 * n]
        f_fb_now = self._E @ self._F_port.Eval(context)[3:]
        f_h = self._h_port.Eval(context) if self._h_port.HasValue(context) else np.zeros(n)
        if d:
            buf = s[4 * n : 4 * n + d * n].reshape(d, n)
            f_fb = buf[0].copy()
            s[4 * n : 4 * n + d * n] = np.vstack([buf[1:], f_fb_now]).ravel()
        else:
            f_fb = f_fb_now
        u = f_fb + f_h
        x_new = self._A[0, 0] * x + self._A[0, 1] * v + self._B[0] * u
        v_new = self._A[1, 1] * v + self._B[1] * u
        dx = x_new - x
        s[-2] += float(f_h @ dx)
        s[-1] += float(f_fb @ dx)
        s[2 * n : 3 * n], s[3 * n : 4 * n] = x_new, v_new
        discrete_state.set_value(self._state, s)

    def _sample(self, context, discrete_state):
        n = self.num_axes
        s = context.get_discrete_state_vector().value().copy()
        s[n : 2 * n] = s[:n]
        s[:n] = s[2 * n : 3 * n]
        discrete_state.set_value(self._state, s)

    def displacement_W(self, context) -> np.ndarray:
        """The device's displacement from home in W (m)."""
        return context.get_discrete_state_vector().value()[: self.num_axes] @ self._E

    def _calc_X_WD(self, context, output):
        X = self._X_home
        output.set_value(RigidTransform(X.rotation(), X.translation() + self.displacement_W(context)))

    def _calc_V_WD(self, context, output: BasicVector):
        n = self.num_axes
        s = context.get_discrete_state_vector().value()
        v_hat = (s[:n] - s[n : 2 * n]) / self.period
        output.SetFromVector(np.concatenate([np.zeros(3), v_hat @ self._E]))

    def _calc_grasp(self, context, output):
        output.set_value(self._grasp)
