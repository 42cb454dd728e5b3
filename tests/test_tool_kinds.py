"""The tool-kind registry: a kind defined in this file alone (docs/design.md "Adding a tool kind")
loads from YAML, takes its own command-line flag, builds through ``build_station`` from the loop's
steps, is measured and answers what the studies ask; and contract checks over every kind.

The toy kind, ``!OneBrick``: a rigid tool that may hold one named brick only, on the explicit
coupling without gravity compensation. Its flag ``--brick`` is an alias of its field ``brick``.
"""

import dataclasses
import inspect
import json
from typing import ClassVar

import pytest
from conftest import REPO

from godobject_drake import cli
from godobject_drake.config.flags import Flag
from godobject_drake.config.gains import CouplingGains
from godobject_drake.config.scenario import load_scenario
from godobject_drake.config.tools import TOOL_BUILDERS, TOOL_CONFIGS, tool_kind
from godobject_drake.simulation import simulate
from godobject_drake.station import loop
from godobject_drake.station.build import build_station
from godobject_drake.station.haptic_chain import add_haptic_chain
from godobject_drake.station.kinds import GodObject, builder_of, kind_for
from godobject_drake.station.rigid_tool import RigidGodObject
from godobject_drake.studies.analyze import LOOPS
from godobject_drake.studies.benchmark import case_config, describe, god_object_body, make_case
from godobject_drake.studies.kinds import RIGID, STUDY_KINDS, columns, study_kind

LEGO = REPO / "diagrams" / "lego.yaml"


@dataclasses.dataclass
class OneBrickTool(RigidGodObject):
    """The toy kind: the rigid kind's answers (metrics, drawing, prediction), its own loop."""

    kind: ClassVar[str] = "one_brick"

    @classmethod
    def add_to_plant(cls, plant, scene_graph, scenario, device, *, check_gains=True, name="") -> dict:
        return {}  # nothing before Finalize (the rigid kind adds its implicit springs here)

    @classmethod
    def build(cls, builder, scene, scenario, device, added, *, check_gains=True):
        config, plant = scenario.god_object, scene.plant
        coupling = loop.add_coupling(builder, plant, device, config.gains, graspable=[config.brick],
                                     gravity_compensation=False, check_gains=check_gains)  # fmt: skip
        chain = add_haptic_chain(builder, scenario.haptic, device, coupling)
        feedback = loop.add_feedback(builder, chain, coupling, scenario.feedback)
        loop.connect_target(builder, chain, coupling)
        loop.connect_forces(builder, plant, coupling)
        publisher = loop.render_feedback(builder, device, chain, feedback, coupling)
        return cls(coupling, feedback, source=device, chain=chain, publisher=publisher)

    def configuration(self, scenario, station) -> dict:
        return {"one_brick": scenario.god_object.brick}


@tool_kind(OneBrickTool)
@dataclasses.dataclass
class OneBrick:
    """The toy kind's config: ``god_object: !OneBrick {brick: brick_0, gains: {...}}``."""

    brick: str = "brick_0"
    gains: CouplingGains = dataclasses.field(default_factory=CouplingGains)

    DEVICE_SPACE: ClassVar[str] = "pose"
    FLAGS: ClassVar[tuple[Flag, ...]] = (Flag("--brick", "god_object.brick", "the one brick it may hold"),)

    def check(self, scenario) -> None:
        if not self.brick.startswith("brick_"):
            raise ValueError(f"god_object.brick: {self.brick!r}; name a brick (brick_0, brick_1, ...)")


# What the studies ask of it: the rigid kind's answers (its pose body, its label's tail, the engines
# compared), but its own label words, its columns and its loop (the explicit coupling only).
STUDY_KINDS["one_brick"] = dataclasses.replace(
    RIGID,
    describe=lambda scenario: [f"one={scenario.god_object.brick}"],
    study_config=lambda scenario: columns(contact=scenario.contact.geometry, coupling="explicit"),
    loop_model=lambda config: "body",
)


SCENARIO = (
    "god_object: !OneBrick {brick: brick_0, gains: {omega_n: 30.0, zeta: 1.0}}\nsimulation: {duration_s: 1.0}"
)


def test_a_kind_defined_here_loads_builds_and_runs():
    s = load_scenario(LEGO, SCENARIO)
    assert isinstance(s.god_object, OneBrick) and kind_for(s.god_object) is OneBrickTool
    result = simulate(build_station(s), progress=False)
    m = result.metrics
    assert not m["diverged"] and m["one_brick"] == "brick_0"
    # Without gravity compensation the held brick hangs below its target by g/ωn² (paper Eq. 3's
    # static offset): 9.81 / 30² = 10.9 mm, once the pull has settled (the path holds still at
    # the start, its first waypoints at one place).
    held = result.held
    assert held[-1] == held[100] >= 0
    p_WT = result.coupling_terms("pose_WT")[:, 4:]
    p_WG = result.coupling_terms("pose_WG")[:, 4:]
    sag = p_WT[400, 2] - p_WG[400, 2]
    assert sag == pytest.approx(9.81 / 30.0**2, rel=0.05)


def test_a_kind_defined_here_takes_its_flag_on_the_command_line(tmp_path, capsys):
    """The file says brick_1, which the brick path never grasps (refused: exit 2); ``--brick
    brick_0`` sets the field and the run goes."""
    text = LEGO.read_text()
    start, end = text.index("god_object: !Rigid"), text.index("device:")
    scenario = tmp_path / "one_brick.yaml"
    scenario.write_text(text[:start] + "god_object: !OneBrick {brick: brick_1}\n" + text[end:])
    metrics = tmp_path / "m.json"
    common = ["--duration", "0.2", "--no-progress", "--metrics", str(metrics)]
    with pytest.raises(SystemExit) as refused:
        cli.main(["run", str(scenario), *common])
    assert refused.value.code == 2 and "brick_0" in capsys.readouterr().err
    assert cli.main(["run", str(scenario), *common, "--brick", "brick_0"]) == 0
    assert json.loads(metrics.read_text())["one_brick"] == "brick_0"


@pytest.mark.parametrize(
    ("scene", "body"),
    [("lego", "brick_0"), ("laparoscopy", "tube"), ("deformable_probe", "probe")],
)
def test_the_studies_find_each_shipped_scenes_god_object_body(scene, body):
    """The speed report's god-object pose, per kind: the rigid device's first grasp, the grasper's
    tip body, the probe's core (the grasper's joint device was asked for grasp names it does not
    have, and the speed report's laparoscopy rows failed)."""
    assert god_object_body(load_scenario(REPO / "diagrams" / f"{scene}.yaml")) == body


def test_the_studies_ask_the_kind():
    s = load_scenario(LEGO, SCENARIO)
    assert describe(s) == "h=1ms one=brick_0"
    assert case_config(s, make_case(s))["contact"] == "proxies"  # the rigid kind's columns, inherited
    assert god_object_body(s) == "brick_0"


@pytest.mark.parametrize("config", TOOL_CONFIGS, ids=lambda c: c.__name__)
def test_every_tool_kind_is_whole(config):
    """Every registered tool config has a kind, a device space, flags naming fields it has, and a
    kind that answers every question the library asks (nothing left to the base's NotImplemented)."""
    kind = builder_of(config)
    assert issubclass(kind, GodObject) and config.DEVICE_SPACE in ("pose", "joint")
    default = config()
    for flag in getattr(config, "FLAGS", ()):
        head, _, rest = flag.field.partition(".")
        assert head == "god_object", flag
        target = default
        for part in rest.split("."):
            assert hasattr(target, part), (flag.name, flag.field)
            target = getattr(target, part)
    if config is not OneBrick:  # a shipped kind: registered once, on its config, naming its builder
        assert TOOL_BUILDERS[config].startswith("godobject_drake.station."), TOOL_BUILDERS[config]
    for question in ("build", "new_metrics"):
        assert getattr(kind, question) is not getattr(GodObject, question), (kind.__name__, question)
    assert study_kind(kind.kind).loop_model(default) in LOOPS, kind.kind


def test_a_kind_without_a_study_entry_is_refused_naming_the_entry_to_add():
    with pytest.raises(
        ValueError, match=r"tool kind 'nameless' has no study entry .*STUDY_KINDS\['nameless'\]"
    ):
        study_kind("nameless")


@pytest.mark.parametrize("config", TOOL_CONFIGS, ids=lambda c: c.__name__)
def test_every_kind_answers_with_the_bases_signature(config):
    """A kind that overrides a question takes every argument the base's takes, by the same names, so
    ``build_station`` can ask any kind the same way (the deformable kind's ``predict_penetration``
    once lacked ``duration_s`` and every deformable scene failed to build)."""
    kind = builder_of(config)
    for name, base in inspect.getmembers(GodObject, inspect.isfunction):
        if name.startswith("__"):
            continue
        own = getattr(kind, name)
        want = list(inspect.signature(base).parameters)
        have = list(inspect.signature(own).parameters)
        assert have[: len(want)] == want, (kind.__name__, name, have, want)


def test_a_tool_kind_is_refused_with_what_to_give(monkeypatch):
    """A builder that is neither a class nor a ``module:Class`` path, a config registered again with
    another builder, and a path that cannot be imported: each refused, naming the value and the fix."""
    with pytest.raises(
        ValueError, match=r"builder='OneBrickTool'; give the GodObject subclass that builds it"
    ):
        tool_kind("OneBrickTool")
    with pytest.raises(ValueError, match=r"tool kind !OneBrick is registered already, built by"):
        tool_kind(RigidGodObject)(OneBrick)
    monkeypatch.setitem(TOOL_BUILDERS, OneBrick, "godobject_drake.station.rigid_tool:NoSuchTool")
    with pytest.raises(
        ValueError, match=r"the builder 'godobject_drake.station.rigid_tool:NoSuchTool' cannot be"
    ):
        builder_of(OneBrick)
