"""The rigid god-object kind: free rigid bodies a pose device grasps (paper Eq. 2).

:func:`add_god_object` adds and wires the coupling, the feedback port and any simulated haptic
device; :class:`RigidGodObject` is what it added, and answers everything the library asks of
the kind: its loggers and metrics, its drawing (the target ghost and spring), the worst static
penetration its capped pull can cause (:func:`predict_penetration`), and the position baseline's
per-step imposition.
"""

import dataclasses
import functools
import math
from typing import ClassVar

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Role
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import ContactModel, MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config import scenario as sc
from godobject_drake.config.gains import GRASP_NEAREST, CouplingGains, FeedbackGains
from godobject_drake.devices.sources import DeviceSource
from godobject_drake.metrics import RigidMetrics, TrueShapeMetrics
from godobject_drake.station import loop
from godobject_drake.station.haptic_chain import WARN_FRACTION, add_haptic_chain, check_haptic_gains
from godobject_drake.station.kinds import GodObject
from godobject_drake.station.plant import point_stiffness
from godobject_drake.systems.contacts import ToolParts
from godobject_drake.systems.coupling import TERMS_LAYOUT
from godobject_drake.systems.drawing import ONE_TOOL, Drawing, GodObjectVisualizer
from godobject_drake.systems.implicit import ImplicitCouplingError, SpringHook, add_springs, implicit_terms


@dataclasses.dataclass
class RigidGodObject(GodObject):
    """A rigid god-object (:func:`add_god_object`): the coupling holds one free body at a time."""

    kind: ClassVar[str] = "rigid"
    predicts_penetration: ClassVar[bool] = True

    @classmethod
    def add_to_plant(cls, plant, scene_graph, scenario, device, *, check_gains=True, name="") -> dict:
        """The implicit coupling's springs (SAP constraints, added before ``Finalize``)."""
        if scenario.god_object.coupling == "implicit":
            return {"springs": add_springs(plant, name)}
        return {}

    @classmethod
    def build(cls, builder, scene, scenario, device, added: dict, *, check_gains=True):
        config = scenario.god_object
        return add_god_object(
            builder, scene.plant, device, config.gains, scenario.feedback, haptic=scenario.haptic,
            connect_forces=scenario.simulation.mode == "god_object", check_gains=check_gains,
            springs=added.get("springs"), forces=scene.forces, **coupling_options(config),
        )  # fmt: skip

    def logged_ports(self, plant):
        return {**super().logged_ports(plant), "terms": self.coupling.GetOutputPort("terms")}

    def add_drawing(self, builder, meshcat, scene, scenario, drawing: Drawing = ONE_TOOL) -> None:
        period = scenario.visualization.publish_period_s
        ghost = builder.AddNamedSystem(
            "god_object_visualizer",
            GodObjectVisualizer(
                meshcat, scene.plant, scene.scene_graph, period, drawing.prefix,
                max_stretch_m=self.coupling.max_stretch_m if scenario.visualization.force_cue else None,
                ghost_rgb=drawing.ghost_rgb, spring_rgb=drawing.spring_rgb, tool=drawing.tool,
            ),
        )  # fmt: skip
        for name in ("pose_WT", "pose_WG", "held_body"):
            builder.Connect(self.coupling.GetOutputPort(name), ghost.GetInputPort(name))

    def new_metrics(self, station):
        return _RigidFold(station)

    def predict_penetration(self, scene, penetration_allowance: float = 1e-3, duration_s=None):
        return predict_penetration(scene, self, penetration_allowance, duration_s)

    def configuration(self, scenario, station) -> dict:
        return {"haptic": scenario.haptic.mode}

    holds_free_bodies: ClassVar[bool] = True

    def grasp_spans(self) -> dict[str, tuple[float, float]]:
        spans: dict[str, tuple[float, float]] = {}
        for t, sample in self.source.samples(getattr(self.source, "end_time_s", 0.0)):
            name = sample[2] if sample is not None else ""
            if not name or name == GRASP_NEAREST:
                continue
            body = self.coupling.body_for_grasp(name).name
            first, last = spans.get(body, (t, t))
            spans[body] = (min(first, t), max(last, t))
        return spans

    def contact_parts(self, plant, scene_graph) -> ToolParts:
        """The body it holds, while it holds one (the coupling's ``held_body``)."""
        return ToolParts(holds=True)

    def held_body_port(self):
        return self.coupling.GetOutputPort("held_body")

    def tip_reference(self, data: dict):
        return data["terms"][:, TERMS_LAYOUT["held_body"]]

    def held_bodies(self, root_context) -> set[int]:
        context = self.coupling.GetMyContextFromRoot(root_context)
        held = int(self.coupling.GetOutputPort("held_body").Eval(context)[0])
        return {held} if held >= 0 else set()

    def before_step(self, plant: MultibodyPlant):
        """The position baseline sets the held body to its target every step (paper Fig. 5)."""
        if self.mode != "position":
            return None
        coupling = self.coupling

        def impose(plant_context, root_context):
            self._impose(plant, plant_context, coupling.GetMyContextFromRoot(root_context))

        return impose

    def _impose(self, plant, plant_context, coupling_context) -> None:
        impose_target(plant, plant_context, self.coupling, coupling_context)


class ImplicitGodObject(RigidGodObject):
    """A rigid god-object on the implicit coupling (:mod:`godobject_drake.systems.implicit`): the same
    questions answered, its terms computed from the logs after the run, its springs applied to the
    plant between steps (:class:`~godobject_drake.systems.implicit.SpringHook`)."""

    @functools.cached_property
    def hook(self):
        """What applies the coupling's grasps to the plant between steps."""
        return SpringHook(self.coupling.plant, self.coupling)

    def logged_ports(self, plant):
        return {
            "state": plant.get_state_output_port(),
            "coupling": self.coupling.GetOutputPort("coupling_state"),
        }

    def complete_logs(self, rows: dict) -> dict:
        coupling = rows["coupling"]
        terms = implicit_terms(self.coupling, rows["state"], coupling, self.hook.last_logged_row)
        if len(coupling):
            self.hook.last_logged_row = coupling[-1].copy()
        return {**rows, "terms": terms}

    def configuration(self, scenario, station) -> dict:
        return {**super().configuration(scenario, station), "coupling": "implicit"}

    def prepare(self, plant_context) -> None:
        self.hook.reset()
        self.hook.deactivate(plant_context)

    def before_step(self, plant: MultibodyPlant):
        return self.hook


class _RigidFold:
    """The rigid kind's metrics: true-shape penetration and tracking of the held body, capped steps."""

    def __init__(self, station):

        self._acc = RigidMetrics(TrueShapeMetrics(station.plant, station.scene_graph, station.diagram))
        self.capped = 0

    def fold(self, rows: dict, data: dict, finite):

        terms = rows["terms"]
        held = terms[:, TERMS_LAYOUT["held_body"]].round().astype(int)
        self._acc.update(rows["state"], held, terms[:, TERMS_LAYOUT["pose_WT"]][:, 4:])
        self.capped += int(np.sum(data["terms"][:, TERMS_LAYOUT["capped"]] > 0.5))
        return (data["terms"][:, TERMS_LAYOUT[name]][:, 4:] for name in ("pose_WT", "pose_WG"))

    def result(self) -> dict:
        return {**self._acc.result(), "coupling_capped_steps": self.capped}


def add_god_object(
    builder: DiagramBuilder,
    plant: MultibodyPlant,
    device: DeviceSource,
    gains: CouplingGains,
    feedback_gains: FeedbackGains | None = None,
    *,
    haptic: "sc.Haptic | None" = None,
    connect_forces: bool = True,
    name: str = "coupling",
    check_gains: bool = True,
    springs=None,
    forces: "loop.ForceBus | None" = None,
    **coupling_options,
) -> "RigidGodObject":
    """Make the plant's free bodies god-objects of ``device``: one call, after ``plant.Finalize()``.

    The loop's steps (:mod:`~godobject_drake.station.loop`) for a rigid tool: the coupling named
    ``name`` (explicit, or implicit with ``springs`` from
    :func:`~godobject_drake.systems.implicit.add_springs`), the haptic chain ``haptic`` puts between
    ``device`` and the coupling (:mod:`~godobject_drake.station.haptic_chain`: none, impedance or
    admittance), the feedback port named ``feedback`` with ``feedback_gains`` (zero: a non-haptic
    device; its ``F_Do_W`` is wired whatever its gains), the coupling's wrench into the plant, and
    the wrench back to the device. ``device`` must already be in ``builder``.

    ``connect_forces=False`` leaves the plant's force inputs alone (the position baseline).
    ``check_gains=False`` builds gains past the explicit limit, and haptic gains past the
    device's (:func:`~godobject_drake.station.haptic_chain.check_haptic_gains`; stability analysis
    only). ``forces``: the station's :class:`~godobject_drake.station.loop.ForceBus` when several
    tools share the plant (None: connected now). ``coupling_options`` go to the coupling
    (``carried``, ``graspable``, ``max_stretch_m``,
    ``max_twist_rad``, ``grasp_reach_m``, ``gravity_compensation``).
    """
    haptic = haptic or sc.Haptic()
    if check_gains:
        check_haptic_gains(haptic, feedback_gains or FeedbackGains())
    if springs is not None and (haptic.mode == "admittance" or not connect_forces):
        raise ImplicitCouplingError(
            "the implicit coupling drives a rigid body with springs: not an admittance device "
            "(haptic.mode admittance), the position baseline (connect_forces=False) or a carried shell"
        )
    period = 1.0 / haptic.rate_hz if haptic.mode == "impedance" else None
    coupling = loop.add_coupling(builder, plant, device, gains, period_s=period, springs=springs,
                                 check_gains=check_gains, name=name, **coupling_options)  # fmt: skip
    chain = add_haptic_chain(builder, haptic, device, coupling)
    feedback = loop.add_feedback(builder, chain, coupling, feedback_gains)
    loop.connect_target(builder, chain, coupling)
    if connect_forces:
        loop.connect_forces(builder, plant, coupling, forces)
    publisher = loop.render_feedback(builder, device, chain, feedback, coupling)
    god_class = ImplicitGodObject if springs is not None else RigidGodObject
    return god_class(coupling, feedback, source=device, chain=chain, publisher=publisher,
                     mode="god_object" if connect_forces else "position")  # fmt: skip


def coupling_options(config: "sc.Rigid") -> dict:
    """A :class:`~godobject_drake.config.scenario.Rigid` config's options for :func:`add_god_object`."""
    return dict(
        graspable=config.graspable or None,
        gravity_compensation=config.gravity_compensation,
        max_stretch_m=config.max_stretch_m,
        max_twist_rad=config.max_twist_rad,
        grasp_reach_m=config.grasp_reach_m,
    )


def impose_target(plant, plant_context, coupling, coupling_context) -> None:
    """Position baseline: set the held body to the target's pose and velocity (paper Fig. 5)."""
    held = int(coupling.GetOutputPort("held_body").Eval(coupling_context)[0])
    if held < 0:
        return
    pose_WT = coupling.GetOutputPort("pose_WT").Eval(coupling_context)
    V_WT = coupling.GetOutputPort("V_WT").Eval(coupling_context)
    body = plant.get_body(BodyIndex(held))
    p_BoBcm_B = coupling.bodies[body.scoped_name().get_full()].p_BoBcm_B
    X_WG = RigidTransform(Quaternion(pose_WT[:4] / np.linalg.norm(pose_WT[:4])), pose_WT[4:])
    X_WB = X_WG.multiply(RigidTransform(-p_BoBcm_B))
    p_GB_W = X_WB.translation() - pose_WT[4:]
    plant.SetFreeBodyPose(plant_context, body, X_WB)
    plant.SetFreeBodySpatialVelocity(
        plant_context, body, SpatialVelocity(V_WT[:3], V_WT[3:] + np.cross(V_WT[:3], p_GB_W))
    )


# -- what the god-object's pull can do to contact ----------------------------------------------------------


def predict_penetration(scene, god: RigidGodObject, penetration_allowance: float = 1e-3,
                        duration_s: float | None = None):  # fmt: skip
    """The deepest static penetration a held body's capped pull can cause, or None.

    For each body the device grasps over ``duration_s`` (:func:`grasped_bodies`) and each rigid
    obstacle geometry its own geometry
    is not filtered against: ``depth = F_cap / k``, with ``F_cap`` the coupling's force cap
    (``m ωn² · max_stretch_m``, what a target far inside the obstacle pulls with) and ``k``
    the pair's point-contact stiffness as SAP combines it: harmonically,
    ``k = k_A k_B / (k_A + k_B)``, one contact point (the deepest case; a face resting on
    several proxies shares the force). A geometry without ``point_contact_stiffness`` has
    Drake's default, ``2 m_max g / penetration_allowance`` (m_max the heaviest body).
    Returns ``(depth_m, body, obstacle, force_n, stiffness_n_m)`` for the deepest pair, or
    None where there is nothing to predict: an articulated tool (no force cap), a
    deformable core (no collision geometry: its shell deforms instead), hydroelastic
    contact (its pressure depends on the contact area).
    """
    bodies = grasped_bodies(god.coupling, god.source, duration_s)
    pairs = penetration_pairs(
        scene.plant, scene.scene_graph, god.coupling, penetration_allowance, softest=True, bodies=bodies
    )
    if not pairs:
        return None
    best = max(pairs, key=lambda pair: pair.depth_m)
    return best.depth_m, best.body, best.obstacle, best.force_n, best.stiffness_n_m


@dataclasses.dataclass(frozen=True)
class ContactPair:
    """A held body's geometry against an obstacle geometry it can touch (point contact)."""

    body: str
    body_index: int
    geometry: str
    obstacle: str
    obstacle_anchored: bool  # welded to the world (a fixed obstacle), not another free body
    force_n: float  # the coupling's force cap on the body (N)
    stiffness_n_m: float  # the pair's combined point-contact stiffness (N/m)
    obstacle_body_index: int = -1  # the obstacle's body (its BodyIndex)

    @property
    def depth_m(self) -> float:
        """Static penetration under the capped pull, one contact point (m)."""
        return self.force_n / self.stiffness_n_m


def penetration_pairs(
    plant, scene_graph, coupling, penetration_allowance: float = 1e-3, softest: bool = False,
    bodies=None, force_n: float | None = None, anchored_only: bool = False,
) -> list[ContactPair]:  # fmt: skip
    """Every (held body geometry, obstacle geometry) pair that can touch, with the coupling's
    force cap on the body and the pair's combined stiffness (:func:`predict_penetration`);
    empty without point contact. ``softest``: only, for each held geometry, the softest obstacle
    it can touch (the deepest pair, found by trying obstacles from the softest up: what the
    prediction needs, without the bodies × geometries² loop that took 18 s for 128 bricks).
    ``bodies``: these of the coupling's bodies only (:func:`grasped_bodies`; default all);
    ``force_n``: this force instead of each body's own cap (a body pushed by a held one);
    ``anchored_only``: obstacles welded to the world only."""
    if plant.get_contact_model() != ContactModel.kPoint:
        return []
    inspector = scene_graph.model_inspector()
    masses = [plant.get_body(BodyIndex(i)).default_mass() for i in range(plant.num_bodies())]
    m_max = max([m for m in masses if math.isfinite(m)] or [0.0])
    g = float(np.linalg.norm(plant.gravity_field().gravity_vector()))
    default_k = 2.0 * m_max * g / penetration_allowance
    ids = [
        g_id
        for g_id in inspector.GetAllGeometryIds(Role.kProximity)
        if not inspector.IsDeformableGeometry(g_id)
    ]
    world = inspector.world_frame_id()
    welded = plant.GetBodiesWeldedTo(plant.world_body())  # the world body included
    anchored = {plant.GetBodyFrameIdOrThrow(b.index()) for b in welded} | {world}
    stiffness = {b: point_stiffness(inspector, b, default_k) for b in ids}
    if anchored_only:
        ids = [b for b in ids if inspector.GetFrameId(b) in anchored]
    if softest:
        ids = sorted(ids, key=lambda b: stiffness[b])
    pairs = []
    if bodies is None:
        bodies = {b.index: b for b in coupling.bodies.values()}.values()
    for body in bodies:
        force = coupling.force_caps(body)[0] if force_n is None else force_n
        frame = plant.GetBodyFrameIdOrThrow(BodyIndex(body.index))
        for a in inspector.GetGeometries(frame, Role.kProximity):
            ka = stiffness[a]
            for b in ids:
                if inspector.GetFrameId(b) == frame or inspector.CollisionFiltered(a, b):
                    continue
                kb = stiffness[b]
                k = ka * kb / (ka + kb)
                if k > 0:
                    pairs.append(ContactPair(
                        body.name, body.index, inspector.GetName(a), inspector.GetName(b),
                        inspector.GetFrameId(b) in anchored, force, k,
                        int(plant.GetBodyFromFrameId(inspector.GetFrameId(b)).index()),
                    ))  # fmt: skip
                    if softest:
                        break
    return pairs


def grasped_bodies(coupling, source, duration_s: float | None = None) -> list:
    """The coupling's bodies (:class:`~godobject_drake.systems.coupling.GraspableBody`) the
    device's path or log grasps by name over ``duration_s``; all of them where it grasps the
    nearest (``*``) or names none ahead of time (a live device)."""
    names = source.grasp_names(duration_s)
    everything = list({b.index: b for b in coupling.bodies.values()}.values())
    if not names or GRASP_NEAREST in names:
        return everything
    return list({b.index: b for b in (coupling.body_for_grasp(n) for n in sorted(names))}.values())


def penetration_fix(force_n: float, depth_m: float, budget_m: float, omega_n: float, max_stretch_m: float,
                    margin: float = WARN_FRACTION) -> str:  # fmt: skip
    """What brings a static penetration ``depth_m`` under a capped pull ``force_n`` back inside
    ``budget_m``, with the margin ``analyze`` passes a row at: the run's warning and analyze's row
    give this same text."""
    w, stretch, k = (
        omega_n * math.sqrt(budget_m / depth_m),
        max_stretch_m * budget_m / depth_m,
        force_n / budget_m,
    )
    return (
        f"omega_n ≤ {w * math.sqrt(margin) * (1 - 1e-3):.4g} rad/s, or max_stretch_m ≤ "
        f"{stretch * margin * (1 - 1e-3):.4g} m, or point_contact_stiffness values that combine "
        f"(k_A k_B/(k_A + k_B)) to ≥ {k / margin * (1 + 1e-3):.4g} N/m ({1 - margin:.0%} inside the budget; "
        f"at the budget itself: {w:.4g} rad/s, {stretch:.4g} m, {k:.4g} N/m)"
    )
