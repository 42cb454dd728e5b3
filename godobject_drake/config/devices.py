"""The device kinds' configs: each a scenario dataclass registered once, with all a kind decides.

A device kind is two things: its config here, a dataclass whose fields are the YAML keys under
``device: !Tag``, and its runtime system (:mod:`godobject_drake.devices`), made from the config
by its factory. The :func:`device_kind` decorator registers both at once, in
:data:`DEVICE_KINDS`, with what the rest of the library asks of a kind:

- its factory: the function that makes its system from the config and the scene's context
  (:func:`godobject_drake.devices.factory.make_device` calls it), named ``"module:function"``
  so this layer imports no system (the shipped kinds' are in :mod:`godobject_drake.devices.factory`),
  or the function itself for a kind of one's own;
- its name on the command line (``--device NAME``) and in the metrics (``device``);
- its space: ``pose`` (rigid and deformable tools) or ``joint`` (articulated tools);
- whether it is driven from the browser (``live``: Meshcat is served, the run goes at real
  time), lives on the wall clock otherwise (``real_time``: a real device), reports increments
  (the pseudo-haptic aids apply), reads a log (``--device NAME`` needs ``--device-log``) or
  renders the feedback wrench itself (a real haptic device: no simulated one may stand in
  between);

and the config's methods say the rest: :meth:`~DeviceConfig.check` refuses bad values naming
the field, the value and the fix, ``start_pose`` (pose kinds) says where the target starts, and
:meth:`~DeviceConfig.stand_in` what ``analyze`` runs instead of a kind that needs a browser or a
driver (a kind that needs one and has none says so).

Adding a device kind is therefore one factory and one dataclass with
``@device_kind(..., factory=that_factory)``; the scenario's ``device`` field, the command line's
``--device`` choices, the metrics and ``analyze`` pick it up from the registry (docs/design.md
"Adding a device kind").

This module must not use ``from __future__ import annotations``: ``yaml_load_typed`` reads the
field types at run time.
"""

import dataclasses
import functools
import math
import operator
import re
from collections.abc import Callable
from typing import ClassVar

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw

from godobject_drake.config.device_files import (
    INTERPOLATIONS,
    JointPath,
    JointWaypoint,
    RelativeAids,
    SampleGuard,
    Waypoint,
    load_device_path,
    load_joint_path,
    read_device_log,
    read_joint_log,
)
from godobject_drake.link.transport import parse_url

SPACES = ("pose", "joint")
MAX_RATE_HZ = 1e5  # a device sample every 10 µs at most


@dataclasses.dataclass(frozen=True)
class DeviceKind:
    """What the library knows of a registered device kind (:func:`device_kind`)."""

    config: type
    name: str
    space: str
    factory: "str | Callable"  # "module:function", or the function itself
    live: bool = False
    real_time: bool = False
    increments: bool = False
    needs_log: bool = False
    renders_feedback: bool = False
    summary: str = ""  # a few words for --device's help

    @property
    def tag(self) -> str:
        """The YAML tag: ``!`` and the config class's name."""
        return f"!{self.config.__name__}"


DEVICE_KINDS: dict[type, DeviceKind] = {}
SHIPPED = "godobject_drake.devices.factory:"  # where the shipped kinds' factories are
FACTORY_PATH = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_]\w*")  # module:function


def device_kind(
    name: str,
    *,
    space: str,
    factory: "str | Callable",
    live: bool = False,
    real_time: bool = False,
    increments: bool = False,
    needs_log: bool = False,
    renders_feedback: bool = False,
    summary: str = "",
):
    """Register a device config dataclass as a kind (module docstring); returns the class.

    ``name`` is unique within its ``space``; ``factory`` makes its system (``"module:function"``,
    imported when a device of the kind is first made, or the function); registering a kind makes
    the scenario's ``device`` field accept its YAML tag."""
    if space not in SPACES:
        raise ValueError(f"device kind {name!r}: space={space!r}; choose one of {SPACES}")
    if not (callable(factory) or (isinstance(factory, str) and FACTORY_PATH.fullmatch(factory))):
        raise ValueError(
            f"device kind {name!r}: factory={factory!r}; give the function that makes its system, or its "
            "path as 'module:function' (e.g. 'godobject_drake.devices.factory:scripted')"
        )

    def register(cls):
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"device kind {name!r}: {cls.__name__} must be a dataclass")
        for other in DEVICE_KINDS.values():
            if other.config.__name__ == cls.__name__ and other.config is not cls:
                raise ValueError(f"device kind {name!r}: the YAML tag !{cls.__name__} is taken")
            if other.name == name and other.space == space and other.config is not cls:
                raise ValueError(
                    f"device kind {name!r} ({space}) is registered already, as !{other.config.__name__}"
                )
        DEVICE_KINDS[cls] = DeviceKind(
            cls, name, space, factory, live, real_time, increments, needs_log, renders_feedback,
            summary or cls.__doc__.strip().splitlines()[0],
        )  # fmt: skip
        for callback in _ON_REGISTER:
            callback()
        return cls

    return register


def kind_of(config) -> DeviceKind:
    """The registered kind of a device config; an unknown one is refused, naming the known ones."""
    kind = DEVICE_KINDS.get(type(config))
    if kind is None:
        known = ", ".join(k.tag for k in DEVICE_KINDS.values())
        raise ValueError(
            f"device: {type(config).__name__} is not a registered device kind; the known kinds are {known} "
            "(register one with godobject_drake.config.devices.device_kind)"
        )
    return kind


def kinds_in(space: str) -> dict[str, type]:
    """The registered kinds of a space, by name: ``{"scripted": Scripted, ...}``."""
    return {k.name: k.config for k in DEVICE_KINDS.values() if k.space == space}


def device_union():
    """Every registered config class as one union: the type of the scenario's ``device`` field."""
    return functools.reduce(operator.or_, DEVICE_KINDS)


_ON_REGISTER: list = []


def on_register(callback) -> None:
    """Call ``callback()`` after each kind registered from now on (the scenario's ``device`` field
    retypes itself so: :mod:`godobject_drake.config.scenario`)."""
    _ON_REGISTER.append(callback)


class DeviceConfig:
    """The methods every device config has (a kind overrides what it needs)."""

    rate_hz: float

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"`` (the scenario prefixes ``device.``)."""
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= MAX_RATE_HZ):
            raise ValueError(
                f"rate_hz: {self.rate_hz!r} Hz must be > 0 and at most {MAX_RATE_HZ:g} Hz (haptic devices "
                "run at 1 to 10 kHz)"
            )

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    def stand_in(self):
        """What ``analyze`` runs instead of this device: ``self`` for a device that needs nothing
        outside the process; a kind that needs a browser or a driver returns a scripted device
        standing at its start, or raises saying it has none."""
        if kind_of(self).live or kind_of(self).real_time:
            raise ValueError(
                f"device: !{type(self).__name__} needs a browser or a driver and has no stand-in for "
                "analyze; give the scenario a !Scripted or !ScriptedJoints device to analyse"
            )
        return self


# -- pose devices ------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _PoseDevice(DeviceConfig):
    """What every pose device has: its rate, latency, interpolation, noise and sample guard;
    and, for the increment devices (``!Relative``, ``!MeshcatSliders``) only, the pseudo-haptic
    aids (docs/guide/visual.md, :class:`~godobject_drake.devices.sources.RelativeAids`).

    Attributes
    ----------
    rate_hz : float
        How often the device is sampled (Hz); the target holds between samples.
    latency_s : float
        How late each sample reaches the scene (s); 0 for none.
    interpolation : str
        ``hold`` (the last sample until the next) or ``linear`` (towards the next, one period late).
    noise_m : float
        Gaussian noise added to each position sample (m, standard deviation; seeded by the
        scenario's ``random_seed``); 0 for none.
    guard : SampleGuard
        What the device does with samples it cannot use (non-finite, dropped, absurd jumps).
    tether_m : float
        Increment devices only: how far (m) the target may lead the god-object before the
        increments are re-indexed (a tether); ``.inf`` for none.
    tether_angle_rad : float
        The same for orientation (rad); ``.inf`` for none.
    cd_ratio : float
        Increment devices only: the control/display ratio reached at the force cap (the
        increments shrink as the god-object pushes); 1 for none.
    cd_onset_m : float
        Where that ratio starts to grow: the target's lead on the god-object (m).
    """

    rate_hz: float = 60.0
    latency_s: float = 0.0
    interpolation: str = "hold"
    noise_m: float = 0.0
    guard: SampleGuard = dataclasses.field(default_factory=SampleGuard)
    tether_m: float = math.inf
    tether_angle_rad: float = math.inf
    cd_ratio: float = 1.0
    cd_onset_m: float = 0.005

    AIDS: ClassVar[tuple[str, ...]] = ("tether_m", "tether_angle_rad", "cd_ratio", "cd_onset_m")

    def aids(self) -> RelativeAids:
        return RelativeAids(self.tether_m, self.tether_angle_rad, self.cd_ratio, self.cd_onset_m)

    def changed_aids(self) -> list[str]:
        """The aid fields set away from their defaults."""
        return [f for f in self.AIDS if getattr(self, f) != getattr(_PoseDevice, f)]

    def check(self) -> None:
        super().check()
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation: {self.interpolation!r}; choose one of {INTERPOLATIONS}")
        changed = self.changed_aids()
        if changed and not kind_of(self).increments:
            field = changed[0]
            raise ValueError(
                f"{field}: {getattr(self, field)!r} re-indexes a device's increments; !{type(self).__name__} "
                "reports absolute poses, which cannot be re-indexed (the target would leave the device). "
                f"Use !Relative or !MeshcatSliders (--device relative or meshcat), or remove {field}"
            )
        if changed:
            try:
                self.aids()  # RelativeAids checks its own values
            except ValueError as e:
                raise ValueError(f"{changed[0]}: {e}") from None

    def sampling(self) -> dict:
        """The runtime device's sampling options."""
        return dict(period_s=self.period_s, latency_s=self.latency_s, interpolation=self.interpolation,
                    guard=self.guard)  # fmt: skip

    def start_pose(self) -> RigidTransform:
        """Where the target starts (m, world frame): ``start_xyz``, ``start_rpy_deg`` unless the
        kind's path or log says otherwise."""
        rpy = RollPitchYaw(np.radians(self.start_rpy_deg))
        return RigidTransform(rpy, np.asarray(self.start_xyz, dtype=float))

    def stand_in(self):
        if not (kind_of(self).live or kind_of(self).real_time):
            return self
        return Scripted(  # no browser, no driver: a scripted device standing at the start
            rate_hz=self.rate_hz,
            waypoints=[Waypoint(t=0.0, xyz=list(self.start_xyz), rpy_deg=list(self.start_rpy_deg),
                                grasp=self.grasp)],
        )  # fmt: skip


@device_kind("scripted", space="pose", factory=SHIPPED + "scripted", summary="the scenario's path")
@dataclasses.dataclass
class Scripted(_PoseDevice):
    """A scripted path: waypoints, linear in position, slerp in orientation.

    Attributes
    ----------
    path : str
        A YAML file of ``waypoints`` (t, xyz, rpy_deg, grasp); or give them inline.
    waypoints : list[Waypoint]
        Inline waypoints (when ``path`` is empty).
    rate_hz, latency_s, interpolation, noise_m, guard :
        The device's sampling: rate (Hz), latency (s), ``hold`` or ``linear`` between
        samples, Gaussian noise on each position sample (m, seeded by the scenario's
        ``random_seed``), what to do with bad samples.
    """

    path: str = ""
    waypoints: list[Waypoint] = dataclasses.field(default_factory=list)

    def check(self) -> None:
        super().check()
        if self.path and self.waypoints:
            raise ValueError("path: give a scripted path as path or as waypoints, not both")

    def path_waypoints(self) -> list[Waypoint]:
        self.check()
        return load_device_path(self.path).waypoints if self.path else self.waypoints

    def start_pose(self) -> RigidTransform:
        first = self.path_waypoints()[0]
        return RigidTransform(RollPitchYaw(np.radians(first.rpy_deg)), np.asarray(first.xyz, dtype=float))


@device_kind("replay", space="pose", factory=SHIPPED + "replay", needs_log=True, summary="a CSV log")
@dataclasses.dataclass
class Replay(_PoseDevice):
    """A device log replayed (CSV ``t,x,y,z,qw,qx,qy,qz,grasp``).

    Attributes
    ----------
    log : str
        The CSV file (relative to the scenario's folder); times in s, positions in m, the grasp a
        body's name or empty.
    """

    log: str = ""

    def check(self) -> None:
        super().check()
        if not self.log:
            raise ValueError("log: !Replay needs log: FILE.csv (docs/guide/devices.md)")

    def start_pose(self) -> RigidTransform:
        log = read_device_log(self.log, until_s=0.0)
        return RigidTransform(Quaternion(log.q[0] / np.linalg.norm(log.q[0])), log.p[0])


@device_kind(
    "relative",
    space="pose",
    factory=SHIPPED + "relative",
    increments=True,
    needs_log=True,
    summary="a CSV of increments with a clutch (the paper's mouse)",
)
@dataclasses.dataclass
class Relative(_PoseDevice):
    """Increments with a clutch, the paper's mouse (CSV ``t,dx,dy,dz,drx,dry,drz,clutch,grasp``).

    Attributes
    ----------
    log : str
        The CSV file of increments (m, rad) with the clutch (1: held, the increments ignored).
    start_xyz : list[float]
        Where the target starts (m, world frame).
    start_rpy_deg : list[float]
        Its starting orientation (roll, pitch, yaw in degrees).
    """

    log: str = ""
    start_xyz: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    start_rpy_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])

    def check(self) -> None:
        super().check()
        if not self.log:
            raise ValueError("log: !Relative needs log: FILE.csv (docs/guide/devices.md)")


@device_kind(
    "meshcat",
    space="pose",
    factory=SHIPPED + "meshcat_sliders",
    live=True,
    real_time=True,
    increments=True,
    summary="live from the browser",
)
@dataclasses.dataclass
class MeshcatSliders(_PoseDevice):
    """Driven live from the browser: pose sliders and keys, a gamepad, Grasp and Stop buttons.
    The sliders span the scenario's ``workspace``.

    Attributes
    ----------
    grasp : str
        Empty for the Grasp button (it takes the nearest free body), or a body the device always
        holds.
    start_xyz : list[float]
        Where the target starts (m, world frame).
    start_rpy_deg : list[float]
        Its starting orientation (roll, pitch, yaw in degrees).
    """

    grasp: str = ""
    start_xyz: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    start_rpy_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])

    def check(self) -> None:
        super().check()
        if self.noise_m:
            raise ValueError("noise_m: a live device's samples are the user's own; leave it 0")


@dataclasses.dataclass
class DeviceToWorld:
    """Where a real device's frame Dev sits in the world, and its scale (docs/haptic_devices.md
    "Calibration"): ``p_W = X_WDev (scale p_Dev)`` with ``X_WDev`` from ``xyz`` (m) and
    ``rpy_deg`` (degrees); the feedback wrench goes back as ``f_Dev = scale R_WDevᵀ f_W``,
    ``τ_Dev = R_WDevᵀ τ_W``. The defaults are the identity.

    Attributes
    ----------
    xyz : list[float]
        Where the device frame's origin is in the world (m).
    rpy_deg : list[float]
        The device frame's orientation in the world (roll, pitch, yaw in degrees).
    scale : float
        World metres per device metre (> 0): 2 makes a small device's handle reach twice as far.
    """

    xyz: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    scale: float = 1.0

    def check(self) -> None:
        for name in ("xyz", "rpy_deg"):
            values = getattr(self, name)
            if len(values) != 3 or not all(isinstance(v, int | float) and math.isfinite(v) for v in values):
                raise ValueError(f"device_to_world.{name}: {values!r}; give 3 finite numbers, e.g. [0, 0, 0]")
        if not (isinstance(self.scale, int | float) and math.isfinite(self.scale) and 0 < self.scale <= 1e3):
            raise ValueError(
                f"device_to_world.scale: {self.scale!r} must be > 0 and at most 1000 (world metres per "
                "device metre; 1 maps the device 1:1)"
            )

    def is_identity(self) -> bool:
        return self.xyz == [0.0, 0.0, 0.0] and self.rpy_deg == [0.0, 0.0, 0.0] and self.scale == 1.0

    def transform(self) -> RigidTransform:
        return RigidTransform(RollPitchYaw(np.radians(self.rpy_deg)), np.asarray(self.xyz, dtype=float))


@device_kind(
    "lcm",
    space="pose",
    factory=SHIPPED + "lcm",
    real_time=True,
    renders_feedback=True,
    summary="a real device's driver over LCM",
)
@dataclasses.dataclass
class Lcm(_PoseDevice):
    """A real device whose driver publishes pose samples over LCM (docs/guide/lcm.md).

    Attributes
    ----------
    url : str
        Drake's LCM URL; empty: Drake's default (UDP multicast on this network). ``memq://``
        stays in the process (tests); ``udp://HOST:PORT`` listens for a driver process
        (``godobject-driver``, docs/haptic_devices.md), paired with it by a shared key.
    key_file : str
        ``udp://`` only: the file of the key the scene and its driver pair with (the driver's
        ``--key-file``); empty: ``$GODOBJECT_LINK_KEY``, else ``~/.config/godobject/link.key``,
        created on first use (mode 0600). A file named here must exist (a mistyped name is an
        error, not a new key); refused if others can read or replace it, or if it holds a key
        of few distinct bytes (all zero).
    device_to_world : DeviceToWorld
        The device's frame and scale in the world (identity by default); the scenario's
        ``workspace`` is the box samples are expected in (outside ones are counted).
    channel, feedback_channel : str
        The ``lcmt_robot_state`` samples in; the ``lcmt_force_torque`` feedback wrench out,
        published at ``rate_hz``.
    timeout_periods : int
        Samples without a message after which the device holds at rest (a driver unplugged).
    wait_s : float | None
        How long a run waits (wall time) for the driver's first sample before its clock starts:
        started first, the scene waits for its driver, so either order gives the same run
        (docs/guide/haptic_recipe.md); past it the run stops with an error naming the fix. None:
        30 s on a link to another process (``udp://``, multicast), 0 on ``memq://`` (the
        publisher is the scene's own process); 0: start at once, the device at its start pose
        until its first message.
    start_xyz, start_rpy_deg :
        Where the device stands until its first message (m, degrees).
    grasp : str
        A body the device always holds (a deformable probe's core); empty: the messages'
        ``grasp=`` entries decide.
    rate_hz, latency_s, interpolation, guard :
        The rate the driver is expected to publish at, and the sampling as for any device
        (``noise_m`` must stay 0: the samples are the device's own).
    noise_m : float
        Must stay 0: a real device's samples are its own.
    tether_m, tether_angle_rad, cd_ratio, cd_onset_m :
        Not for this device (its poses are absolute): leave them at their defaults.
    """

    url: str = ""
    key_file: str = ""
    grasp: str = ""
    channel: str = "GODOBJECT_DEVICE_POSE"
    feedback_channel: str = "GODOBJECT_FEEDBACK"
    timeout_periods: int = 5
    wait_s: float | None = None
    start_xyz: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    start_rpy_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    device_to_world: DeviceToWorld = dataclasses.field(default_factory=DeviceToWorld)

    def check(self) -> None:
        super().check()
        _check_timeout(self.timeout_periods)
        if self.noise_m:
            raise ValueError("noise_m: a real device's samples are its own; leave it 0")
        self.device_to_world.check()
        _check_link(self.url, self.key_file)
        _check_wait(self.wait_s)

    def first_wait_s(self) -> float:
        """``wait_s``, its default resolved."""
        return first_wait_s(self.wait_s, self.url)


def _check_link(url: str, key_file: str) -> None:
    if url.startswith("udp://"):
        try:
            parse_url(url)
        except ValueError as e:
            raise ValueError(f"url: {e}") from None
    elif key_file:
        raise ValueError(
            f"key_file: {key_file!r} pairs a udp:// link only, and url is {url or 'Drake default'!r} "
            "(memq:// stays in this process; udpm:// multicast is not paired): remove key_file, "
            "or give url: udp://HOST:PORT"
        )


DEFAULT_WAIT_S = 30.0  # a driver process's first sample: how long a run waits for it


def first_wait_s(wait_s: float | None, url: str) -> float:
    """How long a run waits for an LCM device's first sample (``Lcm.wait_s``)."""
    if wait_s is not None:
        return float(wait_s)
    return 0.0 if url.startswith("memq://") else DEFAULT_WAIT_S


def _check_wait(wait_s) -> None:
    if wait_s is not None and not (isinstance(wait_s, int | float) and math.isfinite(wait_s) and wait_s >= 0):
        raise ValueError(
            f"wait_s: {wait_s!r}; give the seconds to wait for the driver's first sample (≥ 0, e.g. 30; "
            "0: do not wait)"
        )


def _check_timeout(timeout_periods) -> None:
    if not (isinstance(timeout_periods, int) and timeout_periods >= 1):
        raise ValueError(f"timeout_periods: {timeout_periods!r}: give an integer ≥ 1, e.g. 5")


# -- joint devices -----------------------------------------------------------------------------------------


@dataclasses.dataclass
class _JointDevice(DeviceConfig):
    """What every joint-space device has.

    Attributes
    ----------
    channels : list[str]
        The interface's channels (rad or m each), in the order it reports them.
    mix : list[list[float]]
        Rows: the tool's device joints; columns: channels (``q_device = mix · channels``);
        empty: identity.
    limits : list[list[float]]
        Each channel's ``[lower, upper]``: the live sliders' range.
    rate_hz, latency_s : float
        Sampling rate (Hz) and latency (s).
    """

    channels: list[str] = dataclasses.field(default_factory=list)
    mix: list[list[float]] = dataclasses.field(default_factory=list)
    limits: list[list[float]] = dataclasses.field(default_factory=list)
    rate_hz: float = 60.0
    latency_s: float = 0.0

    def sampling(self) -> dict:
        mix = np.array(self.mix, dtype=float) if self.mix else None
        return dict(mix=mix, period_s=self.period_s, latency_s=self.latency_s)

    def start_values(self) -> list[float]:
        """The channels' values at t = 0 (each kind says where they come from)."""
        return [float(v) for v in self.start]

    def stand_in(self):
        if not (kind_of(self).live or kind_of(self).real_time):
            return self
        start = dict(zip(self.channels, self.start or [0.0] * len(self.channels), strict=True))
        return ScriptedJoints(
            channels=list(self.channels), mix=self.mix, limits=self.limits, rate_hz=self.rate_hz,
            waypoints=[JointWaypoint(0.0, start)],
        )  # fmt: skip


@device_kind("scripted", space="joint", factory=SHIPPED + "scripted_joints", summary="the scenario's path")
@dataclasses.dataclass
class ScriptedJoints(_JointDevice):
    """A scripted joint-space path.

    Attributes
    ----------
    path : str
        A YAML file with ``channels`` and ``waypoints`` (each ``t`` in s and a value per channel).
    waypoints : list[JointWaypoint]
        Inline waypoints (when ``path`` is empty).
    """

    path: str = ""
    waypoints: list[JointWaypoint] = dataclasses.field(default_factory=list)

    def check(self) -> None:
        super().check()
        if self.path and self.waypoints:
            raise ValueError("path: give a joint path as path or as waypoints, not both")

    def start_values(self) -> list[float]:
        first = self.joint_path().waypoints[0]
        return [float(first.values[c]) for c in self.joint_path().channels]

    def joint_path(self) -> JointPath:
        self.check()
        path = load_joint_path(self.path) if self.path else JointPath(self.channels, self.waypoints)
        if self.channels and list(path.channels) != list(self.channels):
            raise ValueError(f"channels: {self.channels} differ from the path's channels {path.channels}")
        return path


@device_kind("replay", space="joint", factory=SHIPPED + "replay_joints", needs_log=True, summary="a CSV log")
@dataclasses.dataclass
class ReplayJoints(_JointDevice):
    """A joint-space device log replayed (CSV ``t,<channels>``).

    Attributes
    ----------
    log : str
        The CSV file: a time column (s) and one column per channel (rad or m).
    """

    log: str = ""

    def check(self) -> None:
        super().check()
        if not self.log:
            raise ValueError("log: !ReplayJoints needs log: FILE.csv (header t,<channels>)")

    def start_values(self) -> list[float]:
        _, values = read_joint_log(self.log, self.channels, until_s=0.0)
        return [float(v) for v in values[0]]


@device_kind(
    "meshcat",
    space="joint",
    factory=SHIPPED + "meshcat_joint_sliders",
    live=True,
    real_time=True,
    summary="live from the browser",
)
@dataclasses.dataclass
class MeshcatJointSliders(_JointDevice):
    """Joint channels driven live from the browser, one slider and key pair each.

    Attributes
    ----------
    start : list[float]
        Each channel's value at the start (rad or m), one per channel in the tool's order.
    """

    start: list[float] = dataclasses.field(default_factory=list)

    def check(self) -> None:
        super().check()
        if len(self.limits) != len(self.channels):
            raise ValueError(f"limits: {self.limits}: give one [lower, upper] per channel {self.channels}")


@device_kind(
    "lcm",
    space="joint",
    factory=SHIPPED + "lcm_joints",
    real_time=True,
    summary="a real device's driver over LCM",
)
@dataclasses.dataclass
class LcmJoints(_JointDevice):
    """A real joint-space device whose driver publishes its channels over LCM (``lcmt_robot_state``,
    ``joint_name`` = ``channels``).

    Attributes
    ----------
    url : str
        Drake's LCM URL, as for ``!Lcm``: ``memq://`` in the process, ``udp://HOST:PORT`` for a
        paired driver process; empty: Drake's default (multicast).
    key_file : str
        ``udp://`` only: the file of the key the scene and its driver pair with, as for ``!Lcm``.
    channel : str
        The LCM channel the ``lcmt_robot_state`` samples come on.
    timeout_periods : int
        Samples without a message after which the device holds where it is (a driver unplugged).
    wait_s : float | None
        How long the run waits for the driver's first sample before its clock starts, as for
        ``!Lcm``.
    start : list[float]
        The channel values until the first message (rad or m), one per channel.
    """

    url: str = ""
    key_file: str = ""
    channel: str = "GODOBJECT_DEVICE_JOINTS"
    timeout_periods: int = 5
    wait_s: float | None = None
    start: list[float] = dataclasses.field(default_factory=list)

    def check(self) -> None:
        super().check()
        _check_timeout(self.timeout_periods)
        _check_link(self.url, self.key_file)
        _check_wait(self.wait_s)

    def first_wait_s(self) -> float:
        return first_wait_s(self.wait_s, self.url)
        if len(self.start) != len(self.channels):
            raise ValueError(f"start: {self.start} needs one value per channel {self.channels}")
