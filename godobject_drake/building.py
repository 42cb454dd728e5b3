"""From a scenario to a diagram: plant, device, god-object, haptic chain, logs, drawing.

One call builds any scenario::

    station = build_station(load_scenario("diagrams/lego.yaml"))
    result = simulate(station)                # godobject_drake.simulation

and the pieces it is made of are public, so a diagram of one's own uses the
same ones: :func:`add_plant` (models and contact), :func:`make_device`,
:func:`add_god_object` (the rigid one-call: coupling, feedback port, haptic
device, all wired), :func:`add_articulated` and :func:`add_deformable`, and
:func:`finish` (loggers, Meshcat drawing, camera, ``Build``, the build-time
checks). The shipped scenes' scripts (``diagrams/*.py``) show that wiring in
one screen each.
"""

import dataclasses
import math
import warnings

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Meshcat, Role
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import ContactModel, MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, VectorLogSink

from godobject_drake import scenario as sc
from godobject_drake.articulated import ArticulatedFeedback, add_articulated_god_object
from godobject_drake.coupling import CouplingGains, GodObjectCoupling
from godobject_drake.deformable import add_deformable_god_object
from godobject_drake.device_kinds import kind_of
from godobject_drake.devices import DeviceSource, JointDevice
from godobject_drake.feedback import FeedbackGains, FeedbackPort
from godobject_drake.haptic import (
    AdmittanceDevice,
    HandImpedance,
    HapticDevice,
    PassivityController,
    SimulatedHand,
)
from godobject_drake.recording import (
    GodObjectVisualizer,
    ShellVisualizer,
    ToolGhostVisualizer,
    add_meshcat_visualization,
    start_meshcat,
)
from godobject_drake.scenes import SceneParts, add_bricks, exclude_self_collisions
from godobject_drake.scenes import add_plant as add_scene_plant
from godobject_drake.sleeping import SleepManager


class PenetrationBudgetWarning(UserWarning):
    """A god-object's capped pull can push it deeper into an obstacle than the scene's budget."""


# -- the plant -------------------------------------------------------------------------------------------


def add_plant(builder: DiagramBuilder, scenario: sc.Scenario, before_finalize=None) -> SceneParts:
    """The scenario's plant: its config, directives, ``bricks`` and contact settings; finalized."""

    def before(plant, scene_graph):
        if scenario.bricks:
            try:
                add_bricks(plant, scenario.bricks)
            except ValueError as e:
                raise sc.ScenarioError(str(e)) from None
        if before_finalize is not None:
            before_finalize(plant, scene_graph)

    return add_scene_plant(
        builder,
        scenario.plant,
        scenario.directives,
        scenario.contact.geometry,
        scenario.contact.relaxation_time_s,
        before,
    )


# -- devices ---------------------------------------------------------------------------------------------


def start_pose(config) -> RigidTransform:
    """Where a pose device's target starts: a path's first waypoint, a log's first row, or its start."""
    return config.start_pose()


def first_pose(device: DeviceSource) -> RigidTransform:
    """The pose a device system reports first (its t = 0 sample, noise and all)."""
    p0, q0, _ = device.samples(0.0)[0][1]
    return RigidTransform(Quaternion(q0 / np.linalg.norm(q0)), p0)


def make_device(
    config,
    *,
    seed: int = 0,
    meshcat: Meshcat | None = None,
    workspace: "sc.Workspace | None" = None,
) -> DeviceSource | JointDevice:
    """The device a scenario's ``device`` field describes (not yet added to a builder): its
    registered kind's factory (:mod:`~godobject_drake.device_kinds`).

    ``seed`` seeds the pose devices' noise; a live device (``MeshcatSliders``,
    ``MeshcatJointSliders``) needs the ``meshcat`` whose page drives it, and a pose one the
    ``workspace`` its sliders span.
    """
    kind_of(config)  # an unregistered config is refused, naming the known kinds
    try:
        config.check()
    except ValueError as e:
        raise sc.ScenarioError(f"device.{e}") from None
    try:
        return config.make(seed=seed, meshcat=meshcat, workspace=workspace)
    except ValueError as e:
        if str(e).startswith("device:"):  # what the kind needs from the scene (a Meshcat, a workspace)
            raise sc.ScenarioError(str(e)) from None
        raise


# -- god-objects -----------------------------------------------------------------------------------------


@dataclasses.dataclass
class GodObject:
    """What :func:`add_god_object`, :func:`add_articulated` or :func:`add_deformable` added.

    Attributes
    ----------
    kind : str
        ``rigid``, ``articulated`` or ``deformable``.
    coupling : GodObjectCoupling | ArticulatedCoupling
        The coupling (paper Eq. 2 or 6).
    feedback : FeedbackPort | ArticulatedFeedback
        The feedback port (paper Eq. 8): ``F_Do_W`` (or the articulated wrenches), wired
        whatever its gains, so a logger or a device of one's own can read it.
    source : DeviceSource | JointDevice
        The user's device.
    device : System
        What the coupling reads its target from: ``source``, or the haptic device in between.
    haptic : HapticDevice | AdmittanceDevice | None
    hand : SimulatedHand | None
        The simulated user on an impedance device's handle.
    passivity : PassivityController | None
    publisher : LcmPublisherSystem | None
        The feedback wrench's publisher, for a real device over LCM.
    shell, observer :
        A deformable god-object's shell and its :class:`~godobject_drake.deformable.ShellObserver`.
    mode : str
        ``god_object`` or ``position`` (the coupling's forces are not connected).
    """

    kind: str
    coupling: object
    feedback: object
    source: object
    device: object
    haptic: object = None
    hand: object = None
    passivity: object = None
    publisher: object = None
    shell: object = None
    observer: object = None
    mode: str = "god_object"

    @property
    def tool(self):
        """An articulated god-object's :class:`~godobject_drake.articulated.ArticulatedTool`."""
        return getattr(self.coupling, "tool", None)

    def device_metrics(self, root_context) -> dict:
        """The device guard's counts and the haptic loop's energies (J) at the end of a run."""
        out = dict(self.source.status(self.source.GetMyContextFromRoot(root_context)))
        if isinstance(self.haptic, HapticDevice):
            work = self.haptic.GetOutputPort("work").Eval(self.haptic.GetMyContextFromRoot(root_context))
            out["haptic_energy_to_user_j"] = float(-work[0])
            out["haptic_feedback_work_j"] = float(work[1])
        if self.passivity is not None:
            e = self.passivity.GetOutputPort("energy").Eval(self.passivity.GetMyContextFromRoot(root_context))
            out["passivity_observed_energy_j"] = float(e[0] + e[1])
            out["passivity_dissipated_j"] = float(e[2] + e[3])
        return out

    def prepare(self, plant_context) -> None:
        """Before the simulator initializes: lock an articulated tool's imposed joints."""
        if self.kind == "articulated":
            self.coupling.lock_imposed(plant_context)

    def before_step(self, plant: MultibodyPlant):
        """What must happen before every plant step, or None: the position baseline sets the
        tool to its target (paper Fig. 5); an articulated tool's imposed joints are set."""
        coupling = self.coupling
        if self.kind == "articulated":
            everything = self.mode == "position"
            if not (everything or coupling.tool.imposed):
                return None

            def impose_joints(plant_context, root_context):
                coupling.impose(plant_context, coupling.GetMyContextFromRoot(root_context), everything)

            return impose_joints
        if self.mode != "position":
            return None
        shell = self.shell

        def impose(plant_context, root_context):
            coupling_context = coupling.GetMyContextFromRoot(root_context)
            if shell is None:
                impose_target(plant, plant_context, coupling, coupling_context)
            else:
                shell.impose_core(
                    plant,
                    plant_context,
                    lambda: impose_target(plant, plant_context, coupling, coupling_context),
                )

        return impose


def hand_on_handle(haptic: "sc.Haptic") -> HandImpedance:
    """The simulated user: critically damped at ``hand_frequency_hz`` on the handle's mass."""
    w = 2 * math.pi * haptic.hand_frequency_hz
    return HandImpedance(k=haptic.device_mass_kg * w**2, b=2 * haptic.device_mass_kg * w)


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
    **coupling_options,
) -> GodObject:
    """Make the plant's free bodies god-objects of ``device``: one call, after ``plant.Finalize()``.

    Adds and wires a :class:`~godobject_drake.coupling.GodObjectCoupling` named ``name``
    (plant state in; its wrench into the plant's ``applied_generalized_force``) and a
    :class:`~godobject_drake.feedback.FeedbackPort` named ``feedback`` with
    ``feedback_gains`` (zero: a non-haptic device; any gains work, its ``F_Do_W`` output is
    there to read or to send to a device). ``device`` must already be in ``builder``; every
    grasp name it can report is checked here. ``haptic`` (a :class:`~godobject_drake.scenario.Haptic`)
    puts a simulated haptic device between ``device`` and the coupling:

    - ``impedance``: a simulated hand pushes a 3-axis :class:`~godobject_drake.haptic.HapticDevice`
      along the device's path; its pose is the target and the feedback force (optionally
      through a :class:`~godobject_drake.haptic.PassivityController`) acts on its handle;
    - ``admittance``: the hand pulls an :class:`~godobject_drake.haptic.AdmittanceDevice`'s
      handle with the coupling's own stiffness and damping; the sensed wrench drives the
      god-object, the handle follows it.

    ``connect_forces=False`` leaves the plant's force inputs alone (the position baseline).
    ``coupling_options`` go to the coupling (``carried``, ``graspable``, ``max_stretch_m``,
    ``max_twist_rad``, ``grasp_reach_m``, ``gravity_compensation``).
    """
    feedback_gains = feedback_gains or FeedbackGains()
    haptic = haptic or sc.Haptic()
    coupling = builder.AddNamedSystem(
        name, GodObjectCoupling(plant, gains, device_period_s=device.period_s, **coupling_options)
    )
    coupling.validate_grasp_names(device.grasp_names())
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    device.follow(builder, coupling)  # pseudo-haptic aids read T and G
    feedback = builder.AddNamedSystem("feedback", FeedbackPort(feedback_gains))
    god = GodObject("rigid", coupling, feedback, source=device, device=device)
    period = 1.0 / haptic.rate_hz
    p0, q0, _ = device.samples(0.0)[0][1]
    if haptic.mode == "impedance":
        handle = builder.AddNamedSystem(
            "haptic_device",
            HapticDevice(haptic.device_mass_kg, haptic.device_damping, period, axes="xyz",
                         X_WD_home=RigidTransform(p0)),
        )  # fmt: skip
        hand = builder.AddNamedSystem("hand", SimulatedHand(hand_on_handle(haptic), p0))
        builder.Connect(device.GetOutputPort("X_WD"), hand.GetInputPort("X_WH"))
        builder.Connect(device.GetOutputPort("V_WD"), hand.GetInputPort("V_WH"))
        builder.Connect(handle.GetOutputPort("device_state"), hand.GetInputPort("device_state"))
        builder.Connect(hand.GetOutputPort("human_force"), handle.GetInputPort("human_force"))
        builder.Connect(hand.GetOutputPort("q_WD"), handle.GetInputPort("q_WD"))
        builder.Connect(device.GetOutputPort("grasp"), handle.GetInputPort("grasp_in"))
        force = feedback.GetOutputPort("F_Do_W")
        if haptic.passivity_damping > 0.0:
            pc = builder.AddNamedSystem("passivity", PassivityController(period, haptic.passivity_damping))
            builder.Connect(force, pc.GetInputPort("F_in"))
            builder.Connect(handle.GetOutputPort("X_WD"), pc.GetInputPort("X_WD"))
            force = pc.GetOutputPort("F_out")
            god.passivity = pc
        builder.Connect(force, handle.GetInputPort("F_Do_W"))
        god.haptic = god.device = handle
        god.hand = hand
    elif haptic.mode == "admittance":
        names = sorted(device.grasp_names())
        if not names:
            raise ValueError(
                "haptic mode admittance sizes the hand on the first body the device grasps; it grasps none"
            )
        body = coupling.body_for_grasp(names[0])
        hand = HandImpedance.matching(coupling.gains, body.mass, float(np.trace(body.I_Bcm_B)) / 3.0)
        adm = builder.AddNamedSystem(
            "admittance_device", AdmittanceDevice(hand, period, RigidTransform(Quaternion(q0), p0))
        )
        builder.Connect(device.GetOutputPort("X_WD"), adm.GetInputPort("X_WH"))
        builder.Connect(device.GetOutputPort("V_WD"), adm.GetInputPort("V_WH"))
        builder.Connect(device.GetOutputPort("grasp"), adm.GetInputPort("grasp_in"))
        for port in ("pose_WG", "V_WG"):
            builder.Connect(coupling.GetOutputPort(port), adm.GetInputPort(port))
        builder.Connect(adm.GetOutputPort("F_device_W"), coupling.GetInputPort("F_device_W"))
        god.haptic = god.device = adm
    for port in ("X_WD", "V_WD", "grasp"):
        builder.Connect(god.device.GetOutputPort(port), coupling.GetInputPort(port))
    if connect_forces:
        builder.Connect(
            coupling.GetOutputPort("generalized_force"), plant.get_applied_generalized_force_input_port()
        )
    else:
        god.mode = "position"
    builder.Connect(god.device.GetOutputPort("X_WD"), feedback.GetInputPort("X_WD"))
    for port in ("pose_WT", "V_WT", "pose_WG", "V_WG"):
        builder.Connect(coupling.GetOutputPort(port), feedback.GetInputPort(port))
    god.publisher = device.connect_feedback(builder, feedback.GetOutputPort("F_Do_W"), coupling.bodies)
    return god


def coupling_options(config: "sc.Rigid") -> dict:
    """A :class:`~godobject_drake.scenario.Rigid` config's options for :func:`add_god_object`."""
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


def add_articulated(
    builder: DiagramBuilder,
    scene: SceneParts,
    config: "sc.Articulated",
    device: JointDevice,
    *,
    duration_s: float,
    connect_forces: bool = True,
    check_gains: bool = True,
) -> GodObject:
    """An articulated god-object from its scenario config: the tool starts where the device is.

    Calls :func:`~godobject_drake.articulated.add_articulated_god_object` (checked at every
    ``config.check_every``-th device sample up to ``duration_s``), adds an
    :class:`~godobject_drake.articulated.ArticulatedFeedback` named ``feedback`` (zero gains:
    the joint-space devices here are non-haptic) and connects the device to both.
    """
    plant = scene.plant
    if not config.self_collisions:
        exclude_self_collisions(plant, scene.scene_graph, config.model)
    q_home = device.sample(0.0)
    coupling = add_articulated_god_object(
        builder, plant, config.model, config.device_joints, coupling=config.coupling, gains=config.gains,
        device_period_s=device.period_s, q_reference=q_home, imposed_joints=tuple(config.imposed_joints),
        q_check=device.samples(duration_s)[:: config.check_every], connect_forces=connect_forces,
        check_gains=check_gains,
    )  # fmt: skip
    tool = coupling.tool
    q = plant.GetDefaultPositions()
    q[tool.q_device] = q_home
    plant.SetDefaultPositions(q)  # the tool starts where the interface is
    feedback = builder.AddNamedSystem("feedback", ArticulatedFeedback(tool))
    for name in ("q_device", "v_device"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(device.GetOutputPort("q_device"), feedback.GetInputPort("q_device"))
    builder.Connect(coupling.GetOutputPort("targets"), feedback.GetInputPort("targets"))
    builder.Connect(plant.get_body_poses_output_port(), feedback.GetInputPort("body_poses"))
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), feedback.GetInputPort("body_spatial_velocities")
    )
    mode = "god_object" if connect_forces else "position"
    return GodObject("articulated", coupling, feedback, source=device, device=device, mode=mode)


def add_deformable(
    builder: DiagramBuilder,
    plant: MultibodyPlant,
    shell,
    device: DeviceSource,
    gains: CouplingGains,
    feedback_gains: FeedbackGains | None = None,
    *,
    haptic: "sc.Haptic | None" = None,
    connect_forces: bool = True,
    check_gains: bool = True,
) -> GodObject:
    """A deformable god-object: its shell's observer, and :func:`add_god_object` on its core,
    with gains and gravity compensation scaled by core + shell (``carried``).

    ``shell`` comes from :func:`~godobject_drake.deformable.add_deformable_god_object`,
    called before ``plant.Finalize()`` (:func:`add_plant`'s ``before_finalize``).
    """
    observer = shell.connect(builder, plant)
    god = add_god_object(
        builder, plant, device, gains, feedback_gains, haptic=haptic, connect_forces=connect_forces,
        carried={shell.grasp_name: shell.shell_inertia()}, check_gains=check_gains,
    )  # fmt: skip
    god.kind, god.shell, god.observer = "deformable", shell, observer
    return god


# -- logs, drawing, the finished station -----------------------------------------------------------------


@dataclasses.dataclass
class Station:
    """A built scenario: the diagram and handles to its parts (what :func:`build_station` returns).

    Attributes
    ----------
    scenario : Scenario
        What it was built from.
    diagram : Diagram
    plant, scene_graph :
        Drake's MultibodyPlant and SceneGraph.
    god_object : GodObject
        The coupling, feedback port, device and haptic parts.
    loggers : dict[str, VectorLogSink]
        Per-step logs the metrics read: ``state`` always; ``terms`` (rigid),
        ``q_device`` (articulated), ``pose_WT``, ``vertex_positions``, ``rest_positions``,
        ``pose_WC`` (deformable). Add one's own before ``Build`` and read it from the
        run's context.
    meshcat : Meshcat | None
    predicted_penetration_m : float | None
        Deepest static penetration the god-object's capped pull could cause (m), None where
        it cannot be predicted (:func:`predict_penetration`).
    sleeper : SleepManager | None
        Locks resting free bodies (``scenario.sleep``); rigid and deformable god-objects (an
        articulated tool's bodies are not free bodies it could watch).
    """

    scenario: sc.Scenario
    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: object
    god_object: GodObject
    loggers: dict[str, VectorLogSink]
    meshcat: Meshcat | None = None
    predicted_penetration_m: float | None = None
    sleeper: SleepManager | None = None

    @property
    def device(self):
        """The user's device."""
        return self.god_object.source

    @property
    def coupling(self):
        return self.god_object.coupling

    @property
    def feedback(self):
        return self.god_object.feedback

    @property
    def live(self) -> bool:
        """Driven from the browser (the device kind says so)."""
        return kind_of(self.scenario.device).live


def make_meshcat(scenario: sc.Scenario) -> Meshcat | None:
    """The scenario's Meshcat, on ``visualization.host`` (this machine only, by default): at
    ``visualization.port`` when it is live (``visualization.serve`` or a browser device), on
    any free port for a recording only, None otherwise (:func:`~godobject_drake.recording.start_meshcat`)."""
    vis = scenario.visualization
    if vis.serve or kind_of(scenario.device).live:
        return start_meshcat(vis.host, vis.port)
    return start_meshcat(vis.host, 0) if scenario.recording.file else None


def add_loggers(builder: DiagramBuilder, plant: MultibodyPlant, god: GodObject) -> dict[str, VectorLogSink]:
    """Per-step logs of what the metrics need (each logged port costs a call per step)."""
    ports = {"state": plant.get_state_output_port()}
    if god.kind == "rigid":
        ports["terms"] = god.coupling.GetOutputPort("terms")
    elif god.kind == "articulated":
        ports["q_device"] = god.source.GetOutputPort("q_device")
    else:
        ports["pose_WT"] = god.coupling.GetOutputPort("pose_WT")
        for name in ("vertex_positions", "rest_positions", "pose_WC"):
            ports[name] = god.observer.GetOutputPort(name)
    loggers = {}
    for name, port in ports.items():
        loggers[name] = LogVectorOutput(port, builder, plant.time_step())
        loggers[name].set_name(f"{name}_log")  # named, so GetGraphvizString reads well
    return loggers


def add_visualization(
    builder: DiagramBuilder, meshcat: Meshcat, scene: SceneParts, god: GodObject, scenario: sc.Scenario
) -> None:
    """Drake's MeshcatVisualizer, and the god-object's own drawing: the target ghost and spring
    (rigid), the device's tool as a wireframe (articulated), the shell and device ghost (deformable)."""
    period = scenario.visualization.publish_period_s
    add_meshcat_visualization(builder, meshcat, scene.scene_graph, period)
    if god.kind == "rigid":
        ghost = builder.AddNamedSystem(
            "god_object_visualizer",
            GodObjectVisualizer(
                meshcat, scene.plant, scene.scene_graph, period,
                max_stretch_m=god.coupling.max_stretch_m if scenario.visualization.force_cue else None,
            ),
        )  # fmt: skip
        for name in ("pose_WT", "pose_WG", "held_body"):
            builder.Connect(god.coupling.GetOutputPort(name), ghost.GetInputPort(name))
    elif god.kind == "articulated":
        ghost = builder.AddNamedSystem(
            "device_tool_ghost", ToolGhostVisualizer(meshcat, god.tool, scene.scene_graph, period)
        )
        builder.Connect(god.source.GetOutputPort("q_device"), ghost.GetInputPort("q_device"))
    else:
        drawing = builder.AddNamedSystem("shell_visualizer", ShellVisualizer(meshcat, god.shell, period))
        builder.Connect(
            god.observer.GetOutputPort("vertex_positions"), drawing.GetInputPort("vertex_positions")
        )
        builder.Connect(god.observer.GetOutputPort("pose_WC"), drawing.GetInputPort("pose_WC"))
        builder.Connect(god.coupling.GetOutputPort("pose_WT"), drawing.GetInputPort("pose_WT"))
    camera = scenario.visualization.camera
    if camera is not None:
        meshcat.SetCameraPose(np.asarray(camera.position_m, float), np.asarray(camera.target_m, float))


def finish(
    builder: DiagramBuilder,
    scenario: sc.Scenario,
    scene: SceneParts,
    god: GodObject,
    meshcat: Meshcat | None = None,
) -> Station:
    """Add the loggers and the drawing, build the diagram, check the wiring and the penetration budget."""
    loggers = add_loggers(builder, scene.plant, god)
    if meshcat is not None:
        add_visualization(builder, meshcat, scene, god, scenario)
    diagram = builder.Build()
    from godobject_drake.safeguards import check_wiring

    check_wiring(diagram, mode=god.mode)
    predicted = predict_penetration(scene, god, scenario.plant.penetration_allowance)
    budget = scenario.metrics.penetration_budget_m
    if predicted is not None and predicted[0] > budget:
        depth, body, obstacle, force, k = predicted
        w_max = god.coupling.gains.omega_n * math.sqrt(budget / depth)
        stretch_max = god.coupling.max_stretch_m * budget / depth
        warnings.warn(
            f"{body}'s capped pull ({force:.3g} N) can push it {depth * 1e3:.3g} mm into {obstacle} "
            f"(their point contacts combine to {k:.3g} N/m), past the scene's penetration budget "
            f"{budget * 1e3:.3g} mm. Fix: omega_n ≤ {w_max:.3g} rad/s, or max_stretch_m ≤ "
            f"{stretch_max:.3g} m, or point_contact_stiffness values that combine "
            f"(k_A k_B / (k_A + k_B)) to ≥ {force / budget:.3g} N/m",
            PenetrationBudgetWarning,
            stacklevel=2,
        )
    sleeper = None
    if scenario.sleep.enabled and god.kind != "articulated":
        sleeper = SleepManager(scene.plant, scene.scene_graph, scenario.sleep, god.coupling, meshcat)
    return Station(
        scenario, diagram, scene.plant, scene.scene_graph, god, loggers, meshcat,
        predicted[0] if predicted else None, sleeper,
    )  # fmt: skip


def build_station(
    scenario: sc.Scenario, meshcat: Meshcat | None = None, *, check_gains: bool = True
) -> Station:
    """Build any scenario into a diagram (module docstring); ``meshcat`` None makes the one
    the scenario asks for (:func:`make_meshcat`). ``check_gains=False`` builds gains past
    the explicit limit instead of refusing them: for stability analysis only
    (:mod:`godobject_drake.analyze` simulates them to find the limit)."""
    sc.check_scenario(scenario)
    meshcat = meshcat or make_meshcat(scenario)
    builder = DiagramBuilder()
    device = builder.AddNamedSystem(
        "device",
        make_device(
            scenario.device, seed=scenario.random_seed, meshcat=meshcat, workspace=scenario.workspace
        ),
    )
    god_config, haptic = scenario.god_object, scenario.haptic
    connect = scenario.simulation.mode == "god_object"
    if scenario.kind == "articulated":
        scene = add_plant(builder, scenario)
        duration = scenario.simulation.duration_s
        god = add_articulated(
            builder, scene, god_config, device, duration_s=duration, connect_forces=connect,
            check_gains=check_gains,
        )  # fmt: skip
    elif scenario.kind == "deformable":
        if check_gains:
            god_config.gains.check(scenario.time_step)  # before meshing anything
        X_WC = first_pose(device)  # the probe starts at the device
        shells = {}

        def add_shell(plant, scene_graph):
            shells["shell"] = add_deformable_god_object(
                plant, scene_graph, god_config.shell, god_config.spec, X_WC, god_config.name
            )

        scene = add_plant(builder, scenario, before_finalize=add_shell)
        god = add_deformable(
            builder, scene.plant, shells["shell"], device, god_config.gains, scenario.feedback,
            haptic=haptic, connect_forces=connect, check_gains=check_gains,
        )  # fmt: skip
    else:
        scene = add_plant(builder, scenario)
        god = add_god_object(
            builder, scene.plant, device, god_config.gains, scenario.feedback, haptic=haptic,
            connect_forces=connect, check_gains=check_gains, **coupling_options(god_config),
        )  # fmt: skip
    return finish(builder, scenario, scene, god, meshcat)


# -- what the god-object's pull can do to contact --------------------------------------------------------


def predict_penetration(scene: SceneParts, god: GodObject, penetration_allowance: float = 1e-3):
    """The deepest static penetration a held body's capped pull can cause, or None.

    For each body the coupling may hold and each rigid obstacle geometry its own geometry
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
    if god.kind != "rigid":
        return None
    pairs = penetration_pairs(
        scene.plant, scene.scene_graph, god.coupling, penetration_allowance, softest=True
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

    @property
    def depth_m(self) -> float:
        """Static penetration under the capped pull, one contact point (m)."""
        return self.force_n / self.stiffness_n_m


def penetration_pairs(
    plant, scene_graph, coupling, penetration_allowance: float = 1e-3, softest: bool = False
) -> list[ContactPair]:
    """Every (held body geometry, obstacle geometry) pair that can touch, with the coupling's
    force cap on the body and the pair's combined stiffness (:func:`predict_penetration`);
    empty without point contact. ``softest``: only, for each held geometry, the softest obstacle
    it can touch (the deepest pair, found by trying obstacles from the softest up: what the
    prediction needs, without the bodies × geometries² loop that took 18 s for 128 bricks)."""
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
    stiffness = {b: _stiffness(inspector, b, default_k) for b in ids}
    if softest:
        ids = sorted(ids, key=lambda b: stiffness[b])
    pairs = []
    for body in {b.index: b for b in coupling.bodies.values()}.values():
        force, _ = coupling.force_caps(body)
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
                    ))  # fmt: skip
                    if softest:
                        break
    return pairs


def _stiffness(inspector, geometry_id, default: float) -> float:
    props = inspector.GetProximityProperties(geometry_id)
    if props is not None and props.HasProperty("material", "point_contact_stiffness"):
        return float(props.GetProperty("material", "point_contact_stiffness"))
    return default
