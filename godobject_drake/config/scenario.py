"""A scene described once: the typed scenario a YAML file is loaded into.

A :class:`Scenario` says everything a god-object run needs: the plant and
its models, the contact settings, which god-object (rigid, articulated or
deformable) and its gains, the device, the feedback and haptic chain, how
long to run, what to draw and record, and the metrics' budget. It is loaded
with Drake's ``yaml_load_typed``, like Drake's own ``hardware_sim`` scenarios:
a union field takes a YAML tag naming its type (``device: !Replay {log:
path.csv}``), and a key the schema does not know is an error naming the key
and the file. :func:`godobject_drake.station.build.build_station` turns a scenario
into a diagram; ``python -m godobject_drake run SCENARIO.yaml`` runs one.

Every length is in m, time in s, angle in rad unless a field says degrees,
mass in kg, frequency in Hz, bandwidth in rad/s. Input files (model files in
the directives, device paths and logs) may be ``package://`` URLs or paths
relative to the YAML file; output files (recording, metrics) are relative to
the working directory, like the command line's.

This module must not use ``from __future__ import annotations``:
``yaml_load_typed`` reads the field types at run time.
"""

import copy
import dataclasses
import importlib.resources
import math
import os
import re
import types
import typing
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.multibody.parsing import ModelDirective
from pydrake.multibody.plant import MultibodyPlantConfig

from godobject_drake.config import tools
from godobject_drake.config.device_files import JointWaypoint, SampleGuard, Waypoint  # noqa: F401

# The scenario's parts, re-exported: ``from godobject_drake.config import scenario as sc`` gives
# every type a scenario file names (``sc.Rigid``, ``sc.Haptic``, ``sc.Lcm``, ...).
from godobject_drake.config.devices import (  # noqa: F401
    DEVICE_KINDS,
    DeviceKind,
    DeviceToWorld,
    Lcm,
    LcmJoints,
    MeshcatJointSliders,
    MeshcatSliders,
    Relative,
    Replay,
    ReplayJoints,
    Scripted,
    ScriptedJoints,
    device_union,
    kind_of,
    on_register,
)
from godobject_drake.config.gains import MAX_RENDERED_STIFFNESS_N_M, CouplingGains, FeedbackGains  # noqa: F401
from godobject_drake.config.inputs import InputFileError, check_input_file, check_inputs
from godobject_drake.config.scene import (  # noqa: F401
    CONTACT_GEOMETRIES,
    HAPTIC_MODES,
    MAX_BRICKS,
    MIN_TIME_STEP_S,
    SIMULATION_MODES,
    Camera,
    Contact,
    Haptic,
    Metrics,
    Organs,
    Recording,
    Simulation,
    Sleep,
    SoftAttach,
    SoftBody,
    Visualization,
    Workspace,
    default_plant_config,
)
from godobject_drake.config.task import OnPeg, Task  # noqa: F401
from godobject_drake.config.tools import (  # noqa: F401
    ARTICULATED_COUPLINGS,
    RIGID_COUPLINGS,
    SHELL_MODELS,
    TOOL_CONFIGS,
    Articulated,
    Deformable,
    Rigid,
    ShellSpec,
    tool_union,
)
from godobject_drake.config.yaml_guard import YamlShapeError, check_yaml, check_yaml_file, shown
from godobject_drake.link.transport import parse_url


class ScenarioError(ValueError):
    """A scenario that cannot be loaded or built: names the file or field, the value and the fix."""


# The device kinds live in godobject_drake.config.devices, each registered once; their names here
# are the scenario's (``sc.Scripted``, ``sc.Lcm``, ...).
POSE_DEVICES = tuple(k.config for k in DEVICE_KINDS.values() if k.space == "pose")
JOINT_DEVICES = tuple(k.config for k in DEVICE_KINDS.values() if k.space == "joint")
SPACE_NAMES = {"pose": "pose", "joint": "joint-space"}


# The fields a tool of its own holds: in a scene of one tool they are the scenario's top-level ones.
TOOL_FIELDS = ("god_object", "device", "feedback", "haptic", "workspace")
TOOL_NAME = re.compile(r"[a-z][a-z0-9_]{0,31}")


@dataclasses.dataclass
class Tool:
    """One tool of a scene of several (``tools: {NAME: {...}}``): what a one-tool scene gives at
    the scenario's top level, for this tool alone.

    Attributes
    ----------
    god_object : Rigid | Articulated | Deformable
        The tool (YAML tag ``!Rigid``, ``!Articulated`` or ``!Deformable``); in a scene of several
        tools, each tool's in ``tools`` instead.
    device : a registered device kind
        Its device (``!Scripted``, ``!Lcm``, ...), bound to this tool by the tool's name.
    feedback : FeedbackGains
        Its feedback port's gains (N/m, N·s/m, N·m/rad, N·m·s/rad).
    haptic : Haptic
        Its simulated haptic device, if any.
    workspace : Workspace
        Where its device may go (m).
    """

    god_object: tool_union() = dataclasses.field(default_factory=Rigid)
    device: device_union() = dataclasses.field(default_factory=Scripted)
    feedback: FeedbackGains = dataclasses.field(default_factory=FeedbackGains)
    haptic: Haptic = dataclasses.field(default_factory=Haptic)
    workspace: Workspace = dataclasses.field(default_factory=Workspace)


@dataclasses.dataclass
class Scenario:
    """A whole god-object scene (module docstring). Field by field, YAML keys of the same names.

    Attributes
    ----------
    name : str
        The scene's name (the metrics' ``scene``).
    random_seed : int
        Seed of every random draw (device noise).
    plant : MultibodyPlantConfig
        Drake's plant settings: ``time_step`` h (s), ``discrete_contact_approximation``,
        ``contact_model``, ``sap_near_rigid_threshold``, ... (default SAP, point, 1 ms).
    directives : list[ModelDirective]
        Drake model directives: ``add_model``, ``add_weld``, ``add_directives`` (a whole
        ``*.dmd.yaml``), ``add_frame``, ``add_collision_filter_group``.
    contact : Contact
        Which geometry touches, and SAP's relaxation time.
    god_object : Rigid | Articulated | Deformable
        The tool (YAML tag ``!Rigid``, ``!Articulated`` or ``!Deformable``).
    device : a registered device kind (:mod:`~godobject_drake.config.devices`)
        The device, by YAML tag: ``!Scripted``, ``!Replay``, ``!Relative``, ``!MeshcatSliders``,
        ``!Lcm`` (pose devices, for rigid and deformable tools) or ``!ScriptedJoints``,
        ``!ReplayJoints``, ``!MeshcatJointSliders``, ``!LcmJoints`` (joint devices, for
        articulated tools).
    workspace : Workspace
        Where the device may go (the live sliders' range).
    feedback : FeedbackGains
        Feedback gains ``kd`` (N/m), ``gamma_d`` (N·s/m), ``kd_rot`` (N·m/rad),
        ``gamma_d_rot`` (N·m·s/rad); all zero for a non-haptic device.
    bricks : int
        The brick scene's brick count: 0 keeps the directives' models; N adds brick_2x4 models
        (``brick_8``, ...) on a grid beside the path, in layers, up to N in all (``--bricks``).
    sleep : Sleep
        When resting free bodies are locked, so they cost nothing (``--sleep on|off``;
        docs/guide/sleeping.md).
    organs : Organs
        Rigid organs (the default: the directives' shapes) or FEM tissue (``--set
        organs.model=fem``: the laparoscopy scene's uterus as a Drake FEM body,
        :mod:`godobject_drake.systems.tissue`).
    deformables : dict[str, SoftBody]
        Soft bodies of the user's own, in any scene: each a name (lower case, digits, ``_``) and
        its tetrahedral mesh or primitive, pose, material and attachment (Drake FEM,
        :mod:`godobject_drake.systems.soft_body`; docs/guide/own_soft_body.md).
    haptic, simulation, visualization, recording, metrics :
        See their classes.
    tools : dict[str, Tool]
        A scene of several tools: each a name (lower case, digits, ``_``) and its own
        ``god_object``, ``device``, ``feedback``, ``haptic`` and ``workspace``; the top-level ones
        then stay unset. Empty (the default): one tool, the top-level fields.
    task : Task
        A task's success rules (which object must end on which peg) and score: task time,
        transfers, drops, the FLS score (:mod:`godobject_drake.task_score`;
        docs/guide/peg_transfer.md). Empty (the default): no task score.
    """

    name: str = "scene"
    random_seed: int = 0
    plant: MultibodyPlantConfig = dataclasses.field(default_factory=default_plant_config)
    directives: list[ModelDirective] = dataclasses.field(default_factory=list)
    contact: Contact = dataclasses.field(default_factory=Contact)
    god_object: tool_union() = dataclasses.field(default_factory=Rigid)
    device: device_union() = dataclasses.field(default_factory=Scripted)
    workspace: Workspace = dataclasses.field(default_factory=Workspace)
    feedback: FeedbackGains = dataclasses.field(default_factory=FeedbackGains)
    haptic: Haptic = dataclasses.field(default_factory=Haptic)
    simulation: Simulation = dataclasses.field(default_factory=Simulation)
    visualization: Visualization = dataclasses.field(default_factory=Visualization)
    recording: Recording = dataclasses.field(default_factory=Recording)
    metrics: Metrics = dataclasses.field(default_factory=Metrics)
    bricks: int = 0
    sleep: Sleep = dataclasses.field(default_factory=Sleep)
    organs: Organs = dataclasses.field(default_factory=Organs)
    deformables: dict[str, SoftBody] = dataclasses.field(default_factory=dict)
    tools: dict[str, Tool] = dataclasses.field(default_factory=dict)
    task: Task = dataclasses.field(default_factory=Task)

    def per_tool(self) -> dict[str, "Scenario"]:
        """Each tool's view of the scene, by name: the scenario itself under ``""`` for a scene of one
        tool (its top-level ``god_object``, ``device``, ...); for ``tools``, a copy per tool whose
        top-level tool fields are that tool's (everything else shared, ``tools`` empty)."""
        if not self.tools:
            return {"": self}
        views = {}
        for name, tool in self.tools.items():
            view = copy.copy(self)
            for field in TOOL_FIELDS:
                setattr(view, field, getattr(tool, field))
            view.tools = {}
            views[name] = view
        return views

    @property
    def kind(self) -> str:
        """``rigid``, ``articulated`` or ``deformable``."""
        return type(self.god_object).__name__.lower()

    @property
    def time_step(self) -> float:
        """The plant step h (s)."""
        return self.plant.time_step


@dataclasses.dataclass(frozen=True)
class ToolRecord:
    """One tool of a scene, resolved once (:func:`tool_records`, returned by :func:`check_scenario`
    and carried by the built station): what everything after the checks reads instead of working
    it out again.

    Attributes
    ----------
    name : str
        The tool's key in ``tools``; ``""`` for the one tool of a scene of one.
    view : Scenario
        The scenario as this tool sees it (:meth:`Scenario.per_tool`).
    device : DeviceKind
        Its device's registered kind (live, on the wall clock, rendering the feedback, ...).
    """

    name: str
    view: Scenario
    device: DeviceKind

    def named(self, what: str) -> str:
        """A system's or a log's name in this tool's loop: ``NAME/what``, or ``what`` alone."""
        return f"{self.name}/{what}" if self.name else what

    def field(self, path: str) -> str:
        """One of this tool's scenario fields as a user writes it: ``tools.NAME.path``, or ``path``."""
        return f"tools.{self.name}.{path}" if self.name else path

    @property
    def who(self) -> str:
        """What a message about this tool starts with: ``NAME: ``, or nothing."""
        return f"{self.name}: " if self.name else ""


def tool_records(s: Scenario, where: str = "scenario", names=None) -> dict[str, ToolRecord]:
    """Each tool of ``s`` resolved once, by name (``{"": ...}`` for a scene of one tool); a device
    of no registered kind is refused (:class:`ScenarioError`). ``names``: tools of a diagram of
    one's own that are not the scenario's, each seeing the whole scenario."""
    views = s.per_tool() if names is None else dict.fromkeys(names, s)
    records = {}
    for name, view in views.items():
        try:
            device = kind_of(view.device)
        except ValueError as e:
            raise ScenarioError(f"{where}: {'tools.' + name + '.' if name else ''}{e}") from None
        records[name] = ToolRecord(name, view, device)
    return records


def _retype_device() -> None:
    """A device kind registered after this module was imported: the ``device`` fields take its tag."""
    for holder in (Scenario, Tool):
        holder.__dataclass_fields__["device"].type = device_union()


def _retype_tool() -> None:
    """A tool kind registered after this module was imported: the ``god_object`` fields take its tag."""
    for holder in (Scenario, Tool):
        holder.__dataclass_fields__["god_object"].type = tool_union()


on_register(_retype_device)
tools.on_register(_retype_tool)

# The installed package godobject_models (the clone's models/ folder in an editable install): the
# models a scenario names as package://godobject_models/...
MODELS_DIR = Path(str(importlib.resources.files("godobject_models")))
# The installed package godobject_scenarios (the clone's diagrams/ folder in an editable install).
SCENARIOS_DIR = Path(str(importlib.resources.files("godobject_scenarios")))
# the shipped scenes: diagrams/NAME.yaml
SHIPPED = (
    "lego",
    "laparoscopy",
    "deformable_probe",
    "lego_two_hands",
    "laparoscopy_bimanual",
    "lego_driver",
    "laparoscopy_bimanual_drivers",
    "peg_transfer",
    "peg_transfer_drivers",
)


def shipped_scenario_file(name: str) -> Path:
    """The scenario file of the shipped scene ``name`` (``lego``, ...), from the installed package."""
    if name not in SHIPPED:
        raise ScenarioError(f"no shipped scene {name!r}; the shipped scenes are {', '.join(SHIPPED)}")
    return SCENARIOS_DIR / f"{name}.yaml"


def shipped_scenario(name: str, overrides: str | None = None) -> Scenario:
    """A shipped scene's scenario (``diagrams/NAME.yaml`` of a clone; package data when installed)."""
    return load_scenario(shipped_scenario_file(name), overrides)


def load_scenario(filename: str | Path, overrides: str | None = None, *, check: bool = True) -> Scenario:
    """Load a scenario YAML file; relative input paths are taken relative to it.

    ``overrides`` is YAML text merged on top (e.g. ``"simulation: {duration_s: 1.0}"``).
    Raises :class:`ScenarioError` naming the file (and the key) on any problem. ``check=False``
    leaves :func:`check_scenario` to the caller, once more is added to it (the command line's flags).
    """
    path = Path(filename)
    try:
        check_input_file(path, "scenario file")  # a FIFO, a loop, a huge file: before reading it
    except InputFileError as e:
        raise ScenarioError(str(e)) from None
    if not path.is_file():
        raise ScenarioError(f"scenario file {path} does not exist")
    where = str(path)
    try:
        check_yaml_file(path, where)  # an alias bomb, a deep nest, a key twice, a huge file
        scenario = yaml_load_typed(schema=Scenario, filename=str(path))
        if overrides:
            where = "the overrides"
            check_yaml(overrides, where)
            overrides = _keep_kinds(scenario, overrides)
            scenario = yaml_load_typed(schema=Scenario, data=overrides, defaults=scenario)
    except YamlShapeError as e:
        raise ScenarioError(str(e)) from None
    except LOAD_ERRORS as e:
        text = path.read_text(errors="replace") if where == str(path) else overrides
        raise ScenarioError(f"{shown(path)}: {_explain(e, text, where)}") from None
    resolve_paths(scenario, path.resolve().parent)
    if check:
        check_scenario(scenario, where=str(path))
    return scenario


def _keep_kinds(scenario: Scenario, overrides: str) -> str:
    """``overrides`` with the file's kind tag on each untagged mapping given to a field that holds
    one of several kinds (``device``, ``god_object``): Drake's loader reads an untagged mapping
    there as the first kind (``!Scripted``, ``!Rigid``), so ``device: {path: p}`` over a
    ``!ScriptedJoints`` device would replace it by a ``!Scripted`` one instead of setting its path.
    A tag the user gives is kept (a change of kind)."""
    try:
        root = yaml.compose(overrides)
    except yaml.YAMLError:
        return overrides  # the loader names the error
    if not isinstance(root, yaml.MappingNode):
        return overrides
    changed = _tag_kinds(root, scenario, typing.get_type_hints(Scenario))
    for key, value in root.value:  # each tool of a scene of several: its own kinds
        if isinstance(key, yaml.ScalarNode) and key.value == "tools" and isinstance(value, yaml.MappingNode):
            for name, tool in value.value:
                existing = scenario.tools.get(name.value) if isinstance(name, yaml.ScalarNode) else None
                if existing is not None and isinstance(tool, yaml.MappingNode):
                    changed |= _tag_kinds(tool, existing, typing.get_type_hints(Tool))
    return yaml.serialize(root) if changed else overrides


def _tag_kinds(node, holder, hints) -> bool:
    """Tag each untagged mapping of ``node`` given to a field of several kinds with ``holder``'s kind."""
    changed = False
    for key, value in node.value:
        field = key.value if isinstance(key, yaml.ScalarNode) else None
        hint = hints.get(field)
        union = typing.get_origin(hint) in (typing.Union, types.UnionType)  # not dict[str, Tool]'s args
        kinds = [k for k in typing.get_args(hint) if k is not type(None)] if union else []
        untagged = (
            isinstance(value, yaml.MappingNode)
            and value.tag == yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG
        )
        if len(kinds) > 1 and untagged:
            value.tag = "!" + type(getattr(holder, field)).__name__
            changed = True
    return changed


def scenario_from_yaml(text: str, base_dir: str | Path = ".") -> Scenario:
    """A scenario from YAML text (relative paths against ``base_dir``)."""
    try:
        check_yaml(text, "scenario text")
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except YamlShapeError as e:
        raise ScenarioError(str(e)) from None
    except LOAD_ERRORS as e:
        raise ScenarioError(f"scenario text: {_explain(e, text, 'the text')}") from None
    resolve_paths(scenario, Path(base_dir).resolve())
    check_scenario(scenario, where="scenario text")
    return scenario


def scenario_to_yaml(scenario: Scenario) -> str:
    """The scenario as YAML text (what :func:`scenario_from_yaml` reads back)."""
    return yaml_dump_typed(scenario)


# The most of the loader's message a ScenarioError repeats: it quotes the value it could not read.
MAX_QUOTED = 300
# What yaml_load_typed raises for a file it cannot read into a Scenario.
LOAD_ERRORS = (RuntimeError, ValueError, TypeError, AssertionError, yaml.YAMLError)


def _explain(e: Exception, source: str = "", where: str = "") -> str:
    """The loader's message, with the key it is about and the fix where they can be told; a long
    value it quotes is cut and control characters are escaped (a file's content stays out)."""
    full = str(e) or type(e).__name__
    text = shown(full if len(full) <= MAX_QUOTED else full[:MAX_QUOTED] + " …")
    if isinstance(e, yaml.YAMLError):
        return (
            f"not valid YAML in {where}: {' '.join(text.split())}; check the brackets, colons and indentation"
        )
    if "were unknown to the schema" in text:
        return f"{text}: a key the scenario does not know (check its spelling and indentation)"
    if "did not match any of the allowed type options" in text:
        return f"{text}: give the YAML tag of one of those types, e.g. device: !Scripted {{...}}"
    keys = _keys_holding(source, full)
    if keys:
        at = ", ".join(keys)
        return f"{text} (at {at} in {where}): give that key a value of its type (a number, a list, ...)"
    return text


def _keys_holding(source: str, message: str) -> list[str]:
    """The key paths of ``source`` (YAML text) whose value the loader's ``message`` quotes: the
    loader names the bad value but not its key."""
    try:
        data = yaml.load(source, Loader=_AnyTagLoader)
    except yaml.YAMLError:
        return []
    found = []

    def walk(node, at):
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{at}.{k}" if at else str(k))
        elif isinstance(node, list) and at and (repr(node) in message or str(node) in message):
            found.append(at)
        elif isinstance(node, str) and at and repr(node) in message:
            found.append(at)

    walk(data, "")
    return found


class _AnyTagLoader(yaml.SafeLoader):
    """A plain loader that reads ``!Tag {...}`` as its mapping (for finding keys only)."""


_AnyTagLoader.add_multi_constructor(
    "!",
    lambda loader, suffix, node: (
        loader.construct_mapping(node) if isinstance(node, yaml.MappingNode) else None
    ),
)


PACKAGE_URL = "package://godobject_models/"


def replaying_devices(s: "Scenario", log: str | Path) -> "Scenario":
    """``s`` with each tool's device the replay of its recorded device log (``--replay-devices``:
    ``recording.device_log``'s files, ``log`` for a scene of one tool, ``log``'s stem and the
    tool's name for several): a pose device a :class:`Replay`, a joint device a
    :class:`ReplayJoints`, each keeping the old one's period, interpolation, guard, channels, mix
    and limits, with no latency or noise (the log holds the samples as they were reported)."""
    s = copy.deepcopy(s)
    paths = Recording(device_log=str(absolute(log)))
    for name, device in [("", s.device)] if not s.tools else [(n, t.device) for n, t in s.tools.items()]:
        space = kind_of(device).space
        cls = Replay if space == "pose" else ReplayJoints
        keep = {f.name: getattr(device, f.name) for f in dataclasses.fields(cls) if hasattr(device, f.name)}
        for field in ("path", "waypoints", "log", "start_xyz", "start_rpy_deg", "start"):
            keep.pop(field, None)
        replay = cls(**keep)
        replay.log = str(paths.device_log_for(name))
        replay.latency_s = 0.0
        if space == "pose":
            replay.noise_m = 0.0
        if name:
            s.tools[name].device = replay
        else:
            s.device = replay
    return s


def absolute(path: str | Path) -> Path:
    """``path`` made absolute, its links resolved where they can be: a symlink loop is kept as it is
    written (``Path.resolve`` raised ``RuntimeError``), for :func:`check_inputs` to name it."""
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError):
        return Path(os.path.abspath(path))


def _resolve(value: str, base: Path) -> str:
    """A path relative to ``base`` made absolute; ``package://godobject_models/`` to the models."""
    if value.startswith(PACKAGE_URL):
        return str(MODELS_DIR / value[len(PACKAGE_URL) :])
    if not value or "://" in value or Path(value).is_absolute():
        return value
    return str(absolute(base / value))


def _resolve_url(value: str, base: Path) -> str:
    """A model file for Drake's parser: ``package://`` kept, anything else a ``file://`` URL."""
    if not value or "://" in value:
        return value
    return "file://" + _resolve(value, base)


def resolve_paths(scenario: Scenario, base: Path) -> None:
    """Make the scenario's relative input paths absolute against ``base`` (in place)."""
    for directive in scenario.directives:
        if directive.add_model is not None:
            directive.add_model.file = _resolve_url(directive.add_model.file, base)
        if directive.add_directives is not None:
            directive.add_directives.file = _resolve_url(directive.add_directives.file, base)
    for device in [scenario.device, *(tool.device for tool in scenario.tools.values())]:
        for attribute in ("path", "log"):
            if hasattr(device, attribute):
                setattr(device, attribute, _resolve(getattr(device, attribute), base))
    for body in scenario.deformables.values():  # a soft body's tetrahedral mesh
        body.mesh = _resolve(body.mesh, base)


def _fail(where: str, field: str, message: str):
    raise ScenarioError(f"{where}: {field}: {message}")


# The scenario's parts that check themselves, in the order a user reads them: the scene's, then each
# tool's (the top-level ones in a scene of one tool).
SCENE_PARTS = ("contact", "simulation", "visualization", "recording", "metrics", "organs", "task")
TOOL_PARTS = ("haptic", "device", "god_object", "workspace")


def check_scenario(s: Scenario, where: str = "scenario") -> dict[str, ToolRecord]:
    """Raise :class:`ScenarioError` naming the field, its value and the fix; no value is clamped.
    Returns the tools' records (:func:`tool_records`).

    Each part checks itself (its ``check()``); this adds Drake's plant settings and the rules that
    span two parts."""
    h = s.plant.time_step
    if not (isinstance(h, float | int) and math.isfinite(h) and h > 0):
        _fail(
            where,
            "plant.time_step",
            f"{h!r} s; SAP is discrete: give a step h > 0 (e.g. 0.001). A continuous plant (time_step 0, "
            "Drake's cenic integrator) is not offered: on the brick scene it was slower than SAP at "
            "equal penetration (docs/results.md, 'CENIC against SAP')",
        )
    if h < MIN_TIME_STEP_S:
        _fail(
            where,
            "plant.time_step",
            f"{h!r} s is under {MIN_TIME_STEP_S:g} s: a simulated second would take {1 / h:.3g} steps. "
            "Give h ≥ 1e-05 (the shipped scenes use 0.001)",
        )
    if s.plant.discrete_contact_approximation not in ("sap", "lagged", "similar"):
        _fail(
            where,
            "plant.discrete_contact_approximation",
            f"{s.plant.discrete_contact_approximation!r}; use sap, lagged or similar (the god-object's "
            "joint modes and deformable shells need sap)",
        )
    for field, strict in (("sap_near_rigid_threshold", False), ("penetration_allowance", True),
                          ("stiction_tolerance", True)):  # fmt: skip
        value = getattr(s.plant, field)
        finite = isinstance(value, float | int) and math.isfinite(value)
        if not (finite and (value > 0 if strict else value >= 0)):
            default = getattr(MultibodyPlantConfig(), field)
            _fail(where, f"plant.{field}", f"{value!r} must be a finite number {'>' if strict else '≥'} 0 "
                  f"(Drake's default: {default:g})")  # fmt: skip
    for device in [s.device, *(tool.device for tool in s.tools.values())]:  # set after loading (Python)
        for attribute in ("path", "log"):
            value = getattr(device, attribute, "")
            if isinstance(value, str) and value.startswith(PACKAGE_URL):  # what loading makes of it
                setattr(device, attribute, _resolve(value, Path.cwd()))
    try:  # every file Drake or a device will read: a FIFO, a device, a loop, a huge file (config.inputs)
        check_inputs(s, MODELS_DIR, where)
    except InputFileError as e:
        raise ScenarioError(str(e)) from None
    for part in SCENE_PARTS:
        try:
            getattr(s, part).check()
        except ValueError as e:
            raise ScenarioError(f"{where}: {part}.{e}") from None
    try:
        s.sleep.check()
    except ValueError as e:
        _fail(where, "sleep", str(e))
    if not (isinstance(s.bricks, int) and 0 <= s.bricks <= MAX_BRICKS):
        _fail(
            where,
            "bricks",
            f"{s.bricks!r}: give a whole number of bricks up to {MAX_BRICKS} (the grid's 54 places a layer; "
            "the scale study goes to 128), or 0 for the directives' own",
        )
    _check_scene(s, where)
    _check_deformables(s, where)
    if s.tools:
        _check_tools(s, where)
    records = tool_records(s, where)
    for record in records.values():
        _check_tool(record, where)
    return records


def _check_tool(record: ToolRecord, where: str) -> None:
    """One tool's parts (its device, tool, haptic chain, workspace) and the rules between them,
    its fields named as the user writes them (``tools.left.``) in a scene of several."""
    s, at, device_kind = record.view, record.field(""), record.device
    for part in TOOL_PARTS:
        try:
            getattr(s, part).check(s) if part == "god_object" else getattr(s, part).check()
        except ValueError as e:
            prefix = "" if part == "god_object" else f"{part}."  # a god-object names its own fields
            raise ScenarioError(f"{where}: {at}{prefix}{e}") from None
    device, kind, space = s.device, s.kind, s.god_object.DEVICE_SPACE
    through = getattr(s.god_object, "POSE_DEVICE_THROUGH", "")  # a pose device mapped to the joints
    if device_kind.space == "pose" and space == "joint" and through:
        try:
            getattr(s.god_object, through).check(s.god_object)
        except ValueError as e:
            tags = ", ".join(k.tag for k in DEVICE_KINDS.values() if k.space == space)
            _fail(
                where,
                f"{at}device",
                f"a{'n' if kind[0] in 'aeiou' else ''} {kind} god-object needs a {SPACE_NAMES[space]} device "
                f"({tags}), or a pose device mapped through its trocar; got !{type(device).__name__}, and "
                f"{at}{e}",
            )
    elif device_kind.space != space:
        tags = ", ".join(k.tag for k in DEVICE_KINDS.values() if k.space == space)
        _fail(
            where,
            f"{at}device",
            f"a{'n' if kind[0] in 'aeiou' else ''} {kind} god-object needs a {SPACE_NAMES[space]} device "
            f"({tags}); got !{type(device).__name__}",
        )
    if device_kind.space == "pose" and device.changed_aids() and s.haptic.mode != "none":
        field = device.changed_aids()[0]
        _fail(
            where,
            f"{at}device.{field}",
            f"{getattr(device, field)!r} is for a device that cannot feel the god-object; with haptic.mode "
            f"{s.haptic.mode!r} the force is felt: set haptic.mode: none, or remove {field}",
        )
    if device_kind.renders_feedback:
        _check_rendered_stiffness(s, at, where)
    if device_kind.renders_feedback and s.haptic.mode != "none":
        _fail(
            where,
            f"{at}haptic.mode",
            f"{s.haptic.mode!r} simulates a haptic device; with !{type(device).__name__} the real device is "
            "the haptic one and the feedback wrench goes to it: set haptic.mode: none",
        )


def _check_rendered_stiffness(s: Scenario, at: str, where: str) -> None:
    """A device that renders the feedback feels ``scale² kd``: at most what a device renders."""
    scale = getattr(getattr(s.device, "device_to_world", None), "scale", 1.0)
    felt = s.feedback.kd * scale**2
    if felt > MAX_RENDERED_STIFFNESS_N_M:
        said = f" (× scale² = {scale**2:g}: {felt:.4g} N/m on the device)" if scale != 1.0 else ""
        _fail(
            where,
            f"{at}feedback.kd",
            f"{s.feedback.kd:.4g} N/m{said} is past the stiffest a haptic device renders, "
            f"{MAX_RENDERED_STIFFNESS_N_M:,.0f} N/m (an omega.3's; a Touch's is 1,020): its driver would "
            f"refuse every model. Give --kd ≤ {MAX_RENDERED_STIFFNESS_N_M / scale**2:.4g} (the shipped scene "
            "uses 50)",
        )


def _check_scene(s: Scenario, where: str) -> None:
    """The rules between the scene's own parts: contact and plant, organs and plant."""
    if s.contact.geometry == "hydroelastic" and s.plant.contact_model == "point":
        _fail(
            where,
            "contact.geometry",
            "hydroelastic needs plant.contact_model hydroelastic or hydroelastic_with_fallback (it is point)",
        )
    if s.organs.model == "fem" and s.plant.discrete_contact_approximation != "sap":
        _fail(
            where,
            "organs.model",
            f"fem needs plant.discrete_contact_approximation sap (Drake's deformable bodies are SAP only); "
            f"it is {s.plant.discrete_contact_approximation!r}: set it to sap, or organs.model: rigid",
        )


def _check_deformables(s: Scenario, where: str) -> None:
    """Each soft body's fields (its mesh is read and checked when the plant is built)."""
    for name, body in s.deformables.items():
        if not (isinstance(name, str) and TOOL_NAME.fullmatch(name)):
            _fail(where, "deformables", f"{name!r}: a soft body's name is lower case letters, digits and _, "
                  "a letter first, at most 32 (e.g. liver, sponge)")  # fmt: skip
        try:
            body.check()
        except ValueError as e:
            raise ScenarioError(f"{where}: deformables.{name}.{e}") from None
        if s.plant.discrete_contact_approximation != "sap":
            said = s.plant.discrete_contact_approximation
            _fail(where, f"deformables.{name}", "needs plant.discrete_contact_approximation sap (Drake's "
                  f"deformable bodies are SAP only); it is {said!r}")  # fmt: skip


def _check_tools(s: Scenario, where: str) -> None:
    """A scene of several tools: their names, the top-level tool fields left unset, and two devices
    never on one LCM channel of one link."""
    for name in s.tools:
        if not (isinstance(name, str) and TOOL_NAME.fullmatch(name)):
            _fail(where, "tools", f"{name!r}: a tool's name is lower case letters, digits and _, a letter "
                  "first, at most 32 (e.g. left, right, grasper_2)")  # fmt: skip
    default = Scenario()
    for field in TOOL_FIELDS:
        given, unset = (yaml_dump_typed(Tool(**{field: getattr(x, field)})) for x in (s, default))
        if given != unset:
            _fail(
                where,
                field,
                f"this scene has tools ({', '.join(s.tools)}): give each tool its own {field} under "
                f"tools.NAME.{field} and leave the top-level {field} out (a flag that sets it: use --set "
                f"tools.NAME.{field}...=VALUE)",
            )
    _check_links(s, where)


def _check_links(s: Scenario, where: str) -> None:
    """Two LCM devices never on one channel of one link, and two devices never on one ``udp://``
    address: such a link pairs with one driver, which drives one tool (docs/guide/laparoscopy.md
    "Both hands from two drivers")."""
    links: dict[tuple, str] = {}
    listens: dict[tuple, str] = {}
    for name, tool in s.tools.items():
        channel = getattr(tool.device, "channel", None)
        if channel is None:
            continue
        url = getattr(tool.device, "url", "")
        if url.startswith("udp://"):
            host, port = parse_url(url)
            if (host, port) in listens:
                _fail(
                    where,
                    f"tools.{name}.device.url",
                    f"{url!r} is tools.{listens[host, port]}'s driver link too: a udp:// link pairs with one "
                    f"driver, which drives one tool; give each tool a port of its own (e.g. "
                    f"udp://{host}:{port + 1}) and start one driver for each",
                )
            listens[host, port] = name
        key = (url, channel)
        if key in links:
            _fail(
                where,
                f"tools.{name}.device.channel",
                f"{channel!r} on {key[0] or 'the default LCM'} is tools.{links[key]}'s too: two devices on "
                "one channel would read each other's samples; give each its own channel (or its own "
                "udp:// link, one driver each)",
            )
        links[key] = name


def replace(scenario: Scenario, **changes) -> Scenario:
    """A copy of ``scenario`` with fields changed; nested fields as ``"simulation.duration_s"``.

    ``replace(s, **{"simulation.duration_s": 2.0, "plant.time_step": 2e-3})``. The copy is
    deep, so the original is never changed.
    """
    out = copy.deepcopy(scenario)
    for key, value in changes.items():
        *parents, last = key.split(".")
        target = out
        for name in parents:
            target = getattr(target, name)
        if not hasattr(target, last):
            raise ScenarioError(f"replace: {type(target).__name__} has no field {last!r} (in {key!r})")
        setattr(target, last, value)
    return out
