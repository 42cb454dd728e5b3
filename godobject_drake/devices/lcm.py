"""Devices on LCM, Drake's hardware convention: a driver publishes the device's samples, the
scene publishes the feedback wrench back.

Messages (the ``lcmt_*`` types the drake wheel ships; docs/guide/lcm.md):

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
- **Local model** on ``GODOBJECT_LOCAL_MODEL`` (``udp://`` driver links only):
  :class:`~godobject_drake.link.messages.LocalModel`, the god-object, the feedback gains and the
  contact planes near the held body, in the device's frame, every device period and at most
  every :data:`~godobject_drake.link.scene_model.LOCAL_MODEL_MIN_PERIOD_S` of simulated time
  (:class:`~godobject_drake.link.scene_model.LocalModelPublisher`;
  docs/local_model.md): the driver renders from it at its own rate. Between two models, while
  the scene's loop is held up (folding its logs, a long step), a thread of its own says on
  ``GODOBJECT_LOCAL_MODEL_ALIVE`` that the scene is alive and its newest model stands
  (:class:`~godobject_drake.link.scene_model.SceneHeartbeat`), for at most
  :data:`~godobject_drake.link.scene_model.STALL_LIMIT_S` after that model.

What arrives is checked at each device sample (:class:`LcmReceiver`), and every fault is
counted in the metrics (:data:`~godobject_drake.link.messages.LCM_STATUS_KEYS`):

- no message yet: the device stays at its start pose, at rest;
- none for ``timeout_periods`` samples (a driver unplugged): the sample is dropped, so the
  device source holds the last pose at rest (``device_dropped_samples``);
- a ``utime`` going backwards or repeated: the message is dropped (``lcm_stale_messages``); a
  ``udp://`` link's new pairing (a restarted driver, its clock from zero) starts the check anew;
- several new messages in one period (a burst): the newest is used (``lcm_bursts``);
- a message that does not decode as ``lcmt_robot_state``, names other entries, or grasps a
  body the coupling does not know: dropped (``lcm_bad_messages``);
- NaN, infinite or a non-unit quaternion: the device's :class:`~godobject_drake.devices.sources.SampleGuard`
  handles it as for any device (joint devices: a non-finite value drops the message).

Use ``memq://`` for tests (in-process; nothing leaves the process). Drake's default URL is UDP
multicast, for a lab's own network. ``udp://HOST:PORT`` is a point-to-point link to a driver
process (:mod:`~godobject_drake.link.transport`, :mod:`~godobject_drake.driver.process`).

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
``GODOBJECT_DRIVER_STATUS`` (``lcmt_robot_state``, one entry per count,
:data:`~godobject_drake.link.messages.DRIVER_STATUS_KEYS`) and what the hand felt (the force
rendered: its peak, its mean in contact and the time in contact,
:data:`~godobject_drake.link.messages.DRIVER_FORCE_KEYS`); on a ``udp://`` link the newest are in the
metrics as ``driver_*``.

**Pairing** (``udp://`` only): the link takes messages from its one paired driver only, each
authenticated with the key of ``key_file`` and never twice (:mod:`~godobject_drake.link.transport`);
what it drops is counted as ``lcm_udp_*`` in the metrics (``lcm_udp_unauthenticated``,
``lcm_udp_replayed``, ``lcm_udp_refused_drivers``, ...). ``memq://`` (one process) and Drake's
``udpm://`` (multicast: anyone on the network) are not paired.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np
from drake import lcmt_force_torque, lcmt_robot_state
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.lcm import DrakeLcm
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from godobject_drake.config.device_files import DEFAULT_DEVICE_RATE_HZ, SampleGuard
from godobject_drake.config.gains import GRASP_NEAREST
from godobject_drake.devices.sources import DeviceSource, JointDevice
from godobject_drake.link.messages import (
    DRIVER_FORCE_KEYS,
    DRIVER_STATUS_CHANNEL,
    DRIVER_STATUS_KEYS,
    FEEDBACK_CHANNEL,
    JOINT_CHANNEL,
    LCM_STATUS_KEYS,
    POSE_CHANNEL,
    POSE_NAMES,
    STOP_SUFFIX,
    decode,
    parse_robot_state,
)
from godobject_drake.link.scene_model import LocalModelPublisher


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
        self._pairings: int | None = None  # a udp:// link's sessions paired: a new one, a new clock
        self._quiet = 0
        lcm.Subscribe(channel, self._pending.append)

    def poll(self) -> bool:
        self.lcm.HandleSubscriptions(0)
        pairings = getattr(self.lcm, "counts", {}).get("udp_pairings")
        if pairings != self._pairings:  # a driver restarted: its utime counts from its own start again
            self._pairings, self._last_utime = pairings, None
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
        self.driver_felt = dict.fromkeys(DRIVER_FORCE_KEYS)  # what the hand felt: None until reported
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
        self.throttle = None  # the wrench publisher's, test-only (ForceTorquePublisher)
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
            elif name in self.driver_felt and math.isfinite(value):
                self.driver_felt[name] = float(value)

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
            counts.update({f"driver_{k}": v for k, v in self.driver_felt.items()})
            counts["driver_status_messages"] = self.driver_status_messages
            counts["driver_bad_status"] = self.driver_bad_status
            counts.update({f"lcm_{k}": v for k, v in self.lcm.counts.items()})
            publisher = getattr(self, "local_publisher", None)
            if publisher is not None:  # the local model's cost on the scene's side
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
        """A driver link (``udp://``) also gets the local model after each step
        (docs/local_model.md): :class:`~godobject_drake.link.scene_model.LocalModelPublisher`,
        reading the coupling and the scene's geometry. Other transports (``memq://``, Drake's
        multicast): nothing."""
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
        # test-only: publish a step only if throttle.due(t) (analysis/throttled_scene.py emulates
        # a scene that sustains only a given rate of wall time); None: every period
        self.throttle = None

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
