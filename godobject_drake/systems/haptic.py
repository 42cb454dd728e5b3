"""A simulated impedance-type haptic device: position out, force in.

The device is a mass ``m_d`` with physical damping ``b_d`` on each of its
1 or 3 translational axes. Its servo loop runs at period ``T``: it samples the
position, and holds the commanded force (the feedback port's ``F_Do_W``,
optionally ``d`` samples late) plus the user's force for one period. Between
samples the mechanics are integrated exactly (zero-order-hold discretisation
of ``m_d ẍ + b_d ẋ = f``), so the simulated device is the sampled-data system
Colgate's passivity analysis describes, with no integrator error of its own.

It plugs into the god-object loop where a :class:`~godobject_drake.devices.sources.DeviceSource`
would: it outputs ``X_WD``, ``V_WD`` (backward difference of the last two
samples, as a device's encoder-based velocity) and ``grasp``. It also
integrates the exact work of each held force over each hold interval,
``W += f_k · (x_{k+1} − x_k)``: ``work[0]`` by the user, ``work[1]`` by the
feedback. ``−work[0]`` is the energy the device has given to the user; a
passive device never makes it positive (from rest).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import BasicVector, LeafSystem

from godobject_drake.limits import zoh_mass_damper
from godobject_drake.spatial import pose_arrays, rotation_error

AXES = {"x": [[1, 0, 0]], "y": [[0, 1, 0]], "z": [[0, 0, 1]], "xyz": np.eye(3).tolist()}


class HapticDevice(LeafSystem):
    """A sampled, force-controlled haptic device (impedance causality).

    .. pydrake_system::

        name: HapticDevice
        input_ports:
        - F_Do_W
        - human_force (optional)
        - q_WD (optional)
        - grasp_in (optional)
        output_ports:
        - X_WD
        - V_WD
        - grasp
        - device_state
        - work

    ``F_Do_W`` is the feedback wrench ``[τ; f]`` (N·m, N) from
    :class:`~godobject_drake.systems.feedback.FeedbackPort`; only the force along the
    device's axes acts. ``human_force`` (N, one entry per axis) is the user's
    force, zero when unconnected. ``q_WD`` (optional) is the orientation a
    6-DoF-sensing, 3-DoF-force device (a Phantom's gimbal) reads, ``[w x y z]``;
    ``grasp_in`` (optional) its button. ``X_WD`` is the home pose moved by the
    device's displacement ``x`` along its axes, turned to ``q_WD`` if given; ``V_WD`` is ``[0; v̂]`` with
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
    period_s : float
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
        period_s: float = 1e-3,
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
        self.mass, self.damping, self.period_s, self.delay = mass, damping, period_s, int(delay)
        self._A, self._B = zoh_mass_damper(mass, damping, period_s)
        self._E = np.array(AXES[axes], float)  # (n, 3): rows are the axes in W
        n = self.num_axes = len(self._E)
        self._X_home = X_WD_home or RigidTransform()
        self._grasp = grasp

        self._F_port = self.DeclareVectorInputPort("F_Do_W", 6)
        self._h_port = self.DeclareVectorInputPort("human_force", n)
        self._q_port = self.DeclareVectorInputPort("q_WD", 4)
        self._grasp_in = self.DeclareAbstractInputPort("grasp_in", AbstractValue.Make(""))
        # [x_sample (n), x_sample_prev (n), x (n), v (n), delayed feedback forces (d·n, oldest first),
        #  W_user, W_feedback]
        self._n_state = 4 * n + self.delay * n + 2
        self._state = self.DeclareDiscreteState(self._n_state)
        # The mechanics advance at kT with the force computed from the sample x_k; the sample
        # x_{k+1} is published just before (k+1)T, so plant steps between samples see x_k.
        self.sample_lead_s = 1e-6 * period_s
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._advance)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, period_s - self.sample_lead_s, self._sample)

        self.DeclareAbstractOutputPort(
            "X_WD",
            lambda: AbstractValue.Make(RigidTransform()),
            self._calc_X_WD,
            {self.xd_ticket(), self._q_port.ticket()},
        )
        self.DeclareVectorOutputPort("V_WD", 6, self._calc_V_WD, {self.xd_ticket()})
        self.DeclareAbstractOutputPort(
            "grasp", lambda: AbstractValue.Make(""), self._calc_grasp, {self._grasp_in.ticket()}
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
        R = X.rotation()
        if self._q_port.HasValue(context):
            q = self._q_port.Eval(context)
            R = RotationMatrix(Quaternion(q / np.linalg.norm(q)))
        output.set_value(RigidTransform(R, X.translation() + self.displacement_W(context)))

    def _calc_V_WD(self, context, output: BasicVector):
        n = self.num_axes
        s = context.get_discrete_state_vector().value()
        v_hat = (s[:n] - s[n : 2 * n]) / self.period_s
        output.SetFromVector(np.concatenate([np.zeros(3), v_hat @ self._E]))

    def _calc_grasp(self, context, output):
        output.set_value(self._grasp_in.Eval(context) if self._grasp_in.HasValue(context) else self._grasp)


# -- the user's hand, an admittance device, a passivity controller ---------------------------------------


@dataclasses.dataclass(frozen=True)
class HandImpedance:
    """A simulated user: the hand pulls the handle toward where the user means it to be.

    ``f = k (p_H − p_D) + b (v_H − v_D)`` and ``τ = k_rot α u + b_rot (w_H − w_D)`` with
    ``α u`` the axis-angle of ``q_H q_D⁻¹``: H is the user's intended pose (a device path's
    samples), D the handle. With ``(k, b)`` equal to a coupling's ``(m ωn², 2 ζ m ωn)`` an
    admittance device driven by this hand moves a god-object as the coupling would
    (:class:`AdmittanceDevice`).

    Attributes
    ----------
    k, b : float
        Translational stiffness (N/m) and damping (N·s/m).
    k_rot, b_rot : float
        Rotational stiffness (N·m/rad) and damping (N·m·s/rad).
    """

    k: float
    b: float
    k_rot: float = 0.0
    b_rot: float = 0.0

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"hand impedance {f.name}={v!r} must be a finite number ≥ 0")

    @classmethod
    def matching(cls, gains, mass: float, inertia: float) -> HandImpedance:
        """The hand that equals a coupling of ``gains`` on a body of ``mass`` (kg) and ``inertia`` (kg·m²)."""
        return cls(
            k=mass * gains.omega_n**2,
            b=2.0 * gains.zeta * mass * gains.omega_n,
            k_rot=inertia * gains.omega_r**2,
            b_rot=2.0 * gains.zeta_r * inertia * gains.omega_r,
        )

    def wrench(self, pose_WH, V_WH, pose_WD, V_WD) -> np.ndarray:
        """``[τ; f]`` from poses ``[qw qx qy qz x y z]`` and velocities ``[w; v]`` of H and D."""
        f = self.k * (pose_WH[4:] - pose_WD[4:]) + self.b * (V_WH[3:] - V_WD[3:])
        tau = self.k_rot * rotation_error(pose_WH[:4], pose_WD[:4]) + self.b_rot * (V_WH[:3] - V_WD[:3])
        return np.concatenate([tau, f])


class AdmittanceDevice(LeafSystem):
    """A simulated admittance-type haptic device: force out, pose in (paper Fig. 2).

    .. pydrake_system::

        name: AdmittanceDevice
        input_ports:
        - X_WH
        - V_WH
        - grasp_in
        - pose_WG
        - V_WG
        output_ports:
        - F_device_W
        - X_WD
        - V_WD
        - grasp

    The handle has a force–torque sensor between it and the user's hand
    (:class:`HandImpedance` pulling toward ``X_WH``/``V_WH``, a device
    source's ``X_WD``/``V_WD``). Every period T the device samples the
    sensor and sends the wrench ``F_device_W`` (held for the period) to
    the god-object coupling's ``F_device_W`` input, which applies it to the
    held body; it reads back the god-object's pose ``pose_WG``/``V_WG`` and its
    position servo puts the handle there (ideal servo: ``X_WD`` is ``pose_WG``
    as of the last sample). ``grasp`` passes ``grasp_in`` on.

    Timing: at ``kT`` the device reads the god-object (the plant's state
    before that step) and the hand, and publishes the handle pose and the
    sensed wrench together; the coupling applies that wrench until
    ``(k+1)T``. Compared with the impedance coupling, which uses the
    god-object's state of every plant step, the wrench is at most one
    period old.
    """

    def __init__(self, hand: HandImpedance, period_s: float = 1e-3, X_WD0: RigidTransform | None = None):
        super().__init__()
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ValueError(f"admittance device period_s={period_s!r} s must be > 0")
        self.hand, self.period_s = hand, float(period_s)
        self._X_WH = self.DeclareAbstractInputPort("X_WH", AbstractValue.Make(RigidTransform()))
        self._V_WH = self.DeclareVectorInputPort("V_WH", 6)
        self._grasp_in = self.DeclareAbstractInputPort("grasp_in", AbstractValue.Make(""))
        self._pose_WG = self.DeclareVectorInputPort("pose_WG", 7)
        self._V_WG = self.DeclareVectorInputPort("V_WG", 6)
        X = X_WD0 or RigidTransform()
        q0, p0, _ = pose_arrays(X)
        # [F (6), handle pose q p (7), handle velocity w v (6)]
        self._state = self.DeclareDiscreteState(np.concatenate([np.zeros(6), q0, p0, np.zeros(6)]))
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._update)
        xd = {self.xd_ticket()}
        self.DeclareVectorOutputPort("F_device_W", 6, lambda c, o: o.SetFromVector(self._x(c)[:6]), xd)
        self.DeclareAbstractOutputPort(
            "X_WD", lambda: AbstractValue.Make(RigidTransform()), self._calc_X_WD, xd
        )
        self.DeclareVectorOutputPort("V_WD", 6, lambda c, o: o.SetFromVector(self._x(c)[13:19]), xd)
        self.DeclareAbstractOutputPort(
            "grasp", lambda: AbstractValue.Make(""), lambda c, o: o.set_value(self._grasp_in.Eval(c)),
            {self._grasp_in.ticket()},
        )  # fmt: skip

    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state).get_value()

    def _calc_X_WD(self, context, output):
        x = self._x(context)
        output.set_value(RigidTransform(Quaternion(x[6:10] / np.linalg.norm(x[6:10])), x[10:13]))

    def _update(self, context, discrete_state):
        pose_WD, V_WD = self._pose_WG.Eval(context), self._V_WG.Eval(context)  # the servo follows G
        q_WH, p_WH, _ = pose_arrays(self._X_WH.Eval(context))
        F = self.hand.wrench(np.concatenate([q_WH, p_WH]), self._V_WH.Eval(context), pose_WD, V_WD)
        discrete_state.get_mutable_vector(self._state).SetFromVector(np.concatenate([F, pose_WD, V_WD]))


class PassivityController(LeafSystem):
    """Hannaford & Ryu's passivity observer and controller on the feedback path (docs/theory.md §2).

    .. pydrake_system::

        name: PassivityController
        input_ports:
        - F_in
        - X_WD
        output_ports:
        - F_out
        - energy

    Placed between :class:`~godobject_drake.systems.feedback.FeedbackPort`'s
    ``F_Do_W`` (``F_in``) and the device's force input (``F_out``), with the
    device's sampled pose ``X_WD``. The observer counts the exact work of
    each zero-order-hold interval, which the device applies between two
    samples: ``E_k = E_{k−1} − f_{k−1}·(x_k − x_{k−1})`` (and the same for
    the torque with the rotation between samples), the energy the virtual
    side has absorbed; a passive virtual side keeps ``E ≥ 0``. Before it
    sends ``f_k`` the controller predicts ``E_k − f_k·v_k T`` (the device
    keeps its velocity ``v_k = (x_k − x_{k−1})/T``); if that is negative it
    adds damping ``α = −E/(T |v_k|²)``, capped at ``max_damping`` (≈ ``m_d/T``,
    or the controller itself drives the device unstable), and sends
    ``f_k − α v_k``.

    Timing: it updates just before each multiple of ``period_s`` (offset
    ``period_s·(1 − 5e-7)``), after :class:`HapticDevice` has published its
    sample (``1e-6·T`` before) and before the device reads the force.

    ``energy`` is ``[E_trans, E_rot, dissipated_trans, dissipated_rot]`` (J):
    observed energies, and what the controller's damping took out.

    Parameters
    ----------
    period_s : float
        The device's servo period T (s).
    max_damping : float
        Cap on the injected translational damping (N·s/m).
    max_damping_rot : float
        Cap on the injected rotational damping (N·m·s/rad); 0 = translation only.
    """

    def __init__(self, period_s: float, max_damping: float, max_damping_rot: float = 0.0):
        super().__init__()
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ValueError(f"passivity controller period_s={period_s!r} s must be > 0")
        for name, v in (("max_damping", max_damping), ("max_damping_rot", max_damping_rot)):
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"passivity controller {name}={v!r} must be a finite number ≥ 0")
        self.period_s, self.max_damping, self.max_damping_rot = float(period_s), max_damping, max_damping_rot
        self._F_in = self.DeclareVectorInputPort("F_in", 6)
        self._X_WD = self.DeclareAbstractInputPort("X_WD", AbstractValue.Make(RigidTransform()))
        # [F_out (6), q_prev (4), p_prev (3), E_t, E_r, D_t, D_r]
        x0 = np.zeros(17)
        x0[6] = 1.0
        self._state = self.DeclareDiscreteState(x0)
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, period_s * (1.0 - 5e-7), self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        xd = {self.xd_ticket()}
        self.DeclareVectorOutputPort("F_out", 6, lambda c, o: o.SetFromVector(self._x(c)[:6]), xd)
        self.DeclareVectorOutputPort("energy", 4, lambda c, o: o.SetFromVector(self._x(c)[13:17]), xd)

    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state).get_value()

    def _initialize(self, context, discrete_state):
        x = self._x(context).copy()
        q, p, _ = pose_arrays(self._X_WD.Eval(context))
        x[:6] = self._F_in.Eval(context)
        x[6:10], x[10:13] = q, p
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)

    def _update(self, context, discrete_state):
        x = self._x(context).copy()
        T = self.period_s
        q, p, _ = pose_arrays(self._X_WD.Eval(context))
        dtheta = rotation_error(q, x[6:10])
        dp = p - x[10:13]
        E_t = x[13] - x[3:6] @ dp  # the work of the force held over the last interval
        E_r = x[14] - x[0:3] @ dtheta
        F = self._F_in.Eval(context).copy()
        ports = (((3, 6), E_t, dp, self.max_damping, 15), ((0, 3), E_r, dtheta, self.max_damping_rot, 16))
        for (lo, hi), E, delta, cap, i in ports:
            v = delta / T
            v2 = float(v @ v)
            E_pred = E - float(F[lo:hi] @ v) * T
            if E_pred < 0.0 and v2 > 0.0 and cap > 0.0:
                alpha = min(-E_pred / (T * v2), cap)
                F[lo:hi] -= alpha * v
                x[i] += alpha * v2 * T
        x[:6] = F
        x[6:10], x[10:13] = q, p
        x[13], x[14] = E_t, E_r
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)


class SimulatedHand(LeafSystem):
    """A user's hand holding an impedance device's handle and moving it along a path.

    .. pydrake_system::

        name: SimulatedHand
        input_ports:
        - X_WH
        - V_WH
        - device_state
        output_ports:
        - human_force
        - q_WD

    ``X_WH``/``V_WH`` are where the user means the handle to be (a device
    source's ``X_WD``/``V_WD``); ``device_state`` is a 3-axis
    :class:`HapticDevice`'s ``[x; v]``, its handle at ``p_home + x``. The
    hand pushes with ``human_force = k (p_H − p_D) + b (v_H − v_D)``
    (:class:`HandImpedance`, translational part) and turns the gimbal to the
    path's orientation (``q_WD``). The hand feels the device's force
    feedback through the handle, as a real hand does.
    """

    def __init__(self, hand: HandImpedance, p_home: np.ndarray):
        super().__init__()
        self.hand, self._p_home = hand, np.asarray(p_home, float).reshape(3)
        self._X_WH = self.DeclareAbstractInputPort("X_WH", AbstractValue.Make(RigidTransform()))
        self._V_WH = self.DeclareVectorInputPort("V_WH", 6)
        self._dev = self.DeclareVectorInputPort("device_state", 6)
        self.DeclareVectorOutputPort("human_force", 3, self._calc_force)
        self.DeclareVectorOutputPort("q_WD", 4, self._calc_q, {self._X_WH.ticket()})

    def _calc_force(self, context, output):
        _, p_WH, _ = pose_arrays(self._X_WH.Eval(context))
        x = self._dev.Eval(context)
        v_WH = self._V_WH.Eval(context)[3:]
        output.SetFromVector(self.hand.k * (p_WH - self._p_home - x[:3]) + self.hand.b * (v_WH - x[3:]))

    def _calc_q(self, context, output):
        output.SetFromVector(pose_arrays(self._X_WH.Eval(context))[0])
