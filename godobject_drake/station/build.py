"""From a scenario to a diagram, in one straight line: :func:`build_station`.

::

    station = build_station(load_scenario("diagrams/lego.yaml"))
    result = simulate(station)                # godobject_drake.simulation

Every entry point (the command line, the scene scripts, ``analyze``, the benchmarks, the
notebooks) builds through it; a diagram of one's own composes the same parts
(:mod:`~godobject_drake.station.plant`, :mod:`~godobject_drake.station.loop`, the tool kinds'
builders) and ends with :func:`finish`. The tool's kind is the one registered for the scenario's
``god_object`` config (:func:`~godobject_drake.station.kinds.kind_for`); everything that differs
by kind is asked of it.
"""

import dataclasses
import logging
import math
import warnings

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import VectorLogSink

from godobject_drake.config import scenario as sc
from godobject_drake.config.devices import kind_of
from godobject_drake.safeguards import check_wiring
from godobject_drake.sleeping import SleepManager
from godobject_drake.station.kinds import GodObject, kind_for
from godobject_drake.station.loop import add_device
from godobject_drake.station.plant import SceneParts, add_plant
from godobject_drake.station.rigid_tool import PenetrationBudgetWarning
from godobject_drake.systems.drawing import add_meshcat_visualization, start_meshcat


def build_station(
    scenario: sc.Scenario, meshcat: Meshcat | None = None, *, check_gains: bool = True
) -> "Station":
    """Build any scenario into a diagram (module docstring); ``meshcat`` None makes the one
    the scenario asks for (:func:`make_meshcat`). ``check_gains=False`` builds gains past
    the explicit limit instead of refusing them: for stability analysis only
    (:mod:`godobject_drake.studies.analyze` simulates them to find the limit)."""
    sc.check_scenario(scenario)
    meshcat = meshcat or make_meshcat(scenario)
    builder = DiagramBuilder()
    kind = kind_for(scenario.god_object)
    device = add_device(builder, scenario, meshcat)
    added = {}

    def before_finalize(plant, scene_graph):
        added.update(kind.add_to_plant(plant, scene_graph, scenario, device, check_gains=check_gains))

    scene = add_plant(builder, scenario, before_finalize)
    god = kind.build(builder, scene, scenario, device, added, check_gains=check_gains)
    return finish(builder, scenario, scene, god, meshcat)


def finish(
    builder: DiagramBuilder,
    scenario: sc.Scenario,
    scene: SceneParts,
    god: GodObject,
    meshcat: Meshcat | None = None,
) -> "Station":
    """The loggers and the drawing added, the diagram built, its wiring and penetration budget
    checked, resting bodies put to sleep where the tool allows: the :class:`Station`."""
    loggers = god.add_loggers(builder, scene.plant)
    if meshcat is not None:
        add_visualization(builder, meshcat, scene, god, scenario)
    diagram = builder.Build()
    check_wiring(diagram, mode=god.mode)
    predicted = check_penetration_budget(god, scene, scenario)
    sleeper = None
    if scenario.sleep.enabled and god.sleeps_others:
        sleeper = SleepManager(scene.plant, scene.scene_graph, scenario.sleep, god.coupling, meshcat)
    return Station(
        scenario, diagram, scene.plant, scene.scene_graph, god, loggers, meshcat, predicted, sleeper
    )


def check_penetration_budget(god: GodObject, scene: SceneParts, scenario: sc.Scenario) -> float | None:
    """The deepest static penetration the tool's capped pull can cause (m; None where it cannot be
    predicted), with a :class:`PenetrationBudgetWarning` naming the fix when it is past the
    scenario's budget."""
    predicted = god.predict_penetration(scene, scenario.plant.penetration_allowance)
    if predicted is None:
        return None
    budget = scenario.metrics.penetration_budget_m
    depth, body, obstacle, force, k = predicted
    if depth > budget:
        w_max = god.coupling.gains.omega_n * math.sqrt(budget / depth)
        stretch_max = god.coupling.max_stretch_m * budget / depth
        warnings.warn(
            f"{body}'s capped pull ({force:.3g} N) can push it {depth * 1e3:.3g} mm into {obstacle} "
            f"(their point contacts combine to {k:.3g} N/m), past the scene's penetration budget "
            f"{budget * 1e3:.3g} mm. Fix: omega_n ≤ {w_max:.3g} rad/s, or max_stretch_m ≤ "
            f"{stretch_max:.3g} m, or point_contact_stiffness values that combine "
            f"(k_A k_B / (k_A + k_B)) to ≥ {force / budget:.3g} N/m",
            PenetrationBudgetWarning,
            stacklevel=3,
        )
    return depth


def add_visualization(
    builder: DiagramBuilder, meshcat: Meshcat, scene: SceneParts, god: GodObject, scenario: sc.Scenario
) -> None:
    """Drake's MeshcatVisualizer, the god-object kind's own drawing, and the scenario's camera."""
    add_meshcat_visualization(builder, meshcat, scene.scene_graph, scenario.visualization.publish_period_s)
    god.add_drawing(builder, meshcat, scene, scenario)
    camera = scenario.visualization.camera
    if camera is not None:
        meshcat.SetCameraPose(np.asarray(camera.position_m, float), np.asarray(camera.target_m, float))


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
