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
import logging
import math
import warnings

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import VectorLogSink

from godobject_drake.config import scenario as sc
from godobject_drake.config.devices import kind_of
from godobject_drake.devices import factory
from godobject_drake.devices.sources import DeviceSource, JointDevice
from godobject_drake.sleeping import SleepManager
from godobject_drake.station.articulated_tool import (
    ArticulatedGodObject,
    add_articulated,  # noqa: F401  (public here)
)
from godobject_drake.station.deformable_tool import (
    DeformableGodObject,
    add_deformable,  # noqa: F401
)
from godobject_drake.station.kinds import GodObject
from godobject_drake.station.plant import SceneParts
from godobject_drake.station.rigid_tool import (  # noqa: F401  the one-call helpers, public here too
    ContactPair,
    PenetrationBudgetWarning,
    RigidGodObject,
    add_god_object,
    coupling_options,
    hand_on_handle,
    impose_target,
    penetration_pairs,
    predict_penetration,
)
from godobject_drake.systems.drawing import add_meshcat_visualization, start_meshcat

KINDS = {
    sc.Rigid: RigidGodObject,
    sc.Articulated: ArticulatedGodObject,
    sc.Deformable: DeformableGodObject,
}


def kind_for(config):
    """The kind class of a scenario's ``god_object`` config; an unknown one is refused, naming the known."""
    try:
        return KINDS[type(config)]
    except KeyError:
        known = ", ".join(f"!{c.__name__}" for c in KINDS)
        raise ValueError(
            f"god_object: {type(config).__name__} is not a god-object kind; the kinds are {known}"
        ) from None


# -- the plant -------------------------------------------------------------------------------------------


# -- devices ---------------------------------------------------------------------------------------------


def start_pose(config) -> RigidTransform:
    """Where a pose device's target starts: a path's first waypoint, a log's first row, or its start."""
    return config.start_pose()


def make_device(
    config,
    *,
    seed: int = 0,
    meshcat: Meshcat | None = None,
    workspace: "sc.Workspace | None" = None,
    duration_s: float = math.inf,
) -> DeviceSource | JointDevice:
    """The device a scenario's ``device`` field describes (not yet added to a builder): its
    registered kind's factory (:func:`godobject_drake.devices.factory.make_device`), its errors
    as a :class:`~godobject_drake.config.scenario.ScenarioError` naming the field.

    ``seed`` seeds the pose devices' noise; a live device (``MeshcatSliders``,
    ``MeshcatJointSliders``) needs the ``meshcat`` whose page drives it, and a pose one the
    ``workspace`` its sliders span. ``duration_s``: the run's length, so a log is read only as far
    as the run reaches (a log of any length costs what the run uses).
    """
    kind_of(config)  # an unregistered config is refused, naming the known kinds
    try:
        config.check()
    except ValueError as e:
        raise sc.ScenarioError(f"device.{e}") from None
    try:
        return factory.make_device(
            config, seed=seed, meshcat=meshcat, workspace=workspace, duration_s=duration_s
        )
    except ValueError as e:
        if str(e).startswith("device:"):  # what the kind needs from the scene (a Meshcat, a workspace)
            raise sc.ScenarioError(str(e)) from None
        raise


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
    any free port for a recording only, None otherwise
    (:func:`~godobject_drake.systems.drawing.start_meshcat`)."""
    vis = scenario.visualization
    if vis.serve or kind_of(scenario.device).live:
        return start_meshcat(vis.host, vis.port)
    if not scenario.recording.file:
        return None
    # A Meshcat that only records: nobody is to open it, so Drake's "Meshcat listening for
    # connections at ..." (its INFO log) is not shown; a non-loopback host is still announced.
    drake_log = logging.getLogger("drake")
    level = drake_log.level
    drake_log.setLevel(max(level, logging.WARNING))
    try:
        return start_meshcat(vis.host, 0)
    finally:
        drake_log.setLevel(level)


def add_loggers(builder: DiagramBuilder, plant: MultibodyPlant, god: GodObject) -> dict[str, VectorLogSink]:
    """Per-step logs of what the metrics need: the god-object kind's (``god.logged_ports``)."""
    return god.add_loggers(builder, plant)


def add_visualization(
    builder: DiagramBuilder, meshcat: Meshcat, scene: SceneParts, god: GodObject, scenario: sc.Scenario
) -> None:
    """Drake's MeshcatVisualizer, the god-object kind's own drawing, and the scenario's camera."""
    add_meshcat_visualization(builder, meshcat, scene.scene_graph, scenario.visualization.publish_period_s)
    god.add_drawing(builder, meshcat, scene, scenario)
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
    predicted = god.predict_penetration(scene, scenario.plant.penetration_allowance)
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
    if scenario.sleep.enabled and god.sleeps_others:
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
    (:mod:`godobject_drake.studies.analyze` simulates them to find the limit)."""
    sc.check_scenario(scenario)
    meshcat = meshcat or make_meshcat(scenario)
    builder = DiagramBuilder()
    device = builder.AddNamedSystem(
        "device",
        make_device(
            scenario.device, seed=scenario.random_seed, meshcat=meshcat, workspace=scenario.workspace,
            duration_s=scenario.simulation.duration_s,
        ),
    )  # fmt: skip
    scene, god = kind_for(scenario.god_object).build(builder, scenario, device, check_gains=check_gains)
    return finish(builder, scenario, scene, god, meshcat)
