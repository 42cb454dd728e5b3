"""The scene's half of the local model (docs/local_model.md): what a scene on a driver
link (``udp://``) publishes beside the wrench. :class:`LocalModelPublisher`, a Drake system the
LCM device (:mod:`godobject_drake.devices.lcm`) adds after each step, builds the
:class:`~godobject_drake.link.messages.LocalModel` (the god-object, the gains, the contact planes
near the held body, the coupling's free lag: :class:`FreeLag`); :class:`SceneHeartbeat` says the
scene is alive while its loop is held up. The driver's half, the renderer, is
:mod:`godobject_drake.driver.local_model`; the payloads they share are in
:mod:`godobject_drake.link.messages`. A driver process never loads this module (it is the only
one of the link that loads ``pydrake.systems``).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.math import RigidTransform
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import LeafSystem

from godobject_drake.link.messages import (
    ALIVE_CHANNEL,
    LOCAL_MODEL_CHANNEL,
    MAX_PLANES,
    LocalModel,
    alive_message,
)

PLANE_MARGIN_M = 0.005  # contacts the god-object could reach: within this of its held body
# The local model is published every device period, at most this often (s of simulated time):
# the driver renders at its own rate from it, and a model costs the scene ~0.5 ms (Python: the
# signed distances, the message), which every 1 ms step could not afford (docs/local_model.md)
LOCAL_MODEL_MIN_PERIOD_S = 0.004


class FreeLag:
    """The stretch ``p_G − p_T`` of a god-object free of every contact, driven by the same
    device samples as the scene's (docs/local_model.md): the coupling's own lag as the
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
# ... unless its models come slower: STALL_INTERVALS times the median of its last 16 intervals
# between models, at most MAX_STALL_S (the FEM uterus at h = 1 ms sends one every 0.3 to 0.6 s
# of wall time, some 1.8 s apart on a loaded machine: docs/local_model.md "An articulated tool")
STALL_INTERVALS = 6.0
MAX_STALL_S = 5.0


class SceneHeartbeat:
    """The scene's word that it is alive while its loop is held up (docs/local_model.md
    "Validity"): a thread of its own, every :data:`BEAT_S` of wall time, publishes
    :func:`~godobject_drake.link.messages.alive_message` with the newest model's time, when that
    model is at least ``beat_s`` old and at most :meth:`limit` (``stall_limit_s``, longer for a
    scene whose models come slower than ``stall_limit_s / 6``). The driver holds the model
    for as long as it hears this (its validity counts from the newest of the model and its
    heartbeats), so a loop paused by a fold of its logs or a long step (0.1 to 0.2 s on a
    loaded machine, where the model's own validity is 3 scene periods + 50 ms) does not fade
    the wall; a scene killed falls silent, and the fade bound holds from its last word; a loop
    that hangs is vouched for :meth:`limit` at most.

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
        self.intervals: deque = deque(maxlen=16)  # between the last models sent (s of ``clock``)
        self.beats = 0
        self.stopped = False
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None

    def model_sent(self, utime: int, now: float) -> None:
        """The loop sent a model of scene time ``utime`` at ``now``; the first starts the thread,
        and the first after a stop (the same scene run again) a new one."""
        with self._lock:
            if self.stopped:  # run again: its own pace
                self.stopped, self._wake, self._thread = False, threading.Event(), None
                self.model_at = -math.inf
                self.intervals.clear()
            if now > self.model_at > -math.inf:
                self.intervals.append(float(now) - self.model_at)
            self.utime, self.model_at = int(utime), float(now)
            start = self._thread is None
            if start:
                self._thread = threading.Thread(
                    target=self._run, args=(self._wake,), name="scene-heartbeat", daemon=True
                )
        if start:
            self._thread.start()

    def limit(self) -> float:
        """How long after a model it is vouched for (s): ``stall_limit_s``, or for a scene whose
        models come slower :data:`STALL_INTERVALS` times the median of its last 16 intervals
        between them, at most :data:`MAX_STALL_S` (a loop that hangs is still caught: its models
        stop, and the limit does not grow without them)."""
        if not self.intervals:
            return self.stall_limit_s
        return max(self.stall_limit_s, min(MAX_STALL_S, STALL_INTERVALS * float(np.median(self.intervals))))

    def tick(self, now: float) -> bool:
        """Beat now if a model stands that is at least ``beat_s`` and at most :meth:`limit`
        old; whether it beat. Sent under the lock, so a stop returns only once a beat under way
        has left: none follows the scene's stop message."""
        with self._lock:
            if self.stopped or self.utime is None:
                return False
            age = now - self.model_at
            if age < self.beat_s or age > self.limit():
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
    simulated time (docs/local_model.md):
    :class:`~godobject_drake.link.messages.LocalModel` on
    :data:`~godobject_drake.link.messages.LOCAL_MODEL_CHANNEL`, in the device's frame
    (``p_Dev = R_WDevᵀ (p_W − p_WDev) / scale``; gains ``scale² kd``). ``device``: the scene's
    :class:`~godobject_drake.devices.lcm.LcmDevice` (its ``X_WDev``, ``scale`` and period).

    The planes: every geometry pair of the held body and another body within
    :data:`PLANE_MARGIN_M` (Drake's signed distance query, broad phase first), one plane per
    distinct normal (the nearest), at most :data:`~godobject_drake.link.messages.MAX_PLANES`:
    through the god-object's point moved against the normal as far as it may still move
    (:func:`plane_point`), normal out of the obstacle, stiffness the pair's point-contact
    stiffness in series (inf when the geometries state none)."""

    def __init__(self, device, plant, gains, coupling=None):
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
        # test-only (analysis/throttled_scene.py): publish a step only if throttle.due(t), and say
        # a period of at least throttle.interval; its own: its steps are not the wrench's
        self.throttle = None
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
