"""Scene building blocks: model loading, contact settings, proxy filtering.

Collision geometry convention (see ``models/lego/brick_2x4.sdf``): a
geometry whose name starts with ``proxy_`` is a contact proxy (the paper's
spheres); every other proximity geometry is a *true shape*. Penetration is
always measured on true shapes (:mod:`godobject_drake.metrics`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import re
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    CollisionFilterDeclaration,
    GeometrySet,
    ProximityProperties,
    Role,
    RoleAssign,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import (
    AddDirectives,
    ModelDirective,
    ModelDirectives,
    Parser,
    ProcessModelDirectives,
)
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import BodyIndex, ModelInstanceIndex
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config import scenario as sc
from godobject_drake.config.scenario import MODELS_DIR
from godobject_drake.config.scene import CORNER_PREFIX, FLAT_PREFIX, is_proxy, local_name
from godobject_drake.station.loop import ForceBus
from godobject_drake.systems.soft_body import FemSoftBody
from godobject_drake.systems.tissue import weld_glued

CONTACT_MODELS = ("proxies", "hydroelastic")
# Drake's discrete contact approximations that work from Python on this scene kind (TAMSI is
# deprecated in 1.51.1; a deformable body needs "sap").
APPROXIMATIONS = ("sap", "lagged", "similar")


def make_parser(plant: MultibodyPlant) -> Parser:
    """A Parser that resolves ``package://godobject_models/...`` (the installed package data); a
    scene of one's own with no such URL does not need it."""
    parser = Parser(plant)
    package_xml = MODELS_DIR / "package.xml"
    if package_xml.is_file():
        parser.package_map().AddPackageXml(str(package_xml))
    return parser


def set_contact_material(plant: MultibodyPlant, scene_graph: SceneGraph, **values: float) -> None:
    """Set ``("material", name)`` proximity properties on every rigid proximity geometry of ``plant``.

    E.g. ``relaxation_time=1e-3`` (s) or ``point_contact_stiffness=2e4`` (N/m).
    """
    inspector = scene_graph.model_inspector()
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        if inspector.IsDeformableGeometry(gid):
            continue  # a deformable body sets its own (godobject_drake.systems.shell)
        props = ProximityProperties(inspector.GetProximityProperties(gid))
        for name, value in values.items():
            if props.HasProperty("material", name):
                props.UpdateProperty("material", name, value)
            else:
                props.AddProperty("material", name, value)
        scene_graph.AssignRole(plant.get_source_id(), gid, props, RoleAssign.kReplace)


def set_relaxation_time(plant: MultibodyPlant, scene_graph: SceneGraph, tau: float) -> None:
    """Set SAP's ``relaxation_time`` (s) on every proximity geometry of ``plant``.

    SAP's default (0.1 s) makes point contact far softer than its nominal
    stiffness (docs/design.md); ``tau ≈ h`` keeps the nominal stiffness.
    """
    set_contact_material(plant, scene_graph, relaxation_time=tau)


def apply_contact_model(plant: MultibodyPlant, scene_graph: SceneGraph, contact: str) -> None:
    """Filter collision pairs for ``contact`` ∈ ``CONTACT_MODELS``.

    ``proxies``: proxies touch true shapes only, never other proxies. Two
    bodies that both have proxies touch only through them (a brick's proxies
    on another brick's box, so bricks stack flat); a body with proxies keeps
    its true shape against bodies without (the welded wall), as a backstop
    where an edge could slip between two proxies. Against a ``flat_*``
    geometry (a floor) only ``proxy_corner_*`` proxies touch: a convex body
    meets a plane at its vertices, so the other proxies and the true shape
    would add contacts (and SAP solve time: 64 instead of 32 contacts for 8
    resting bricks) without changing what the floor does.
    ``hydroelastic``: proxies are removed from contact; true shapes touch
    each other (use with a hydroelastic contact model).
    """
    if contact not in CONTACT_MODELS:
        raise ValueError(f"contact={contact!r}; choose one of {CONTACT_MODELS}")
    inspector = scene_graph.model_inspector()
    ids = inspector.GetAllGeometryIds(Role.kProximity)
    proxies = [g for g in ids if is_proxy(inspector.GetName(g))]
    true_shapes = [g for g in ids if not is_proxy(inspector.GetName(g))]
    manager = scene_graph.collision_filter_manager()
    if contact == "hydroelastic":
        manager.Apply(CollisionFilterDeclaration().ExcludeBetween(GeometrySet(proxies), GeometrySet(ids)))
        return
    manager.Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(proxies)))
    frames_with_proxies = {inspector.GetFrameId(g) for g in proxies}
    shapes_with_proxies = [g for g in true_shapes if inspector.GetFrameId(g) in frames_with_proxies]
    manager.Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(shapes_with_proxies)))
    flat = [g for g in true_shapes if local_name(inspector.GetName(g)).startswith(FLAT_PREFIX)]
    not_corners = shapes_with_proxies + [
        g for g in proxies if not local_name(inspector.GetName(g)).startswith(CORNER_PREFIX)
    ]
    if flat and not_corners:
        declaration = CollisionFilterDeclaration().ExcludeBetween(GeometrySet(flat), GeometrySet(not_corners))
        manager.Apply(declaration)


@dataclasses.dataclass
class SceneParts:
    """What a scene builder returns: the plant, its SceneGraph and the scene's names."""

    plant: MultibodyPlant
    scene_graph: SceneGraph
    contact: str
    tissue: object = None  # with organs.model fem: the organ, a godobject_drake.systems.soft_body.FemSoftBody
    forces: object = None  # the station's loop.ForceBus: every tool's forces into the plant
    tool_names: tuple = ()  # the scenario's tools by name (empty: the one-tool form)
    soft_bodies: dict = dataclasses.field(default_factory=dict)  # deformables: name → FemSoftBody


def add_directives_plant(
    builder: DiagramBuilder,
    config: MultibodyPlantConfig,
    directives,
    contact: str = "proxies",
    relaxation_time: float | None = None,
    before_finalize=None,
) -> SceneParts:
    """Add a discrete MultibodyPlant with the scene's models, finalize it, set its contact.

    Parameters
    ----------
    config : MultibodyPlantConfig
        Drake's plant settings; ``time_step`` must be > 0 (SAP is discrete).
    directives : list[ModelDirective]
        Model directives (``package://godobject_models/...`` resolves to the project's models).
    contact : str
        Which geometry touches (:func:`apply_contact_model`): ``proxies`` or ``hydroelastic``.
    relaxation_time : float | None
        SAP relaxation time (s) for every rigid contact geometry; None = the time step.
    before_finalize : callable | None
        ``before_finalize(plant, scene_graph)`` adds what must exist before
        ``Finalize()`` (a deformable god-object) after the directives load.
    """
    h = config.time_step
    if not h > 0.0:
        raise ValueError(f"time_step={h!r} s: SAP needs a discrete plant, give h > 0")
    if config.discrete_contact_approximation not in APPROXIMATIONS:
        raise ValueError(
            f"discrete_contact_approximation={config.discrete_contact_approximation!r}; "
            f"choose one of {APPROXIMATIONS}"
        )
    plant, scene_graph = AddMultibodyPlant(config, builder)
    parser = make_parser(plant)
    ProcessModelDirectives(ModelDirectives(directives=list(directives)), plant, parser)
    if before_finalize is not None:
        before_finalize(plant, scene_graph)
    plant.Finalize()
    set_relaxation_time(plant, scene_graph, h if relaxation_time is None else relaxation_time)
    apply_contact_model(plant, scene_graph, contact)
    return SceneParts(plant, scene_graph, contact)


BRICK_URL = "package://godobject_models/lego/brick_2x4.sdf"
BRICK_HEIGHT_M = 0.0096
# Where the brick scene's extra bricks go: 3 rows on each side of the table, past the wall's ends
# (|y| ≤ 0.1 m) and the default path's set-down spot, 9 columns, stacked layer by layer.
BRICK_GRID_X_M = tuple(-0.16 + 0.04 * i for i in range(9))
BRICK_GRID_Y_M = (0.125, 0.15, 0.175, -0.125, -0.15, -0.175)


def brick_grid_positions(count: int) -> list[tuple[float, float, float]]:
    """Centres (m) of ``count`` extra bricks: the grid's 54 places a layer, then the next layer up."""
    per_layer = len(BRICK_GRID_X_M) * len(BRICK_GRID_Y_M)
    out = []
    for k in range(count):
        layer, place = divmod(k, per_layer)
        y, x = divmod(place, len(BRICK_GRID_X_M))
        out.append((BRICK_GRID_X_M[x], BRICK_GRID_Y_M[y], 0.5 * BRICK_HEIGHT_M + BRICK_HEIGHT_M * layer))
    return out


def add_bricks(plant: MultibodyPlant, total: int) -> int:
    """Make the brick scene's brick count ``total``: the ``brick_0..`` it has, and brick_2x4 models
    on :func:`brick_grid_positions` for the rest; returns how many were added."""
    names = {plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())}
    have = sum(1 for n in names if re.fullmatch(r"brick_\d+", n))
    if have == 0:
        raise ValueError(
            f"bricks: {total} adds brick_2x4 models to the brick scene; this scene has no brick_k models. "
            "Leave bricks at 0 (the directives' models)"
        )
    if total < have:
        raise ValueError(
            f"bricks: {total} is fewer than the {have} bricks the scene has; give ≥ {have} (0: as is)"
        )
    # One read of the brick's SDF, parsed from text for each copy: 12 ms a brick, where parsing
    # the package URL each time takes 44 ms (128 bricks: 1.4 s instead of 5.3 s).
    parser = make_parser(plant)
    text = Path(parser.package_map().ResolveUrl(BRICK_URL)).read_text()
    if text.count('<model name="brick_2x4">') != 1:
        raise RuntimeError(f"{BRICK_URL} no longer names its model brick_2x4: add_bricks renames that line")
    placed = brick_grid_positions(total - have)
    for k, xyz in enumerate(placed):
        name = f"brick_{have + k}"
        (instance,) = parser.AddModelsFromString(
            text.replace('<model name="brick_2x4">', f'<model name="{name}">'), "sdf"
        )
        body = plant.GetBodyByName("brick", instance)
        plant.SetDefaultFloatingBaseBodyPose(body, RigidTransform(list(xyz)))
    return len(placed)


def add_scene_from_directives(
    builder: DiagramBuilder,
    directives: str | Path,
    time_step: float,
    contact: str = "proxies",
    relaxation_time: float | None = None,
    near_rigid_threshold: float | None = None,
    before_finalize=None,
    approximation: str = "sap",
) -> SceneParts:
    """:func:`add_plant` for one ``*.dmd.yaml`` file, with SAP and the contact model ``contact`` needs.

    ``directives`` is a ``*.dmd.yaml`` path or ``package://godobject_models/...`` URL;
    ``time_step`` h (s); ``contact`` ``proxies`` (point contact) or ``hydroelastic``
    (hydroelastic with fallback); ``near_rigid_threshold`` SAP's (None: Drake's default);
    ``approximation`` one of :data:`APPROXIMATIONS`.
    """
    config = MultibodyPlantConfig(
        time_step=time_step,
        discrete_contact_approximation=approximation,
        contact_model="point" if contact == "proxies" else "hydroelastic_with_fallback",
    )
    if near_rigid_threshold is not None:
        config.sap_near_rigid_threshold = near_rigid_threshold
    url = str(directives)
    if "://" not in url:
        url = "file://" + str(Path(url).resolve())
    directive = ModelDirective(add_directives=AddDirectives(file=url))
    return add_directives_plant(builder, config, [directive], contact, relaxation_time, before_finalize)


def exclude_self_collisions(plant: MultibodyPlant, scene_graph: SceneGraph, model: str) -> None:
    """Filter contact between any two geometries of one model instance (a tool's own parts)."""
    instance = plant.GetModelInstanceByName(model)
    frames = [plant.GetBodyFrameIdOrThrow(b) for b in plant.GetBodyIndices(instance)]
    inspector = scene_graph.model_inspector()
    ids = [g for f in frames for g in inspector.GetGeometries(f, Role.kProximity)]
    scene_graph.collision_filter_manager().Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(ids)))


# The organs' fields a soft body's error names (Organs.soft_body's entry, written as organs:).
ORGAN_FIELDS = {"replaces": "organ", "attach": "attached_below_m"}


def workspace_diagonal(scenario: sc.Scenario) -> float:
    """The scene's size (m): the diagonal of the box around its devices' workspaces (each tool's,
    or the scene's one)."""
    boxes = [tool.workspace for tool in scenario.tools.values()] or [scenario.workspace]
    lower = np.min([box.lower_m for box in boxes], axis=0)
    upper = np.max([box.upper_m for box in boxes], axis=0)
    return float(np.linalg.norm(upper - lower))


def add_plant(builder: DiagramBuilder, scenario: sc.Scenario, before_finalize=None) -> SceneParts:
    """The scenario's plant: its config, directives, ``bricks`` and contact settings; finalized."""

    tissue = []
    soft = {}

    def before(plant, scene_graph):
        try:
            workspace_m = workspace_diagonal(scenario)
            organs = scenario.organs
            if organs.model == "fem":  # the deformables entry it stands for, named as organs' fields
                tissue.append(FemSoftBody(plant, organs.name, organs.soft_body(), scene_graph, where="organs",
                                          workspace_m=workspace_m, fields=ORGAN_FIELDS))  # fmt: skip
            else:
                weld_glued(plant, organs)
            for name, spec in scenario.deformables.items():
                soft[name] = FemSoftBody(plant, name, spec, scene_graph, workspace_m=workspace_m)
        except ValueError as e:
            raise sc.ScenarioError(str(e)) from None
        if scenario.bricks:
            try:
                add_bricks(plant, scenario.bricks)
            except ValueError as e:
                raise sc.ScenarioError(str(e)) from None
        if before_finalize is not None:
            before_finalize(plant, scene_graph)

    with _DrakeWarnings() as drake_warnings:
        try:
            scene = add_directives_plant(
                builder,
                scenario.plant,
                scenario.directives,
                scenario.contact.geometry,
                scenario.contact.relaxation_time_s,
                before,
            )
        except RuntimeError as e:  # Drake's parser and plant: a model file, a name, a frame
            said = " ".join(str(e).split()).rstrip(".")
            download = _DOWNLOAD_FAILED.search(said)
            if download is not None:
                package = download.group(1) or download.group(2)
                raise sc.ScenarioError(_download_advice(package, said)) from None
            raise sc.ScenarioError(
                f"directives: Drake could not build the scene's plant: {said}. Check the directives' files, "
                "model names (each once) and frame names (model::frame)"
            ) from None
    refuse_replaced_inertia(drake_warnings.messages)
    check_free_bodies(scene.plant)
    scene.tissue = tissue[0] if tissue else None
    scene.soft_bodies = soft
    scene.forces = ForceBus(scene.plant)
    scene.tool_names = tuple(scenario.tools)
    return scene


# Drake's PackageMap, failing to fetch a remote package (drake_models: the YCB objects, the iiwa,
# the WSG gripper, ... which the drake wheel does not ship), or forbidden to (DRAKE_ALLOW_NETWORK).
_DOWNLOAD_FAILED = re.compile(
    r"PackageMap: when downloading '([^']+)'|PackageMap::AddRemote on '([^']+)' only provides network URLs"
)


def _download_advice(package: str, said: str) -> str:
    """The error for a model of a package Drake must download and could not (no network)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "drake" / "package_map"
    return (
        f"directives: a model of the package '{package}' (package://{package}/...) is not in the drake "
        f"wheel, and Drake could not download it ({said}). Either use models the wheel ships "
        "(package://drake/examples/..., e.g. package://drake/examples/kuka_iiwa_arm/models/objects/"
        "folding_table.urdf, the kuka_iiwa_arm tables and objects, the acrobot, the planar gripper) or "
        f"your own files, or run the scene once where there is network: Drake keeps the download in {cache} "
        "(copy that folder to this machine to run offline)"
    )


def refuse_replaced_inertia(messages) -> None:
    """Drake's parser warns and replaces a body's mass or inertia it cannot use (a NaN, a negative or
    zero mass, moments that are negative or break the triangle inequality): the body then moves
    with an inertia its model does not give. Refused, naming the file and line Drake names."""
    for message in messages:
        if "mass > 0" in message or "mass <= 0" in message:  # Drake then gives the body 1 kg, silently
            raise sc.ScenarioError(
                f"a model declares a body with no positive mass; Drake replaced its inertia ({message}). "
                "Give the body <inertial><mass> > 0 in its model file, or weld it (add_weld) if it should "
                "not move"
            )
        if "While parsing inertia matrix" in message:  # a NaN or negative moment: Drake makes one up
            raise sc.ScenarioError(
                f"a model declares a body whose rotational inertia is not physically valid (a NaN, a "
                f"negative moment, or one moment larger than the other two together); Drake replaced it "
                f"({' '.join(message.split())[:400]}). Give the body's <inertia> finite moments ixx, iyy, "
                "izz > 0, each at most the sum of the other two"
            )


class _DrakeWarnings(logging.Handler):
    """Drake's log warnings while a block runs (pydrake sends its log to Python's ``drake`` logger)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())

    def __enter__(self):
        logging.getLogger("drake").addHandler(self)
        return self

    def __exit__(self, *exc):
        logging.getLogger("drake").removeHandler(self)


# A free body that starts inside another leaves it at up to depth · sqrt(k/m) (the contact's spring
# energy, ½ k d², all turned into speed; SAP's damping takes some): past this it is thrown, not settled.
START_OVERLAP_SPEED_MPS = 0.25


def point_stiffness(inspector, geometry_id, default: float) -> float:
    """A geometry's point-contact stiffness (N/m), or ``default`` (Drake's from the penetration
    allowance) where its model gives none."""
    props = inspector.GetProximityProperties(geometry_id)
    if props is not None and props.HasProperty("material", "point_contact_stiffness"):
        return float(props.GetProperty("material", "point_contact_stiffness"))
    return default


def check_start_overlaps(diagram, plant: MultibodyPlant, scene_graph, penetration_allowance: float) -> None:
    """Refuse a free body that starts inside another body deeper than the contact can resolve
    gently (it would leave at more than :data:`START_OVERLAP_SPEED_MPS`), naming both, the depth,
    the speed and the likely cause: a model that should be welded, or a wrong starting pose."""
    free = {int(b) for b in plant.GetFloatingBaseBodies()}
    if not free:
        return
    context = diagram.CreateDefaultContext()
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    masses = [plant.get_body(BodyIndex(i)).default_mass() for i in range(plant.num_bodies())]
    g = float(np.linalg.norm(plant.gravity_field().gravity_vector()))
    default_k = 2.0 * max([m for m in masses if math.isfinite(m)] or [0.0]) * g / penetration_allowance
    worst = None
    for pair in query.ComputePointPairPenetration():
        bodies = [plant.GetBodyFromFrameId(inspector.GetFrameId(i)) for i in (pair.id_A, pair.id_B)]
        moving = [b for b in bodies if b is not None and int(b.index()) in free]
        if not moving:
            continue
        ka, kb = (point_stiffness(inspector, i, default_k) for i in (pair.id_A, pair.id_B))
        k = ka * kb / (ka + kb)
        m = 1.0 / sum(1.0 / b.default_mass() for b in moving)  # two free bodies: the reduced mass
        speed = pair.depth * math.sqrt(k / m)
        if speed > START_OVERLAP_SPEED_MPS and (worst is None or speed > worst[0]):
            worst = (speed, pair.depth, bodies, moving)
    if worst is None:
        return
    speed, depth, bodies, moving = worst
    names = [b.scoped_name().get_full() if b is not None else "the world" for b in bodies]
    fixed = [b for b in bodies if b is not None and int(b.index()) not in free]
    model = plant.GetModelInstanceName(moving[0].model_instance())
    raise sc.ScenarioError(
        f"{names[0]} and {names[1]} start {depth * 1e3:.3g} mm inside each other: contact would throw "
        f"{' and '.join(b.scoped_name().get_full() for b in moving)} out at up to {speed:.2g} m/s "
        f"(the contact's spring energy; more than {START_OVERLAP_SPEED_MPS:g} m/s). Likely a missing weld "
        f"(model {model!r} has none: "
        f"add_weld it if it should stay put{' on ' + fixed[0].scoped_name().get_full() if fixed else ''}) "
        "or a wrong starting pose (its default_free_body_pose, or the X_PC of a weld): move it out"
    )


def check_free_bodies(plant: MultibodyPlant) -> None:
    """Refuse a free body without a positive, finite mass: Drake only logs a warning, and the body
    then has no dynamics the coupling or contact could act on."""
    for body in plant.GetFloatingBaseBodies():
        body = plant.get_body(body)
        mass = body.default_mass()
        if not (math.isfinite(mass) and mass > 0):
            raise sc.ScenarioError(
                f"{body.scoped_name().get_full()}: a free body with mass {mass!r} kg; give it "
                "<inertial><mass> > 0 in its model file, or weld it (add_weld) if it should not move"
            )
