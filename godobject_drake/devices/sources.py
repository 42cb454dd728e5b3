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
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.trajectories import PiecewisePolynomial, PiecewiseQuaternionSlerp

from godobject_drake.config.device_files import (
    CSV_HEADER,
    DEFAULT_DEVICE_RATE_HZ,
    DEVICE_STATUS_KEYS,
    INTERPOLATIONS,
    DeviceLog,
    IncrementLog,
    JointPath,
    RelativeAids,
    Sample,
    SampleGuard,
    Waypoint,
    read_device_log,
    read_increment_log,
    read_joint_log,
    rotation_from_vector,
)
from godobject_drake.spatial import pose_from_array, quat_to_rotation, rotation_error


def _check_timing(period_s: float, latency_s: float) -> None:
    if not (period_s > 0.0 and math.isfinite(period_s)):
        raise ValueError(f"device period_s={period_s!r} must be a positive number of seconds")
    if not (latency_s >= 0.0 and math.isfinite(latency_s)):
        raise ValueError(f"device latency_s={latency_s!r} must be ≥ 0 s")


# DeviceSource state layout.
_QC, _PC, _QP, _PP = slice(0, 4), slice(4, 7), slice(7, 11), slice(11, 14)
_QN, _PN, _NCAND, _GAP, _TLAST = slice(14, 18), slice(18, 21), 21, 22, 23
_STATUS = slice(24, 31)
_QR, _PR = slice(31, 35), slice(35, 38)  # the last raw sample, when RelativeAids move the target
_N_STATE = 38


class SampleRecorder:
    """What a device reported at each of its ticks, written row by row to a CSV device log as the
    run goes (``recording.device_log``): the replay devices (:class:`ReplayDevice`,
    :class:`ReplayJointDevice`) read it back, and hold each row from its tick, so a replay at the
    same period gives the scene the same samples, bit for bit. Values are written with ``repr``;
    the file is flushed every second of device time, so a run that fails late keeps its log."""

    def __init__(self, path: str | Path, header: Sequence[str], period_s: float):
        self.path = Path(path)
        self._file = self.path.open("w", newline="")
        self._writer = csv.writer(self._file)
        self._writer.writerow(header)
        self._flush_every = max(1, round(1.0 / period_s))
        self.rows = 0

    def write(self, t: float, values, tail=()) -> None:
        self._writer.writerow([repr(float(t)), *(repr(float(v)) for v in values), *tail])
        self.rows += 1
        if self.rows % self._flush_every == 0:
            self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


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
        outputs of the same names (:func:`~godobject_drake.add_god_object` does); the
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
        self.recorder: SampleRecorder | None = None

    def record_to(self, path: str | Path) -> SampleRecorder:
        """Write every sample the device reports (its latency and noise applied, before the
        :class:`SampleGuard`) to the device log ``path`` (``t,x,y,z,qw,qx,qy,qz,grasp``); a tick
        with no sample (a dropout) writes no row. Its replay at this period, with no latency or
        noise, reports the same samples. A relative device's tether or control/display ratio
        moves the target off its samples, so it is refused."""
        if self.aids is not None:
            raise ValueError(
                f"recording.device_log: {path}: this device's tether or control/display ratio moves the "
                "target off the samples a replay would report; record without the aids, or keep the run's "
                "own relative log (device.log) to replay it"
            )
        self.recorder = SampleRecorder(path, CSV_HEADER, self.period_s)
        return self.recorder

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
        if self.recorder is not None and sample is not None:
            self.recorder.write(context.get_time(), [*sample[0], *sample[1]], (sample[2],))
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
                "(godobject_drake.add_god_object does), or build the device without aids"
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
        self.recorder: SampleRecorder | None = None

    def record_to(self, path: str | Path) -> SampleRecorder:
        """Write the channels the device reports at each tick (its latency applied) to the joint
        log ``path`` (``t,<channels>``), which :class:`ReplayJointDevice` replays at this period,
        with no latency, as the same samples."""
        self.recorder = SampleRecorder(path, ("t", *self.channels), self.period_s)
        return self.recorder

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

    def grasp_names(self, duration_s: float | None = None) -> set[str]:
        """None (:meth:`DeviceSource.grasp_names`): a joint device names no body; its jaws grasp
        what they close on."""
        return set()

    def zero_feedback(self, t: float) -> bool:
        """The joint devices here render no feedback (:meth:`DeviceSource.zero_feedback`)."""
        return False

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._state).get_value()
        u = self.channel_values(context.get_time())
        if self.recorder is not None:
            self.recorder.write(context.get_time(), u)
        q = self.mix @ u  # as sample(t)
        discrete_state.get_mutable_vector(self._state).SetFromVector(np.concatenate([q, x[: self._nq]]))

    def _calc_q(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._state).get_value()[: self._nq])

    def _calc_v(self, context, output):
        x = context.get_discrete_state(self._state).get_value()
        output.SetFromVector((x[: self._nq] - x[self._nq :]) / self.period_s)


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
    "DeviceSource",
    "JointDevice",
    "RelativeDevice",
    "ReplayDevice",
    "ReplayJointDevice",
    "ScriptedDevice",
    "ScriptedJointDevice",
]


def first_pose(device: DeviceSource) -> RigidTransform:
    """The pose a device system reports first (its t = 0 sample, noise and all)."""
    p0, q0, _ = device.samples(0.0)[0][1]
    return RigidTransform(Quaternion(q0 / np.linalg.norm(q0)), p0)
