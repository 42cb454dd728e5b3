"""The scene's config types: contact, haptic chain, run, drawing, outputs, organs, sleeping.

Plain dataclasses a scenario file fills field by field; each ``check()`` raises ``ValueError`` as
``"field: value, limit and fix"`` and the scenario prefixes the part's name. Every length is in m,
time in s, mass in kg, frequency in Hz, bandwidth in rad/s.

This module must not use ``from __future__ import annotations``: ``yaml_load_typed`` reads the
field types at run time.
"""

import dataclasses
import math
import os
from pathlib import Path

from pydrake.multibody.plant import MultibodyPlantConfig


def default_plant_config() -> MultibodyPlantConfig:
    """SAP, point contact, h = 1 ms: what the shipped scenes use."""
    return MultibodyPlantConfig(time_step=1e-3, discrete_contact_approximation="sap", contact_model="point")


CONTACT_GEOMETRIES = ("proxies", "hydroelastic")


# Geometry names the contact settings go by (``Contact.geometry: proxies``).
PROXY_PREFIX = "proxy_"
CORNER_PREFIX = "proxy_corner_"  # a proxy at a vertex of its body's convex true shape
FLAT_PREFIX = "flat_"  # a welded geometry only ever touched on one flat face (a floor, a baseplate)


def local_name(name: str) -> str:
    """A geometry's own name, without its model's scope (``brick_0::proxy_3`` → ``proxy_3``)."""
    return name.rsplit("/", 1)[-1].rsplit("::", 1)[-1]


def is_proxy(name: str) -> bool:
    """True for a contact-proxy geometry name (scoped or not)."""
    return local_name(name).startswith(PROXY_PREFIX)


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
    """Where the device may go (m, world frame): the live sliders' range and the camera's frame.

    Attributes
    ----------
    lower_m : list[float]
        The box's lowest corner (x, y, z in m).
    upper_m : list[float]
        Its highest corner (m); each coordinate above ``lower_m``'s.
    """

    lower_m: list[float] = dataclasses.field(default_factory=lambda: [-0.1, -0.1, 0.0])
    upper_m: list[float] = dataclasses.field(default_factory=lambda: [0.1, 0.1, 0.1])

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        for attribute in ("lower_m", "upper_m"):
            if len(getattr(self, attribute)) != 3:
                raise ValueError(f"{attribute}: needs 3 values (x, y, z in m)")
        for axis, lo, hi in zip("xyz", self.lower_m, self.upper_m, strict=True):
            if not lo < hi:
                raise ValueError(
                    f"upper_m: {self.upper_m} is not above lower_m: {self.lower_m} in {axis} "
                    f"({hi!r} <= {lo!r}); give the box's lowest corner as lower_m, its highest as upper_m"
                )


@dataclasses.dataclass
class Camera:
    """Where Meshcat's camera stands and what it looks at (world frame, z up).

    Attributes
    ----------
    position_m : list[float]
        Where the camera stands (m).
    target_m : list[float]
        The point it looks at (m).
    """

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
        from elsewhere (docs/guide/live.md).
    port : int | None
        The live page's port; None: Drake's default (7000, or the next free one).
    publish_period_s : float
        Drawing period (s), live and in recordings.
    camera : Camera | None
        The view to open on; None: Meshcat's default.
    force_cue : bool
        Rigid god-objects: the target ghost and the spring turn from faint to solid magenta as the
        coupling's stretch reaches its force cap (pseudo-haptics for a non-haptic device).
    trust_local_pages : bool
        The opt-in to serve the live page with a haptic device (``haptic.mode`` impedance or
        admittance, or a device that renders the feedback: ``!Lcm``). Drake's Meshcat checks
        no websocket Origin and takes no secret, so any web page open on this machine (a
        ``file://`` page, a page from another local port) can read the scene, move the
        sliders, grasp and stop the run, and so command the forces on a hand; without this the
        run is refused (``--trust-local-pages``; docs/guide/live.md).
    """

    serve: bool = False
    host: str = "localhost"
    port: int | None = None
    publish_period_s: float = 1.0 / 64.0
    camera: Camera | None = None
    force_cue: bool = True
    trust_local_pages: bool = False

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
    """A self-contained Meshcat HTML recording of the run.

    Attributes
    ----------
    file : str
        The HTML file to write (``--record``); empty: no recording.
    frames_per_second : float
        How many frames a second of simulated time the recording keeps.
    max_duration_s : float
        The recording covers the run's first this many seconds (the rest runs unrecorded), so its
        size is known in advance: about 2.2 MB of viewer plus the frames, some 0.1 MB per second
        for the brick scene at 64 frames per second (docs/guide/visual.md).
    device_log : str
        Write each tool's device as it was sampled, tick by tick, to this CSV (``--record-devices``):
        the device log its replay reads (``--replay-devices``), so a session replayed gives the
        same run, bit for bit. A scene of several tools writes one per tool, the tool's name before
        the suffix (``session.left.csv``). Empty: none.
    """

    file: str = ""
    frames_per_second: float = 64.0
    max_duration_s: float = 300.0
    device_log: str = ""

    def device_log_for(self, tool: str) -> Path:
        """The device log of the tool ``tool`` (``""``: a scene of one tool)."""
        path = Path(self.device_log)
        return path if not tool else path.with_name(f"{path.stem}.{tool}{path.suffix or '.csv'}")

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if self.device_log and self.device_log == self.file:
            raise ValueError(f"device_log: {self.device_log!r} is the recording's own file: give another")
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
    """Where the metrics JSON goes and what the run may cost.

    Attributes
    ----------
    file : str
        The JSON file to write (``--metrics``); empty: the metrics are printed only.
    penetration_budget_m : float
        How deep a god-object may go into an obstacle (m). At build, a god-object whose capped
        pull could push it deeper (capped force / contact stiffness) gets a
        :class:`~godobject_drake.metrics.PenetrationBudgetWarning`; a run that went
        deeper says so at its end (``over_penetration_budget``).
    checkpoint_period_s : float
        While a run goes, the command line rewrites ``file`` with the metrics so far (marked
        ``partial``) every this many seconds of wall time, so even a killed run leaves them.
    impossible_pose_distance_m : float
        A target farther than this from the god-object (m) is in a pose the god-object cannot
        take (it is blocked); ``impossible_pose_time_s`` is the time spent so. The default, 5 mm,
        is four times the shipped scenes' free-space tracking lag.
    idle_speed_mps : float
        A tool's tip slower than this (m/s) is idle: ``tip_idle_time_s``, and ``task_time_s`` runs
        from the first time it is faster to the last (docs/task_metrics.md).
    smoothing_window_s : float
        The Savitzky–Golay window (s) the tip's speed and jerk are estimated over (a degree-5
        polynomial fitted to this much of the trajectory; rounded to an odd count of plant steps,
        at least 7).
    tool_forces : bool
        Measure each tool's contact force on other bodies and the contacts between tools, every
        plant step (a contact meter on Drake's contact results: about a fifth more CPU a step on
        the brick scene, docs/results.md); ``false``: those scores are left out and cost nothing,
        the rest (the tips' motion) stays.
    """

    file: str = ""
    penetration_budget_m: float = 1e-3
    checkpoint_period_s: float = 10.0
    impossible_pose_distance_m: float = 0.005
    idle_speed_mps: float = 0.005
    smoothing_window_s: float = 0.1
    tool_forces: bool = True

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        if not (self.checkpoint_period_s > 0):
            raise ValueError(f"checkpoint_period_s: {self.checkpoint_period_s!r} s must be > 0")
        if not (self.penetration_budget_m > 0):
            raise ValueError(f"penetration_budget_m: {self.penetration_budget_m!r} m must be > 0")
        far = self.impossible_pose_distance_m
        if not (math.isfinite(far) and far > 0):
            raise ValueError(f"impossible_pose_distance_m: {far!r} m must be > 0 (e.g. 0.005)")
        idle = self.idle_speed_mps
        if not (math.isfinite(idle) and idle >= 0):
            raise ValueError(f"idle_speed_mps: {idle!r} m/s must be finite and ≥ 0 (e.g. 0.005)")
        window = self.smoothing_window_s
        if not (math.isfinite(window) and window > 0):
            raise ValueError(f"smoothing_window_s: {window!r} s must be finite and > 0 (e.g. 0.1)")


TISSUE_MODELS = ("rigid", "fem")
# Drake's FEM materials (pydrake.multibody.fem.MaterialModel), by the name a scenario gives
TISSUE_MATERIALS = ("linear_corotated", "corotated", "neohookean", "linear")


@dataclasses.dataclass
class Organs:
    """The organs of the laparoscopy scene: rigid (the default) or FEM tissue.

    Attributes
    ----------
    model : str
        ``rigid``: the organs are rigid shapes with a soft point-contact stiffness (the
        directives' model files as they are). ``fem``: the organ named ``organ`` becomes a
        Drake FEM deformable body of the same ellipsoid.
    organ : str
        The pelvis's geometry replaced (an ellipsoid collision geometry, ``model::name``).
    youngs_modulus_pa, poissons_ratio, density_kg_m3 :
        The tissue's material (Pa, –, kg/m³); ν in [0, 0.5).
    mass_damping_per_s, stiffness_damping_s :
        Rayleigh damping: α (1/s) and β (s), damping matrix α M + β K.
    cells : int
        Cells across the organ's mesh per axis (even): 8 gives 729 vertices, 3072 tetrahedra.
    attached_below_m : float
        Vertices lower than this below the organ's top (m) are fixed to the pelvis.
    friction : float
        Coulomb friction of the tissue (static = dynamic).
    relaxation_time_s : float
        SAP's relaxation time of the tissue's contact (s): its contact is a near-rigid
        constraint damped over this time; the tissue's own elasticity gives the force.
    glued : list[str]
        Free bodies of the directives the tissue is glued to (grasp sites: a patch of tissue a
        grasper's jaws can hold, :class:`~godobject_drake.config.tools.JawGrasp`): with ``fem``,
        the organ's vertices within a cube of ``glue_size_m`` about each body's start move with it;
        with ``rigid`` organs, which cannot move, each is welded where it starts.
    glue_size_m : float
        The side of that cube (m).
    grading : float
        1: the mesh's cells evenly spaced. Above 1, finest at the organ's top centre (where the
        instruments press) and each cell this many times as wide as its neighbour toward there,
        so fewer cells (vertices: the FEM's cost) keep the resolution under the tool.
    material : str
        Drake's FEM constitutive model: ``linear_corotated`` (Drake's default), ``corotated``,
        ``neohookean`` or ``linear`` (small strains only: it resists rotation).
    threads : int
        Threads Drake's FEM may use for the tissue (its deformable model's parallelism): 1 by
        default; more uses more CPU for a shorter step (docs/results.md, the FEM's levers).
    modulus_factor : float
        The mesh's Young's modulus as a fraction of ``youngs_modulus_pa`` (1: the material's). A
        coarse mesh of linear tetrahedra is stiffer than the tissue it stands for (6 cells 43 %
        and 4 cells 59 % less displacement than 8 under the same press): below 1, it answers as
        a finer mesh does. ``python analysis/fem_levers.py --out DIR --calibrate shipped`` finds the
        factor whose displacement follows the reference's over the scene's path (least squares):
        it holds for that path (docs/guide/laparoscopy.md, "A real-time organ").
    """

    model: str = "rigid"
    organ: str = "pelvis::uterus"
    youngs_modulus_pa: float = 5.0e4
    poissons_ratio: float = 0.45
    density_kg_m3: float = 1000.0
    mass_damping_per_s: float = 0.0
    stiffness_damping_s: float = 0.01
    cells: int = 8
    attached_below_m: float = 0.035
    friction: float = 0.2
    relaxation_time_s: float = 0.01
    glued: list[str] = dataclasses.field(default_factory=list)
    glue_size_m: float = 0.012
    grading: float = 1.0
    material: str = "linear_corotated"
    threads: int = 1
    modulus_factor: float = 1.0

    @property
    def mesh_youngs_modulus_pa(self) -> float:
        """The Young's modulus the FEM mesh is given (Pa): the material's times ``modulus_factor``."""
        return self.youngs_modulus_pa * self.modulus_factor

    @property
    def name(self) -> str:
        """The soft body's name: the organ's geometry's (``uterus`` of ``pelvis::uterus``)."""
        return self.organ.split("::")[-1]

    def soft_body(self) -> "SoftBody":
        """The ``deformables:`` entry ``model: fem`` stands for: the body that ``replaces`` the organ's
        ellipsoid, meshed at ``cells`` and ``grading``, held in place below ``attached_below_m``
        under its top, glued to ``glued``. A scenario that writes this entry itself under
        ``deformables`` builds the same scene, step for step."""
        return SoftBody(
            replaces=self.organ, cells=self.cells, grading=self.grading,
            youngs_modulus_pa=self.youngs_modulus_pa, modulus_factor=self.modulus_factor,
            poissons_ratio=self.poissons_ratio, density_kg_m3=self.density_kg_m3,
            mass_damping_per_s=self.mass_damping_per_s, stiffness_damping_s=self.stiffness_damping_s,
            material=self.material, friction=self.friction, relaxation_time_s=self.relaxation_time_s,
            attach=[SoftAttach(below_top_m=self.attached_below_m)], glued=list(self.glued),
            glue_size_m=self.glue_size_m, threads=self.threads, max_slowdown=math.inf,
        )  # fmt: skip

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"``."""
        self.check_material()
        if not (isinstance(self.cells, int) and 2 <= self.cells <= 24 and self.cells % 2 == 0):
            raise ValueError(
                f"cells: {self.cells!r} must be an even integer in [2, 24] (8: 729 vertices; 24 has 15625 "
                "and steps far below real time)"
            )
        if not (isinstance(self.grading, int | float) and 1.0 <= self.grading <= 3.0):
            raise ValueError(
                f"grading: {self.grading!r} must be in [1, 3] (1: cells evenly spaced; 1.5: each cell 1.5 "
                "times as wide as its neighbour toward the top's centre)"
            )
        if not (isinstance(self.attached_below_m, int | float) and math.isfinite(self.attached_below_m)
                and self.attached_below_m > 0):  # fmt: skip
            raise ValueError(f"attached_below_m: {self.attached_below_m!r} must be a finite number > 0")

    def check_material(self) -> None:
        """The material's, contact's and solver's fields (shared with :class:`SoftBody`)."""
        if self.model not in TISSUE_MODELS:
            raise ValueError(
                f"model: {self.model!r}; choose one of {TISSUE_MODELS} (rigid: the rigid organs with a soft "
                "point contact; fem: FEM tissue), e.g. --set organs.model=fem"
            )
        positive = (
            ("youngs_modulus_pa", self.youngs_modulus_pa),
            ("density_kg_m3", self.density_kg_m3),
            ("relaxation_time_s", self.relaxation_time_s),
        )
        for name, value in positive:
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: {value!r} must be a finite number > 0")
        if not (isinstance(self.poissons_ratio, int | float) and 0.0 <= self.poissons_ratio < 0.5):
            raise ValueError(
                f"poissons_ratio: {self.poissons_ratio!r} must be in [0, 0.5) (soft tissue: about 0.45)"
            )
        for name in ("mass_damping_per_s", "stiffness_damping_s", "friction"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: {value!r} must be a finite number ≥ 0")
        if not (isinstance(self.glue_size_m, int | float) and 0 < self.glue_size_m <= 0.05):
            raise ValueError(f"glue_size_m: {self.glue_size_m!r} m must be in (0, 0.05] (e.g. 0.012)")
        if not (isinstance(self.modulus_factor, int | float) and 0.05 <= self.modulus_factor <= 1.0):
            raise ValueError(
                f"modulus_factor: {self.modulus_factor!r} must be in [0.05, 1] (1: the material's modulus; "
                "below 1 for a mesh coarser than the one it should answer as: python analysis/fem_levers.py "
                "--calibrate finds it)"
            )
        if self.material not in TISSUE_MATERIALS:
            raise ValueError(
                f"material: {self.material!r}; choose one of {TISSUE_MATERIALS} (Drake's FEM models; "
                "linear_corotated is Drake's default)"
            )
        cores = os.cpu_count() or 1
        if not (isinstance(self.threads, int) and 1 <= self.threads <= cores):
            raise ValueError(
                f"threads: {self.threads!r} must be a whole number from 1 to this machine's {cores} cores "
                "(e.g. 2)"
            )


@dataclasses.dataclass
class Sleep:
    """When free bodies sleep (module docstring); ``enabled: false`` keeps every body awake.

    Attributes
    ----------
    enabled : bool
        Lock resting bodies (``--sleep on|off``).
    check_period_s : float
        Simulated time between checks (s), rounded to whole plant steps.
    speed_m_s, spin_rad_s : float
        A body slower than both, for ``hold_s``, is calm.
    hold_s : float
        How long a body must stay calm before it may sleep (s). Three checks: a body in free
        flight changes speed by g × 10 ms = 98 mm/s between two checks, so it is never calm at
        two in a row; a body that stays under 2 mm/s for three is resting, or creeping.
    margin_m : float
        Added to every reach (m).
    deactivate : bool
        Also take a sleeping body out of the geometry query while no awake body can reach it,
        where Drake has ``CollisionFilterManager.Deactivate`` (1.58 on); older Drake keeps it in
        (the run's log says which). ``false``: locked only, as on older Drake.
    """

    enabled: bool = True
    check_period_s: float = 0.01
    speed_m_s: float = 0.002
    spin_rad_s: float = 0.05
    hold_s: float = 0.03
    margin_m: float = 0.005
    deactivate: bool = True

    def check(self) -> None:
        """Raise ``ValueError`` naming a setting out of range."""
        for name, unit in (("check_period_s", "s"), ("speed_m_s", "m/s"), ("spin_rad_s", "rad/s")):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                default = getattr(Sleep, name)
                raise ValueError(f"sleep.{name}={value!r} {unit} must be > 0 (default {default!r})")
        for name in ("hold_s", "margin_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"sleep.{name}={value!r} must be ≥ 0 (default {getattr(Sleep, name)!r})")


SOFT_SHAPES = ("box", "sphere", "ellipsoid", "capsule")
# How many numbers each primitive's size_m takes: box its sides, sphere its radius, ellipsoid its radii,
# capsule its radius and its cylinder's length (along its z).
SOFT_SIZES = {"box": 3, "sphere": 1, "ellipsoid": 3, "capsule": 2}


@dataclasses.dataclass
class SoftAttach:
    """Where a soft body is held (``deformables.NAME.attach``), in one of three ways:

    - the vertices of its rest mesh inside the box ``[lower_m, upper_m]`` (in W), or
    - within ``within_m`` of the body ``to``'s origin,

    fixed to ``to`` (``world``, or a free body of the directives as ``model::body``) by Drake's
    ``DeformableModel.AddFixedConstraint``; or

    - the vertices more than ``below_top_m`` under the body's highest point, held where they are
      by Drake's wall boundary condition (``SetWallBoundaryCondition``: their degrees of freedom
      leave the problem, so it costs nothing; ``to: world`` only). The laparoscopy's organ is held
      so (``organs.attached_below_m``).

    Attributes
    ----------
    to : str
        ``world`` or a free body as ``model::body`` (a body welded to the world cannot hold it:
        Drake refuses the constraint; give ``world``).
    lower_m, upper_m : list[float]
        The box's corners in W (m); both empty with ``within_m`` or ``below_top_m``.
    within_m : float
        Above 0: the vertices this close to ``to``'s origin (a body, not the world).
    below_top_m : float
        Above 0: the vertices lower than this under the body's top (m), held in place.
    """

    to: str = "world"
    lower_m: list[float] = dataclasses.field(default_factory=list)
    upper_m: list[float] = dataclasses.field(default_factory=list)
    within_m: float = 0.0
    below_top_m: float = 0.0

    def check(self) -> None:
        if not (isinstance(self.to, str) and self.to):
            raise ValueError(f"to: {self.to!r}; give world or a body as model::body")
        box = bool(self.lower_m or self.upper_m)
        for name in ("within_m", "below_top_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: {value!r} m must be a finite number ≥ 0 (0: not this way)")
        if [box, self.within_m > 0, self.below_top_m > 0].count(True) != 1:
            raise ValueError(
                f"lower_m/upper_m {self.lower_m}/{self.upper_m}, within_m {self.within_m!r}, below_top_m "
                f"{self.below_top_m!r}: give one way, a box (lower_m and upper_m, 3 numbers each, m in W), "
                "within_m > 0 of a body, or below_top_m > 0"
            )
        if box:
            for name in ("lower_m", "upper_m"):
                value = getattr(self, name)
                if len(value) != 3 or not all(math.isfinite(v) for v in value):
                    raise ValueError(f"{name}: {value!r} must be 3 finite numbers (m, in W)")
            if not all(a < b for a, b in zip(self.lower_m, self.upper_m, strict=True)):
                raise ValueError(f"lower_m {self.lower_m} must be below upper_m {self.upper_m} on every axis")
        elif self.below_top_m > 0:
            if self.to != "world":
                raise ValueError(
                    f"to: {self.to!r} with below_top_m: the vertices are held in place, to the world only; "
                    "give to: world, or a box or within_m to hold them to a body"
                )
        elif self.to == "world":
            raise ValueError(f"within_m: {self.within_m!r} of the world: give a box, or a body as to")
        elif self.within_m > 1.0:
            raise ValueError(f"within_m: {self.within_m!r} m must be in (0, 1]")


@dataclasses.dataclass
class SoftBody:
    """A soft body of the scene (``deformables: {NAME: ...}``): Drake FEM tissue from a tetrahedral
    mesh file, a primitive or a rigid shape of the directives it replaces, placed at
    ``xyz_m``/``rpy_deg``, of its material, held where ``attach`` says
    (docs/guide/own_soft_body.md).

    Attributes
    ----------
    mesh : str
        A tetrahedral volume mesh, VTK (cell type 10), relative to the scenario or
        ``package://godobject_models/...``; its coordinates in m (``scale`` otherwise). Empty:
        ``shape`` or ``replaces``.
    scale : float
        The mesh's coordinates times this are metres (0.001 for a mesh in millimetres).
    shape, size_m, resolution_m :
        A primitive instead of a mesh: ``box`` (``size_m`` its 3 sides), ``sphere`` (its radius),
        ``ellipsoid`` (its 3 radii), ``capsule`` (its radius and its cylinder's length, along its
        z), meshed with cells about ``resolution_m`` wide.
    replaces : str
        A collision geometry of the directives (``model::name``: an Ellipsoid, Sphere or Box on a
        body welded to the world) this body takes the place of: its shape and pose are the body's
        (``xyz_m``/``rpy_deg`` are then left out), the rigid one no longer touches or is drawn.
    cells, grading :
        A primitive's (or replaced shape's) mesh by count, not ``resolution_m``: ``cells`` (even,
        2 to 24) across each axis (0: from ``resolution_m``); for an ellipsoid or sphere,
        ``grading`` > 1 makes the cells finest at its top's centre, each this many times as wide
        as its neighbour toward there (as ``organs.grading``).
    xyz_m, rpy_deg :
        The body's pose in W: the mesh's own frame (a primitive's centre) there.
    youngs_modulus_pa, poissons_ratio, density_kg_m3 :
        The tissue's material (Pa, –, kg/m³), as :class:`Organs`'s; ν in [0, 0.5).
    modulus_factor : float
        The mesh's Young's modulus as a fraction of the material's (as ``organs.modulus_factor``:
        below 1, a coarse mesh answers as a finer one).
    mass_damping_per_s, stiffness_damping_s :
        Rayleigh damping: α (1/s) and β (s), damping matrix α M + β K.
    material, friction, relaxation_time_s :
        Drake's FEM model (as :class:`Organs`'s), the contact's Coulomb friction and SAP's
        relaxation time of its contact (s).
    attach : list[SoftAttach]
        Where it is held. Empty: refused, unless ``free`` (it would fall).
    free : bool
        Held by nothing: it rests on something (a table) or falls.
    glued, glue_size_m :
        Free bodies of the directives glued to it (grasp sites), each holding its vertices within a
        cube of ``glue_size_m`` about the body's start.
    threads : int
        Threads Drake's FEM may use (one setting for all the scene's soft bodies: the most any
        asks for).
    max_slowdown : float
        The run is refused when this body's FEM step is estimated to take more than this many
        time steps of wall time (docs/results.md, "A soft body's cost"); ``.inf``: no limit.
    """

    mesh: str = ""
    scale: float = 1.0
    shape: str = ""
    size_m: list[float] = dataclasses.field(default_factory=list)
    resolution_m: float = 0.01
    replaces: str = ""
    cells: int = 0
    grading: float = 1.0
    xyz_m: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    youngs_modulus_pa: float = 5.0e4
    modulus_factor: float = 1.0
    poissons_ratio: float = 0.45
    density_kg_m3: float = 1000.0
    mass_damping_per_s: float = 0.0
    stiffness_damping_s: float = 0.01
    material: str = "linear_corotated"
    friction: float = 0.2
    relaxation_time_s: float = 0.01
    attach: list[SoftAttach] = dataclasses.field(default_factory=list)
    free: bool = False
    glued: list[str] = dataclasses.field(default_factory=list)
    glue_size_m: float = 0.012
    threads: int = 1
    max_slowdown: float = 20.0

    @property
    def mesh_youngs_modulus_pa(self) -> float:
        """The modulus the FEM mesh is given (as :attr:`Organs.mesh_youngs_modulus_pa`)."""
        return self.youngs_modulus_pa * self.modulus_factor

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"`` (the mesh itself is checked
        when it is read: :func:`godobject_drake.systems.soft_body.soft_body_mesh`)."""
        if [bool(self.mesh), bool(self.shape), bool(self.replaces)].count(True) != 1:
            raise ValueError(
                f"mesh {self.mesh!r}, shape {self.shape!r}, replaces {self.replaces!r}: give one, a "
                f"tetrahedral VTK file as mesh, a primitive as shape ({', '.join(SOFT_SHAPES)}) with size_m, "
                "or a rigid shape of the directives as replaces (model::name)"
            )
        if self.shape:
            self._check_shape()
        if self.replaces and "::" not in self.replaces:
            raise ValueError(f"replaces: {self.replaces!r}; give the collision geometry as model::name")
        if self.replaces and (any(self.xyz_m) or any(self.rpy_deg)):
            raise ValueError(
                f"xyz_m {self.xyz_m}, rpy_deg {self.rpy_deg} with replaces {self.replaces!r}: the body takes "
                "the replaced shape's pose; leave them out (move the shape in the directives instead)"
            )
        if not (isinstance(self.cells, int) and 0 <= self.cells <= 24 and self.cells % 2 == 0):
            raise ValueError(
                f"cells: {self.cells!r} must be 0 (from resolution_m) or an even integer in [2, 24]"
            )
        if self.mesh and (self.cells or self.grading != 1.0):
            raise ValueError(
                f"cells {self.cells}, grading {self.grading}: a mesh file is meshed already; leave them out"
            )
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale: {self.scale!r} must be > 0 (0.001 for a mesh in millimetres)")
        for name in ("xyz_m", "rpy_deg"):
            value = getattr(self, name)
            if len(value) != 3 or not all(math.isfinite(v) for v in value):
                raise ValueError(f"{name}: {value!r} must be 3 finite numbers")
        material = Organs(
            model="fem", youngs_modulus_pa=self.youngs_modulus_pa, poissons_ratio=self.poissons_ratio,
            density_kg_m3=self.density_kg_m3, mass_damping_per_s=self.mass_damping_per_s,
            stiffness_damping_s=self.stiffness_damping_s, material=self.material, friction=self.friction,
            relaxation_time_s=self.relaxation_time_s, glue_size_m=self.glue_size_m,
            modulus_factor=self.modulus_factor, threads=self.threads,
        )  # fmt: skip
        material.check_material()  # the same limits and words as the organs'
        if self.cells or self.replaces:
            material.cells, material.grading = self.cells or 2, self.grading
            material.check()  # the organs' mesh counts
        if not self.attach and not self.free:
            raise ValueError(
                "attach: none, so the body will fall: give attach (a box of its vertices fixed to the "
                "world or a body), or free: true if it rests on something"
            )
        for i, attach in enumerate(self.attach):
            try:
                attach.check()
            except ValueError as e:
                raise ValueError(f"attach[{i}].{e}") from None
        if not (self.max_slowdown > 0 and not math.isnan(self.max_slowdown)):
            raise ValueError(f"max_slowdown: {self.max_slowdown!r} must be > 0 (e.g. 20; .inf: no limit)")

    def _check_shape(self) -> None:
        if self.shape not in SOFT_SHAPES:
            raise ValueError(f"shape: {self.shape!r}; choose one of {SOFT_SHAPES}")
        n = SOFT_SIZES[self.shape]
        if len(self.size_m) != n or not all(math.isfinite(v) and v > 0 for v in self.size_m):
            raise ValueError(f"size_m: {self.size_m!r}; a {self.shape} takes {n} lengths > 0 (m)")
        if not (math.isfinite(self.resolution_m) and 0 < self.resolution_m <= max(self.size_m)):
            raise ValueError(
                f"resolution_m: {self.resolution_m!r} m must be > 0 and at most the shape's size "
                f"({max(self.size_m):g} m)"
            )
        if self.grading != 1.0 and self.shape not in ("sphere", "ellipsoid"):
            raise ValueError(f"grading: {self.grading!r} grades a sphere or an ellipsoid only; leave it at 1")
