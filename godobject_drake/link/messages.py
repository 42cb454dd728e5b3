"""What a scene and a device's driver say to each other on the link: the channel names, the
packing of a pose sample and of a driver's counts, the parsing of a pose message (Drake's
``lcmt_*`` types, which the drake wheel ships without ``pydrake.systems``), and the payloads of
the local model and of the scene's heartbeat (docs/local_model.md). The message formats
are in :mod:`godobject_drake.devices.lcm`'s docstring and docs/haptic_devices.md; the transport
that carries them is :mod:`godobject_drake.link.transport`.
"""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
from drake import lcmt_robot_state

POSE_CHANNEL = "GODOBJECT_DEVICE_POSE"


JOINT_CHANNEL = "GODOBJECT_DEVICE_JOINTS"


FEEDBACK_CHANNEL = "GODOBJECT_FEEDBACK"


DRIVER_STATUS_CHANNEL = "GODOBJECT_DRIVER_STATUS"


STOP_SUFFIX = "_STOP"


POSE_NAMES = ("x", "y", "z", "qw", "qx", "qy", "qz")


# What a driver counts (godobject_drake.driver.process), in the metrics as driver_<key>.
DRIVER_STATUS_KEYS = (
    "loops",  # device periods run
    "overruns",  # periods that started more than one period late
    "watchdog_trips",  # feedback went silent for the watchdog time: force zeroed
    "scene_stops",  # the scene said it stopped: force zeroed
    "force_clamps",  # device periods with the force cut to the device's rated maximum
    "rate_clamps",  # device periods with the force's change cut to the rated rate
    "buzz_events",  # feedback oscillating near the device's Nyquist rate: damped
    "bad_feedback",  # feedback messages that did not decode or were not finite
    "link_rejected",  # datagrams the driver's end of the link dropped (LINK_REJECTED)
)

# What the hand felt, as the driver reports it beside its counts (godobject_drake.driver.report):
# in the metrics as driver_<key>, None until a driver reports it (a driver before these keys).
DRIVER_FORCE_KEYS = (
    "force_peak_n",  # the largest force rendered (N)
    "force_mean_contact_n",  # its mean over the periods in contact (above 0.1 N); NaN: none yet
    "contact_s",  # how long the force rendered was above 0.1 N (s)
)


GRASP_PREFIX = "grasp="


LCM_STATUS_KEYS = (
    "lcm_messages",
    "lcm_bad_messages",
    "lcm_stale_messages",
    "lcm_bursts",
    "lcm_silent_samples",
)


def decode(message_type, raw: bytes):
    """``message_type.decode(raw)``, or None when ``raw`` is not one: another type (a fingerprint
    that differs: ``ValueError``), a truncated message or lengths past its end (``struct.error``)."""
    try:
        return message_type.decode(raw)
    except (ValueError, struct.error):
        return None


def parse_robot_state(raw: bytes, names) -> tuple[int, list[str], list[float], str | None] | None:
    """An ``lcmt_robot_state`` pose or joint sample: ``(utime, names, values, grasp)`` with the
    ``grasp=`` entry taken out (``grasp`` None when the message has none), or None when ``raw`` is
    not one (another type, a truncated message: LCM's decoding reads ``num_joints`` names and
    values, or fails)."""
    msg = decode(lcmt_robot_state, raw)
    if msg is None:
        return None
    names, values = list(msg.joint_name), list(msg.joint_position)
    grasp = None
    for i, name in enumerate(names):
        if name.startswith(GRASP_PREFIX):
            grasp = name[len(GRASP_PREFIX) :]
            del names[i], values[i]
            break
    return int(msg.utime), names, values, grasp


def status_message(utime: int, counts: dict) -> lcmt_robot_state:
    """A driver's counts as an ``lcmt_robot_state`` (names :data:`DRIVER_STATUS_KEYS`), and what the
    hand felt (:data:`DRIVER_FORCE_KEYS`, those ``counts`` has; None goes as NaN). A scene takes the
    names it knows: one older than a name ignores it."""
    names = [*DRIVER_STATUS_KEYS, *(k for k in DRIVER_FORCE_KEYS if k in counts)]
    msg = lcmt_robot_state()
    msg.utime = int(utime)
    msg.num_joints = len(names)
    msg.joint_name = names
    msg.joint_position = [math.nan if counts.get(k, 0) is None else float(counts.get(k, 0)) for k in names]
    return msg


def pose_message(utime: int, p, q, grasp: str | None = None) -> lcmt_robot_state:
    """An ``lcmt_robot_state`` pose sample, as a driver publishes it."""
    msg = lcmt_robot_state()
    msg.utime = int(utime)
    names, values = list(POSE_NAMES), [*map(float, p), *map(float, q)]
    if grasp is not None:
        names.append(GRASP_PREFIX + grasp)
        values.append(0.0)
    msg.num_joints, msg.joint_name, msg.joint_position = len(names), names, values
    return msg


# -- the local model ----------------------------------------------------------------------------

LOCAL_MODEL_CHANNEL = "GODOBJECT_LOCAL_MODEL"
LOCAL_MODEL_MAGIC = b"GLM2"  # GLM2: with the coupling's free lag (GLM1 had none)
# GLM3: GLM2 with the coupling's stiffness and damping as 3×3 matrices (an articulated tool
# through a trocar: stiffer along the tube than across it), each row-major after the lag
LOCAL_MODEL_MATRIX_MAGIC = b"GLM3"
MAX_PLANES = 8  # contacts per local model: a god-object held in a corner needs 3
_LM_HEAD = struct.Struct(">4sqqd4d3d3d4d3d3d3dB")  # see LocalModel
_LM3_HEAD = struct.Struct(">4sqqd4d3d3d4d3d3d3d9d9dB")  # GLM3: the two matrices before the plane count
_LM_PLANE = struct.Struct(">3d3dd")
UNIT_TOLERANCE = 1e-6  # a normal or quaternion further from unit length is refused, not renormalised
# A matrix further from symmetric than this (relative to its largest entry) is refused; one whose
# smallest eigenvalue is below this times its largest is not positive definite (a stiffness) or
# semidefinite (a damping: its eigenvalues ≥ −this times the largest)
MATRIX_TOLERANCE = 1e-9


class LocalModelError(ValueError):
    """A local model payload that cannot be rendered: the message names the field, its value and
    the limit."""


@dataclasses.dataclass(frozen=True)
class LocalModel:
    """What the scene publishes after each step on :data:`LOCAL_MODEL_CHANNEL`, so the
    driver computes the force with the handle's *current* pose (docs/local_model.md). Everything
    is in the device's frame Dev (m, m/s; a W-first unit quaternion), and the gains are the
    feedback coupling's seen from the device (``scale² kd``: N per metre of the handle).

    ``scene_utime``: the scene's simulated time (µs); ``pose_utime``: the ``utime`` of the newest
    pose sample the scene had taken (the driver's clock, µs; 0 before the first);
    ``period_s``: the scene's nominal publication period (s); ``p_G``, ``v_G``, ``q_G``, ``w_G``:
    the god-object's pose and velocity; ``p_T``: the coupling's target; ``lag``: the stretch
    ``p_G − p_T`` a god-object free of every contact would have now, driven by the same targets
    (the coupling's own lag as the hand moves: the scene's slow motion makes it large, and the
    driver leaves it out of the force in free space, docs/local_model.md); ``planes``: each
    ``(point, normal, stiffness)``: the god-object's reference point may not cross the plane
    through ``point`` against the unit ``normal`` (pointing out of the obstacle), ``stiffness``
    N/m (``inf``: rigid).

    ``stiffness``, ``damping``: None (the payload ``GLM2``: the coupling is ``kd``, ``gamma_d``
    alike in every direction), or the coupling's 3×3 matrices at the device, row-major (9
    floats; the payload ``GLM3``): an articulated tool driven through a trocar is stiffer along
    its tube than across it (docs/local_model.md "An articulated tool"). The stiffness is
    symmetric positive definite (or all zero: no spring), the damping symmetric positive
    semidefinite; ``kd`` and ``gamma_d`` are then their largest eigenvalues (the stiffest
    direction's: what a device's rated stiffness is checked against)."""

    scene_utime: int
    pose_utime: int
    period_s: float
    kd: float
    gamma_d: float
    kd_rot: float
    gamma_d_rot: float
    p_G: tuple
    v_G: tuple
    q_G: tuple
    w_G: tuple
    p_T: tuple
    lag: tuple = (0.0, 0.0, 0.0)
    planes: tuple = ()
    stiffness: tuple | None = None
    damping: tuple | None = None

    def encode(self) -> bytes:
        if len(self.planes) > MAX_PLANES:
            raise LocalModelError(
                f"a local model of {len(self.planes)} planes: at most {MAX_PLANES} (keep the nearest)"
            )
        if (self.stiffness is None) != (self.damping is None):
            raise LocalModelError("a local model states both its stiffness and damping matrices, or neither")
        matrices, head_format, magic = (), _LM_HEAD, LOCAL_MODEL_MAGIC
        if self.stiffness is not None:
            matrices = (*map(float, self.stiffness), *map(float, self.damping))
            head_format, magic = _LM3_HEAD, LOCAL_MODEL_MATRIX_MAGIC
        head = head_format.pack(
            magic, int(self.scene_utime), int(self.pose_utime), float(self.period_s),
            self.kd, self.gamma_d, self.kd_rot, self.gamma_d_rot,
            *self.p_G, *self.v_G, *self.q_G, *self.w_G, *self.p_T, *self.lag, *matrices, len(self.planes),
        )  # fmt: skip
        planes = (_LM_PLANE.pack(*point, *normal, stiffness) for point, normal, stiffness in self.planes)
        return head + b"".join(planes)


def _finite(name: str, values) -> None:
    if not all(math.isfinite(v) for v in values):
        raise LocalModelError(f"local model: {name} {list(values)} is not finite")


def _matrix(name: str, values, definite: bool) -> tuple:
    """``values`` (9, row-major) checked as a symmetric positive definite (``definite``; or all
    zero) or semidefinite 3×3 matrix, or :class:`LocalModelError` naming the matrix, the value
    and the limit."""
    _finite(name, values)
    m = np.array(values, float).reshape(3, 3)
    size = float(np.max(np.abs(m)))
    asymmetry = float(np.max(np.abs(m - m.T)))
    if asymmetry > MATRIX_TOLERANCE * size:
        raise LocalModelError(
            f"local model: {name} {list(values)} is not symmetric ({asymmetry:.3g} between an entry and its "
            f"transpose's, past {MATRIX_TOLERANCE:g} of its largest entry {size:.6g})"
        )
    low, high = (float(e) for e in np.linalg.eigvalsh(m)[[0, -1]])
    if definite and size > 0.0 and not low > MATRIX_TOLERANCE * high:
        raise LocalModelError(
            f"local model: {name} {list(values)} has the eigenvalue {low:.6g}, not > {MATRIX_TOLERANCE:g} "
            f"of its largest {high:.6g}: a stiffness is positive definite (or all zero: no spring)"
        )
    if not definite and low < -MATRIX_TOLERANCE * max(high, 0.0):
        raise LocalModelError(
            f"local model: {name} {list(values)} has the eigenvalue {low:.6g} < 0: a damping is positive "
            "semidefinite"
        )
    return tuple(values)


def parse_local_model(raw: bytes) -> LocalModel:
    """A :class:`LocalModel` from its payload (``GLM2``, or ``GLM3`` with the coupling's
    matrices), or :class:`LocalModelError` naming what is wrong: another magic, a length that
    does not match the plane count, more than :data:`MAX_PLANES` planes, a value that is not
    finite (a stiffness may be ``inf``: rigid), a negative gain, a stiffness ≤ 0, a normal or
    quaternion not of unit length (within :data:`UNIT_TOLERANCE`), a negative time or a period
    not > 0; in ``GLM3`` a stiffness matrix not symmetric or not positive definite (nor all
    zero), a damping matrix not symmetric or not positive semidefinite
    (:data:`MATRIX_TOLERANCE`). Nothing is renormalised or clamped."""
    raw = bytes(raw)
    head = _LM3_HEAD if raw[:4] == LOCAL_MODEL_MATRIX_MAGIC else _LM_HEAD
    if len(raw) < head.size:
        raise LocalModelError(f"local model: {len(raw)} bytes, shorter than its {head.size}-byte head")
    fields = head.unpack_from(raw)
    if fields[0] not in (LOCAL_MODEL_MAGIC, LOCAL_MODEL_MATRIX_MAGIC):
        raise LocalModelError(f"local model: magic {fields[0]!r}, not {LOCAL_MODEL_MAGIC!r}")
    n = fields[-1]
    if n > MAX_PLANES:
        raise LocalModelError(f"local model: {n} planes, at most {MAX_PLANES}")
    if len(raw) != head.size + n * _LM_PLANE.size:
        raise LocalModelError(
            f"local model: {len(raw)} bytes for {n} planes; expected {head.size + n * _LM_PLANE.size}"
        )
    scene_utime, pose_utime, period = fields[1:4]
    gains, rest = fields[4:8], fields[8:-1]
    p_G, v_G, q_G, w_G, p_T, lag = rest[0:3], rest[3:6], rest[6:10], rest[10:13], rest[13:16], rest[16:19]
    if scene_utime < 0 or pose_utime < 0:
        raise LocalModelError(f"local model: times {scene_utime}, {pose_utime} µs must be ≥ 0")
    _finite("period_s", [period])
    if not period > 0:
        raise LocalModelError(f"local model: period_s {period!r} must be > 0")
    _finite("gains", gains)
    if min(gains) < 0:
        raise LocalModelError(f"local model: gains {list(gains)} must be ≥ 0")
    for name, values in (("p_G", p_G), ("v_G", v_G), ("q_G", q_G), ("w_G", w_G), ("p_T", p_T), ("lag", lag)):
        _finite(name, values)
    if abs(math.hypot(*q_G) - 1.0) > UNIT_TOLERANCE:
        raise LocalModelError(f"local model: q_G {list(q_G)} is not a unit quaternion")
    matrices = {}
    if head is _LM3_HEAD:
        matrices = {"stiffness": _matrix("stiffness", rest[19:28], True),
                    "damping": _matrix("damping", rest[28:37], False)}  # fmt: skip
    planes = []
    for i in range(n):
        values = _LM_PLANE.unpack_from(raw, head.size + i * _LM_PLANE.size)
        point, normal, stiffness = values[0:3], values[3:6], values[6]
        _finite(f"plane {i} point/normal", [*point, *normal])
        if abs(math.hypot(*normal) - 1.0) > UNIT_TOLERANCE:
            raise LocalModelError(f"local model: plane {i} normal {list(normal)} is not of unit length")
        if math.isnan(stiffness) or not stiffness > 0:
            raise LocalModelError(f"local model: plane {i} stiffness {stiffness!r} must be > 0 (inf: rigid)")
        planes.append((point, normal, stiffness))
    return LocalModel(
        scene_utime, pose_utime, period, *gains, p_G, v_G, q_G, w_G, p_T, lag, tuple(planes), **matrices
    )


# -- the scene's word that it is alive -----------------------------------------------------------

ALIVE_CHANNEL = "GODOBJECT_LOCAL_MODEL_ALIVE"
ALIVE_MAGIC = b"GLA1"
_ALIVE = struct.Struct(">4sq")  # the magic, then the scene time (µs) of the newest model sent


def alive_message(scene_utime: int) -> bytes:
    """The scene's heartbeat: it is alive and its newest model (``scene_utime``) still stands
    (link/scene_model.py ``SceneHeartbeat``, docs/local_model.md "Validity")."""
    return _ALIVE.pack(ALIVE_MAGIC, int(scene_utime))


def parse_alive(raw: bytes) -> int:
    """The model time a heartbeat vouches for (µs), or :class:`LocalModelError` naming the
    length, the magic or the time that is wrong."""
    raw = bytes(raw)
    if len(raw) != _ALIVE.size:
        raise LocalModelError(f"scene heartbeat: {len(raw)} bytes; expected {_ALIVE.size}")
    magic, scene_utime = _ALIVE.unpack(raw)
    if magic != ALIVE_MAGIC:
        raise LocalModelError(f"scene heartbeat: magic {magic!r}, not {ALIVE_MAGIC!r}")
    if scene_utime < 0:
        raise LocalModelError(f"scene heartbeat: time {scene_utime} µs must be ≥ 0")
    return scene_utime
