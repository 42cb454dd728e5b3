"""The tool (god-object) kinds' config types: rigid, articulated, deformable.

Each is the YAML mapping under ``god_object: !Tag`` (or a tool's ``god_object`` in ``tools:``);
the builders that turn them into Drake systems are in :mod:`godobject_drake.station`.

This module must not use ``from __future__ import annotations``: ``yaml_load_typed`` reads the
field types at run time.
"""

import dataclasses
import functools
import math
import operator
import re
from typing import ClassVar

from godobject_drake.config.flags import Flag
from godobject_drake.config.gains import DEFAULT_MAX_STRETCH_M, DEFAULT_MAX_TWIST_RAD, CouplingGains

SHELL_MODELS = ("fem", "mass_spring")
RIGID_COUPLINGS = ("explicit", "implicit")
ARTICULATED_COUPLINGS = ("cartesian", "joint_pd", "joint_pd_sap")

# One --coupling for the kinds that have a coupling field; each kind's check refuses the other's.
COUPLING_FLAG = Flag(
    "--coupling", "god_object.coupling",
    f"coupling of the tool: rigid {'|'.join(RIGID_COUPLINGS)}; articulated {'|'.join(ARTICULATED_COUPLINGS)}",
    choices=(*RIGID_COUPLINGS, *ARTICULATED_COUPLINGS),
)  # fmt: skip


class ShellSpecError(ValueError):
    """A shell specification that cannot be built or simulated."""


@dataclasses.dataclass
class ShellSpec:
    """Geometry and material of a spherical deformable god-object (SI units).

    Attributes
    ----------
    radius_m : float
        Outer radius R of the shell.
    core_radius_m : float
        Radius rc of the rigid core; the shell is R − rc thick.
    core_mass_kg : float
        Mass of the core (a solid sphere).
    density_kg_m3 : float
        Shell density ρ.
    youngs_modulus_pa : float
        Young's modulus E of the shell.
    poissons_ratio : float
        Poisson's ratio ν (FEM only), in [0, 0.5).
    damping_ratio : float
        Damping ratio ζ of the shell's through-thickness mode.
    friction : float
        Coulomb friction of the shell (static = dynamic).
    nodes : int
        Mass–spring nodes on the surface (a Fibonacci lattice).
    fem_resolution_m : float
        Drake's meshing hint for the FEM ball (0.02 m gives 129 vertices at R = 0.03).
    node_contact_stiffness : float
        Point-contact stiffness of a mass–spring node's sphere (N/m),
        combined harmonically with the obstacle's.
    fem_contact_relaxation_s : float
        SAP relaxation time of the FEM shell's contact (s), added to the
        obstacle's. At h = 10 ms, 0.01 s lets the pressed shell chatter
        against the obstacle (a 40 ms limit cycle, 1.5–5 mm deep); 0.1 s
        damps it.
    """

    radius_m: float = 0.03
    core_radius_m: float = 0.018
    core_mass_kg: float = 0.1
    density_kg_m3: float = 1000.0
    youngs_modulus_pa: float = 5.0e4
    poissons_ratio: float = 0.4
    damping_ratio: float = 1.0
    friction: float = 0.3
    nodes: int = 42
    fem_resolution_m: float = 0.02
    node_contact_stiffness: float = 1.0e5
    fem_contact_relaxation_s: float = 0.1

    @property
    def thickness_m(self) -> float:
        return self.radius_m - self.core_radius_m

    @property
    def shell_omega(self) -> float:
        """ω_s = √(E/ρ)/t (rad/s): the shell's through-thickness mode."""
        return math.sqrt(self.youngs_modulus_pa / self.density_kg_m3) / self.thickness_m

    def check(self) -> None:
        """Raise :class:`ShellSpecError` naming the bad value, its limit and the fix."""
        positive = (
            ("radius_m", self.radius_m), ("core_radius_m", self.core_radius_m),
            ("core_mass_kg", self.core_mass_kg), ("density_kg_m3", self.density_kg_m3),
            ("youngs_modulus_pa", self.youngs_modulus_pa), ("fem_resolution_m", self.fem_resolution_m),
            ("node_contact_stiffness", self.node_contact_stiffness),
            ("fem_contact_relaxation_s", self.fem_contact_relaxation_s),
        )  # fmt: skip
        for name, value in positive:
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ShellSpecError(f"{name}={value!r} must be a finite number > 0")
        if not self.core_radius_m < self.radius_m:
            raise ShellSpecError(
                f"core_radius_m={self.core_radius_m} must be < radius_m={self.radius_m}: "
                "the shell lies between them; shrink the core or grow the shell"
            )
        if not 0.0 <= self.poissons_ratio < 0.5:
            raise ShellSpecError(f"poissons_ratio={self.poissons_ratio} must be in [0, 0.5)")
        if not (math.isfinite(self.damping_ratio) and self.damping_ratio >= 0):
            raise ShellSpecError(f"damping_ratio={self.damping_ratio} must be ≥ 0")
        if not (math.isfinite(self.friction) and self.friction >= 0):
            raise ShellSpecError(f"friction={self.friction} must be ≥ 0")
        if not (isinstance(self.nodes, int) and 12 <= self.nodes <= 400):
            raise ShellSpecError(
                f"nodes={self.nodes!r} must be an integer in [12, 400]: fewer cannot cover "
                "the sphere; more make one dense kinematic tree too slow to step "
                "(use the fem shell for fine meshes)"
            )


# -- the registry of tool kinds ----------------------------------------------------------------------------

TOOL_CONFIGS: list[type] = []  # in registration order: the first is an untagged mapping's kind
TOOL_BUILDERS: dict[type, "str | type"] = {}  # each config's builder, or its "module:Class"
SHIPPED = "godobject_drake.station."  # where the shipped kinds' builders are
BUILDER_PATH = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_]\w*")
_ON_REGISTER: list = []


def tool_kind(builder: "str | type"):
    """Register the decorated config dataclass as a tool kind, once: the scenario's ``god_object``
    field takes its YAML tag (``!Name``), and ``builder`` builds it: the
    :class:`~godobject_drake.station.kinds.GodObject` subclass, or its path as ``"module:Class"``
    (imported when a tool of the kind is first built, so this layer loads no Drake system)."""
    if not (isinstance(builder, type) or (isinstance(builder, str) and BUILDER_PATH.fullmatch(builder))):
        raise ValueError(
            f"tool kind: builder={builder!r}; give the GodObject subclass that builds it, or its path as "
            "'module:Class' (e.g. 'godobject_drake.station.rigid_tool:RigidGodObject')"
        )

    def register(config_type: type) -> type:
        if not dataclasses.is_dataclass(config_type):
            raise TypeError(f"tool kind {config_type.__name__} must be a dataclass")
        if config_type in TOOL_BUILDERS and TOOL_BUILDERS[config_type] != builder:
            raise ValueError(f"tool kind !{config_type.__name__} is registered already, built by "
                             f"{TOOL_BUILDERS[config_type]!r}")  # fmt: skip
        if any(c.__name__ == config_type.__name__ and c is not config_type for c in TOOL_CONFIGS):
            raise ValueError(f"tool kind: the YAML tag !{config_type.__name__} is taken")
        TOOL_BUILDERS[config_type] = builder
        if config_type not in TOOL_CONFIGS:
            TOOL_CONFIGS.append(config_type)
            for callback in _ON_REGISTER:
                callback()
        return config_type

    return register


@tool_kind(SHIPPED + "rigid_tool:RigidGodObject")
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
        :mod:`godobject_drake.systems.implicit`).
    """

    gains: CouplingGains = dataclasses.field(default_factory=CouplingGains)
    graspable: list[str] = dataclasses.field(default_factory=list)
    gravity_compensation: bool = True
    max_stretch_m: float = DEFAULT_MAX_STRETCH_M
    max_twist_rad: float = DEFAULT_MAX_TWIST_RAD
    grasp_reach_m: float = 0.05
    coupling: str = "explicit"

    DEVICE_SPACE: ClassVar[str] = "pose"
    FLAGS: ClassVar[tuple[Flag, ...]] = (COUPLING_FLAG,)

    def check(self, scenario) -> None:
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


GRASP_HOLDS = ("point", "pose")  # JawGrasp.hold


@dataclasses.dataclass
class JawGrasp:
    """What an articulated tool's jaws hold when they close on it (``god_object.grasp``).

    Grasping soft tissue is a constraint here, as surgical simulators make it (SOFA's attach
    constraints, iMSTK's grasping): while the jaws are closed, the free body nearest the grasp
    point within ``reach_m`` (a grasp site: a patch of tissue glued to it, ``organs.glued``) is held
    there by a ball constraint (SAP), and let go when they open.

    Attributes
    ----------
    bodies : list[str]
        The free bodies the jaws may hold (``model::body``); empty: none (no grasping).
    jaw : str
        The device joint whose value is the jaws' opening (rad).
    closed_below_rad : float
        The jaws are closed below this opening (rad).
    reach_m : float
        A body within this of the grasp point is taken when the jaws close (m): its origin with
        ``hold: point``, its collision geometry with ``hold: pose``.
    point_m : list[float]
        The grasp point in the tip body's frame (m; the grasper's: between its jaws).
    hold : str
        ``point``: a ball constraint holds the body's origin at the grasp point (a grasp site; the
        body may turn about it), ``reach_m`` measured to its origin. ``pose``: the body is held as
        it is when the jaws close, where they close on it, turning with the jaws (an object the
        jaws pinch: a ring, a needle), ``reach_m`` measured to its collision geometry; six distance
        constraints between three points of the tip body and three of the body (a rigid
        octahedron), set when the jaws close.
    """

    bodies: list[str] = dataclasses.field(default_factory=list)
    jaw: str = "jaw_upper"
    closed_below_rad: float = 0.1
    reach_m: float = 0.008
    point_m: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, -0.010])
    hold: str = "point"

    def check(self, tool: "Articulated") -> None:
        """Raise ``ValueError`` as ``"god_object.grasp.field: value, limit and fix"``."""
        if not self.bodies:
            return
        if self.jaw not in tool.device_joints:
            raise ValueError(
                f"god_object.grasp.jaw: {self.jaw!r} is not one of the device joints {tool.device_joints}"
            )
        if not tool.tip_body:
            raise ValueError("god_object.grasp: the grasp point is on tip_body; give god_object.tip_body")
        for name, value in (("closed_below_rad", self.closed_below_rad), ("reach_m", self.reach_m)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"god_object.grasp.{name}: {value!r} must be a finite number > 0")
        if len(self.point_m) != 3:
            raise ValueError(f"god_object.grasp.point_m: {self.point_m!r}; give x, y, z in m")
        if self.hold not in GRASP_HOLDS:
            raise ValueError(
                f"god_object.grasp.hold: {self.hold!r}; choose one of {GRASP_HOLDS} (point: a grasp site's "
                "origin, free to turn; pose: the body held as the jaws take it)"
            )


@dataclasses.dataclass
class PoseToJoints:
    """How a pose device (``!Lcm``, ``!Scripted``, ...) drives an articulated tool through a trocar
    (``god_object.pose_to_joints``; used when the device is a pose device: docs/guide/laparoscopy.md
    "From a pose device"). The device's pose is the instrument's tip: its position, and its twist
    about the instrument's axis as the handle's roll; its button (grasp) closes the jaws.

    Attributes
    ----------
    joints : list[str]
        The trocar's joints: the two rotations about the insertion point (about its x, then y),
        the insertion (m) and the roll, in that order.
    jaw_joints : list[str]
        The jaws' joints: each turns by half of ``jaw_open_rad`` with the button up, 0 with it down.
    jaw_open_rad : float
        The jaws' opening with the button up (rad).
    min_insertion_m : float
        Closer to the insertion point than this the tip's force cannot be mapped (the trocar's
        Jacobian is singular at the pivot): the device's wrench is zero there.
    """

    joints: list[str] = dataclasses.field(default_factory=lambda: ["yaw", "pitch", "insertion", "roll"])
    jaw_joints: list[str] = dataclasses.field(default_factory=lambda: ["jaw_upper", "jaw_lower"])
    jaw_open_rad: float = 0.6
    min_insertion_m: float = 0.01

    def check(self, tool: "Articulated") -> None:
        """Raise ``ValueError`` as ``"god_object.pose_to_joints.field: value, limit and fix"``."""
        at = "god_object.pose_to_joints"
        if len(self.joints) != 4:
            raise ValueError(
                f"{at}.joints: {self.joints!r}; give the trocar's 4 joints: yaw, pitch, insertion, roll"
            )
        mapped = [*self.joints, *self.jaw_joints]
        if sorted(mapped) != sorted(tool.device_joints):
            raise ValueError(
                f"{at}: joints {self.joints} and jaw_joints {self.jaw_joints} must name every one of "
                f"god_object.device_joints {tool.device_joints} once; a pose device gives no other joint"
            )
        for name, value in (("jaw_open_rad", self.jaw_open_rad), ("min_insertion_m", self.min_insertion_m)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{at}.{name}: {value!r} must be a finite number ≥ 0")
        if not (tool.tip_body and tool.pivot_body):
            raise ValueError(
                f"{at}: a pose device drives the tool's tip about its pivot; give god_object.tip_body and "
                "god_object.pivot_body (the laparoscopy scene's: tube and port)"
            )


@tool_kind(SHIPPED + "articulated_tool:ArticulatedGodObject")
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
    grasp : JawGrasp
        What the jaws hold when they close on it (nothing by default).
    pose_to_joints : PoseToJoints
        With a pose device (``device: !Lcm``, ``!Scripted``): how its pose becomes the joints
        (through the trocar); unused with a joint-space device.
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
    grasp: JawGrasp = dataclasses.field(default_factory=JawGrasp)
    pose_to_joints: PoseToJoints = dataclasses.field(default_factory=PoseToJoints)

    DEVICE_SPACE: ClassVar[str] = "joint"
    POSE_DEVICE_THROUGH: ClassVar[str] = "pose_to_joints"  # a pose device is mapped by this field
    FLAGS: ClassVar[tuple[Flag, ...]] = (
        COUPLING_FLAG,
        Flag("--jaws", "god_object.imposed_joints",
             "imposed: the scenario's imposed joints (the paper's jaws); simulated: couple them like the "
             "rest",
             choices=("imposed", "simulated"),
             value=lambda given, s: [] if given == "simulated" else list(s.god_object.imposed_joints)),
    )  # fmt: skip

    def check(self, scenario) -> None:
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
        self.grasp.check(self)
        if not (isinstance(self.check_every, int) and self.check_every >= 1):
            raise ValueError(f"god_object.check_every: {self.check_every!r} must be an integer ≥ 1")


@tool_kind(SHIPPED + "deformable_tool:DeformableGodObject")
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
    FLAGS: ClassVar[tuple[Flag, ...]] = (
        Flag("--shell", "god_object.shell", "shell model", choices=SHELL_MODELS),
        Flag("--youngs-modulus", "god_object.spec.youngs_modulus_pa", "shell's Young's modulus E (Pa)",
             type=float),
        Flag("--nodes", "god_object.spec.nodes", "mass_spring: surface nodes", type=int),
        Flag("--fem-resolution", "god_object.spec.fem_resolution_m",
             "fem: Drake's meshing hint (m); 0.03 / 0.02 / 0.01 give 25 / 129 / 833 vertices", type=float),
    )  # fmt: skip

    def check(self, scenario) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if self.shell not in SHELL_MODELS:
            raise ValueError(f"god_object.shell: {self.shell!r}; choose one of {SHELL_MODELS}")


def on_register(callback) -> None:
    """Call ``callback()`` after each tool config registered from now on."""
    _ON_REGISTER.append(callback)


def tool_union():
    """Every registered tool config as one union: the type of the scenario's ``god_object``."""
    return functools.reduce(operator.or_, TOOL_CONFIGS)
