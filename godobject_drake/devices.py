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
from pydrake.common.yaml import yaml_load_typed
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.trajectories import PiecewisePolynomial, PiecewiseQuaternionSlerp

from godobject_drake.spatial import normalized_quaternion, rotation_error

CSV_HEADER = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "grasp")
DEFAULT_DEVICE_RATE_HZ = 60.0

# A sample: position p_WD (m), quaternion q_WD [w, x, y, z], grasp ("" = none).
Sample = tuple[np.ndarray, np.ndarray, str]


def _check_timing(period_s: float, latency_s: float) -> None:
    if not (period_s > 0.0 and math.isfinite(period_s)):
        raise ValueError(f"device period_s={period_s!r} must be a positive number of seconds")
    if not (latency_s >= 0.0 and math.isfinite(latency_s)):
        raise ValueError(f"device latency_s={latency_s!r} must be ≥ 0 s")


class DeviceSource(LeafSystem):
    """Samples a device at its own period and holds the sample.

    .. pydrake_system::

        name: DeviceSource
        output_ports:
        - X_WD
        - V_WD
        - grasp

    ``X_WD`` is an abstract ``RigidTransform``; ``V_WD`` the 6-vector
    ``[w_WD; v_WD]`` (rad/s, m/s) expressed in W; ``grasp`` an abstract
    ``str``, the name of the body to hold or ``""`` for none.

    Parameters
    ----------
    sampler : callable
        ``sampler(t) -> (p_WD, q_WD, grasp)`` for a device time ``t`` (s).
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
    """

    def __init__(
        self,
        sampler: Callable[[float], Sample],
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        noise_m: float = 0.0,
        seed: int = 0,
    ):
        super().__init__()
        _check_timing(period_s, latency_s)
        if not (noise_m >= 0.0 and math.isfinite(noise_m)):
            raise ValueError(f"device noise_m={noise_m!r} must be ≥ 0 m")
        self.noise_m = float(noise_m)
        self.seed = int(seed)
        self.period_s = float(period_s)
        self.latency_s = float(latency_s)
        self._sampler = sampler
        p0, q0, g0 = self._sample(0.0)
        # State: [q_cur(4), p_cur(3), q_prev(4), p_prev(3)]; grasp is abstract.
        x0 = np.concatenate([q0, p0, q0, p0])
        self._pose_index = self.DeclareDiscreteState(x0)
        self._grasp_index = self.DeclareAbstractState(AbstractValue.Make(g0))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.period_s, 0.0, self._update)
        self.DeclareAbstractOutputPort(
            "X_WD",
            lambda: AbstractValue.Make(RigidTransform()),
            self._calc_X_WD,
            prerequisites_of_calc={self.xd_ticket()},
        )
        self.DeclareVectorOutputPort("V_WD", 6, self._calc_V_WD, prerequisites_of_calc={self.xd_ticket()})
        self.DeclareStateOutputPort("grasp", self._grasp_index)

    def _sample(self, t: float) -> Sample:
        p, q, grasp = self._sampler(max(0.0, t - self.latency_s))
        p = np.asarray(p, float)
        if self.noise_m > 0.0:
            k = round(t / self.period_s)
            p = p + self.noise_m * np.random.default_rng([self.seed, k]).standard_normal(3)
        return p, np.asarray(q, float), grasp or ""

    def _update(self, context, state):
        x = context.get_discrete_state(self._pose_index).get_value()
        p, q, grasp = self._sample(context.get_time())
        state.get_mutable_discrete_state(self._pose_index).set_value(np.concatenate([q, p, x[:7]]))
        state.get_mutable_abstract_state(self._grasp_index).set_value(grasp)

    def _calc_X_WD(self, context, output):
        x = context.get_discrete_state(self._pose_index).get_value()
        output.set_value(RigidTransform(Quaternion(x[:4] / np.linalg.norm(x[:4])), x[4:7]))

    def _calc_V_WD(self, context, output: BasicVector):
        x = context.get_discrete_state(self._pose_index).get_value()
        w = rotation_error(x[:4], x[7:11]) / self.period_s
        v = (x[4:7] - x[11:14]) / self.period_s
        output.SetFromVector(np.concatenate([w, v]))

    def samples(self, duration_s: float) -> list[tuple[float, Sample]]:
        """The samples this device reports on ``[0, duration_s]``, as ``(t_k, sample)``."""
        n = math.floor(duration_s / self.period_s + 1e-9)
        return [(k * self.period_s, self._sample(k * self.period_s)) for k in range(n + 1)]

    def grasp_names(self, duration_s: float) -> set[str]:
        """Every non-empty grasp name the device reports on ``[0, duration_s]``."""
        return {s[2] for _, s in self.samples(duration_s) if s[2]}


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
    ):
        waypoints = list(waypoints)
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
        super().__init__(self._sample_path, period_s, latency_s, noise_m, seed)

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
    """Non-empty data rows of a device CSV as ``(where, row)``, after checking the header.

    ``where`` is ``file:line``, for errors that say where to look.
    """
    filename = Path(filename)
    if not filename.is_file():
        raise FileNotFoundError(f"device log {filename} does not exist")
    with filename.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows or tuple(c.strip() for c in rows[0]) != tuple(header):
        got = rows[0] if rows else "an empty file"
        raise ValueError(f"{filename}:1: header must be {','.join(header)}; got {got}.{hint}")
    out = [(f"{filename}:{line}", row) for line, row in enumerate(rows[1:], start=2) if row]
    if not out:
        raise ValueError(f"{filename}: the log has a header but no rows")
    return out


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


def read_device_log(filename: str | Path) -> DeviceLog:
    """Read and check a device CSV log with header ``t,x,y,z,qw,qx,qy,qz,grasp``.

    Raises ``ValueError`` naming the file and line of the first bad row.
    """
    t, p, q, grasp = [], [], [], []
    for where, row in _csv_rows(filename, CSV_HEADER, " See the README section 'Device log format'."):
        if len(row) not in (8, 9):
            raise ValueError(f"{where}: expected 9 columns ({','.join(CSV_HEADER)}), got {len(row)}")
        values = _finite_floats(where, row[:8])
        _check_after(where, values[0], t)
        t.append(values[0])
        p.append(values[1:4])
        q.append(normalized_quaternion(values[4:8], what=where))
        grasp.append(row[8].strip() if len(row) == 9 else "")
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
    ):
        self.log = log if isinstance(log, DeviceLog) else read_device_log(log)
        self.end_time_s = float(self.log.t[-1])
        super().__init__(self._sample_log, period_s, latency_s, noise_m, seed)

    def _sample_log(self, t: float) -> Sample:
        k = max(int(np.searchsorted(self.log.t, t + 1e-9, side="right")) - 1, 0)
        return self.log.p[k], self.log.q[k], self.log.grasp[k]


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


def read_joint_log(filename: str | Path, channels: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read a joint-space device CSV with header ``t,<channels>``: times (s) and values.

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
                 period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ, latency_s: float = 0.0):  # fmt: skip
        self._t, self._u = read_joint_log(filename, channels)
        self.end_time_s = float(self._t[-1])
        super().__init__(self._value, channels, mix, period_s, latency_s)

    def _value(self, t: float) -> np.ndarray:
        return self._u[max(int(np.searchsorted(self._t, t + 1e-9, side="right")) - 1, 0)]


__all__ = [
    "CSV_HEADER",
    "DeviceLog",
    "DevicePath",
    "DeviceSource",
    "JointDevice",
    "JointPath",
    "JointWaypoint",
    "ReplayDevice",
    "ReplayJointDevice",
    "ScriptedDevice",
    "ScriptedJointDevice",
    "Waypoint",
    "load_device_path",
    "load_joint_path",
    "read_device_log",
    "read_joint_log",
    "write_device_log",
    "write_joint_log",
]
