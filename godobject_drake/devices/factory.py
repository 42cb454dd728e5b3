"""Each device kind's factory: its config (:mod:`godobject_drake.config.devices`) to its system.

One function per kind, as Drake's ``hardware_sim`` has one ``Apply…Config`` per driver config,
named by its kind's registration (``@device_kind(..., factory="godobject_drake.devices.factory:
scripted")``); :func:`make_device` is the one dispatch. A kind of one's own gives its factory to
``@device_kind`` itself (docs/design.md "Adding a device kind").

Every factory takes the config and the scene's context as keywords: ``seed`` (the noise of pose
devices), ``meshcat`` and ``workspace`` (a live device's page and slider range; an LCM device's
expected box), ``duration_s`` (the run's length: a log is read only as far as the run reaches).
"""

import functools
import importlib
import math
from collections.abc import Callable

from godobject_drake.config import devices as dk
from godobject_drake.devices.lcm import LcmDevice, LcmJointDevice
from godobject_drake.devices.live import MeshcatDevice, MeshcatJointDevice
from godobject_drake.devices.sources import (
    DeviceSource,
    JointDevice,
    RelativeDevice,
    ReplayDevice,
    ReplayJointDevice,
    ScriptedDevice,
    ScriptedJointDevice,
)
from godobject_drake.link.transport import make_lcm


def factory_of(kind: dk.DeviceKind) -> Callable:
    """A device kind's factory: the function it was registered with, or the one its
    ``"module:function"`` names (imported once)."""
    if callable(kind.factory):
        return kind.factory
    return _imported(kind.factory)


@functools.cache
def _imported(path: str) -> Callable:
    module, _, name = path.partition(":")
    try:
        function = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as e:
        why = f"device: the factory {path!r} cannot be imported ({e}): fix its kind's factory="
        raise ValueError(why) from None
    if not callable(function):
        raise ValueError(f"device: the factory {path!r} is not a function: fix the kind's factory=")
    return function


def make_device(
    config, *, seed: int = 0, meshcat=None, workspace=None, duration_s: float = math.inf, tool: str = ""
) -> DeviceSource | JointDevice:
    """The system of a device config (not yet added to a builder), checked first. ``tool``: the
    tool it drives in a scene of several (a live device names its sliders and buttons by it)."""
    return make_device_of(
        dk.kind_of(config), config, seed=seed, meshcat=meshcat, workspace=workspace, duration_s=duration_s,
        tool=tool,
    )  # fmt: skip


def make_device_of(
    kind: dk.DeviceKind, config, *, seed: int, meshcat, workspace, duration_s: float, tool: str
) -> DeviceSource | JointDevice:
    """:func:`make_device` for a config whose kind is known already (a tool's record)."""
    factory = factory_of(kind)
    try:
        config.check()
    except ValueError as e:
        raise ValueError(f"device.{e}") from None
    if kind.live and meshcat is None:
        raise ValueError(f"device: !{type(config).__name__} needs the scene's Meshcat")
    scene = dict(seed=seed, meshcat=meshcat, workspace=workspace, duration_s=duration_s)
    return factory(config, **scene, **({"tool": tool} if kind.live else {}))


def _box(workspace):
    return None if workspace is None else (workspace.lower_m, workspace.upper_m)


def scripted(config: dk.Scripted, *, seed, meshcat, workspace, duration_s) -> ScriptedDevice:
    return ScriptedDevice(config.path_waypoints(), noise_m=config.noise_m, seed=seed, **config.sampling())


def replay(config: dk.Replay, *, seed, meshcat, workspace, duration_s) -> ReplayDevice:
    return ReplayDevice(
        config.log, noise_m=config.noise_m, seed=seed, **config.sampling(), until_s=duration_s
    )


def relative(config: dk.Relative, *, seed, meshcat, workspace, duration_s) -> RelativeDevice:
    return RelativeDevice(config.log, config.start_pose(), noise_m=config.noise_m, seed=seed,
                          **config.sampling(), aids=config.aids(), until_s=duration_s)  # fmt: skip


def meshcat_sliders(
    config: dk.MeshcatSliders, *, seed, meshcat, workspace, duration_s, tool=""
) -> MeshcatDevice:
    if workspace is None:
        raise ValueError("device: !MeshcatSliders needs the scene's workspace (its sliders' range)")
    return MeshcatDevice(meshcat, config.start_pose(), _box(workspace), grasp=config.grasp or None,
                         **config.sampling(), aids=config.aids(), tool=tool)  # fmt: skip


def lcm(config: dk.Lcm, *, seed, meshcat, workspace, duration_s) -> LcmDevice:
    frame = {}
    if not config.device_to_world.is_identity():
        frame = dict(X_WDev=config.device_to_world.transform(), scale=config.device_to_world.scale)
    return LcmDevice(
        make_lcm(config.url, config.key_file), config.start_pose(), config.channel, config.timeout_periods,
        config.period_s, config.latency_s, config.guard, config.interpolation, config.feedback_channel,
        config.grasp,
        workspace=_box(workspace), **frame,
    )  # fmt: skip


def scripted_joints(
    config: dk.ScriptedJoints, *, seed, meshcat, workspace, duration_s
) -> ScriptedJointDevice:
    return ScriptedJointDevice(config.joint_path(), **config.sampling())


def replay_joints(config: dk.ReplayJoints, *, seed, meshcat, workspace, duration_s) -> ReplayJointDevice:
    return ReplayJointDevice(config.log, config.channels, **config.sampling(), until_s=duration_s)


def meshcat_joint_sliders(config, *, seed, meshcat, workspace, duration_s, tool="") -> MeshcatJointDevice:
    limits = [tuple(lim) for lim in config.limits]
    return MeshcatJointDevice(meshcat, config.channels, limits, config.start, **config.sampling(), tool=tool)


def lcm_joints(config: dk.LcmJoints, *, seed, meshcat, workspace, duration_s) -> LcmJointDevice:
    return LcmJointDevice(
        make_lcm(config.url, config.key_file), config.channels, config.start, config.channel,
        config.timeout_periods, config.sampling()["mix"], config.period_s, config.latency_s,
    )  # fmt: skip
