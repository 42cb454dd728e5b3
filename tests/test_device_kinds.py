"""The device-kind registry: a kind defined in this file alone runs through build_station and the
command line (docs/design.md "Adding a device kind"), and contract checks over every kind."""

import dataclasses
import json
import math

import numpy as np
import pytest
from conftest import REPO

from godobject_drake import cli
from godobject_drake.config.devices import DEVICE_KINDS, _PoseDevice, device_kind, kind_of, kinds_in
from godobject_drake.config.scenario import ScenarioError, load_scenario, scenario_from_yaml
from godobject_drake.devices.factory import factory_of
from godobject_drake.devices.sources import DeviceSource
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.station.loop import make_device

LEGO = REPO / "diagrams" / "lego.yaml"


class CircleDevice(DeviceSource):
    """The toy kind's runtime class: the device point goes round a horizontal circle, holding brick_0."""

    def __init__(self, center, radius_m, turn_s, period_s):
        self.center, self.radius_m, self.turn_s = np.asarray(center, float), radius_m, turn_s
        super().__init__(self._circle, period_s)

    def point(self, t: float) -> np.ndarray:
        a = 2 * math.pi * t / self.turn_s
        return self.center + self.radius_m * np.array([math.cos(a), math.sin(a), 0.0])

    def _circle(self, t: float):
        return self.point(t), np.array([1.0, 0.0, 0.0, 0.0]), "brick_0"


def make_circle(config: "Circle", **scene) -> CircleDevice:
    """The toy kind's factory: its config to its system."""
    return CircleDevice(config.center_m, config.radius_m, config.turn_s, config.period_s)


@device_kind("circle", space="pose", factory=make_circle)
@dataclasses.dataclass
class Circle(_PoseDevice):
    """The toy kind's config: ``device: !Circle {radius_m: ..., turn_s: ...}``."""

    center_m: list[float] = dataclasses.field(default_factory=lambda: [-0.12, 0.0, 0.03])
    radius_m: float = 0.02
    turn_s: float = 2.0

    def check(self) -> None:
        super().check()
        if not self.radius_m > 0:
            raise ValueError(f"radius_m: {self.radius_m!r} m must be > 0 (e.g. 0.02)")

    def start_pose(self):
        from pydrake.math import RigidTransform

        return RigidTransform(CircleDevice(self.center_m, self.radius_m, self.turn_s, 0.02).point(0.0))


def test_a_kind_defined_here_runs_through_build_station():
    """The target follows the toy's circle exactly: with the hold interpolation the coupling's
    target T moves by the device point's displacement since the grasp at t = 0 (no rotation)."""
    s = load_scenario(LEGO, "device: !Circle {rate_hz: 50.0}\nsimulation: {duration_s: 0.5}")
    assert isinstance(s.device, Circle)
    result = simulate(build_station(s), progress=False)
    assert result.metrics["device"] == "circle" and not result.metrics["diverged"]
    p_WT = result.coupling_terms("pose_WT")[:, 4:]
    device = make_device(s.device)
    for k in range(1, 25):  # the middle of each 20 ms sample: 10 plant steps after sample k
        row = 20 * k + 10
        moved = device.point(0.02 * k) - device.point(0.0)
        np.testing.assert_allclose(p_WT[row] - p_WT[0], moved, atol=1e-12)
    assert result.held[-1] == result.held[1] >= 0  # brick_0 held throughout


def test_a_kind_defined_here_runs_from_the_command_line(tmp_path):
    metrics = tmp_path / "m.json"
    common = ["--duration", "0.2", "--no-progress", "--metrics", str(metrics)]
    assert cli.main(["run", str(LEGO), "--device", "circle", *common]) == 0
    assert json.loads(metrics.read_text())["device"] == "circle"
    own = tmp_path / "circle.yaml"
    own.write_text(LEGO.read_text().split("device: !Scripted")[0] + "device: !Circle {radius_m: 0.01}\n"
                   + "simulation: {duration_s: 0.2}\n")  # fmt: skip
    assert cli.main(["run", str(own), *common]) == 0
    assert json.loads(metrics.read_text())["device"] == "circle"
    with pytest.raises(SystemExit):  # its own check, through the command line's error path
        cli.main(["run", str(own), "--device", "circle", *common, "--device-rate", "-1"])


def test_a_kind_checks_itself_naming_the_field():
    with pytest.raises(ScenarioError, match=r"device\.radius_m: -0\.01 m must be > 0 \(e\.g\. 0\.02\)"):
        text = LEGO.read_text().split("device: !Scripted")[0] + "device: !Circle {radius_m: -0.01}"
        scenario_from_yaml(text, REPO / "diagrams")


def test_an_unknown_kind_is_refused_naming_the_known_ones():
    @dataclasses.dataclass
    class Unregistered(_PoseDevice):
        pass

    with pytest.raises(ValueError, match=r"Unregistered is not a registered device kind; the known kinds are "
                       r"!Scripted, !Replay, !Relative, !MeshcatSliders, !Lcm, !ScriptedJoints"):  # fmt: skip
        make_device(Unregistered())
    with pytest.raises(ValueError, match=r"device kind 'circle' \(pose\) is registered already, as !Circle"):
        device_kind("circle", space="pose", factory=make_circle)(
            dataclasses.make_dataclass("Other", [], bases=(_PoseDevice,))
        )
    with pytest.raises(ValueError, match=r"space='hand'; choose one of \('pose', 'joint'\)"):
        device_kind("glove", space="hand", factory=make_circle)
    said = r"factory='make_glove'; give the function that makes its system, or its path as 'module:function'"
    with pytest.raises(ValueError, match=said):
        device_kind("glove", space="pose", factory="make_glove")


def test_every_kind_registered_once_with_its_factory():
    """Each kind is one registration, its config's: the factory it names is a function (the shipped
    ones in godobject_drake.devices.factory, imported by name), and one that cannot be imported is
    refused when a device of the kind is made, naming the path."""
    for config, kind in DEVICE_KINDS.items():
        assert callable(factory_of(kind)), config
        if config is not Circle:
            assert kind.factory.startswith("godobject_drake.devices.factory:"), kind.factory
    broken = dataclasses.replace(DEVICE_KINDS[Circle], factory="godobject_drake.devices.factory:nothing")
    with pytest.raises(
        ValueError, match=r"the factory 'godobject_drake.devices.factory:nothing' cannot be imported"
    ):
        factory_of(broken)


def test_registry_contract():
    """Every kind: a unique tag and (space, name); the command line offers its name; a kind that needs
    a browser or a driver has a stand-in for analyze that needs neither, starting where it starts."""
    tags = [k.tag for k in DEVICE_KINDS.values()]
    assert len(tags) == len(set(tags))
    assert len({(k.space, k.name) for k in DEVICE_KINDS.values()}) == len(DEVICE_KINDS)
    assert set(kinds_in("pose")) >= {"scripted", "replay", "relative", "meshcat", "lcm", "circle"}
    assert set(kinds_in("joint")) == {"scripted", "replay", "meshcat", "lcm"}
    for kind in DEVICE_KINDS.values():
        assert kind.name in cli.device_names()
        assert kind.config.__doc__, kind.tag
        assert kind.live <= kind.real_time, f"{kind.tag}: a live device is on the wall clock"
    for config in (kinds_in("pose")["meshcat"](start_xyz=[0.01, 0.02, 0.03], grasp="brick_0"),
                   kinds_in("pose")["lcm"](start_xyz=[0.01, 0.02, 0.03])):  # fmt: skip
        stand_in = config.stand_in()
        assert not (kind_of(stand_in).live or kind_of(stand_in).real_time)
        assert stand_in.waypoints[0].xyz == [0.01, 0.02, 0.03] and stand_in.waypoints[0].t == 0.0
        assert stand_in.waypoints[0].grasp == config.grasp
    joint = kinds_in("joint")["lcm"](channels=["a", "b"], start=[0.1, 0.2])
    assert joint.stand_in().waypoints[0].values == {"a": 0.1, "b": 0.2}
