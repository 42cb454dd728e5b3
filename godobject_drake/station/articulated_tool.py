"""The articulated god-object kind: a tree model whose joints a joint-space device drives (paper Eq. 4–9).

:func:`add_articulated` adds the coupling (Cartesian per body, or joint-space PD, explicit or
SAP's implicit actuators) and its feedback; :class:`ArticulatedGodObject` is what it added: it
logs the device's joint values, draws the device's tool as a wireframe, measures the tool's tip
and trocar, locks and sets the imposed joints (the paper's jaws) before each step, and keeps
resting bodies awake (its bodies are not free bodies the sleep manager could watch).
"""

import dataclasses
from typing import ClassVar

import numpy as np
from pydrake.multibody.plant import DistanceConstraintParams, MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config import scenario as sc
from godobject_drake.devices.sources import DeviceSource, JointDevice
from godobject_drake.devices.trocar import PoseJointDevice, TrocarKinematics
from godobject_drake.metrics import TissueMetrics, ToolMetrics
from godobject_drake.station import loop
from godobject_drake.station.articulated_model import add_articulated_model
from godobject_drake.station.kinds import GodObject
from godobject_drake.station.plant import SceneParts, exclude_self_collisions
from godobject_drake.systems.contacts import ToolParts
from godobject_drake.systems.drawing import ONE_TOOL, Drawing, ToolGhostVisualizer
from godobject_drake.systems.tissue import connect_tissue_observer, free_body, tool_capsules


@dataclasses.dataclass
class ArticulatedGodObject(GodObject):
    """An articulated god-object (:func:`add_articulated`).

    Attributes
    ----------
    tissue, tissue_observer :
        With ``organs.model: fem``: the organ (a
        :class:`~godobject_drake.systems.soft_body.FemSoftBody`) and its
        :class:`~godobject_drake.systems.tissue.TissueObserver` (logged, drawn, folded into the metrics).
    """

    tissue: object = None
    tissue_observer: object = None
    grasp: "JawHold | None" = None

    kind: ClassVar[str] = "articulated"
    device_space: ClassVar[str] = "joint"
    sleeps_others: ClassVar[bool] = False
    no_prediction_reason: ClassVar[str] = (
        "articulated tool: its coupling has no force cap, so no worst-case pull to predict from"
    )

    @property
    def tool(self):
        """The :class:`~godobject_drake.systems.articulated.ArticulatedTool`."""
        return self.coupling.tool

    @classmethod
    def add_to_plant(cls, plant, scene_graph, scenario, device, *, check_gains=True, name="") -> dict:
        """A ball constraint from the grasp point to each body the jaws may hold (off until they do)."""
        grasp = scenario.god_object.grasp
        if not grasp.bodies:
            return {}
        model = plant.GetModelInstanceByName(scenario.god_object.model)
        tip = plant.GetBodyByName(scenario.god_object.tip_body, model)
        point = np.asarray(grasp.point_m, float)
        constraints = {}
        for scoped in grasp.bodies:
            try:  # rigid organs weld their glued sites; a body held as it is taken must move
                body = free_body(plant, scoped, welded_ok=grasp.hold == "point")
            except ValueError as e:
                where = f"tools.{name}." if name else ""
                raise sc.ScenarioError(f"{where}god_object.grasp.bodies: {e}") from None
            if grasp.hold == "pose" and not plant.GetCollisionGeometriesForBody(body):
                where = f"tools.{name}." if name else ""
                raise sc.ScenarioError(
                    f"{where}god_object.grasp.bodies: {scoped!r} has no collision geometry, and hold: pose "
                    "takes a body by its geometry (reach_m from its surface); give it one, or use hold: point"
                )
            constraints[body.scoped_name().get_full()] = (
                plant.AddBallConstraint(tip, point, body, np.zeros(3)) if grasp.hold == "point" else None,
                body.index(),
            )
        truss = []
        if grasp.hold == "pose":  # six rods, their bodies and points set when the jaws close
            first = plant.get_body(next(iter(constraints.values()))[1])
            truss = [plant.AddDistanceConstraint(tip, point, first, np.zeros(3), 0.01) for _ in TRUSS]
        return {"grasp": JawHold(grasp, tip.index(), constraints, truss)}

    @classmethod
    def build(cls, builder, scene, scenario, device, added: dict, *, check_gains=True):
        pose_device = device if isinstance(device, DeviceSource) else None
        if pose_device is not None:  # a pose device: its pose through the trocar to the joints
            device = builder.AddNamedSystem(
                "pose_to_joints", pose_to_joints(scene.plant, scenario, pose_device)
            )
        god = add_articulated(
            builder, scene, scenario.god_object, device, duration_s=scenario.simulation.duration_s,
            connect_forces=scenario.simulation.mode == "god_object", check_gains=check_gains,
            feedback_gains=scenario.feedback,
        )  # fmt: skip
        god.grasp = added.get("grasp")
        if pose_device is not None:  # the joints' feedback forces back to the device (J^T f = tau)
            plant, tool = scene.plant, god.tool
            model = plant.GetModelInstanceByName(scenario.god_object.model)
            v_device = list(tool.v_device)
            tau_at = [v_device.index(plant.GetJointByName(name, model).velocity_start())
                      for name in scenario.god_object.pose_to_joints.joints]  # fmt: skip
            if getattr(pose_device, "driver_link", False):  # a driver process: the local model too,
                # added before the wrench's publisher so that its first model leaves first (Drake
                # runs the publish events of one time in the order the systems were added): a
                # driver that heard the wrench first would trip its watchdog before the model came
                add_articulated_model(builder, scene, pose_device, device, god)
            device.connect_joint_feedback(
                builder, god.feedback.GetOutputPort("tau_device"), device.GetOutputPort("q_device"), tau_at
            )
        if god.grasp is not None:
            god.grasp.jaw_index = list(scenario.god_object.device_joints).index(god.grasp.config.jaw)
        return god

    def logged_ports(self, plant):
        ports = {**super().logged_ports(plant), "q_device": self.source.GetOutputPort("q_device")}
        if self.tissue_observer is not None:
            ports["tissue"] = self.tissue_observer.GetOutputPort("summary")
        if self.feedback.has_gains:  # Eq. 8/9 for a device of the user's own (zero gains: nothing)
            ports["feedback_subtree"] = self.feedback.GetOutputPort("F_subtree_W")
            ports["feedback_tau"] = self.feedback.GetOutputPort("tau_device")
        return ports

    def add_drawing(self, builder, meshcat, scene, scenario, drawing: Drawing = ONE_TOOL) -> None:
        """The device's tool as a wireframe ghost (the organ's tissue is the scene's to draw)."""
        period = scenario.visualization.publish_period_s
        ghost = builder.AddNamedSystem(
            "device_tool_ghost",
            ToolGhostVisualizer(meshcat, self.tool, scene.scene_graph, period,
                                f"{drawing.prefix}/device_tool", rgb=drawing.ghost_rgb, name=drawing.tool),
        )  # fmt: skip
        builder.Connect(self.source.GetOutputPort("q_device"), ghost.GetInputPort("q_device"))

    def new_metrics(self, station):
        return _ToolFold(station, self)

    def configuration(self, scenario, station) -> dict:
        out = {
            "coupling": scenario.god_object.coupling,
            "imposed_joints": list(scenario.god_object.imposed_joints),
        }
        if self.tissue is not None:  # the rigid organs' keys stay as they were
            organs = scenario.organs
            out.update(
                organs="fem",
                tissue_vertices=self.tissue.vertex_count,
                tissue_tetrahedra=self.tissue.tet_count,
                tissue_youngs_modulus_pa=organs.youngs_modulus_pa,
                **({} if organs.modulus_factor == 1.0 else {"tissue_modulus_factor": organs.modulus_factor}),
                tissue_poissons_ratio=organs.poissons_ratio,
            )
        return out

    def prepare(self, plant_context) -> None:
        """Lock the imposed joints (SAP then holds them where they are set); the jaws hold nothing."""
        self.coupling.lock_imposed(plant_context)
        if self.grasp is not None:
            self.grasp.release_all(self.coupling.tool.plant, plant_context)

    def before_step(self, plant: MultibodyPlant):
        """The imposed joints are set to the device's values (all of them in position mode); the
        jaws take or let go what they hold as they close and open."""
        coupling, grasp, source = self.coupling, self.grasp, self.source
        everything = self.mode == "position"
        impose = everything or bool(coupling.tool.imposed)
        if not (impose or grasp is not None):
            return None

        def step(plant_context, root_context):
            if impose:
                coupling.impose(plant_context, coupling.GetMyContextFromRoot(root_context), everything)
            if grasp is not None:
                q = source.GetOutputPort("q_device").Eval(source.GetMyContextFromRoot(root_context))
                grasp.update(plant, plant_context, float(q[grasp.jaw_index]))

        return step

    def contact_parts(self, plant, scene_graph) -> ToolParts:
        """Every body of its model (what the jaws hold is not the tool: a constraint holds it)."""
        return ToolParts(bodies=frozenset(int(b) for b in plant.GetBodyIndices(self.tool.model)))

    def held_bodies(self, root_context) -> set[int]:
        """What the jaws hold now."""
        return set() if self.grasp is None else {int(index) for index in self.grasp.holding.values()}


def pose_to_joints(plant, scenario, pose_device: DeviceSource) -> PoseJointDevice:
    """The device adapter of a pose device on an articulated tool (``god_object.pose_to_joints``):
    the trocar's pivot and joint ranges read from the plant."""
    config = scenario.god_object
    mapping = config.pose_to_joints
    model = plant.GetModelInstanceByName(config.model)
    try:
        trocar = TrocarKinematics.from_plant(
            plant, model, config.pivot_body, config.tip_body, mapping.joints, mapping.min_insertion_m
        )
    except ValueError as e:  # names the field itself
        raise sc.ScenarioError(str(e)) from None
    except RuntimeError as e:  # Drake: a body or joint the model does not have
        raise sc.ScenarioError(f"god_object.pose_to_joints: {e}") from None
    limits = {}
    for name in mapping.joints:
        joint = plant.GetJointByName(name, model)
        limits[name] = (float(joint.position_lower_limits()[0]), float(joint.position_upper_limits()[0]))
    try:
        return PoseJointDevice(pose_device, trocar, config.device_joints, mapping.joints, mapping.jaw_joints,
                               mapping.jaw_open_rad, limits)  # fmt: skip
    except ValueError as e:
        raise sc.ScenarioError(f"device: {e}") from None


# The pose hold's rods (JawGrasp.hold pose): three points of the tip body about the grasp point
# (a triangle of TRUSS_RADIUS_M across the tool's axis) and three of the held body (the triangle
# turned by 60° and TRUSS_OFFSET_M along the axis), each of the body's joined to two of the tip's:
# a triangular antiprism, rigid, so the body keeps its pose in the jaws.
TRUSS_RADIUS_M = 0.004
TRUSS_OFFSET_M = 0.003
TRUSS = ((0, 0), (1, 0), (1, 1), (2, 1), (2, 2), (0, 2))  # (tip point, body point) of each rod


def _triangle(turn: float) -> np.ndarray:
    a = turn + np.arange(3) * 2 * np.pi / 3
    return TRUSS_RADIUS_M * np.stack([np.cos(a), np.sin(a), np.zeros(3)], axis=1)


class JawHold:
    """The jaws' grasp at run time (:class:`~godobject_drake.config.tools.JawGrasp`): which ball
    constraint (or, holding a pose, which body the rods hold) is on, switched before a plant step as
    the jaws close and open, and when."""

    def __init__(self, config, tip_index, constraints: dict, truss: list | None = None):
        self.config, self.tip_index, self.constraints = config, tip_index, constraints
        self.truss = list(truss or [])
        self.jaw_index = 0
        self.holding: dict[str, object] = {}  # body name -> BodyIndex, while held
        self.events: list[tuple[float, str, bool]] = []  # (t, body, taken or let go)

    def _switch(self, plant, plant_context, name: str, on: bool) -> None:
        ids = self.truss if self.truss else [self.constraints[name][0]]
        for cid in ids:
            plant.SetConstraintActiveStatus(plant_context, cid, on)

    def release_all(self, plant, plant_context) -> None:
        for cid in self.truss or [c for c, _ in self.constraints.values()]:
            plant.SetConstraintActiveStatus(plant_context, cid, False)
        self.holding, self.events = {}, []

    def _nearest_origin(self, plant, plant_context, p_WP):
        best, best_d = None, self.config.reach_m
        for name, (_, index) in self.constraints.items():
            X_WB = plant.EvalBodyPoseInWorld(plant_context, plant.get_body(index))
            d = float(np.linalg.norm(X_WB.translation() - p_WP))
            if d <= best_d:
                best, best_d = name, d
        return best

    def _nearest_surface(self, plant, plant_context, p_WP):
        """The listed body whose collision geometry comes nearest the grasp point, within reach."""
        query = plant.get_geometry_query_input_port().Eval(plant_context)
        inspector = query.inspector()
        names = {int(index): name for name, (_, index) in self.constraints.items()}
        best, best_d = None, self.config.reach_m
        for found in query.ComputeSignedDistanceToPoint(p_WP, self.config.reach_m):
            body = plant.GetBodyFromFrameId(inspector.GetFrameId(found.id_G))
            name = names.get(int(body.index())) if body is not None else None
            if name is not None and found.distance <= best_d:
                best, best_d = name, float(found.distance)
        return best

    def _hold_pose(self, plant, plant_context, name: str, X_WT) -> None:
        """Set the rods from the tip to ``name`` as the two are now."""
        tip, body = plant.get_body(self.tip_index), plant.get_body(self.constraints[name][1])
        X_BW = plant.EvalBodyPoseInWorld(plant_context, body).inverse()
        point = np.asarray(self.config.point_m, float)
        on_tip = point + _triangle(0.0)
        on_body = point + _triangle(np.pi / 3) + [0.0, 0.0, TRUSS_OFFSET_M]
        for cid, (i, j) in zip(self.truss, TRUSS, strict=True):
            p_WQ = X_WT.multiply(on_body[j])
            length = float(np.linalg.norm(X_WT.multiply(on_tip[i]) - p_WQ))
            params = DistanceConstraintParams(tip.index(), on_tip[i], body.index(), X_BW.multiply(p_WQ),
                                              length, np.inf, 0.0)  # fmt: skip
            plant.SetDistanceConstraintParams(plant_context, cid, params)

    def update(self, plant, plant_context, opening: float) -> None:
        closed = opening < self.config.closed_below_rad
        if closed and not self.holding:
            X_WT = plant.EvalBodyPoseInWorld(plant_context, plant.get_body(self.tip_index))
            p_WP = X_WT.multiply(np.asarray(self.config.point_m, float))
            if self.truss:
                best = self._nearest_surface(plant, plant_context, p_WP)
            else:
                best = self._nearest_origin(plant, plant_context, p_WP)
            if best is not None:
                if self.truss:
                    self._hold_pose(plant, plant_context, best, X_WT)
                self._switch(plant, plant_context, best, True)
                self.holding[best] = self.constraints[best][1]
                self.events.append((plant_context.get_time(), best, True))
        elif not closed and self.holding:
            for name in list(self.holding):
                self._switch(plant, plant_context, name, False)
                self.events.append((plant_context.get_time(), name, False))
            self.holding = {}


class _ToolFold:
    """The articulated kind's metrics (:class:`~godobject_drake.metrics.ToolMetrics`)."""

    def __init__(self, station, god):

        plant, config = station.plant, station.scenario.god_object
        tip = config.tip_body or plant.get_body(BodyIndex(god.tool.bodies[-1].index)).name()
        self._acc = ToolMetrics(station.diagram, plant, station.scene_graph, god.tool, tip,
                                config.pivot_body or None)  # fmt: skip
        self._tissue = None
        if god.tissue_observer is not None:
            self._tissue = TissueMetrics()
        self._grasp, self._rise = god.grasp, {}
        if god.grasp is not None:  # how far each body the jaws may hold rose above its start
            for name, (_, index) in god.grasp.constraints.items():
                body = plant.get_body(index)
                if body.is_floating_base_body():
                    self._rise[name] = [body.floating_positions_start() + 6, None, 0.0]  # z, z0, rise
        self._feedback = None
        if god.feedback.has_gains:
            self._root = next(i for i, b in enumerate(god.tool.bodies) if b.parent < 0)
            self._feedback = {"max_feedback_force_N": 0.0, "feedback_force_at_max_N": [0.0, 0.0, 0.0],
                              "max_feedback_tau_device": np.zeros(len(god.tool.v_device))}  # fmt: skip

    def fold(self, rows: dict, data: dict, finite):
        self._acc.update(rows["state"], rows["q_device"])
        if self._tissue is not None:
            self._tissue.update(rows["tissue"])
        states = np.asarray(rows["state"], float)
        for rise in self._rise.values():
            if len(states):
                z = states[:, rise[0]]
                rise[1] = z[0] if rise[1] is None else rise[1]
                rise[2] = max(rise[2], float(np.max(z - rise[1])))
        if self._feedback is not None and len(rows["feedback_tau"]):
            # The root's Eq. 9 wrenches: every body's feedback moved to the root, what a device
            # holding the whole tool would feel; and the forces on the device's joints.
            f = np.asarray(rows["feedback_subtree"], float)[:, 6 * self._root + 3 : 6 * self._root + 6]
            norm = np.linalg.norm(f, axis=1)
            k = int(np.argmax(norm))
            if norm[k] > self._feedback["max_feedback_force_N"]:
                self._feedback["max_feedback_force_N"] = float(norm[k])
                self._feedback["feedback_force_at_max_N"] = [float(v) for v in f[k]]
            tau = np.max(np.abs(np.asarray(rows["feedback_tau"], float)), axis=0)
            top = self._feedback["max_feedback_tau_device"]
            self._feedback["max_feedback_tau_device"] = np.maximum(top, tau)
        return self._acc.take_tips(len(data["state"]), finite)

    def result(self) -> dict:
        out = self._acc.result()
        tissue = self._tissue.result() if self._tissue is not None else {}
        if tissue:  # the tool's penetration is into the deformed tissue (and the rigid organs')
            out["max_penetration_m"] = max(out["max_penetration_m"], tissue["tool_penetration_into_tissue_m"])
        feedback = {}
        if self._feedback is not None:
            feedback = dict(self._feedback)
            feedback["max_feedback_tau_device"] = [float(v) for v in feedback["max_feedback_tau_device"]]
        grasp = {}
        if self._grasp is not None:  # when the jaws took and let go of what, and how high it rose
            grasp["grasp_events"] = [
                f"{t:.3f} s {'took' if taken else 'let go of'} {body}"
                for t, body, taken in self._grasp.events
            ]
            grasp["grasped_max_rise_m"] = max((r[2] for r in self._rise.values()), default=0.0)
        return {
            "max_penetration_m": out["max_penetration_m"],
            "rms_tracking_error_m": out["tip_tracking_rms_m"],
            "max_other_body_speed_mps": None,
            **out,
            **tissue,
            **feedback,
            **grasp,
        }


def add_articulated(
    builder: DiagramBuilder,
    scene: SceneParts,
    config: "sc.Articulated",
    device: JointDevice,
    *,
    duration_s: float,
    connect_forces: bool = True,
    check_gains: bool = True,
    feedback_gains=None,
) -> ArticulatedGodObject:
    """An articulated god-object from its scenario config: the tool starts where the device is.

    Calls :func:`~godobject_drake.station.loop.add_joint_coupling` (checked at every
    ``config.check_every``-th device sample up to ``duration_s``), adds an
    :class:`~godobject_drake.systems.articulated.ArticulatedFeedback`
    (:func:`~godobject_drake.station.loop.add_joint_feedback`) with
    ``feedback_gains`` (the scenario's ``feedback``; zero by default: the joint-space devices here
    are non-haptic, and with gains its wrenches are logged for a device of the user's own) and
    connects the device to both.
    """
    plant = scene.plant
    if not config.self_collisions:
        exclude_self_collisions(plant, scene.scene_graph, config.model)
    q_home = device.sample(0.0)
    coupling = loop.add_joint_coupling(
        builder, plant, config.model, config.device_joints, coupling=config.coupling, gains=config.gains,
        device_period_s=device.period_s, q_reference=q_home, imposed_joints=tuple(config.imposed_joints),
        q_check=device.samples(duration_s)[:: config.check_every], connect_forces=connect_forces,
        check_gains=check_gains, bus=scene.forces,
    )  # fmt: skip
    tool = coupling.tool
    q = plant.GetDefaultPositions()
    q[tool.q_device] = q_home
    plant.SetDefaultPositions(q)  # the tool starts where the interface is
    feedback = loop.add_joint_feedback(builder, plant, device, coupling, feedback_gains)
    for name in ("q_device", "v_device"):  # the joint device is the target (no haptic chain)
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    mode = "god_object" if connect_forces else "position"
    god = ArticulatedGodObject(coupling, feedback, source=device, mode=mode)
    if scene.tissue is not None:
        god.tissue = scene.tissue
        mine = None  # one tool: every contact with the tissue is its own
        if len(scene.tool_names) > 1:  # several: each observer counts its own tool's contacts
            mine = [g for b in plant.GetBodyIndices(tool.model)
                    for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))]  # fmt: skip
        god.tissue_observer = connect_tissue_observer(
            builder, plant, scene.tissue, tool_capsules(plant, scene.scene_graph, tool.model), mine
        )
    return god
