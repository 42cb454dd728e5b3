"""Device sources: the target a user's device gives, sampled at its own rate.

A device reports a pose ``X_WD`` of its frame D in the world W at a fixed
period (60 Hz by default), optionally late by a latency. Between two samples
the output holds (zero-order hold), so the target jumps from sample to
sample: the paper's uncorrelated "hand of God" samples. The velocity
``V_WD = [w; v]`` is the backward difference of the last two samples, which
is what a tracker that only knows its samples can report.

Two sources share that sampling: :class:`ScriptedDevice` (waypoints,
linear in position and slerp in orientation) and :class:`ReplayDevice`
(a CSV log ``t,x,y,z,qw,qx,qy,qz,grasp``).
"""

import csv
import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import AngleAxis, Quaternion
from pydrake.common.value import AbstractValue
from pydrake.common.yaml import yaml_load_typed
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.trajectories import PiecewisePolynomial, PiecewiseQuaternionSlerp

from godobject_drake.spatial import normalized_quaternion, pose_from_array, quat_to_rotation, rotation_error

CSV_HEADER = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "grasp")
DEFAULT_DEVICE_RATE_HZ = 60.0

# A sample: position p_WD (m), quaternion q_WD [w, x, y, z], grasp ("" = none).
Sample = tuple[np.ndarray, np.ndarray, str]


def _check_timing(period_s: float, latency_s: float) -> None:
    if not (period_s > 0.0 and math.isfinite(period_s)):
        raise ValueError(f"device period_s={period_s!r} must be a positive number of seconds")
    if not (latency_s >= 0.0 and math.isfinite(latency_s)):
        raise ValueError(f"device latency_s={latency_s!r} must be ≥ 0 s")


INTERPOLATIONS = ("hold", "linear")
# device_status output: counts since t = 0, and the longest time without a usable sample.
DEVICE_STATUS_KEYS = (
    "device_samples",
    "device_invalid_samples",
    "device_dropped_samples",
    "device_rejected_jumps",
    "device_relocations",
    "device_tethered_samples",
    "device_longest_gap_s",
)


@dataclasses.dataclass
class SampleGuard:
    """What a device does with samples it cannot use (README "Bad device input").

    Every sample a device reports passes this guard before it reaches the
    target; the plant never sees a NaN. What each case does, and the
    ``device_status`` count that reports it:

    - **invalid** (a non-finite value, a quaternion of norm off 1 by more
      than ``quaternion_tolerance``, a zero quaternion): the last valid
      sample is held; ``device_invalid_samples``.
    - **dropout** (the sampler returns ``None``: no new sample): the last
      sample is held; ``device_dropped_samples``.
    - **absurd jump** (farther from the last accepted sample than
      ``max_speed_m_s`` could carry it since then): held back as a glitch;
      ``device_rejected_jumps``. If ``confirm_samples`` consecutive samples
      agree with each other at the new place, the device *was* moved there
      (a tracker re-acquired, a clutch released): the new place is accepted
      with zero velocity, so no damping kick; ``device_relocations``.

    While a sample is held the reported velocity is zero, and
    ``device_longest_gap_s`` is the longest run of held samples (s).
    ``max_speed_m_s = inf`` turns the jump check off.
    """

    max_speed_m_s: float = 10.0
    confirm_samples: int = 3
    quaternion_tolerance: float = 1e-3

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Raise ``ValueError`` naming a setting out of its range."""
        if not (self.max_speed_m_s > 0.0):
            raise ValueError(f"SampleGuard max_speed_m_s={self.max_speed_m_s!r} must be > 0 m/s (inf: off)")
        if int(self.confirm_samples) != self.confirm_samples or self.confirm_samples < 1:
            raise ValueError(f"SampleGuard confirm_samples={self.confirm_samples!r} must be an integer ≥ 1")
        if not (0.0 < self.quaternion_tolerance < 1.0):
            raise ValueError(
                f"SampleGuard quaternion_tolerance={self.quaternion_tolerance!r} must be in (0, 1)"
            )


@dataclasses.dataclass
class RelativeAids:
    """What an increment device does for a god-object it cannot feel (README "Pseudo-haptics").

    A relative device (a mouse, the live keys and gamepad) moves its target by increments; with
    the god-object stopped at an obstacle, nothing stops the target, which runs on through the
    obstacle, and the tool lags by the whole overshoot when the user turns back (the paper's
    "impossible position"). Both aids act once per device sample, on the increment just
    reported, given the coupling's target T and god-object G at that instant:

    - **tether** (``tether_m``, ``tether_angle_rad``): after the increment, the target is
      re-indexed (moved, as a mouse is lifted and put down) so that ``|p_T − p_G| ≤ tether_m``
      and the angle of ``R_G⁻¹ R_T`` is at most ``tether_angle_rad``. Turning back then moves
      the tool at once. ``inf``: off.
    - **control/display ratio** (``cd_ratio`` R ≥ 1): the component of a translation increment
      that carries T further from G is divided by ``CD(s) = 1 + (R − 1)(s − s₀)/(s_cap − s₀)``
      for a stretch ``s = |p_T − p_G|`` past ``s₀ = cd_onset_m`` (1 below it), ``s_cap`` the
      coupling's force-cap stretch: the ratio grows linearly from 1 at the onset to R at the
      force cap, where the force cue turns solid red. The target visibly resists being pushed
      into an obstacle. ``R = 1``: off. Rotation increments are not scaled.

    With the god-object held still, pushing the device a distance X past the onset leaves the
    target :meth:`predicted_stretch` ``(X)`` past it (the continuous curve's integral).
    """

    tether_m: float = math.inf
    tether_angle_rad: float = math.inf
    cd_ratio: float = 1.0
    cd_onset_m: float = 0.005
    cap_stretch_m: float = math.inf  # the coupling's (DeviceSource.follow sets it)

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Raise ``ValueError`` naming a setting out of its range."""
        for name, unit in (("tether_m", "m"), ("tether_angle_rad", "rad")):
            value = getattr(self, name)
            if not value > 0.0:
                raise ValueError(f"{name}={value!r} {unit} must be > 0 (inf: no tether)")
        if not (math.isfinite(self.cd_ratio) and self.cd_ratio >= 1.0):
            raise ValueError(f"cd_ratio={self.cd_ratio!r} must be ≥ 1 (1: off; e.g. 10)")
        if not (math.isfinite(self.cd_onset_m) and self.cd_onset_m >= 0.0):
            raise ValueError(f"cd_onset_m={self.cd_onset_m!r} m must be ≥ 0")

    @property
    def active(self) -> bool:
        return self.tethered or self.cd_ratio != 1.0

    @property
    def tethered(self) -> bool:
        return math.isfinite(self.tether_m) or math.isfinite(self.tether_angle_rad)

    def check_cap(self, cap_stretch_m: float) -> None:
        """Refuse a ratio that has no force cap to grow to."""
        if self.cd_ratio != 1.0 and not (cap_stretch_m > self.cd_onset_m and math.isfinite(cap_stretch_m)):
            raise ValueError(
                f"cd_ratio={self.cd_ratio:g} grows to R at the coupling's force-cap stretch, which is "
                f"{cap_stretch_m!r} m; it must be finite and past cd_onset_m={self.cd_onset_m!r} m. "
                "Set god_object.max_stretch_m, or a smaller cd_onset_m"
            )

    def cd(self, stretch_m: float) -> float:
        """The control/display ratio at a stretch (m): 1 up to the onset, R at the force cap."""
        if self.cd_ratio == 1.0 or stretch_m <= self.cd_onset_m:
            return 1.0
        s0 = self.cd_onset_m
        return 1.0 + (self.cd_ratio - 1.0) * (stretch_m - s0) / (self.cap_stretch_m - s0)

    def predicted_stretch(self, push_m: float) -> float:
        """The stretch after pushing the device ``push_m`` straight away from a fixed god-object,
        from the onset: ``u + a u²/2 = X − s₀``, ``u = s − s₀``, ``a = (R−1)/(s_cap − s₀)``."""
        s0 = self.cd_onset_m
        if push_m <= s0 or self.cd_ratio == 1.0:
            return push_m
        a = (self.cd_ratio - 1.0) / (self.cap_stretch_m - s0)
        return s0 + (math.sqrt(1.0 + 2.0 * a * (push_m - s0)) - 1.0) / a

    def apply(
        self, X_WD: RigidTransform, dp: np.ndarray, dR: np.ndarray, X_WT: RigidTransform, X_WG: RigidTransform
    ) -> tuple[RigidTransform, bool]:
        """The device pose after an increment (``dp`` in W, rotation ``dR`` about D's origin in W),
        from ``X_WD``, with the coupling's target ``X_WT`` (= ``X_WD X_DT``) and god-object
        ``X_WG`` before it; and whether the tether moved it."""
        p_TG = X_WT.translation() - X_WG.translation()
        s = float(np.linalg.norm(p_TG))
        if s > 0.0 and self.cd_ratio != 1.0:
            u = p_TG / s
            out = float(dp @ u)
            if out > 0.0:
                dp = dp - (1.0 - 1.0 / self.cd(s)) * out * u
        X_DT = X_WD.inverse() @ X_WT
        D = RigidTransform(RotationMatrix(dR @ X_WD.rotation().matrix()), X_WD.translation() + dp)
        T = D @ X_DT
        moved = False
        if math.isfinite(self.tether_angle_rad):
            e = rotation_error(T.rotation().ToQuaternion().wxyz(), X_WG.rotation().ToQuaternion().wxyz())
            angle = float(np.linalg.norm(e))
            if angle > self.tether_angle_rad:
                # rotate D about T's origin, so T turns back to the tether's angle and stays put
                back = rotation_from_vector(e * (self.tether_angle_rad / angle - 1.0))
                p_T = T.translation()
                D = RigidTransform(
                    RotationMatrix(back @ D.rotation().matrix()), p_T + back @ (D.translation() - p_T)
                )
                T, moved = D @ X_DT, True
        if math.isfinite(self.tether_m):
            p_GT = T.translation() - X_WG.translation()
            s = float(np.linalg.norm(p_GT))
            if s > self.tether_m:
                D = RigidTransform(D.rotation(), D.translation() - (1.0 - self.tether_m / s) * p_GT)
                moved = True
        return D, moved


# DeviceSource state layout.
_QC, _PC, _QP, _PP = slice(0, 4), slice(4, 7), slice(7, 11), slice(11, 14)
_QN, _PN, _NCAND, _GAP, _TLAST = slice(14, 18), slice(18, 21), 21, 22, 23
_STATUS = slice(24, 31)
_QR, _PR = slice(31, 35), slice(35, 38)  # the last raw sample, when RelativeAids move the target
_N_STATE = 38


class DeviceSource(LeafSystem):
    """Samples a device at its own period and holds (or interpolates) the sample.

    .. pydrake_system::

        name: DeviceSource
        output_ports:
        - X_WD
        - V_WD
        - grasp
        - device_status

    ``X_WD`` is an abstract ``RigidTransform``; ``V_WD`` the 6-vector
    ``[w_WD; v_WD]`` (rad/s, m/s) expressed in W; ``grasp`` an abstract
    ``str``, the name of the body to hold or ``""`` for none.
    ``device_status`` counts what the :class:`SampleGuard` did
    (:data:`DEVICE_STATUS_KEYS`).

    The device period is independent of the plant step (multi-rate): a 60 Hz
    device drives a 1 ms plant, a 1 kHz one a 10 ms plant. Between samples
    the output holds (``interpolation="hold"``, the paper's uncorrelated
    samples) or moves linearly from the previous sample to the latest over
    one period (``"linear"``: smooth, one period later; slerp in rotation).
    ``V_WD`` is the backward difference of the last two samples either way,
    the slope of the linear interpolation.

    Parameters
    ----------
    sampler : callable
        ``sampler(t) -> (p_WD, q_WD, grasp)`` for a device time ``t`` (s),
        or ``None`` when the device gives no new sample (a dropout).
    period_s : float
        Device sampling period T (s); 1/60 s by default.
    latency_s : float
        The sample taken at ``t_k`` reports the device at ``t_k − latency``.
    noise_m : float
        Standard deviation (m) of Gaussian noise added to each position
        sample, as a tracker's jitter. The draw of sample k depends only on
        ``(seed, k)``, so a run is reproducible whatever order samples are taken in.
    seed : int
        Seed of the noise.
    interpolation : str
        ``"hold"`` (default) or ``"linear"``.
    guard : SampleGuard | None
        What to do with invalid, missing and absurd samples; default
        :class:`SampleGuard()`.
    aids : RelativeAids | None
        A tether and a control/display ratio, for a device that reports increments
        (``reports_increments``; others refuse them). Active aids add the input ports
        ``pose_WT`` and ``pose_WG`` (``[qw qx qy qz x y z]``), to wire from the coupling's
        outputs of the same names (:func:`~godobject_drake.building.add_god_object` does); the
        outputs do not depend on them, so the loop has no algebraic cycle.
    """

    reports_increments = False  # a relative device: only its increments mean anything

    def __init__(
        self,
        sampler: Callable[[float], Sample | None],
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        noise_m: float = 0.0,
        seed: int = 0,
        interpolation: str = "hold",
        guard: SampleGuard | None = None,
        aids: RelativeAids | None = None,
    ):
        super().__init__()
        _check_timing(period_s, latency_s)
        if aids is not None and aids.active and not self.reports_increments:
            raise ValueError(
                f"a tether or control/display ratio re-indexes a device's increments; a "
                f"{type(self).__name__} reports absolute poses, which cannot be re-indexed (the "
                "target would no longer be where the device is). Use a relative or live device, or "
                "leave the aids off"
            )
        self.aids = aids if aids is not None and aids.active else None
        if not (noise_m >= 0.0 and math.isfinite(noise_m)):
            raise ValueError(f"device noise_m={noise_m!r} must be ≥ 0 m")
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"device interpolation={interpolation!r}; choose one of {INTERPOLATIONS}")
        self.noise_m = float(noise_m)
        self.seed = int(seed)
        self.period_s = float(period_s)
        self.latency_s = float(latency_s)
        self.interpolation = interpolation
        self.guard = guard or SampleGuard()
        self.guard.check()
        self._sampler = sampler
        first = self._sample(0.0)
        problem = None if first is None else self._problem(first)
        if first is None or problem:
            raise ValueError(
                f"the device's first sample (t = 0) is {'missing' if first is None else problem}; "
                "a device must start from a valid pose"
            )
        p0, q0, g0 = first
        q0 = q0 / np.linalg.norm(q0)
        x0 = np.zeros(_N_STATE)
        x0[_QC] = x0[_QP] = x0[_QN] = q0
        x0[_PC] = x0[_PP] = x0[_PN] = x0[_PR] = p0
        x0[_QR] = q0
        self._pose_index = self.DeclareDiscreteState(x0)
        self._grasp_index = self.DeclareAbstractState(AbstractValue.Make(g0))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.period_s, 0.0, self._update)
        tickets = {self.xd_ticket()} | ({self.time_ticket()} if interpolation == "linear" else set())
        self.DeclareAbstractOutputPort(
            "X_WD", lambda: AbstractValue.Make(RigidTransform()), self._calc_X_WD, tickets
        )
        self.DeclareVectorOutputPort("V_WD", 6, self._calc_V_WD, prerequisites_of_calc={self.xd_ticket()})
        self.DeclareStateOutputPort("grasp", self._grasp_index)
        self.DeclareVectorOutputPort(
            "device_status",
            len(DEVICE_STATUS_KEYS),
            lambda c, o: o.SetFromVector(c.get_discrete_state(self._pose_index).get_value()[_STATUS]),
            prerequisites_of_calc={self.xd_ticket()},
        )
        if self.aids is not None:
            self._aid_ports = [self.DeclareVectorInputPort(name, 7) for name in ("pose_WT", "pose_WG")]

    def _sample(self, t: float) -> Sample | None:
        raw = self._sampler(max(0.0, t - self.latency_s))
        if raw is None:
            return None
        p, q, grasp = raw
        p = np.asarray(p, float).reshape(-1)
        if self.noise_m > 0.0 and p.size == 3:
            k = round(t / self.period_s)
            p = p + self.noise_m * np.random.default_rng([self.seed, k]).standard_normal(3)
        return p, np.asarray(q, float).reshape(-1), grasp or ""

    def _problem(self, sample: Sample) -> str | None:
        """Why a sample cannot be used, or None."""
        p, q, _ = sample
        if p.size != 3 or q.size != 4:
            return f"a sample of {p.size} positions and {q.size} quaternion values (need 3 and 4)"
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
            return f"non-finite: p={p.tolist()}, q={q.tolist()}"
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > self.guard.quaternion_tolerance:
            tol = self.guard.quaternion_tolerance
            return f"quaternion {q.tolist()} of norm {norm:.6g} (need 1 ± {tol:g})"
        return None

    def _update(self, context, state):
        x = context.get_discrete_state(self._pose_index).get_value().copy()
        grasp = context.get_abstract_state(self._grasp_index).get_value()
        g = self.guard
        status = x[_STATUS]
        status[0] += 1
        x[_TLAST] = context.get_time()
        sample = self._sample(context.get_time())
        accepted = False
        if sample is None:
            status[2] += 1
        elif self._problem(sample):
            status[1] += 1
        else:
            p, q, name = sample
            q = q / np.linalg.norm(q)
            step = g.max_speed_m_s * self.period_s
            last = x[_PR] if self.aids else x[_PC]  # with aids the target is not the sample
            relocated = False
            if np.linalg.norm(p - last) <= step * (x[_GAP] + 1.0):
                accepted = True
            else:
                agrees = x[_NCAND] > 0 and np.linalg.norm(p - x[_PN]) <= step
                x[_NCAND] = x[_NCAND] + 1 if agrees else 1
                x[_QN], x[_PN] = q, p
                if x[_NCAND] >= g.confirm_samples:  # the device really is there now
                    status[4] += 1
                    accepted = relocated = True
                else:
                    status[3] += 1
            if accepted:
                if self.aids:
                    q, p = self._aided(context, x, q, p, status)
                # a relocation arrives at rest (no damping kick): the previous sample is the new one
                x[_QP], x[_PP] = (q, p) if relocated else (x[_QC], x[_PC])
                x[_QC], x[_PC] = q, p
                grasp = name
        if accepted:
            x[_NCAND] = 0.0
            x[_GAP] = 0.0
        else:
            x[_QP], x[_PP] = x[_QC], x[_PC]  # hold, at rest
            x[_GAP] += 1.0
            status[6] = max(status[6], x[_GAP] * self.period_s)
        x[_STATUS] = status
        state.get_mutable_discrete_state(self._pose_index).set_value(x)
        state.get_mutable_abstract_state(self._grasp_index).set_value(grasp)

    def _aided(self, context, x, q_raw, p_raw, status):
        """The target after the raw sample's increment, through :class:`RelativeAids`."""
        if not all(port.HasValue(context) for port in self._aid_ports):
            raise RuntimeError(
                f"{self.get_name()}: a tether or control/display ratio needs the coupling's pose_WT and "
                "pose_WG on the device's inputs of the same names; connect them "
                "(godobject_drake.building.add_god_object does), or build the device without aids"
            )
        pose_WT, pose_WG = (port.Eval(context) for port in self._aid_ports)
        dR = quat_to_rotation(q_raw) @ quat_to_rotation(x[_QR]).T
        X_WD = RigidTransform(Quaternion(x[_QC]), x[_PC])
        X_WT, X_WG = pose_from_array(pose_WT), pose_from_array(pose_WG)
        X, moved = self.aids.apply(X_WD, p_raw - x[_PR], dR, X_WT, X_WG)
        x[_QR], x[_PR] = q_raw, p_raw
        status[5] += moved
        q = X.rotation().ToQuaternion().wxyz()
        return q / np.linalg.norm(q), X.translation()

    def _calc_X_WD(self, context, output):
        x = context.get_discrete_state(self._pose_index).get_value()
        q, p = x[_QC], x[_PC]
        if self.interpolation == "linear":
            s = min(max((context.get_time() - x[_TLAST]) / self.period_s, 0.0), 1.0)
            p = x[_PP] + s * (x[_PC] - x[_PP])
            q = Quaternion(x[_QP]).slerp(s, Quaternion(x[_QC])).wxyz()
        output.set_value(RigidTransform(Quaternion(q / np.linalg.norm(q)), p))

    def _calc_V_WD(self, context, output: BasicVector):
        x = context.get_discrete_state(self._pose_index).get_value()
        w = rotation_error(x[_QC], x[_QP]) / self.period_s
        v = (x[_PC] - x[_PP]) / self.period_s
        output.SetFromVector(np.concatenate([w, v]))

    def samples(self, duration_s: float) -> list[tuple[float, Sample | None]]:
        """What the sampler reports on ``[0, duration_s]``, as ``(t_k, sample)``, before the guard."""
        n = math.floor(duration_s / self.period_s + 1e-9)
        return [(k * self.period_s, self._sample(k * self.period_s)) for k in range(n + 1)]

    def grasp_names(self, duration_s: float | None = None) -> set[str]:
        """Every non-empty grasp name the device reports on ``[0, duration_s]``.

        ``None``: over everything it will report: a path or log to its end (``end_time_s``),
        a source without one at its first sample.
        """
        if duration_s is None:
            duration_s = getattr(self, "end_time_s", 0.0)
        return {s[2] for _, s in self.samples(duration_s) if s is not None and s[2]}

    def status(self, context) -> dict:
        """The device's counts in ``context`` (its own): the metrics' ``device_*`` keys."""
        return self.status_dict(self.GetOutputPort("device_status").Eval(context))

    def reversals(self, min_travel_m: float) -> list[tuple[float, np.ndarray]] | None:
        """Where the device turns back, ``(t, direction)``, for the reversal-latency metrics; None
        where it cannot be known before the run (a device that does not report increments)."""
        return None

    def follow(self, builder, coupling) -> None:
        """Pseudo-haptic aids read where the coupling puts T and G: wire ``pose_WT`` and ``pose_WG``
        and grow the control/display ratio to the coupling's force-cap stretch. Without aids: nothing."""
        if self.aids is None:
            return
        self.aids.check_cap(coupling.max_stretch_m)
        self.aids = dataclasses.replace(self.aids, cap_stretch_m=coupling.max_stretch_m)
        for port in ("pose_WT", "pose_WG"):
            builder.Connect(coupling.GetOutputPort(port), self.GetInputPort(port))

    def zero_feedback(self, t: float) -> bool:
        """The run stops at time ``t`` (s): a device that renders the feedback itself is sent a zero
        wrench, so it is never left pushing; returns whether one was sent (False: nothing to send)."""
        return False

    def connect_feedback(self, builder, F_Do_W_port, grasp_names) -> "LeafSystem | None":
        """Wire the feedback wrench ``F_Do_W`` to a device that renders it itself (a real haptic
        device: its kind's class overrides this) and tell it the bodies it may grasp; other
        devices add nothing (None)."""
        return None

    @staticmethod
    def status_dict(values) -> dict:
        """``device_status`` values as a dict keyed by :data:`DEVICE_STATUS_KEYS` (counts as int)."""
        out = {k: round(v) for k, v in zip(DEVICE_STATUS_KEYS[:-1], values[:-1], strict=True)}
        out[DEVICE_STATUS_KEYS[-1]] = float(values[-1])
        return out


@dataclasses.dataclass
class Waypoint:
    """One waypoint of a scripted device path.

    Attributes
    ----------
    t : float
        Time (s); strictly increasing along a path.
    xyz : list[float]
        Position p_WD of the device frame D in the world W (m).
    rpy_deg : list[float]
        Orientation of D in W as roll-pitch-yaw (degrees, Drake's RollPitchYaw).
    grasp : str
        Body to hold from this waypoint on ("" = hold nothing).
    """

    t: float = 0.0
    xyz: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    grasp: str = ""


@dataclasses.dataclass
class DevicePath:
    """A scripted device path, as loaded from YAML (``waypoints: [...]``)."""

    waypoints: list[Waypoint] = dataclasses.field(default_factory=list)


def load_device_path(filename: str | Path) -> DevicePath:
    """Load a :class:`DevicePath` from a YAML file."""
    return yaml_load_typed(schema=DevicePath, filename=str(filename))


class ScriptedDevice(DeviceSource):
    """A device that follows waypoints: linear in position, slerp in orientation.

    Grasp names are piecewise constant: the value of the latest waypoint
    whose time has passed.
    """

    def __init__(
        self,
        waypoints: Sequence[Waypoint],
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        noise_m: float = 0.0,
        seed: int = 0,
        interpolation: str = "hold",
        guard: SampleGuard | None = None,
    ):
        waypoints = list(waypoints)
        for i, w in enumerate(waypoints):
            values = [w.t, *w.xyz, *w.rpy_deg]
            if len(w.xyz) != 3 or len(w.rpy_deg) != 3 or not all(math.isfinite(v) for v in values):
                raise ValueError(
                    f"waypoint {i} (t={w.t}) needs a finite t, 3 finite xyz (m) and 3 finite rpy_deg; "
                    f"got xyz={list(w.xyz)}, rpy_deg={list(w.rpy_deg)}"
                )
        if len(waypoints) < 2:
            raise ValueError(f"a scripted device needs at least 2 waypoints, got {len(waypoints)}")
        times = np.array([w.t for w in waypoints], dtype=float)
        if not np.all(np.diff(times) > 0):
            raise ValueError(
                f"waypoint times must increase strictly; got {times.tolist()}. Sort them or drop duplicates."
            )
        positions = np.array([w.xyz for w in waypoints], dtype=float).T
        rotations = [RollPitchYaw(np.radians(w.rpy_deg)).ToRotationMatrix() for w in waypoints]
        self._position = PiecewisePolynomial.FirstOrderHold(times, positions)
        self._orientation = PiecewiseQuaternionSlerp(times.tolist(), rotations)
        self._times = times
        self._grasps = [w.grasp or "" for w in waypoints]
        self.end_time_s = float(times[-1])
        super().__init__(self._sample_path, period_s, latency_s, noise_m, seed, interpolation, guard)

    def grasp_names(self, duration_s: float | None = None) -> set[str]:
        """The waypoints' grasp names (up to ``duration_s`` of device time): read off the path, not
        sampled, so a path of any length costs its waypoints only."""
        return _names_until(self._times, self._grasps, duration_s, self.latency_s)

    def path_sample(self, t: float) -> Sample:
        """The path itself at time ``t`` (clamped to its span): no latency, noise or guard."""
        return self._sample_path(t)

    def _sample_path(self, t: float) -> Sample:
        t = min(max(t, self._times[0]), self._times[-1])
        p = self._position.value(t).ravel()
        q = self._orientation.orientation(t).wxyz()
        k = int(np.searchsorted(self._times, t, side="right")) - 1
        return p, np.asarray(q), self._grasps[max(k, 0)]


@dataclasses.dataclass(frozen=True)
class DeviceLog:
    """A device log: times (s), positions (m), quaternions [w,x,y,z], grasp names."""

    t: np.ndarray
    p: np.ndarray
    q: np.ndarray
    grasp: list[str]


def _csv_rows(filename: str | Path, header: Sequence[str], hint: str = ""):
    """Non-empty data rows of a device CSV as ``(where, row)``, after checking the header, read as
    they are needed: a bad row is found without reading the rest, and a reader that stops early
    (a run shorter than the log) reads no further.

    ``where`` is ``file:line``, for errors that say where to look.
    """
    filename = Path(filename)
    if not filename.is_file():
        raise FileNotFoundError(f"device log {filename} does not exist")
    rows = 0
    with filename.open(newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        try:
            first = next(reader, None)
            if first is None or tuple(c.strip() for c in first) != tuple(header):
                got = first if first is not None else "an empty file"
                raise ValueError(f"{filename}:1: header must be {','.join(header)}; got {got}.{hint}")
            for line, row in enumerate(reader, start=2):
                if row:
                    rows += 1
                    yield f"{filename}:{line}", row
        except (UnicodeDecodeError, csv.Error) as e:  # found by tests/test_fuzz.py: not a text CSV
            raise ValueError(
                f"{filename}: not a UTF-8 text CSV ({e}); write the log as text.{hint}"
            ) from None
    if not rows:
        raise ValueError(f"{filename}: the log has a header but no rows")


def _finite_floats(where: str, cells: Sequence[str]) -> list[float]:
    try:
        values = [float(c) for c in cells]
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{where}: non-finite value in {list(cells)}")
    return values


def _check_after(where: str, t: float, times: list[float]) -> None:
    if times and t <= times[-1]:
        raise ValueError(
            f"{where}: time {t} is not after the previous row's {times[-1]}; rows "
            "must be in strictly increasing time"
        )


def read_device_log(filename: str | Path, until_s: float = math.inf) -> DeviceLog:
    """Read and check a device CSV log with header ``t,x,y,z,qw,qx,qy,qz,grasp``, up to the first
    row past ``until_s`` (s): a run reads what it can reach, however long the log.

    Raises ``ValueError`` naming the file and line of the first bad row.
    """
    t, p, q, grasp = [], [], [], []
    for where, row in _csv_rows(filename, CSV_HEADER, " See the device log format in docs/guide/devices.md."):
        if len(row) not in (8, 9):
            raise ValueError(f"{where}: expected 9 columns ({','.join(CSV_HEADER)}), got {len(row)}")
        values = _finite_floats(where, row[:8])
        _check_after(where, values[0], t)
        t.append(values[0])
        p.append(values[1:4])
        q.append(normalized_quaternion(values[4:8], what=where))
        grasp.append(row[8].strip() if len(row) == 9 else "")
        if values[0] > until_s:
            break
    return DeviceLog(np.array(t), np.array(p), np.array(q), grasp)


def write_device_log(filename: str | Path, samples: Sequence[tuple[float, Sample]]) -> None:
    """Write samples ``(t, (p, q, grasp))`` as a device CSV log.

    Values are written with ``repr`` precision, so a replay reproduces them exactly.
    """
    with Path(filename).open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_HEADER)
        for t, (p, q, grasp) in samples:
            writer.writerow([repr(float(t)), *map(repr, map(float, p)), *map(repr, map(float, q)), grasp])


class ReplayDevice(DeviceSource):
    """Replays a device CSV log, holding the latest row whose time has passed.

    The log's own rows may come at any rate; this device samples them at its
    period (zero-order hold of the latest row with ``t_row ≤ t``, 1 ns of
    tolerance for logs written at the same ticks). Before the first row it
    reports the first row.
    """

    def __init__(
        self,
        log: DeviceLog | str | Path,
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        noise_m: float = 0.0,
        seed: int = 0,
        interpolation: str = "hold",
        guard: SampleGuard | None = None,
        until_s: float = math.inf,
    ):
        self.log = log if isinstance(log, DeviceLog) else read_device_log(log, until_s)
        self.end_time_s = float(self.log.t[-1])
        super().__init__(self._sample_log, period_s, latency_s, noise_m, seed, interpolation, guard)

    def _sample_log(self, t: float) -> Sample:
        k = max(int(np.searchsorted(self.log.t, t + 1e-9, side="right")) - 1, 0)
        return self.log.p[k], self.log.q[k], self.log.grasp[k]

    def grasp_names(self, duration_s: float | None = None) -> set[str]:
        """The log's grasp names (up to ``duration_s``), read off its rows."""
        return _names_until(self.log.t, self.log.grasp, duration_s, self.latency_s)


def _names_until(times, names, duration_s: float | None, latency_s: float) -> set[str]:
    """The non-empty names of the rows a device reports on ``[0, duration_s]`` (None: all): the
    rows up to ``duration_s − latency_s`` of its own time, and the first row, reported before it."""
    last = len(names) if duration_s is None else max(int(np.searchsorted(times, duration_s - latency_s + 1e-9,
                                                                        side="right")), 1)  # fmt: skip
    return {n for n in names[:last] if n}


RELATIVE_CSV_HEADER = ("t", "dx", "dy", "dz", "drx", "dry", "drz", "clutch", "grasp")
MAX_INCREMENT_M, MAX_INCREMENT_RAD = 10.0, 1000.0  # one row's increment at most (a mouse's is mm)


@dataclasses.dataclass(frozen=True)
class IncrementLog:
    """A relative device's log: row times (s), increments of position (m) and of rotation
    (rotation vector, rad), both in W, clutch flags and grasp names."""

    t: np.ndarray
    dp: np.ndarray
    drot: np.ndarray
    clutch: np.ndarray
    grasp: list[str]


def read_increment_log(filename: str | Path, until_s: float = math.inf) -> IncrementLog:
    """Read and check a relative device's CSV (``t,dx,dy,dz,drx,dry,drz,clutch,grasp``), up to the
    first row past ``until_s`` (s).

    Raises ``ValueError`` naming the file and line of the first bad row.
    """
    t, dp, drot, clutch, grasp = [], [], [], [], []
    hint = " See the relative device in docs/guide/devices.md."
    for where, row in _csv_rows(filename, RELATIVE_CSV_HEADER, hint):
        if len(row) not in (8, 9):
            raise ValueError(f"{where}: expected 9 columns ({','.join(RELATIVE_CSV_HEADER)}), got {len(row)}")
        values = _finite_floats(where, row[:8])
        _check_after(where, values[0], t)
        if values[7] not in (0.0, 1.0):
            raise ValueError(f"{where}: clutch is {row[7]!r}; it must be 0 (released: move) or 1 (pressed)")
        for name, vector, most, unit in (("dx,dy,dz", values[1:4], MAX_INCREMENT_M, "m"),
                                         ("drx,dry,drz", values[4:7], MAX_INCREMENT_RAD, "rad")):  # fmt: skip
            size = math.hypot(*vector)
            if not size <= most:
                raise ValueError(
                    f"{where}: the increment {name} = {vector} is {size:.3g} {unit} long, over {most:g} "
                    f"{unit} in one row; a device reports small steps: write the log in metres and radians"
                )
        t.append(values[0])
        dp.append(values[1:4])
        drot.append(values[4:7])
        clutch.append(values[7] == 1.0)
        grasp.append(row[8].strip() if len(row) == 9 else "")
        if values[0] > until_s:
            break
    return IncrementLog(np.array(t), np.array(dp), np.array(drot), np.array(clutch), grasp)


def write_increment_log(filename: str | Path, log: IncrementLog) -> None:
    """Write a relative device's CSV at ``repr`` precision."""
    with Path(filename).open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(RELATIVE_CSV_HEADER)
        for k in range(len(log.t)):
            cells = [log.t[k], *log.dp[k], *log.drot[k]]
            writer.writerow([*map(repr, map(float, cells)), int(log.clutch[k]), log.grasp[k]])


def increments_along(samples: Sequence[tuple[float, Sample]]) -> IncrementLog:
    """The increments a relative device reports along absolute samples ``(t_k, (p, q, grasp))``
    (e.g. :meth:`DeviceSource.samples` of a scripted path): row k is the motion from sample
    k−1 to k, clutch released; a :class:`RelativeDevice` started at the first sample follows
    the samples (to the rounding of summing the increments)."""
    pairs = itertools.pairwise(samples)
    rows = [(t1, p1 - p0, rotation_error(q1, q0), g1) for (_, (p0, q0, _)), (t1, (p1, q1, g1)) in pairs]
    return IncrementLog(
        np.array([r[0] for r in rows]),
        np.array([r[1] for r in rows]).reshape(-1, 3),
        np.array([r[2] for r in rows]).reshape(-1, 3),
        np.zeros(len(rows), bool),
        [r[3] for r in rows],
    )


class RelativeDevice(DeviceSource):
    """The paper's mouse: a device that reports increments, applied to the target.

    Row k of the log is the motion the device measured up to ``t_k``: a
    translation ``dp`` (m) and a rotation vector ``drot`` (rad), both in W.
    With the clutch released (``clutch = 0``) the increment moves the
    target: ``p_k = p_{k−1} + dp``, ``R_k = exp(drot) R_{k−1}``. With the
    clutch pressed (``clutch = 1``) it is ignored: the user lifts the mouse
    and brings it back without moving the target (paper: "their movement can
    be ignored, if necessary"). The target starts at ``X_WD0``; between rows
    it holds the latest row at or before ``t`` (1 ns tolerance), sampled at
    the device period like :class:`ReplayDevice`. ``aids``: a tether and a control/display
    ratio (:class:`RelativeAids`).
    """

    reports_increments = True

    def __init__(
        self,
        log: IncrementLog | str | Path,
        X_WD0: RigidTransform | None = None,
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        noise_m: float = 0.0,
        seed: int = 0,
        interpolation: str = "hold",
        guard: SampleGuard | None = None,
        aids: RelativeAids | None = None,
        until_s: float = math.inf,
    ):
        self.log = log if isinstance(log, IncrementLog) else read_increment_log(log, until_s)
        X = X_WD0 or RigidTransform()
        p, R = X.translation().copy(), X.rotation().matrix().copy()
        self._p, self._q = [], []
        for k in range(len(self.log.t)):
            if not self.log.clutch[k]:
                p = p + self.log.dp[k]
                R = rotation_from_vector(self.log.drot[k]) @ R
            self._p.append(p)
            self._q.append(RotationMatrix(R).ToQuaternion().wxyz())
        self._p0, self._q0 = X.translation().copy(), X.rotation().ToQuaternion().wxyz()
        self.end_time_s = float(self.log.t[-1])
        super().__init__(self._sample_log, period_s, latency_s, noise_m, seed, interpolation, guard, aids)

    def _sample_log(self, t: float) -> Sample:
        k = int(np.searchsorted(self.log.t, t + 1e-9, side="right")) - 1
        if k < 0:
            return self._p0, self._q0, self.log.grasp[0]
        return self._p[k], self._q[k], self.log.grasp[k]

    def grasp_names(self, duration_s: float | None = None) -> set[str]:
        """The log's grasp names (up to ``duration_s``), read off its rows."""
        return _names_until(self.log.t, self.log.grasp, duration_s, self.latency_s)

    def reversals(self, min_travel_m: float) -> list[tuple[float, np.ndarray]]:
        """``(t, d)`` for each log row whose increment points more than 90° from the last non-zero
        one and that starts a return of at least ``min_travel_m`` along ``d`` (so a jitter is not a
        reversal); ``t`` is the device sample that reports it."""
        log, period, latency = self.log, self.period_s, self.latency_s
        moving = [k for k in range(len(log.t)) if not log.clutch[k] and np.linalg.norm(log.dp[k]) > 0.0]
        out, last = [], None
        for i, k in enumerate(moving):
            dp = log.dp[k]
            if last is not None and float(dp @ last) < 0.0:
                d = dp / np.linalg.norm(dp)
                travel = 0.0
                for j in moving[i:]:
                    step = float(log.dp[j] @ d)
                    if step < 0.0:
                        break
                    travel += step
                if travel < min_travel_m:
                    continue  # a jitter: the motion it interrupts goes on
                t = math.ceil((log.t[k] + latency) / period - 1e-9) * period
                out.append((t, d))
            last = dp
        return out


def rotation_from_vector(r) -> np.ndarray:
    """The rotation matrix ``exp([r]×)`` of a rotation vector ``r`` (rad)."""
    r = np.asarray(r, float)
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    return RotationMatrix(AngleAxis(angle, r / angle)).matrix()


class JointDevice(LeafSystem):
    """Samples a joint-space device (an articulated interface) at its own period.

    .. pydrake_system::

        name: JointDevice
        output_ports:
        - q_device
        - v_device

    The device reports values of named *channels* (e.g. a laparoscopic
    interface's ``yaw, pitch, insertion, roll, jaw``: rad, m) at a fixed
    period, zero-order held like :class:`DeviceSource`. ``q_device`` are the
    positions of the tool's driven joints, ``A · channels`` with the
    ``mix`` matrix A (identity by default; the grasper maps one ``jaw``
    opening to its two jaw joints at ½ each). ``v_device`` is the backward
    difference of the last two ``q_device`` samples divided by the period:
    the time derivative of the joint positions (``q̇``, equal to the joint
    velocity for revolute and prismatic joints).

    Parameters
    ----------
    sampler : callable
        ``sampler(t) -> channel values`` at device time ``t`` (s).
    channels : sequence of str
        Channel names, in the order ``sampler`` returns them.
    mix : array_like | None
        ``(n_q, n_channels)`` matrix from channels to joint positions.
    period_s, latency_s : float
        Sampling period and latency (s), as for :class:`DeviceSource`.
    """

    def __init__(
        self,
        sampler: Callable[[float], np.ndarray],
        channels: Sequence[str],
        mix=None,
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
    ):
        super().__init__()
        _check_timing(period_s, latency_s)
        self.channels = tuple(channels)
        n = len(self.channels)
        self.mix = np.eye(n) if mix is None else np.asarray(mix, dtype=float)
        if self.mix.ndim != 2 or self.mix.shape[1] != n:
            raise ValueError(f"mix has shape {self.mix.shape}; it needs {n} columns, one per channel")
        self.period_s = float(period_s)
        self.latency_s = float(latency_s)
        self._sampler = sampler
        q0 = self.sample(0.0)
        self._nq = q0.size
        self._state = self.DeclareDiscreteState(np.concatenate([q0, q0]))
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._update)
        self.DeclareVectorOutputPort("q_device", self._nq, self._calc_q, {self.xd_ticket()})
        self.DeclareVectorOutputPort("v_device", self._nq, self._calc_v, {self.xd_ticket()})

    def channel_values(self, t: float) -> np.ndarray:
        """The channels the device reports at time ``t`` (latency applied)."""
        u = np.asarray(self._sampler(max(0.0, t - self.latency_s)), dtype=float).reshape(-1)
        if u.size != len(self.channels):
            raise ValueError(
                f"the device gave {u.size} values for {len(self.channels)} channels {self.channels}"
            )
        return u

    def sample(self, t: float) -> np.ndarray:
        """Joint positions ``A · channels`` reported at time ``t``."""
        return self.mix @ self.channel_values(t)

    def samples(self, duration_s: float) -> np.ndarray:
        """``q_device`` at every sample time on ``[0, duration_s]``, one row per sample."""
        n = math.floor(duration_s / self.period_s + 1e-9)
        return np.array([self.sample(k * self.period_s) for k in range(n + 1)])

    def status(self, context) -> dict:
        """The device's counts for the metrics (none for a joint device that cannot fail)."""
        return {}

    def reversals(self, min_travel_m: float) -> None:
        """Not measured for joint devices (:meth:`DeviceSource.reversals`)."""
        return None

    def zero_feedback(self, t: float) -> bool:
        """The joint devices here render no feedback (:meth:`DeviceSource.zero_feedback`)."""
        return False

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._state).get_value()
        q = self.sample(context.get_time())
        discrete_state.get_mutable_vector(self._state).SetFromVector(np.concatenate([q, x[: self._nq]]))

    def _calc_q(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._state).get_value()[: self._nq])

    def _calc_v(self, context, output):
        x = context.get_discrete_state(self._state).get_value()
        output.SetFromVector((x[: self._nq] - x[self._nq :]) / self.period_s)


@dataclasses.dataclass
class JointWaypoint:
    """One waypoint of a scripted joint-space path: time (s) and channel values (rad, m)."""

    t: float = 0.0
    values: dict[str, float] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class JointPath:
    """A scripted joint-space path, as loaded from YAML (``channels: [...]``, ``waypoints: [...]``)."""

    channels: list[str] = dataclasses.field(default_factory=list)
    waypoints: list[JointWaypoint] = dataclasses.field(default_factory=list)


def load_joint_path(filename: str | Path) -> JointPath:
    """Load a :class:`JointPath` from YAML; every waypoint must give every channel."""
    path = yaml_load_typed(schema=JointPath, filename=str(filename))
    for i, w in enumerate(path.waypoints):
        if set(w.values) != set(path.channels):
            raise ValueError(
                f"{filename}: waypoint {i} (t={w.t}) gives {sorted(w.values)}; every waypoint must "
                f"give exactly the channels {path.channels}"
            )
    return path


class ScriptedJointDevice(JointDevice):
    """A joint-space device following waypoints, linear between them."""

    def __init__(self, path: JointPath, mix=None, period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
                 latency_s: float = 0.0):  # fmt: skip
        if len(path.waypoints) < 2:
            raise ValueError(f"a scripted device needs at least 2 waypoints, got {len(path.waypoints)}")
        times = np.array([w.t for w in path.waypoints], dtype=float)
        if not np.all(np.diff(times) > 0):
            raise ValueError(
                f"waypoint times must increase strictly; got {times.tolist()}. Sort them or drop duplicates."
            )
        values = np.array([[w.values[c] for c in path.channels] for w in path.waypoints]).T
        self._trajectory = PiecewisePolynomial.FirstOrderHold(times, values)
        self._t_range = (float(times[0]), float(times[-1]))
        self.end_time_s = self._t_range[1]
        super().__init__(self._value, path.channels, mix, period_s, latency_s)

    def _value(self, t: float) -> np.ndarray:
        return self._trajectory.value(min(max(t, self._t_range[0]), self._t_range[1])).ravel()


def read_joint_log(
    filename: str | Path, channels: Sequence[str], until_s: float = math.inf
) -> tuple[np.ndarray, np.ndarray]:
    """Read a joint-space device CSV with header ``t,<channels>``: times (s) and values, up to the
    first row past ``until_s`` (s).

    Raises ``ValueError`` naming the file and line of the first bad row.
    """
    header = ("t", *channels)
    t, u = [], []
    for where, row in _csv_rows(filename, header):
        if len(row) != len(header):
            raise ValueError(f"{where}: expected {len(header)} columns ({','.join(header)}), got {len(row)}")
        values = _finite_floats(where, row)
        _check_after(where, values[0], t)
        t.append(values[0])
        u.append(values[1:])
        if values[0] > until_s:
            break
    return np.array(t), np.array(u)


def write_joint_log(filename: str | Path, channels: Sequence[str], times, values) -> None:
    """Write a joint-space device CSV (``t,<channels>``) at ``repr`` precision."""
    with Path(filename).open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["t", *channels])
        for t, row in zip(times, values, strict=True):
            writer.writerow([repr(float(t)), *map(repr, map(float, row))])


class ReplayJointDevice(JointDevice):
    """Replays a joint-space CSV log, holding the latest row whose time has passed (1 ns tolerance)."""

    def __init__(self, filename: str | Path, channels: Sequence[str], mix=None,
                 period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ, latency_s: float = 0.0,
                 until_s: float = math.inf):  # fmt: skip
        self._t, self._u = read_joint_log(filename, channels, until_s)
        self.end_time_s = float(self._t[-1])
        super().__init__(self._value, channels, mix, period_s, latency_s)

    def _value(self, t: float) -> np.ndarray:
        return self._u[max(int(np.searchsorted(self._t, t + 1e-9, side="right")) - 1, 0)]


__all__ = [
    "CSV_HEADER",
    "DEVICE_STATUS_KEYS",
    "INTERPOLATIONS",
    "RELATIVE_CSV_HEADER",
    "DeviceLog",
    "DevicePath",
    "DeviceSource",
    "IncrementLog",
    "JointDevice",
    "JointPath",
    "JointWaypoint",
    "RelativeAids",
    "RelativeDevice",
    "ReplayDevice",
    "ReplayJointDevice",
    "SampleGuard",
    "ScriptedDevice",
    "ScriptedJointDevice",
    "Waypoint",
    "increments_along",
    "load_device_path",
    "load_joint_path",
    "read_device_log",
    "read_increment_log",
    "read_joint_log",
    "write_device_log",
    "write_increment_log",
    "write_joint_log",
]
