"""Devices on LCM, Drake's hardware convention: a driver publishes the device's samples, the
scene publishes the feedback wrench back.

Messages (the ``lcmt_*`` types the drake wheel ships; README "Real devices over LCM"):

- **Pose samples** on ``GODOBJECT_DEVICE_POSE``: ``lcmt_robot_state`` with ``utime`` (µs, the
  driver's clock), ``joint_name = [x, y, z, qw, qx, qy, qz]`` (m; a unit quaternion, W first)
  and their values in ``joint_position``. An extra entry named ``grasp=*`` holds the body
  nearest the device (a device's button), ``grasp=`` holds nothing; without one the grasp is
  unchanged.
- **Joint samples** on ``GODOBJECT_DEVICE_JOINTS``: ``lcmt_robot_state`` with the scenario's
  channels as ``joint_name``, in order.
- **Feedback** on ``GODOBJECT_FEEDBACK``: ``lcmt_force_torque`` at the device's rate,
  ``timestamp`` the simulation time in µs, ``fx, fy, fz`` (N) and ``tx, ty, tz`` (N·m) the wrench
  the device should render, in W (the feedback port's ``F_Do_W``).
- **Local model** on ``GODOBJECT_LOCAL_MODEL`` (``udp://`` driver links only, issue 44):
  :class:`~godobject_drake.protocol.LocalModel`, the god-object, the feedback gains and the
  contact planes near the held body, in the device's frame, every device period and at most
  every :data:`LOCAL_MODEL_MIN_PERIOD_S` of simulated time (:class:`LocalModelPublisher`;
  docs/local_model.md): the driver renders from it at its own rate. Between two models, while
  the scene's loop is held up (folding its logs, a long step), a thread of its own says on
  ``GODOBJECT_LOCAL_MODEL_ALIVE`` that the scene is alive and its newest model stands
  (:class:`SceneHeartbeat`), for at most :data:`STALL_LIMIT_S` after that model.

What arrives is checked at each device sample (:class:`LcmReceiver`), and every fault is
counted in the metrics (:data:`LCM_STATUS_KEYS`):

- no message yet: the device stays at its start pose, at rest;
- none for ``timeout_periods`` samples (a driver unplugged): the sample is dropped, so the
  device source holds the last pose at rest (``device_dropped_samples``);
- a ``utime`` going backwards or repeated: the message is dropped (``lcm_stale_messages``);
- several new messages in one period (a burst): the newest is used (``lcm_bursts``);
- a message that does not decode as ``lcmt_robot_state``, names other entries, or grasps a
  body the coupling does not know: dropped (``lcm_bad_messages``);
- NaN, infinite or a non-unit quaternion: the device's :class:`~godobject_drake.devices.sources.SampleGuard`
  handles it as for any device (joint devices: a non-finite value drops the message).

Use ``memq://`` for tests (in-process; nothing leaves the process). Drake's default URL is UDP
multicast, for a lab's own network. ``udp://HOST:PORT`` is a point-to-point link to a driver
process (:mod:`~godobject_drake.protocol`, :mod:`~godobject_drake.driver.process`).

**Device frame** (docs/haptic_devices.md "Calibration"): a driver reports the device's pose in
its own frame Dev (m); ``X_WDev`` and ``scale`` map it into W, ``p_W = X_WDev (scale p_Dev)``,
``R_W = R_WDev R_Dev``, and the feedback wrench goes back into Dev with the power-preserving
inverse, ``f_Dev = scale R_WDevᵀ f_W``, ``τ_Dev = R_WDevᵀ τ_W`` (what the hand puts in through
the device equals what the scene takes out). The identity (the default) leaves every value as it
was. Samples outside the scenario's workspace are counted (``device_outside_workspace``), not moved.

**Stop**: at every stop the scene publishes the zero wrench on the feedback channel and then
an empty ``lcmt_force_torque`` on ``<feedback channel>_STOP``, which a driver takes as "the scene
has stopped": zero force at once, without waiting for its watchdog.

**Driver status**: a driver (:mod:`~godobject_drake.driver.process`) publishes its fault counts on
``GODOBJECT_DRIVER_STATUS`` (``lcmt_robot_state``, one entry per count, :data:`DRIVER_STATUS_KEYS`);
on a ``udp://`` link the newest counts are in the metrics as ``driver_*``.

**Pairing** (``udp://`` only): the link takes messages from its one paired driver only, each
authenticated with the key of ``key_file`` and never twice (:mod:`~godobject_drake.protocol`);
what it drops is counted as ``lcm_udp_*`` in the metrics (``lcm_udp_unauthenticated``,
``lcm_udp_replayed``, ``lcm_udp_refused_drivers``, ...). ``memq://`` (one process) and Drake's
``udpm://`` (multicast: anyone on the network) are not paired.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np
from drake import lcmt_force_torque, lcmt_robot_state
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.lcm import DrakeLcm
from pydrake.math import RigidTransform
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import LeafSystem

from godobject_drake.config.device_files import DEFAULT_DEVICE_RATE_HZ, SampleGuard
from godobject_drake.config.gains import GRASP_NEAREST
from godobject_drake.devices.sources import DeviceSource, JointDevice
from godobject_drake.protocol import (
    ALIVE_CHANNEL,
    DRIVER_STATUS_CHANNEL,
    DRIVER_STATUS_KEYS,
    FEEDBACK_CHANNEL,
    JOINT_CHANNEL,
    LCM_STATUS_KEYS,
    LOCAL_MODEL_CHANNEL,
    MAX_PLANES,
    POSE_CHANNEL,
    POSE_NAMES,
    STOP_SUFFIX,
    LocalModel,
    alive_message,
    decode,
    parse_robot_state,
)


class LcmReceiver:
    """The messages of one channel, taken at each device sample (module docstring).

    ``poll()`` handles what arrived since the last call and returns whether a new sample was
    accepted; ``latest`` is ``(values, grasp)`` of the newest accepted one (``grasp`` None when
    the message did not say), or None before the first.
    """

    def __init__(
        self,
        lcm: DrakeLcm,
        channel: str,
        names: Sequence[str],
        timeout_periods: int = 5,
        grasp_ok: Callable[[str], bool] | None = None,
    ):
        if int(timeout_periods) != timeout_periods or timeout_periods < 1:
            raise ValueError(
                f"timeout_periods={timeout_periods!r} must be a whole number of samples ≥ 1; it is how "
                "many samples without a message make the device hold (e.g. 5)"
            )
        self.lcm, self.channel, self.names = lcm, channel, tuple(names)
        self.grasp_ok = grasp_ok or (lambda name: True)
        self.timeout_periods = int(timeout_periods)
        self.counts = dict.fromkeys(LCM_STATUS_KEYS, 0)
        self.latest: tuple[np.ndarray, str | None] | None = None
        self._pending: list[bytes] = []
        self._last_utime: int | None = None
        self._quiet = 0
        lcm.Subscribe(channel, self._pending.append)

    def poll(self) -> bool:
        self.lcm.HandleSubscriptions(0)
        accepted = 0
        for raw in self._pending:
            self.counts["lcm_messages"] += 1
            parsed = self._parse(raw)
            if parsed is None:
                self.counts["lcm_bad_messages"] += 1
                continue
            utime, values, grasp = parsed
            if self._last_utime is not None and utime <= self._last_utime:
                self.counts["lcm_stale_messages"] += 1
                continue
            self._last_utime, self.latest = utime, (values, grasp)
            accepted += 1
        self._pending.clear()
        if accepted > 1:
            self.counts["lcm_bursts"] += 1
        self._quiet = 0 if accepted else self._quiet + 1
        if not accepted:
            self.counts["lcm_silent_samples"] += 1
        return accepted > 0

    def wait_first(self, timeout_s: float, clock: Callable[[], float] = time.monotonic) -> bool:
        """Wait up to ``timeout_s`` (wall time) until a first message is accepted; whether one was.
        A run calls it before its clock starts, so the scene started first waits for its driver."""
        deadline = clock() + timeout_s
        while self.latest is None:
            left = deadline - clock()
            if left <= 0:
                return False
            self.lcm.HandleSubscriptions(max(1, min(100, int(left * 1e3))))
            if self._pending:
                self.poll()
        return True

    @property
    def timed_out(self) -> bool:
        """No message for more than ``timeout_periods`` samples since the last one."""
        return self.latest is not None and self._quiet > self.timeout_periods

    def _parse(self, raw: bytes):
        parsed = parse_robot_state(raw, self.names)
        if parsed is None:
            return None
        utime, names, values, grasp = parsed
        if tuple(names) != self.names or (grasp is not None and not self.grasp_ok(grasp)):
            return None
        return utime, np.asarray(values, float), grasp


class LcmDevice(DeviceSource):
    """A pose device whose samples come over LCM (module docstring).

    Parameters
    ----------
    lcm : DrakeLcm
        The LCM to listen on (``memq://`` in tests).
    X_WD0 : RigidTransform
        Where the device stands until its first message.
    channel : str
        The channel of its ``lcmt_robot_state`` samples.
    timeout_periods : int
        Samples without a message after which the device holds at rest.
    period_s, latency_s, guard, interpolation :
        As for :class:`~godobject_drake.devices.sources.DeviceSource`: the rate the driver is expected
        to publish at.
    feedback_channel : str
        Where :func:`add_feedback_publisher` sends the feedback wrench.
    grasp : str
        A body the device always holds; empty: the messages' ``grasp=`` entries decide.
    """

    def __init__(
        self,
        lcm: DrakeLcm,
        X_WD0: RigidTransform,
        channel: str = POSE_CHANNEL,
        timeout_periods: int = 5,
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        guard: SampleGuard | None = None,
        interpolation: str = "hold",
        feedback_channel: str = FEEDBACK_CHANNEL,
        grasp: str = "",
        X_WDev: RigidTransform | None = None,
        scale: float = 1.0,
        workspace: tuple | None = None,
    ):
        self.lcm, self.feedback_channel, self._fixed_grasp = lcm, feedback_channel, grasp
        self.X_WDev = None if X_WDev is None and scale == 1.0 else (X_WDev or RigidTransform())
        self.scale = float(scale)
        self.workspace = None if workspace is None else (np.asarray(workspace[0]), np.asarray(workspace[1]))
        self._outside = 0
        self.driver_link = not isinstance(lcm, DrakeLcm)  # udp://: a driver process reports its counts
        self.driver_counts = dict.fromkeys(DRIVER_STATUS_KEYS, 0)
        self.driver_status_messages = 0
        self.driver_bad_status = 0  # status messages that did not decode
        if self.driver_link:
            lcm.Subscribe(DRIVER_STATUS_CHANNEL, self._driver_status)
        self.known_grasps: set[str] | None = None  # the coupling's names (connect_feedback)
        self.receiver = LcmReceiver(lcm, channel, POSE_NAMES, timeout_periods, self._grasp_ok)
        self._p0 = X_WD0.translation().copy()
        self._q0 = X_WD0.rotation().ToQuaternion().wxyz()
        self._grasp = ""
        self._polled_at = -math.inf
        self.throttle = WallThrottle.from_environment()
        super().__init__(self._read, period_s, latency_s, interpolation=interpolation, guard=guard)

    def _read(self, t: float):
        fresh = False
        if t > self._polled_at:  # once per device sample; not from a build-time query
            self._polled_at = t
            if t > 0.0 or self.receiver.latest is None:
                fresh = self.receiver.poll()
        latest = self.receiver.latest
        if latest is None:
            return self._p0, self._q0, self._fixed_grasp
        if self.receiver.timed_out:
            return None  # dropped: the device source holds the last pose, at rest
        values, grasp = latest
        if grasp is not None:
            self._grasp = GRASP_NEAREST if grasp == "*" else grasp
        p, q = values[:3], values[3:7]
        if self.X_WDev is not None:
            p, q = self.to_world(p, q)
        if fresh and self.workspace is not None and np.all(np.isfinite(p)):
            lower, upper = self.workspace
            self._outside += int(np.any(p < lower) or np.any(p > upper))
        return p, q, self._fixed_grasp or self._grasp

    def to_world(self, p_Dev, q_Dev):
        """A driver's pose (its frame Dev, m; a W-first quaternion) in W: ``X_WDev (scale p)``,
        ``R_WDev R``. A non-unit or NaN quaternion is passed on unchanged for the sample guard."""
        p = self.X_WDev.multiply(self.scale * np.asarray(p_Dev, float))
        q = np.asarray(q_Dev, float)
        norm = np.linalg.norm(q)
        if not (np.all(np.isfinite(q)) and abs(norm - 1.0) < 1e-6):
            return p, q
        from pydrake.common.eigen_geometry import Quaternion

        q_W = self.X_WDev.rotation().ToQuaternion().multiply(Quaternion(q / norm)).wxyz()
        return p, q_W * norm

    def _driver_status(self, raw: bytes) -> None:
        msg = decode(lcmt_robot_state, raw)
        if msg is None:
            self.driver_bad_status += 1
            return
        self.driver_status_messages += 1
        for name, value in zip(msg.joint_name, msg.joint_position, strict=False):
            if name in self.driver_counts and math.isfinite(value):
                self.driver_counts[name] = round(value)

    def _grasp_ok(self, name: str) -> bool:
        return name in ("", "*") or self.known_grasps is None or name in self.known_grasps

    def grasp_names(self, duration_s: float | None = None) -> set[str]:
        """The fixed body if any: a driver names no body in advance (``grasp=*`` picks the nearest)."""
        return {self._fixed_grasp} if self._fixed_grasp else set()

    def samples(self, duration_s: float):
        """Only the start is known before the run (the rest is the driver's)."""
        return [(0.0, self._read(0.0))]

    def lcm_status(self) -> dict:
        counts = dict(self.receiver.counts)
        if (self.workspace is not None and self.X_WDev is not None) or self.driver_link:
            counts["device_outside_workspace"] = self._outside
        if self.driver_link:
            self.lcm.HandleSubscriptions(0)  # the driver's last counts, sent as it stops
            counts.update({f"driver_{k}": v for k, v in self.driver_counts.items()})
            counts["driver_status_messages"] = self.driver_status_messages
            counts["driver_bad_status"] = self.driver_bad_status
            counts.update({f"lcm_{k}": v for k, v in self.lcm.counts.items()})
            publisher = getattr(self, "local_publisher", None)
            if publisher is not None:  # the local model's cost on the scene's side (issue 44)
                counts["lcm_local_models"] = publisher.published
                counts["lcm_local_model_ms"] = 1e3 * publisher.seconds / max(publisher.published, 1)
                counts["lcm_heartbeats"] = publisher.heartbeat.beats  # the loop was held up: the scene spoke
        return counts

    def status(self, context) -> dict:
        return {**super().status(context), **self.lcm_status()}

    def zero_feedback(self, t: float) -> bool:
        """Publish a zero ``lcmt_force_torque`` on the feedback channel, stamped ``t``: whatever
        stopped the run (its end, Stop, a divergence, an error, a signal), the device's last
        feedback message asks for no force."""
        publisher = getattr(self, "local_publisher", None)
        if publisher is not None:  # a stopped scene vouches for no model
            publisher.heartbeat.stop()
        message = lcmt_force_torque()
        message.timestamp = round(t * 1e6)
        self.lcm.Publish(self.feedback_channel, message.encode())
        self.lcm.Publish(self.feedback_channel + STOP_SUFFIX, message.encode())  # then: stopped
        return True

    def connect_feedback(self, builder, F_Do_W_port, grasp_names):
        """The real device renders the feedback: publish it; a message naming another body than
        ``grasp_names`` is refused (counted)."""
        self.known_grasps = set(grasp_names)
        return add_feedback_publisher(builder, F_Do_W_port, self)

    def connect_local_model(self, builder, coupling, gains) -> LeafSystem | None:
        """A driver link (``udp://``) also gets the local model after each step (issue 44,
        docs/local_model.md): :class:`LocalModelPublisher`, reading the coupling and the scene's
        geometry. Other transports (``memq://``, Drake's multicast): nothing."""
        if not self.driver_link or not builder.HasSubsystemNamed("scene_graph"):
            return None
        plant = builder.GetSubsystemByName("plant")
        scene_graph = builder.GetSubsystemByName("scene_graph")
        publisher = builder.AddNamedSystem(
            "local_model_publisher", LocalModelPublisher(self, plant, gains, coupling)
        )
        self.local_publisher = publisher
        for port in ("held_body", "pose_WT", "V_WT", "pose_WG", "V_WG"):
            builder.Connect(coupling.GetOutputPort(port), publisher.GetInputPort(port))
        for port in ("X_WD", "V_WD"):  # the samples the coupling holds, for the free lag
            builder.Connect(self.GetOutputPort(port), publisher.GetInputPort(port))
        builder.Connect(scene_graph.get_query_output_port(), publisher.GetInputPort("query"))
        return publisher


class LcmJointDevice(JointDevice):
    """A joint-space device whose channel values come over LCM; it holds the last good
    values (the start values before the first message, or after a non-finite one)."""

    def __init__(
        self,
        lcm: DrakeLcm,
        channels: Sequence[str],
        start: Sequence[float],
        channel: str = JOINT_CHANNEL,
        timeout_periods: int = 5,
        mix=None,
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
    ):
        self.lcm = lcm
        self.receiver = LcmReceiver(lcm, channel, channels, timeout_periods)
        self._values = self._start = np.asarray(start, float).reshape(-1)
        if self._values.size != len(channels):
            raise ValueError(f"{len(channels)} channels {list(channels)} need as many start values: {start}")
        self._polled_at = -math.inf
        super().__init__(self._read, channels, mix, period_s, latency_s)

    def _read(self, t: float) -> np.ndarray:
        fresh = False
        if t > self._polled_at:
            self._polled_at = t
            fresh = t > 0.0 and self.receiver.poll()
        elif t == 0.0 and self.receiver.latest is not None and self._values is self._start:
            fresh = True  # the run waited for the first message (simulation.wait_for_devices)
        if fresh:
            values, _ = self.receiver.latest
            if np.all(np.isfinite(values)):
                self._values = values
            else:
                self.receiver.counts["lcm_bad_messages"] += 1
        return self._values

    def samples(self, duration_s: float) -> np.ndarray:
        """Only the start is known before the run (the builder checks gains there)."""
        return np.array([self.mix @ self._values])

    def lcm_status(self) -> dict:
        counts = dict(self.receiver.counts)
        if not isinstance(self.lcm, DrakeLcm):  # udp://: the link's own counts
            counts.update({f"lcm_{k}": v for k, v in self.lcm.counts.items()})
        return counts

    def status(self, context) -> dict:
        return self.lcm_status()


def add_feedback_publisher(builder, F_Do_W_port, device: LcmDevice):
    """Publish ``F_Do_W`` as ``lcmt_force_torque`` on the device's feedback channel at its rate
    (in the device's frame when the device has one: module docstring)."""
    from pydrake.systems.lcm import LcmPublisherSystem

    mapping = (
        {} if device.X_WDev is None else dict(R_WDev=device.X_WDev.rotation().matrix(), scale=device.scale)
    )
    message = builder.AddNamedSystem("feedback_message", ForceTorqueMessage(**mapping))
    if isinstance(device.lcm, DrakeLcm):
        system = LcmPublisherSystem.Make(
            device.feedback_channel, lcmt_force_torque, device.lcm, device.period_s
        )
    else:  # a driver link (udp://): Drake's publisher takes only its own C++ LCM
        system = ForceTorquePublisher(device.lcm, device.feedback_channel, device.period_s)
        system.throttle = device.throttle
    publisher = builder.AddNamedSystem("feedback_publisher", system)
    builder.Connect(F_Do_W_port, message.GetInputPort("F_Do_W"))
    builder.Connect(message.GetOutputPort("message"), publisher.get_input_port())
    return publisher


class ForceTorquePublisher(LeafSystem):
    """Publishes its ``lcmt_force_torque`` input every ``period_s`` from t = 0 on a Python LCM
    (``Publish(channel, bytes)``), as Drake's ``LcmPublisherSystem`` does on its own."""

    def __init__(self, lcm, channel: str, period_s: float):
        super().__init__()
        self.lcm, self.channel = lcm, channel
        self._in = self.DeclareAbstractInputPort("lcm_message", AbstractValue.Make(lcmt_force_torque()))
        self.DeclarePeriodicPublishEvent(period_s, 0.0, self._publish)
        self.throttle = None  # a WallThrottle (test-only: the scene's rate of wall time)

    def _publish(self, context):
        if self.throttle is not None and not self.throttle.due(context.get_time()):
            return
        self.lcm.Publish(self.channel, self._in.Eval(context).encode())


class ForceTorqueMessage(LeafSystem):
    """``F_Do_W`` (torque first, as Drake's spatial forces) → ``lcmt_force_torque`` for a publisher;
    with ``R_WDev`` and ``scale``, in the device's frame: ``f = scale R_WDevᵀ f_W``, ``τ = R_WDevᵀ τ_W``."""

    def __init__(self, R_WDev=None, scale: float = 1.0):
        super().__init__()
        self._R_DevW = None if R_WDev is None else np.asarray(R_WDev, float).T
        self._scale = float(scale)
        self._F = self.DeclareVectorInputPort("F_Do_W", 6)
        self.DeclareAbstractOutputPort("message", lambda: AbstractValue.Make(lcmt_force_torque()), self._calc)

    def _calc(self, context, output):
        F = self._F.Eval(context)
        if self._R_DevW is not None:
            F = np.concatenate([self._R_DevW @ F[:3], self._scale * (self._R_DevW @ F[3:])])
        msg = lcmt_force_torque()
        msg.timestamp = round(context.get_time() * 1e6)
        msg.tx, msg.ty, msg.tz, msg.fx, msg.fy, msg.fz = (float(v) for v in F)
        output.set_value(msg)


THROTTLE_ENV = "GODOBJECT_TEST_SCENE_HZ"


class WallThrottle:
    """Test-only: lets a scene's link publish at most ``rate_hz`` times a second of *wall* time,
    to emulate a scene that sustains only that rate (analysis/local_model_bench.py). Set by the
    environment variable :data:`THROTTLE_ENV` (unset: no throttle). Each publisher has its own
    (the wrench's and the local model's steps differ); within one, a step's answer is memoised."""

    def __init__(self, rate_hz: float, clock=None):

        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"{THROTTLE_ENV}={rate_hz!r}: give a rate in Hz > 0 (e.g. 30), or unset it")
        self.interval, self.clock = 1.0 / rate_hz, clock or time.monotonic
        self._next = -math.inf
        self._step, self._due = None, False

    @classmethod
    def from_environment(cls) -> WallThrottle | None:

        text = os.environ.get(THROTTLE_ENV, "")
        if not text:
            return None
        try:
            rate = float(text)
        except ValueError:
            rate = math.nan
        return cls(rate)

    def due(self, step_time: float) -> bool:
        """Whether the step at simulated ``step_time`` is published (the same answer for every
        publisher of that step)."""
        if step_time != self._step:
            now = self.clock()
            self._step, self._due = step_time, now >= self._next
            if self._due:
                self._next = max(self._next + self.interval, now - self.interval)
        return self._due


PLANE_MARGIN_M = 0.005  # contacts the god-object could reach: within this of its held body
# The local model is published every device period, at most this often (s of simulated time):
# the driver renders at its own rate from it, and a model costs the scene ~0.5 ms (Python: the
# signed distances, the message), which every 1 ms step could not afford (docs/local_model.md)
LOCAL_MODEL_MIN_PERIOD_S = 0.004


class FreeLag:
    """The stretch ``p_G − p_T`` of a god-object free of every contact, driven by the same
    device samples as the scene's (issue 44; docs/local_model.md): the coupling's own lag as the
    hand moves, which the driver leaves out of the force.

    The coupling pulls the held body by ``a = ωn² (p_T − p) + 2 ζ ωn (v_T − v)`` (per unit mass,
    gravity compensated, ``|a| ≤ ωn² max_stretch_m`` as its force cap); this integrates that law
    for a body nothing touches as Drake steps it at the plant's step ``h``: symplectic Euler for
    the explicit coupling (an applied force), backward Euler for the implicit one (``implicit``:
    SAP steps its springs), over each device period with the sample the coupling held over it.
    In Drake that is the sample a publish event at the period's *start* reads (measured: a free
    brick carried at 0.35 m/s had ``p_G − p_T`` 0 in the scene and 0.35 mm, one sample's motion,
    in a twin that used the sample read at ``t`` for the period before ``t``), so :meth:`advance`
    is given the sample read at ``t`` and moves on with the one read at the call before. It
    follows the device point D (the target is D carried by the grasp offset: the same lag while
    the device does not turn). Where the scene's body touches nothing it moves the same way, so
    ``p_G − p_T − lag`` is about zero however fast the target moved in simulated time (a scene at
    a tenth of real time sees a 6 cm/s hand at 60 cm/s, and its god-object lags millimetres: drag
    a hand would feel); where a contact held it back, the difference is what the contact did.
    :meth:`reset` on each change of held body (to the god-object's stretch and velocity)."""

    def __init__(
        self, omega_n2: float, two_zeta_omega: float, max_stretch_m: float, step_s: float, implicit=False
    ):
        self.k, self.b, self.h = float(omega_n2), float(two_zeta_omega), float(step_s)
        self.implicit = bool(implicit)  # the implicit coupling's springs: backward Euler, as SAP steps them
        self.a_max = self.k * float(max_stretch_m)  # inf: no cap
        self.held, self.t = None, None
        self.p = self.v = self.lag = (0.0, 0.0, 0.0)  # plain floats: this runs every device period
        self.d = self.u = (0.0, 0.0, 0.0)  # the sample held from self.t on: p_D, v_D

    def reset(self, t: float, held: int, p_D, stretch, v_G, v_D) -> None:
        """Start on the scene's god-object: ``p_D + stretch`` moving at ``v_G`` (nothing held: on
        D), the device's sample ``p_D``, ``v_D`` held from ``t`` on."""
        self.held, self.t = held, t
        self.d, self.u = tuple(float(c) for c in p_D), tuple(float(c) for c in v_D)
        self.lag = tuple(float(c) for c in stretch) if held >= 0 else (0.0, 0.0, 0.0)
        self.p = tuple(d + e for d, e in zip(self.d, self.lag, strict=True))
        self.v = tuple(float(c) for c in v_G) if held >= 0 else self.u

    def advance(self, t: float, p_D, v_D) -> tuple:
        """The lag at ``t`` (W, m) from the device's sample ``p_D``, ``v_D`` that starts at ``t``:
        the free god-object moved over the period since the last call with the sample given then.
        Plain floats: it runs every device period, where numpy on 3-vectors cost 20-70 µs."""
        new_d = tuple(p_D.tolist()) if isinstance(p_D, np.ndarray) else tuple(map(float, p_D))
        new_u = tuple(v_D.tolist()) if isinstance(v_D, np.ndarray) else tuple(map(float, v_D))
        if self.held is None or self.held < 0 or not t > self.t:  # nothing held: G is on D
            self.t, self.p, self.v, self.lag = t, new_d, new_u, (0.0, 0.0, 0.0)
            self.d, self.u = new_d, new_u
            return self.lag
        (d0, d1, d2), (u0, u1, u2) = self.d, self.u
        n = max(1, round((t - self.t) / self.h))
        dt, k, b, a_max = (t - self.t) / n, self.k, self.b, self.a_max
        (p0, p1, p2), (v0, v1, v2) = self.p, self.v
        if self.implicit:
            # v⁺ (1 + h b + h² k) = v + h (k (d − p) + b u), p⁺ = p + h v⁺; the implicit coupling
            # caps the stretch (its target within max_stretch_m), which a free body never reaches
            den = 1.0 + dt * b + dt * dt * k
            for _ in range(n):
                v0 = (v0 + dt * (k * (d0 - p0) + b * u0)) / den
                v1 = (v1 + dt * (k * (d1 - p1) + b * u1)) / den
                v2 = (v2 + dt * (k * (d2 - p2) + b * u2)) / den
                p0, p1, p2 = p0 + dt * v0, p1 + dt * v1, p2 + dt * v2
        else:
            for _ in range(n):
                a0 = k * (d0 - p0) + b * (u0 - v0)
                a1 = k * (d1 - p1) + b * (u1 - v1)
                a2 = k * (d2 - p2) + b * (u2 - v2)
                norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
                if norm > a_max:
                    s = a_max / norm
                    a0, a1, a2 = a0 * s, a1 * s, a2 * s
                v0, v1, v2 = v0 + dt * a0, v1 + dt * a1, v2 + dt * a2
                p0, p1, p2 = p0 + dt * v0, p1 + dt * v1, p2 + dt * v2
        self.t, self.p, self.v, self.d, self.u = t, (p0, p1, p2), (v0, v1, v2), new_d, new_u
        self.lag = (p0 - new_d[0], p1 - new_d[1], p2 - new_d[2])
        return self.lag


def plane_point(p_WG, distance: float, normal, stiffness: float) -> np.ndarray:
    """Where a pair's plane passes: through the god-object's point ``p_WG`` moved against the
    ``normal`` (out of the obstacle) by as much as it may still move toward it. A rigid pair
    (``stiffness`` inf) by its gap while apart, and not at all once touching: a penetration is the
    solver's, the proxy starts at G. A soft pair by its signed distance: G sunk by the contact's
    compliance puts the plane back at the undeformed surface, which the driver lets the proxy into
    by ``kd/(kd + s)`` of the way — the plane through G would soften the contact twice."""
    gap = distance if math.isfinite(stiffness) else max(distance, 0.0)
    return np.asarray(p_WG, float) - gap * np.asarray(normal, float)


BEAT_S = 0.005  # s of wall time between two heartbeats while no model is sent
STALL_LIMIT_S = 0.5  # s: a scene whose loop has sent no model for this long vouches for none


class SceneHeartbeat:
    """The scene's word that it is alive while its loop is held up (issue 44, docs/local_model.md
    "Validity"): a thread of its own, every :data:`BEAT_S` of wall time, publishes
    :func:`~godobject_drake.protocol.alive_message` with the newest model's time, when that
    model is at least ``beat_s`` old and at most ``stall_limit_s``. The driver holds the model
    for as long as it hears this (its validity counts from the newest of the model and its
    heartbeats), so a loop paused by a fold of its logs or a long step (0.1 to 0.2 s on a
    loaded machine, where the model's own validity is 3 scene periods + 50 ms) does not fade
    the wall; a scene killed falls silent, and the fade bound holds from its last word; a loop
    that hangs is vouched for ``stall_limit_s`` at most.

    :meth:`tick` is the decision (plain arithmetic on the times given, tested exactly); the
    thread, started by the first model, calls it. ``publish`` takes the payload."""

    def __init__(
        self,
        publish: Callable[[bytes], None],
        beat_s: float = BEAT_S,
        stall_limit_s: float = STALL_LIMIT_S,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.publish, self.beat_s, self.stall_limit_s, self.clock = publish, beat_s, stall_limit_s, clock
        self.utime: int | None = None  # the newest model's scene time (µs)
        self.model_at = -math.inf  # when it was sent (``clock``)
        self.beats = 0
        self.stopped = False
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None

    def model_sent(self, utime: int, now: float) -> None:
        """The loop sent a model of scene time ``utime`` at ``now``; the first starts the thread,
        and the first after a stop (the same scene run again) a new one."""
        with self._lock:
            self.utime, self.model_at = int(utime), float(now)
            if self.stopped:
                self.stopped, self._wake, self._thread = False, threading.Event(), None
            start = self._thread is None
            if start:
                self._thread = threading.Thread(
                    target=self._run, args=(self._wake,), name="scene-heartbeat", daemon=True
                )
        if start:
            self._thread.start()

    def tick(self, now: float) -> bool:
        """Beat now if a model stands that is at least ``beat_s`` and at most ``stall_limit_s``
        old; whether it beat. Sent under the lock, so a stop returns only once a beat under way
        has left: none follows the scene's stop message."""
        with self._lock:
            if self.stopped or self.utime is None:
                return False
            age = now - self.model_at
            if age < self.beat_s or age > self.stall_limit_s:
                return False
            self.publish(alive_message(self.utime))
            self.beats += 1
            return True

    def stop(self) -> None:
        """No more heartbeats (the scene stopped); a beat being sent has left when it returns."""
        with self._lock:
            self.stopped = True
        self._wake.set()

    def _run(self, wake: threading.Event) -> None:
        while not wake.wait(self.beat_s):
            try:
                self.tick(self.clock())
            except (OSError, ValueError):  # the link closed under it: the scene is ending
                self.stop()


class LocalModelPublisher(LeafSystem):
    """The local model every device period, at most every :data:`LOCAL_MODEL_MIN_PERIOD_S` of
    simulated time (issue 44; docs/local_model.md):
    :class:`~godobject_drake.protocol.LocalModel` on :data:`LOCAL_MODEL_CHANNEL`, in the device's
    frame (``p_Dev = R_WDevᵀ (p_W − p_WDev) / scale``; gains ``scale² kd``).

    The planes: every geometry pair of the held body and another body within
    :data:`PLANE_MARGIN_M` (Drake's signed distance query, broad phase first), one plane per
    distinct normal (the nearest), at most :data:`~godobject_drake.protocol.MAX_PLANES`:
    through the god-object's point moved against the normal as far as it may still move
    (:func:`plane_point`), normal out of the obstacle, stiffness the pair's point-contact
    stiffness in series (inf when the geometries state none)."""

    def __init__(self, device: LcmDevice, plant, gains, coupling=None):
        super().__init__()
        self.device, self.plant, self.gains = device, plant, gains
        X = device.X_WDev or RigidTransform()
        self._R_DevW = X.rotation().matrix().T
        self._p_WDev = X.translation().copy()
        self._scale = device.scale
        self._q_DevW = X.rotation().inverse().ToQuaternion()
        for name, size in (("held_body", 1), ("pose_WT", 7), ("V_WT", 6), ("pose_WG", 7), ("V_WG", 6)):
            self.DeclareVectorInputPort(name, size)

        self._query = self.DeclareAbstractInputPort("query", AbstractValue.Make(QueryObject()))
        # every device period the free lag moves on (one event: the lag is moved before a model
        # is built); every `every` of them a model is published
        self.every = max(1, math.ceil(LOCAL_MODEL_MIN_PERIOD_S / device.period_s - 1e-9))
        self.period_s = self.every * device.period_s
        self._ticks = 0
        self.DeclarePeriodicPublishEvent(device.period_s, 0.0, self._publish)
        self._X_WD = self.DeclareAbstractInputPort("X_WD", AbstractValue.Make(RigidTransform()))
        self._V_WD = self.DeclareVectorInputPort("V_WD", 6)
        self.throttle = WallThrottle.from_environment()  # its own: its steps are not the wrench's
        self._geometries: dict = {}  # body index -> its collision geometries, filled as first held
        self._stiffness: dict = {}
        self.published = 0
        self.seconds = 0.0  # spent building and sending the models (the scene's cost)
        self.heartbeat = SceneHeartbeat(lambda raw: device.lcm.Publish(ALIVE_CHANNEL, raw))
        # the coupling's free lag (None: a coupling without the gains: no lag is left out)
        self.free = None
        if hasattr(coupling, "_wn2"):  # a rigid coupling (explicit or implicit): its gains
            step = min(plant.time_step(), device.period_s) if plant.time_step() > 0 else device.period_s
            implicit = getattr(coupling, "integrates_implicitly", False)
            self.free = FreeLag(coupling._wn2, coupling._2zwn, coupling.max_stretch_m, step, implicit)

    def _to_dev(self, p_W) -> tuple:
        return tuple((self._R_DevW @ (np.asarray(p_W) - self._p_WDev)) / self._scale)

    def _point_stiffness(self, inspector, geometry_id) -> float:
        k = self._stiffness.get(geometry_id)
        if k is None:
            props = inspector.GetProximityProperties(geometry_id)
            k = math.inf
            if props is not None and props.HasProperty("material", "point_contact_stiffness"):
                k = float(props.GetProperty("material", "point_contact_stiffness"))
            self._stiffness[geometry_id] = k
        return k

    def planes(self, context, held: int, p_WG) -> list:
        query = self._query.Eval(context)
        inspector = query.inspector()
        geometries = self._geometries.get(held)
        if geometries is None:  # the held body's collision geometries, once
            body = self.plant.get_body(BodyIndex(held))
            geometries = self._geometries[held] = set(self.plant.GetCollisionGeometriesForBody(body))
        found = []  # (distance, normal out of the obstacle in W, stiffness)
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(PLANE_MARGIN_M):
            a, b = pair.id_A in geometries, pair.id_B in geometries
            if a == b:
                continue
            n = np.asarray(pair.nhat_BA_W) if a else -np.asarray(pair.nhat_BA_W)
            ka, kb = self._point_stiffness(inspector, pair.id_A), self._point_stiffness(inspector, pair.id_B)
            k = math.inf if math.isinf(ka) and math.isinf(kb) else 1.0 / (1.0 / ka + 1.0 / kb)  # in series
            found.append((float(pair.distance), n, k))
        kept: list = []
        for distance, n, k in sorted(found, key=lambda c: c[0]):
            if len(kept) < MAX_PLANES and all(float(n @ m) < 0.99 for _, m, _ in kept):
                kept.append((distance, n, k))
        s2 = self._scale**2
        return [
            (self._to_dev(plane_point(p_WG, distance, n, k)), tuple(self._R_DevW @ n), s2 * k)
            for distance, n, k in kept
        ]

    def model(self, context) -> LocalModel:
        held = int(self.GetInputPort("held_body").Eval(context)[0])
        pose_WT, pose_WG = (
            self.GetInputPort("pose_WT").Eval(context),
            self.GetInputPort("pose_WG").Eval(context),
        )
        V_WG = self.GetInputPort("V_WG").Eval(context)
        p_WG = pose_WG[4:]
        lag_W = np.zeros(3)
        if self.free is not None:
            if held != self.free.held:  # a new grasp: the free god-object starts on the scene's
                p_WD = self._X_WD.Eval(context).translation()
                V_WD = self._V_WD.Eval(context)[3:]
                self.free.reset(context.get_time(), held, p_WD, p_WG - pose_WT[4:], V_WG[3:], V_WD)
            lag_W = np.array(self.free.lag)
        q = pose_WG[:4] / np.linalg.norm(pose_WG[:4])
        q_Dev = self._q_DevW.multiply(Quaternion(q)).wxyz()
        g, s2 = self.gains, self._scale**2
        receiver = self.device.receiver
        return LocalModel(
            scene_utime=round(context.get_time() * 1e6),
            pose_utime=receiver._last_utime or 0,
            period_s=self.period_s if self.throttle is None else max(self.period_s, self.throttle.interval),
            kd=s2 * g.kd, gamma_d=s2 * g.gamma_d, kd_rot=g.kd_rot, gamma_d_rot=g.gamma_d_rot,
            p_G=self._to_dev(p_WG), v_G=tuple(self._R_DevW @ V_WG[3:] / self._scale),
            q_G=tuple(q_Dev / np.linalg.norm(q_Dev)), w_G=tuple(self._R_DevW @ V_WG[:3]),
            p_T=self._to_dev(pose_WT[4:]), lag=tuple(self._R_DevW @ lag_W / self._scale),
            planes=tuple(self.planes(context, held, p_WG)) if held >= 0 else (),
        )  # fmt: skip

    def _publish(self, context):
        start = time.perf_counter()
        if self.free is not None:  # every device period: the free lag moves on
            p_WD = self._X_WD.Eval(context).translation()
            self.free.advance(context.get_time(), p_WD, self._V_WD.Eval(context)[3:])
        self._ticks += 1
        throttle = self.throttle
        skip = (self._ticks - 1) % self.every != 0
        if skip or (throttle is not None and not throttle.due(context.get_time())):
            self.seconds += time.perf_counter() - start
            return
        model = self.model(context)
        self.device.lcm.Publish(LOCAL_MODEL_CHANNEL, model.encode())
        self.heartbeat.model_sent(model.scene_utime, time.monotonic())
        self.seconds += time.perf_counter() - start
        self.published += 1
