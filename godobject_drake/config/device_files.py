"""What a device config reads: scripted paths, logs, and the sample guard and aids it sets.

Plain types and file formats, no Drake systems: a scripted path (:class:`Waypoint`,
:class:`JointWaypoint`, YAML), a pose log (CSV ``t,x,y,z,qw,qx,qy,qz,grasp``), an increment
log (CSV ``t,dx,dy,dz,drx,dry,drz,clutch,grasp``, the paper's mouse), a joint log (CSV
``t,<channels>``); the :class:`SampleGuard` every pose device applies and the pseudo-haptic
:class:`RelativeAids` of the increment devices. The device systems that use them are in
:mod:`godobject_drake.devices.sources`; the driver process's log replay reads them too.

This module must not use ``from __future__ import annotations``: ``yaml_load_typed`` reads the
field types at run time.
"""

import csv
import dataclasses
import itertools
import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.common.yaml import yaml_load_typed
from pydrake.math import RigidTransform, RotationMatrix

from godobject_drake.config.yaml_guard import YamlShapeError, check_yaml_file, shown
from godobject_drake.spatial import normalized_quaternion, rotation_error

CSV_HEADER = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "grasp")


DEFAULT_DEVICE_RATE_HZ = 60.0


# A sample: position p_WD (m), quaternion q_WD [w, x, y, z], grasp ("" = none).
Sample = tuple[np.ndarray, np.ndarray, str]


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
    """What a device does with samples it cannot use (docs/guide/devices.md#bad-device-input).

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

    Attributes
    ----------
    max_speed_m_s : float
        The fastest a device can move (m/s): a sample farther from the last accepted one than
        this speed could carry it is held back as a glitch; ``.inf`` turns the check off.
    confirm_samples : int
        How many consecutive samples must agree at a new place before it is accepted (a
        relocation).
    quaternion_tolerance : float
        How far off 1 a sample's quaternion norm may be before the sample is invalid.
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
    """What an increment device does for a god-object it cannot feel (docs/guide/visual.md).

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
      force cap, where the force cue turns solid magenta. The target visibly resists being pushed
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
    return _load_yaml_file(DevicePath, filename, "device path", "waypoints: [{t, xyz, rpy_deg, grasp}, ...]")


def _load_yaml_file(schema, filename, what: str, form: str):
    """``schema`` read from the YAML file ``filename`` (bounded: config.yaml_guard), or a ValueError
    naming the file, the line where it can and the form; it quotes none of the file (a path may name
    a private file): only the schema's own field names."""
    where = f"{what} file {shown(filename)}"
    try:
        check_yaml_file(filename, where)
        return yaml_load_typed(schema=schema, filename=str(filename))
    except YamlShapeError as e:
        raise ValueError(str(e)) from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise ValueError(f"{where}: not valid YAML{at}; check the brackets, colons and indentation") from None
    except (RuntimeError, TypeError, ValueError, AssertionError, AttributeError) as e:
        known = _field_names(schema) | {"float", "int", "str", "list", "dict"}
        said = QUOTED.sub(lambda m: m.group(0) if m.group(1) in known else "…", str(e))
        raise ValueError(f"{where}: not a {what} ({shown(said)}); give {form}") from None


# A quoted word in a loader's message: kept only when it is one of the schema's field names.
QUOTED = re.compile(r"'([^']*)'|\"([^\"]*)\"")


def _field_names(schema) -> set[str]:
    names, todo = set(), [schema]
    while todo:
        for f in dataclasses.fields(todo.pop()):
            names.add(f.name)
            todo.extend(t for t in getattr(f.type, "__args__", ()) if dataclasses.is_dataclass(t))
    return names


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
    path = Path(filename)
    filename = shown(path)  # as messages name it
    if not path.is_file():
        raise FileNotFoundError(f"device log {filename} does not exist")
    rows = 0
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        try:
            first = next(reader, None)
            if first is None or tuple(c.strip() for c in first) != tuple(header):
                # the line itself is not repeated: a log named by mistake may be a private file
                got = f"a line of {len(first)} columns" if first is not None else "an empty file"
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
    values = []
    for column, c in enumerate(cells, start=1):  # the cell is not quoted: the file may be a private one
        try:
            values.append(float(c))
        except ValueError:
            raise ValueError(f"{where}: column {column} is not a number") from None
    bad = [column for column, v in enumerate(values, start=1) if not math.isfinite(v)]
    if bad:
        raise ValueError(f"{where}: non-finite value (nan or inf) in column {bad[0]}")
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
            raise ValueError(
                f"{where}: clutch is {values[7]:g}; it must be 0 (released: move) or 1 (pressed)"
            )
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


def rotation_from_vector(r) -> np.ndarray:
    """The rotation matrix ``exp([r]×)`` of a rotation vector ``r`` (rad)."""
    r = np.asarray(r, float)
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    return RotationMatrix(AngleAxis(angle, r / angle)).matrix()


@dataclasses.dataclass
class JointWaypoint:
    """One waypoint of a scripted joint-space path.

    Attributes
    ----------
    t : float
        Its time (s).
    values : dict[str, float]
        Each channel's value at ``t`` (rad for a revolute joint, m for a prismatic one); every
        waypoint gives every channel.
    """

    t: float = 0.0
    values: dict[str, float] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class JointPath:
    """A scripted joint-space path, as loaded from YAML (``channels: [...]``, ``waypoints: [...]``)."""

    channels: list[str] = dataclasses.field(default_factory=list)
    waypoints: list[JointWaypoint] = dataclasses.field(default_factory=list)


def load_joint_path(filename: str | Path) -> JointPath:
    """Load a :class:`JointPath` from YAML; every waypoint must give every channel."""
    path = _load_yaml_file(
        JointPath, filename, "joint path", "channels: [...], waypoints: [{t, values}, ...]"
    )
    for i, w in enumerate(path.waypoints):
        if set(w.values) != set(path.channels):
            raise ValueError(
                f"{shown(filename)}: waypoint {i} (t={w.t}) gives {sorted(w.values)}; every waypoint must "
                f"give exactly the channels {path.channels}"
            )
    return path


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
