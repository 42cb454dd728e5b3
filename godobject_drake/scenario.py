"""A scene described once: the typed scenario a YAML file is loaded into.

A :class:`Scenario` says everything a god-object run needs: the plant and
its models, the contact settings, which god-object (rigid, articulated or
deformable) and its gains, the device, the feedback and haptic chain, how
long to run, what to draw and record, and the metrics' budget. It is loaded
with Drake's ``yaml_load_typed``, like Drake's own ``hardware_sim`` scenarios:
a union field takes a YAML tag naming its type (``device: !Replay {log:
path.csv}``), and a key the schema does not know is an error naming the key
and the file. :func:`godobject_drake.building.build_station` turns a scenario
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
import typing
from pathlib import Path
from typing import ClassVar

import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.multibody.parsing import ModelDirective
from pydrake.multibody.plant import MultibodyPlantConfig

from godobject_drake.coupling import DEFAULT_MAX_STRETCH_M, DEFAULT_MAX_TWIST_RAD, CouplingGains
from godobject_drake.deformable import SHELL_MODELS, ShellSpec
from godobject_drake.device_kinds import (  # noqa: F401  the scenario's names for the device kinds
    DEVICE_KINDS,
    Lcm,
    LcmJoints,
    MeshcatJointSliders,
    MeshcatSliders,
    Relative,
    Replay,
    Scripted,
    ScriptedJoints,
    device_union,
    kind_of,
)
from godobject_drake.feedback import FeedbackGains
from godobject_drake.sleeping import Sleep
from godobject_drake.tissue import Organs


class ScenarioError(ValueError):
    """A scenario that cannot be loaded or built: names the file or field, the value and the fix."""


def default_plant_config() -> MultibodyPlantConfig:
    """SAP, point contact, h = 1 ms: what the shipped scenes use."""
    return MultibodyPlantConfig(time_step=1e-3, discrete_contact_approximation="sap", contact_model="point")


CONTACT_GEOMETRIES = ("proxies", "hydroelastic")


@dataclasses.dataclass
class Contact:
    """Which geometry touches, and SAP's contact compliance.

    Attributes
    ----------
    geometry : str
        ``proxies``: a geometry named ``proxy_*`` (the paper's small spheres) touches other
        bodies' true shapes, never another proxy; a body's true shape touches only bodies
        without proxies; a ``flat_*`` welded geometry only ``proxy_corner_*`` proxies. With no
        proxies in the scene every true shape touches every other. ``hydroelastic``: proxies
        are ignored and true shapes touch (needs a hydroelastic ``plant.contact_model``).
    relaxation_time_s : float | None
        SAP's relaxation time on every rigid contact geometry (s); None: the plant's time
        step, which keeps point contact at its nominal stiffness (Drake's default, 0.1 s,
        makes it far softer).
    """

    geometry: str = "proxies"
    relaxation_time_s: float | None = None

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if self.geometry not in CONTACT_GEOMETRIES:
            raise ValueError(f"geometry: {self.geometry!r}; choose one of {CONTACT_GEOMETRIES}")
        tau = self.relaxation_time_s
        if tau is not None and not (math.isfinite(tau) and tau >= 0):
            raise ValueError(f"relaxation_time_s: {tau!r} s must be ≥ 0 (None: the time step)")


@dataclasses.dataclass
class Rigid:
    """Free rigid bodies a device grasps by name (paper Eq. 2).

    Attributes
    ----------
    gains : CouplingGains
        Bandwidth ``omega_n`` (rad/s), damping ratio ``zeta``, and the rotation's
        ``omega_n_rot``/``zeta_rot`` (None: as the translation's).
    graspable : list[str]
        The bodies the device may hold (``model``, ``model::body`` or a unique body name);
        empty: every free body.
    gravity_compensation : bool
        Add ``−m g`` so a held body hangs at its target.
    max_stretch_m, max_twist_rad : float
        Force and torque caps, as the stretch (m) and twist (rad) whose spring force they
        equal (``.inf``: no cap).
    grasp_reach_m : float
        A live grasp (``"*"``) takes the free body nearest the device within this (m).
    coupling : str
        ``explicit`` (the PD wrench computed in Python each plant step and applied to the body:
        stable only below ``ωn h < 2(√(1+ζ²) − ζ)``) or ``implicit`` (the same spring made of
        compliant constraints SAP integrates implicitly, no Python per plant step:
        :mod:`godobject_drake.implicit`).
    """

    gains: CouplingGains = dataclasses.field(default_factory=CouplingGains)
    graspable: list[str] = dataclasses.field(default_factory=list)
    gravity_compensation: bool = True
    max_stretch_m: float = DEFAULT_MAX_STRETCH_M
    max_twist_rad: float = DEFAULT_MAX_TWIST_RAD
    grasp_reach_m: float = 0.05
    coupling: str = "explicit"

    DEVICE_SPACE: ClassVar[str] = "pose"

    def check(self, scenario: "Scenario") -> None:
        """Its coupling kind against the scene (the builder checks the gains against the step)."""
        if self.coupling not in RIGID_COUPLINGS:
            raise ValueError(
                f"god_object.coupling: {self.coupling!r}; choose one of {RIGID_COUPLINGS} for a rigid "
                "god-object"
            )
        if self.coupling != "implicit":
            return
        why = None
        if scenario.haptic.mode == "admittance":
            why = (
                "haptic.mode admittance drives the held body with the device's sensed wrench, not a spring; "
                "use haptic.mode impedance or none"
            )
        elif scenario.simulation.mode == "position":
            why = "simulation.mode position imposes the held body's pose: there is no spring to integrate"
        if why:
            raise ValueError(
                f"god_object.coupling: implicit with {why}. Or set god_object.coupling: explicit"
            )


RIGID_COUPLINGS = ("explicit", "implicit")


ARTICULATED_COUPLINGS = ("cartesian", "joint_pd", "joint_pd_sap")


@dataclasses.dataclass
class Articulated:
    """A tree model whose joints a joint-space device drives (paper Eq. 4–9).

    Attributes
    ----------
    model : str
        The tool's model instance.
    device_joints : list[str]
        The joints the device gives values for, in the device's order.
    coupling : str
        ``cartesian`` (paper Eq. 6, explicit), ``joint_pd`` (explicit) or ``joint_pd_sap``
        (SAP's implicit PD actuators).
    imposed_joints : list[str]
        Device joints set to the device's values instead of coupled (the paper's jaws).
    gains : CouplingGains
        As for :class:`Rigid` (joint modes use ``omega_n``, ``zeta``).
    self_collisions : bool
        Let the tool's own parts touch each other (usually they overlap at their joints).
    check_every : int
        The explicit modes' stability is checked at every ``check_every``-th device sample
        of the path (≥ 1).
    tip_body : str
        Metrics: the body whose origin is the tip tracked against the device's (empty: the
        last of the coupled bodies).
    pivot_body : str
        Metrics: a body welded at a pivot (a trocar); ``max_trocar_offset_m`` is its distance
        from the tip body's z axis. Empty: not measured.
    """

    model: str = ""
    device_joints: list[str] = dataclasses.field(default_factory=list)
    coupling: str = "cartesian"
    imposed_joints: list[str] = dataclasses.field(default_factory=list)
    gains: CouplingGains = dataclasses.field(default_factory=CouplingGains)
    self_collisions: bool = False
    check_every: int = 6
    tip_body: str = ""
    pivot_body: str = ""

    DEVICE_SPACE: ClassVar[str] = "joint"

    def check(self, scenario: "Scenario") -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"`` (fields from the scenario's top)."""
        if scenario.haptic.mode != "none":
            raise ValueError(
                f"haptic.mode: {scenario.haptic.mode!r}; the joint-space devices here have no simulated "
                "haptic device: leave haptic.mode none. The feedback gains (feedback.kd, ...) still give "
                "the Eq. 8/9 wrenches and the device joints' forces, logged and in the metrics, for a "
                "haptic device of your own"
            )
        if self.coupling not in ARTICULATED_COUPLINGS:
            raise ValueError(f"god_object.coupling: {self.coupling!r}; choose one of {ARTICULATED_COUPLINGS}")
        if not self.model or not self.device_joints:
            raise ValueError("god_object: an articulated god-object needs model and device_joints")
        if not (isinstance(self.check_every, int) and self.check_every >= 1):
            raise ValueError(f"god_object.check_every: {self.check_every!r} must be an integer ≥ 1")


@dataclasses.dataclass
class Deformable:
    """A rigid core (a god-object) carrying a deformable shell (paper Fig. 4).

    Attributes
    ----------
    name : str
        The core's name (its model instance; the device holds it).
    shell : str
        ``fem`` (Drake's FEM) or ``mass_spring`` (the paper's net).
    spec : ShellSpec
        Geometry and material (radius_m, core_radius_m, youngs_modulus_pa, nodes, ...).
    gains : CouplingGains
        As for :class:`Rigid`, scaled by core + shell.

    A light shell node at a large step presses a contact far softer than its nominal
    stiffness unless ``plant.sap_near_rigid_threshold`` is lowered (the shipped probe: 0.1).
    """

    name: str = "probe"
    shell: str = "fem"
    spec: ShellSpec = dataclasses.field(default_factory=ShellSpec)
    gains: CouplingGains = dataclasses.field(default_factory=CouplingGains)

    DEVICE_SPACE: ClassVar[str] = "pose"

    def check(self, scenario: "Scenario") -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if self.shell not in SHELL_MODELS:
            raise ValueError(f"god_object.shell: {self.shell!r}; choose one of {SHELL_MODELS}")


# The device kinds live in godobject_drake.device_kinds, each registered once; their names here
# are the scenario's (``sc.Scripted``, ``sc.Lcm``, ...).
POSE_DEVICES = tuple(k.config for k in DEVICE_KINDS.values() if k.space == "pose")
JOINT_DEVICES = tuple(k.config for k in DEVICE_KINDS.values() if k.space == "joint")
SPACE_NAMES = {"pose": "pose", "joint": "joint-space"}
# Limits on values that would make a run's output useless or the run never end.
MIN_TIME_STEP_S = 1e-5
MAX_DURATION_S = 1e6
MAX_FRAMES_PER_SECOND = 1000.0
MAX_BRICKS = 512
HAPTIC_MODES = ("none", "impedance", "admittance")


@dataclasses.dataclass
class Haptic:
    """The haptic device the loop closes with (pose devices only).

    Attributes
    ----------
    mode : str
        ``none`` (the device's pose is the target), ``impedance`` (a simulated 3-axis haptic
        device held by a simulated hand; the feedback force acts on its handle) or
        ``admittance`` (the hand's sensed wrench drives the god-object).
    rate_hz : float
        Servo rate (Hz).
    device_mass_kg, device_damping : float
        The handle's moving mass (kg) and physical damping (N·s/m).
    hand_frequency_hz : float
        The simulated hand: critically damped at this frequency on the handle (Hz).
    passivity_damping : float
        A passivity observer/controller on the feedback path, its damping capped at this
        (N·s/m); 0: off.
    """

    mode: str = "none"
    rate_hz: float = 1000.0
    device_mass_kg: float = 0.1
    device_damping: float = 2.0
    hand_frequency_hz: float = 10.0
    passivity_damping: float = 0.0

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if self.mode not in HAPTIC_MODES:
            raise ValueError(f"mode: {self.mode!r}; choose one of {HAPTIC_MODES}")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"rate_hz: {self.rate_hz!r} Hz must be > 0")
        if self.passivity_damping and self.mode != "impedance":
            raise ValueError(
                f"passivity_damping: {self.passivity_damping} N·s/m acts on an impedance device's handle; "
                f"with haptic.mode {self.mode!r} there is none: set haptic.mode: impedance, or 0"
            )


SIMULATION_MODES = ("god_object", "position")


@dataclasses.dataclass
class Simulation:
    """How long and how to run.

    Attributes
    ----------
    duration_s : float
        Simulated time (s).
    mode : str
        ``god_object`` (the coupling drives the tool) or ``position`` (the device's pose is
        imposed on it every step: the baseline the paper argues against).
    realtime_rate : float
        Target real-time rate; 0 runs as fast as it can. A live device runs at 1.
    check_period_s : float
        Simulated time between the safeguards' checks (s).
    max_speed : float
        A generalized velocity past this is a divergence (m/s or rad/s).
    """

    duration_s: float = 10.0
    mode: str = "god_object"
    realtime_rate: float = 0.0
    check_period_s: float = 0.05
    max_speed: float = 1000.0

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if not (math.isfinite(self.duration_s) and 0 < self.duration_s <= MAX_DURATION_S):
            raise ValueError(
                f"duration_s: {self.duration_s!r} s must be > 0 and at most {MAX_DURATION_S:g} s "
                "(11.6 days); a longer session is several runs"
            )
        if self.mode not in SIMULATION_MODES:
            raise ValueError(f"mode: {self.mode!r}; choose one of {SIMULATION_MODES}")
        if not (math.isfinite(self.realtime_rate) and self.realtime_rate >= 0):
            raise ValueError(f"realtime_rate: {self.realtime_rate!r} must be ≥ 0 (0: as fast as it can)")


@dataclasses.dataclass
class Workspace:
    """Where the device may go (m, world frame): the live sliders' range and the camera's frame."""

    lower_m: list[float] = dataclasses.field(default_factory=lambda: [-0.1, -0.1, 0.0])
    upper_m: list[float] = dataclasses.field(default_factory=lambda: [0.1, 0.1, 0.1])

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        for attribute in ("lower_m", "upper_m"):
            if len(getattr(self, attribute)) != 3:
                raise ValueError(f"{attribute}: needs 3 values (x, y, z in m)")


@dataclasses.dataclass
class Camera:
    """Where Meshcat's camera stands and what it looks at (m, world frame, z up)."""

    position_m: list[float] = dataclasses.field(default_factory=lambda: [0.3, -0.4, 0.3])
    target_m: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclasses.dataclass
class Visualization:
    """Drawing in Meshcat.

    Attributes
    ----------
    serve : bool
        Serve the run live (real-time rate) at a Meshcat URL.
    host : str
        The interface Meshcat listens on: ``localhost`` (this machine only; the default), or
        an address or ``*`` (every interface) to let other machines open the page, which
        drives a live device: it is announced loudly. An SSH tunnel is the safe way to watch
        from elsewhere (README "Driving a scene live").
    port : int | None
        The live page's port; None: Drake's default (7000, or the next free one).
    publish_period_s : float
        Drawing period (s), live and in recordings.
    camera : Camera | None
        The view to open on; None: Meshcat's default.
    force_cue : bool
        Rigid god-objects: the target ghost and the spring turn from faint to solid red as the
        coupling's stretch reaches its force cap (pseudo-haptics for a non-haptic device).
    """

    serve: bool = False
    host: str = "localhost"
    port: int | None = None
    publish_period_s: float = 1.0 / 64.0
    camera: Camera | None = None
    force_cue: bool = True

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        period = self.publish_period_s
        if not (math.isfinite(period) and period > 0):
            raise ValueError(
                f"publish_period_s: {period!r} s must be > 0 (e.g. {1 / 64:g}: 64 frames a second)"
            )
        if not self.host.strip():
            raise ValueError(f"host: {self.host!r}: give localhost (this machine only) or an address")
        if self.port is not None and not (isinstance(self.port, int) and 0 <= self.port <= 65535):
            raise ValueError(f"port: {self.port!r} must be a TCP port, 0 to 65535 (None: Drake's)")


@dataclasses.dataclass
class Recording:
    """A self-contained Meshcat HTML recording of the run (``file`` empty: none).

    ``max_duration_s``: the recording covers the run's first this many seconds (the rest runs
    unrecorded), so its size is known in advance: about 2.2 MB of viewer plus the frames, some
    0.1 MB per second for the brick scene at 64 frames per second (README "Recordings").
    """

    file: str = ""
    frames_per_second: float = 64.0
    max_duration_s: float = 300.0

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        fps = self.frames_per_second
        if not (math.isfinite(fps) and 0 < fps <= MAX_FRAMES_PER_SECOND):
            raise ValueError(
                f"frames_per_second: {fps!r} must be in (0, {MAX_FRAMES_PER_SECOND:g}] (a browser shows 60; "
                "the default 64 gives a frame every 1/64 s)"
            )
        if not (self.max_duration_s > 0):
            raise ValueError(
                f"max_duration_s: {self.max_duration_s!r} s must be > 0 (it caps the recording's size)"
            )


@dataclasses.dataclass
class Metrics:
    """Where the metrics JSON goes (``file`` empty: printed only) and what the run may cost.

    ``penetration_budget_m``: how deep a god-object may go into an obstacle (m). At build,
    a god-object whose capped pull could push it deeper (capped force / contact stiffness)
    gets a :class:`~godobject_drake.building.PenetrationBudgetWarning`.
    ``checkpoint_period_s``: while a run goes, the command line rewrites ``file`` with the
    metrics so far (marked ``partial``) every this many seconds of wall time, so even a killed
    run leaves them.
    ``impossible_pose_distance_m``: a target farther than this from the god-object (m) is in a
    pose the god-object cannot take (it is blocked); ``impossible_pose_time_s`` is the time
    spent so. The default, 5 mm, is four times the shipped scenes' free-space tracking lag.
    """

    file: str = ""
    penetration_budget_m: float = 1e-3
    checkpoint_period_s: float = 10.0
    impossible_pose_distance_m: float = 0.005

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if not (self.checkpoint_period_s > 0):
            raise ValueError(f"checkpoint_period_s: {self.checkpoint_period_s!r} s must be > 0")
        if not (self.penetration_budget_m > 0):
            raise ValueError(f"penetration_budget_m: {self.penetration_budget_m!r} m must be > 0")
        far = self.impossible_pose_distance_m
        if not (math.isfinite(far) and far > 0):
            raise ValueError(f"impossible_pose_distance_m: {far!r} m must be > 0 (e.g. 0.005)")


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
    device : a registered device kind (:mod:`~godobject_drake.device_kinds`)
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
        When resting free bodies are locked, so they cost nothing (``--sleep on|off``; README
        "Sleeping bodies").
    organs : Organs
        Rigid organs (the default: the directives' shapes) or FEM tissue (``--set
        organs.model=fem``: the laparoscopy scene's uterus as a Drake FEM body,
        :mod:`godobject_drake.tissue`).
    haptic, simulation, visualization, recording, metrics :
        See their classes.
    """

    name: str = "scene"
    random_seed: int = 0
    plant: MultibodyPlantConfig = dataclasses.field(default_factory=default_plant_config)
    directives: list[ModelDirective] = dataclasses.field(default_factory=list)
    contact: Contact = dataclasses.field(default_factory=Contact)
    god_object: Rigid | Articulated | Deformable = dataclasses.field(default_factory=Rigid)
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

    @property
    def kind(self) -> str:
        """``rigid``, ``articulated`` or ``deformable``."""
        return type(self.god_object).__name__.lower()

    @property
    def time_step(self) -> float:
        """The plant step h (s)."""
        return self.plant.time_step


# The installed package godobject_scenarios (the clone's diagrams/ folder in an editable install).
SCENARIOS_DIR = Path(str(importlib.resources.files("godobject_scenarios")))
SHIPPED = ("lego", "laparoscopy", "deformable_probe")  # the shipped scenes: diagrams/NAME.yaml


def shipped_scenario_file(name: str) -> Path:
    """The scenario file of the shipped scene ``name`` (``lego``, ...), from the installed package."""
    if name not in SHIPPED:
        raise ScenarioError(f"no shipped scene {name!r}; the shipped scenes are {', '.join(SHIPPED)}")
    return SCENARIOS_DIR / f"{name}.yaml"


def shipped_scenario(name: str, overrides: str | None = None) -> Scenario:
    """A shipped scene's scenario (``diagrams/NAME.yaml`` of a clone; package data when installed)."""
    return load_scenario(shipped_scenario_file(name), overrides)


def load_scenario(filename: str | Path, overrides: str | None = None) -> Scenario:
    """Load a scenario YAML file; relative input paths are taken relative to it.

    ``overrides`` is YAML text merged on top (e.g. ``"simulation: {duration_s: 1.0}"``).
    Raises :class:`ScenarioError` naming the file (and the key) on any problem.
    """
    path = Path(filename)
    if not path.is_file():
        raise ScenarioError(f"scenario file {path} does not exist")
    where = str(path)
    try:
        scenario = yaml_load_typed(schema=Scenario, filename=str(path))
        if overrides:
            where = "the overrides"
            overrides = _keep_kinds(scenario, overrides)
            scenario = yaml_load_typed(schema=Scenario, data=overrides, defaults=scenario)
    except LOAD_ERRORS as e:
        text = path.read_text(errors="replace") if where == str(path) else overrides
        raise ScenarioError(f"{path}: {_explain(e, text, where)}") from None
    resolve_paths(scenario, path.resolve().parent)
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
    hints = typing.get_type_hints(Scenario)
    changed = False
    for key, value in root.value:
        field = key.value if isinstance(key, yaml.ScalarNode) else None
        kinds = typing.get_args(hints.get(field)) if field in hints else ()
        untagged = (
            isinstance(value, yaml.MappingNode)
            and value.tag == yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG
        )
        if len(kinds) > 1 and untagged:
            value.tag = "!" + type(getattr(scenario, field)).__name__
            changed = True
    return yaml.serialize(root) if changed else overrides


def scenario_from_yaml(text: str, base_dir: str | Path = ".") -> Scenario:
    """A scenario from YAML text (relative paths against ``base_dir``)."""
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except LOAD_ERRORS as e:
        raise ScenarioError(f"scenario text: {_explain(e, text, 'the text')}") from None
    resolve_paths(scenario, Path(base_dir).resolve())
    check_scenario(scenario, where="scenario text")
    return scenario


def scenario_to_yaml(scenario: Scenario) -> str:
    """The scenario as YAML text (what :func:`scenario_from_yaml` reads back)."""
    return yaml_dump_typed(scenario)


# What yaml_load_typed raises for a file it cannot read into a Scenario.
LOAD_ERRORS = (RuntimeError, ValueError, TypeError, AssertionError, yaml.YAMLError)


def _explain(e: Exception, source: str = "", where: str = "") -> str:
    """The loader's message, with the key it is about and the fix where they can be told."""
    text = str(e) or type(e).__name__
    if isinstance(e, yaml.YAMLError):
        return (
            f"not valid YAML in {where}: {' '.join(text.split())}; check the brackets, colons and indentation"
        )
    if "were unknown to the schema" in text:
        return f"{text}: a key the scenario does not know (check its spelling and indentation)"
    if "did not match any of the allowed type options" in text:
        return f"{text}: give the YAML tag of one of those types, e.g. device: !Scripted {{...}}"
    keys = _keys_holding(source, text)
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


def _resolve(value: str, base: Path) -> str:
    """A path relative to ``base`` made absolute; ``package://godobject_models/`` to the models."""
    if value.startswith(PACKAGE_URL):
        from godobject_drake.scenes import MODELS_DIR

        return str(MODELS_DIR / value[len(PACKAGE_URL) :])
    if not value or "://" in value or Path(value).is_absolute():
        return value
    return str((base / value).resolve())


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
    device = scenario.device
    for attribute in ("path", "log"):
        if hasattr(device, attribute):
            setattr(device, attribute, _resolve(getattr(device, attribute), base))


def _fail(where: str, field: str, message: str):
    raise ScenarioError(f"{where}: {field}: {message}")


# The scenario's parts that check themselves, in the order a user reads them.
SELF_CHECKED = ("contact", "simulation", "haptic", "device", "god_object", "workspace", "visualization",
                "recording", "metrics", "organs")  # fmt: skip


def check_scenario(s: Scenario, where: str = "scenario") -> None:
    """Raise :class:`ScenarioError` naming the field, its value and the fix; no value is clamped.

    Each part checks itself (its ``check()``); this adds Drake's plant settings and the rules that
    span two parts."""
    h = s.plant.time_step
    if not (isinstance(h, float | int) and math.isfinite(h) and h > 0):
        _fail(
            where,
            "plant.time_step",
            f"{h!r} s; SAP is discrete: give a step h > 0 (e.g. 0.001). A continuous plant (time_step 0, "
            "Drake's cenic integrator) is not offered: on the brick scene it was slower than SAP at "
            "equal penetration (docs/results.md, 'CENIC against SAP'; analysis/cenic_trial.py measures it)",
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
    try:
        device_kind = kind_of(s.device)
    except ValueError as e:
        raise ScenarioError(f"{where}: {e}") from None
    for part in SELF_CHECKED:
        try:
            getattr(s, part).check(s) if part == "god_object" else getattr(s, part).check()
        except ValueError as e:
            prefix = "" if part == "god_object" else f"{part}."  # a god-object names its own fields
            raise ScenarioError(f"{where}: {prefix}{e}") from None
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
    _check_across(s, device_kind, where)


def _check_across(s: Scenario, device_kind, where: str) -> None:
    """The rules between two parts: contact and plant, device and tool, device and haptic chain."""
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
    device, kind, space = s.device, s.kind, s.god_object.DEVICE_SPACE
    if device_kind.space != space:
        tags = ", ".join(k.tag for k in DEVICE_KINDS.values() if k.space == space)
        _fail(
            where,
            "device",
            f"a{'n' if kind[0] in 'aeiou' else ''} {kind} god-object needs a {SPACE_NAMES[space]} device "
            f"({tags}); got !{type(device).__name__}",
        )
    if device_kind.space == "pose" and device.changed_aids() and s.haptic.mode != "none":
        field = device.changed_aids()[0]
        _fail(
            where,
            f"device.{field}",
            f"{getattr(device, field)!r} is for a device that cannot feel the god-object; with haptic.mode "
            f"{s.haptic.mode!r} the force is felt: set haptic.mode: none, or remove {field}",
        )
    if device_kind.renders_feedback and s.haptic.mode != "none":
        _fail(
            where,
            "haptic.mode",
            f"{s.haptic.mode!r} simulates a haptic device; with !{type(device).__name__} the real device is "
            "the haptic one and the feedback wrench goes to it: set haptic.mode: none",
        )


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
