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
import warnings

from pydrake.geometry import Meshcat
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, VectorLogSink

from godobject_drake.config import scenario as sc
from godobject_drake.metrics import PenetrationBudgetWarning
from godobject_drake.safeguards import check_wiring
from godobject_drake.sleeping import SleepManager
from godobject_drake.station.kinds import GodObject, kind_for
from godobject_drake.station.loop import add_device, share_grasps
from godobject_drake.station.plant import SceneParts, add_plant, check_start_overlaps
from godobject_drake.station.rigid_tool import penetration_fix
from godobject_drake.systems.contacts import ContactMeter
from godobject_drake.systems.drawing import (
    Drawing,
    TissueVisualizer,
    add_meshcat_visualization,
    draw_soft_body_here,
    soft_body_legend,
    start_meshcat,
)
from godobject_drake.systems.page import set_view
from godobject_drake.task_score import TaskError, resolve_task


def build_station(
    scenario: sc.Scenario,
    meshcat: Meshcat | None = None,
    *,
    check_gains: bool = True,
    records: dict | None = None,
) -> "Station":
    """Build any scenario into a diagram (module docstring); ``meshcat`` None makes the one
    the scenario asks for (:func:`make_meshcat`). ``check_gains=False`` builds gains past
    the explicit limit instead of refusing them: for stability analysis only
    (:mod:`godobject_drake.studies.analyze` simulates them to find the limit). A scene of several
    tools builds each tool's loop alike on the one plant, its systems named ``NAME/...``; each
    tool is resolved once, by the check (:class:`~godobject_drake.config.scenario.ToolRecord`):
    ``records`` are what :func:`~godobject_drake.config.scenario.check_scenario` returned for this
    scenario, unchanged since (the command line checks once, naming its flags); None checks it."""
    if records is None:
        records = sc.check_scenario(scenario)
    meshcat = meshcat or _meshcat(scenario, records)
    builder = DiagramBuilder()
    kinds = {name: kind_for(r.view.god_object) for name, r in records.items()}
    devices = {name: add_device(builder, r, meshcat) for name, r in records.items()}
    added = {name: {} for name in records}

    def before_finalize(plant, scene_graph):
        for name, r in records.items():
            added[name].update(
                kinds[name].add_to_plant(
                    plant, scene_graph, r.view, devices[name], check_gains=check_gains, name=name
                )
            )

    scene = add_plant(builder, scenario, before_finalize)
    tools = {}
    for name, r in records.items():
        before = set(builder.GetSystems())
        tools[name] = kinds[name].build(
            builder, scene, r.view, devices[name], added[name], check_gains=check_gains
        )
        for system in set(builder.GetSystems()) - before:
            system.set_name(r.named(system.get_name()))
    check_grasps(tools)
    share_grasps(builder, [tool.coupling for tool in tools.values() if tool.holds_free_bodies])
    return _finish(builder, scenario, scene, tools, meshcat, records)


def check_grasps(tools: dict[str, GodObject]) -> None:
    """Two tools whose devices grasp one body at the same time are refused, naming both, the body
    and when (a body is held by one tool at a time); a grasp decided at run time (a live or real
    device's ``*``) is arbitrated then: see :class:`~godobject_drake.systems.coupling.GraspingCoupling`."""
    if len(tools) < 2:
        return
    spans = {name: tool.grasp_spans() for name, tool in tools.items()}
    names = list(spans)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            for body, (a0, a1) in spans[a].items():
                if body in spans[b]:
                    b0, b1 = spans[b][body]
                    if a0 <= b1 and b0 <= a1:
                        raise sc.ScenarioError(
                            f"tools.{a} and tools.{b} both grasp {body} from t = {max(a0, b0):g} s to "
                            f"{min(a1, b1):g} s: a body is held by one tool at a time; change one device's "
                            "path (its grasp) so they take turns, or let each hold its own body"
                        )


def finish(
    builder: DiagramBuilder,
    scenario: sc.Scenario,
    scene: SceneParts,
    tools: "dict[str, GodObject] | GodObject",
    meshcat: Meshcat | None = None,
) -> "Station":
    """The loggers and the drawing added, the diagram built, its wiring and penetration budget
    checked, resting bodies put to sleep where the tools allow: the :class:`Station`. ``tools``:
    the tools by name, or one tool (a diagram of one's own)."""
    if isinstance(tools, GodObject):
        tools = {"": tools}
    own = set(tools) != set(scenario.tools or {""})  # tools of one's own: each sees the whole scenario
    records = sc.tool_records(scenario, names=list(tools) if own else None)
    return _finish(builder, scenario, scene, tools, meshcat, records)


def _finish(
    builder: DiagramBuilder,
    scenario: sc.Scenario,
    scene: SceneParts,
    tools: dict[str, GodObject],
    meshcat: Meshcat | None,
    records: dict[str, sc.ToolRecord],
) -> "Station":
    """:func:`finish`, given each tool's record."""
    task = None
    if scenario.task.objects:  # its names checked against the plant before anything is built on it
        try:
            task = resolve_task(scene.plant, scenario.task)
        except TaskError as e:
            raise sc.ScenarioError(str(e)) from None
    if scene.forces is not None:
        scene.forces.connect(builder)  # every tool's forces into the plant
    loggers, tool_loggers = add_loggers(builder, scene.plant, tools, records)
    meter = (
        add_contact_meter(builder, scene, tools, loggers, tool_loggers)
        if scenario.metrics.tool_forces
        else None
    )
    soft_loggers, soft_observers = add_soft_body_observers(builder, scene, scenario)
    if meshcat is not None:
        add_visualization(builder, meshcat, scene, tools, scenario, records)
        period = scenario.visualization.publish_period_s
        for name, observer in soft_observers.items():  # each soft body drawn deforming
            body = scene.soft_bodies[name]
            drawing = builder.AddNamedSystem(
                f"{name}_soft_body_visualizer",
                TissueVisualizer(meshcat, body, period, soft_body_legend(name)),
            )
            draw_soft_body_here(scene.plant, scene.scene_graph, body.geometry_id)
            builder.Connect(
                observer.GetOutputPort("surface_positions"), drawing.GetInputPort("surface_positions")
            )
    diagram = builder.Build()
    check_start_overlaps(diagram, scene.plant, scene.scene_graph, scenario.plant.penetration_allowance)
    predicted = []
    for name, tool in tools.items():
        check_wiring(diagram, mode=tool.mode)
        depth = check_penetration_budget(tool, scene, records[name].view)
        if depth is not None:
            predicted.append(depth)
    sleeper = None
    if scenario.sleep.enabled and all(tool.sleeps_others for tool in tools.values()):
        couplings = [tool.coupling for tool in tools.values()]  # every tool's device wakes what it nears
        sleeper = SleepManager(scene.plant, scene.scene_graph, scenario.sleep, couplings, meshcat)
    return Station(
        scenario, diagram, scene.plant, scene.scene_graph, tools, loggers, meshcat,
        max(predicted) if predicted else None, sleeper, tool_loggers, records,
        soft_loggers=soft_loggers, soft_bodies=scene.soft_bodies, task=task, contact_meter=meter,
    )  # fmt: skip


def add_loggers(
    builder: DiagramBuilder, plant, tools: dict[str, GodObject], records: dict[str, sc.ToolRecord]
):
    """Per-step logs of what the metrics read: each tool's (``logged_ports``), the plant's state
    once. Returns ``(loggers by name, each tool's {its own name: the logger's name})``; in a scene
    of one tool the names are the tool's own (``state``, ``terms``, ...)."""
    loggers, tool_loggers = {}, {}
    for name, tool in tools.items():
        tool_loggers[name] = {}
        for key, port in tool.logged_ports(plant).items():
            full = key if key == "state" else records[name].named(key)
            if full not in loggers:
                loggers[full] = LogVectorOutput(port, builder, plant.time_step())
                loggers[full].set_name(f"{full}_log")  # named, so GetGraphvizString reads well
            tool_loggers[name][key] = full
    return loggers, tool_loggers


def add_contact_meter(builder: DiagramBuilder, scene: SceneParts, tools: dict[str, GodObject], loggers: dict,
                      tool_loggers: dict) -> ContactMeter:  # fmt: skip
    """The :class:`~godobject_drake.systems.contacts.ContactMeter` of every tool's contacts, on the
    plant's contact results, and its per-step log ``contacts``, which every tool's logs share (as
    ``state``)."""
    plant = scene.plant
    parts = {name: tool.contact_parts(plant, scene.scene_graph) for name, tool in tools.items()}
    meter = builder.AddNamedSystem("contact_meter", ContactMeter(plant, scene.scene_graph, parts))
    builder.Connect(plant.get_contact_results_output_port(), meter.GetInputPort("contact_results"))
    for instance, port in meter.instance_ports.items():
        builder.Connect(
            plant.get_generalized_contact_forces_output_port(ModelInstanceIndex(instance)),
            meter.GetInputPort(port),
        )
    for name, tool in tools.items():
        if parts[name].holds:
            builder.Connect(tool.held_body_port(), meter.GetInputPort(f"held_body_{name or 'tool'}"))
    loggers["contacts"] = LogVectorOutput(meter.GetOutputPort("contacts"), builder, plant.time_step())
    loggers["contacts"].set_name("contacts_log")
    for names in tool_loggers.values():
        names["contacts"] = "contacts"
    return meter


def add_soft_body_observers(builder: DiagramBuilder, scene: SceneParts, scenario: sc.Scenario):
    """Each soft body's observer (its glued sites not counted as what presses it) and a per-step
    logger of its summary: ``(loggers, observers)``, by the soft body's name."""
    loggers, observers = {}, {}
    for name, body in scene.soft_bodies.items():
        observer = body.connect(builder, scene.plant, scene.scene_graph, ignored_bodies=body.glued_bodies)
        observers[name] = observer
        loggers[name] = LogVectorOutput(observer.GetOutputPort("summary"), builder, scene.plant.time_step())
        loggers[name].set_name(f"{name}_soft_body_log")
    return loggers, observers


def check_penetration_budget(god: GodObject, scene: SceneParts, scenario: sc.Scenario) -> float | None:
    """The deepest static penetration the tool's capped pull can cause (m; None where it cannot be
    predicted), with a :class:`PenetrationBudgetWarning` naming the fix when it is past the
    scenario's budget."""
    predicted = god.predict_penetration(
        scene, scenario.plant.penetration_allowance, scenario.simulation.duration_s
    )
    if predicted is None:
        return None
    budget = scenario.metrics.penetration_budget_m
    depth, body, obstacle, force, k = predicted
    if depth > budget:
        fix = penetration_fix(force, depth, budget, god.coupling.gains.omega_n, god.coupling.max_stretch_m)
        warnings.warn(
            f"{body}'s capped pull ({force:.3g} N) can push it {depth * 1e3:.3g} mm into {obstacle} "
            f"(their point contacts combine to {k:.3g} N/m), past the scene's penetration budget "
            f"{budget * 1e3:.3g} mm. Fix: {fix}",
            PenetrationBudgetWarning,
            stacklevel=3,
        )
    return depth


def add_visualization(
    builder: DiagramBuilder,
    meshcat: Meshcat,
    scene: SceneParts,
    tools: dict[str, GodObject],
    scenario: sc.Scenario,
    records: dict[str, sc.ToolRecord],
) -> None:
    """Drake's MeshcatVisualizer, each tool kind's own drawing (in its own colour and Meshcat folder
    in a scene of several, each adding its lines to the page's legend), the scenario's camera, and
    no grid or axes (:func:`~godobject_drake.systems.page.set_view`)."""
    add_meshcat_visualization(builder, meshcat, scene.scene_graph, scenario.visualization.publish_period_s)
    for k, (name, tool) in enumerate(tools.items()):
        before = set(builder.GetSystems())
        tool.add_drawing(builder, meshcat, scene, records[name].view, Drawing(name, k))
        for system in set(builder.GetSystems()) - before:
            system.set_name(records[name].named(system.get_name()))
    observers = [tool.tissue_observer for tool in tools.values() if getattr(tool, "tissue_observer", None)]
    if scene.tissue is not None and observers:  # the organ once, whichever tool's observer reads it
        period = scenario.visualization.publish_period_s
        drawing = builder.AddNamedSystem("tissue_visualizer", TissueVisualizer(meshcat, scene.tissue, period))
        draw_soft_body_here(scene.plant, scene.scene_graph, scene.tissue.geometry_id)
        builder.Connect(
            observers[0].GetOutputPort("surface_positions"), drawing.GetInputPort("surface_positions")
        )
    camera = scenario.visualization.camera
    set_view(meshcat, *((camera.position_m, camera.target_m) if camera is not None else ()))


logger = logging.getLogger("godobject_drake")

# Drake's Meshcat (a C++ uWebSockets server: ``.ws("/*", ...)`` with no upgrade handler) accepts a
# websocket from any Origin on any path, and MeshcatParams has no secret: nothing in front of it
# can be added from here. What that lets a page do is said before the page is served.
LOCAL_PAGES_WARNING = (
    "WARNING: the live page takes commands from ANY web page open on this machine, not only its own "
    "tab: Drake's Meshcat checks no Origin and no secret, so a page from a file or from another local "
    "site can read the scene, stop the run and, with a browser device, move its sliders, grasp and "
    "release. Open no page you do not trust while it runs (docs/guide/live.md)."
)


def haptic_tools(records: dict[str, sc.ToolRecord]) -> list[str]:
    """The tools whose feedback reaches a hand: a simulated haptic device (``haptic.mode``) or a
    device that renders the feedback (``!Lcm``), each as ``what (field)``."""
    found = []
    for r in records.values():
        if r.view.haptic.mode != "none":
            found.append(f"--haptic {r.view.haptic.mode} ({r.field('haptic.mode')})")
        if r.device.renders_feedback:
            found.append(f"!{type(r.view.device).__name__} renders the feedback ({r.field('device')})")
    return found


def check_page_with_haptics(scenario: sc.Scenario, records: dict[str, sc.ToolRecord]) -> None:
    """Refuse to serve the live page with a haptic device unless ``visualization.trust_local_pages``
    (``--trust-local-pages``) says so: any page on the machine could drive the forces on a hand."""
    haptics = haptic_tools(records)
    if haptics and not scenario.visualization.trust_local_pages:
        raise sc.ScenarioError(
            f"visualization: a live page with a haptic device ({'; '.join(haptics)}): any web page open on "
            "this machine can connect to the page's websocket (Drake's Meshcat checks no Origin and no "
            "secret) and move the device, grasp and stop the run, and so command the forces on the hand "
            "holding the device. Run without the page (no --meshcat, a non-browser device), or opt in with "
            "--trust-local-pages (visualization.trust_local_pages: true)"
        )


def make_meshcat(scenario: sc.Scenario) -> Meshcat | None:
    """The scenario's Meshcat, on ``visualization.host`` (this machine only, by default): at
    ``visualization.port`` when it is live (``visualization.serve`` or a browser device), on
    any free port for a recording only, None otherwise
    (:func:`~godobject_drake.systems.drawing.start_meshcat`)."""
    return _meshcat(scenario, sc.tool_records(scenario))


def _meshcat(scenario: sc.Scenario, records: dict[str, sc.ToolRecord]) -> Meshcat | None:
    """:func:`make_meshcat`, given the scenario's tools' records."""
    vis = scenario.visualization
    if vis.serve or any(r.device.live for r in records.values()):
        check_page_with_haptics(scenario, records)
        logger.warning(LOCAL_PAGES_WARNING)  # before Drake's "Meshcat listening": the run's first line
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
    tools : dict[str, GodObject]
        Each tool's coupling, feedback port, device and haptic chain, by name (``""`` for the one
        tool of a scene of one; :attr:`god_object` is it).
    loggers : dict[str, VectorLogSink]
        Per-step logs the metrics read: ``state`` always; each tool's own, ``terms`` (rigid),
        ``q_device`` (articulated), ``pose_WT``, ``vertex_positions``, ``rest_positions``,
        ``pose_WC`` (deformable), named ``NAME/terms`` in a scene of several tools. Add one's
        own before ``Build`` and read it from the run's context.
    meshcat : Meshcat | None
    predicted_penetration_m : float | None
        Deepest static penetration a tool's capped pull could cause (m), None where it cannot
        be predicted (:meth:`~godobject_drake.station.kinds.GodObject.predict_penetration`).
    sleeper : SleepManager | None
        Locks resting free bodies (``scenario.sleep``); rigid and deformable god-objects (an
        articulated tool's bodies are not free bodies it could watch).
    tool_loggers : dict[str, dict[str, str]]
        Each tool's logger names: its own name for a log (``terms``) to the station's
        (``left/terms``).
    soft_bodies : dict[str, FemSoftBody]
        The scene's soft bodies (``deformables``), by name
        (:class:`~godobject_drake.systems.soft_body.FemSoftBody`).
    contact_meter : ContactMeter | None
        Each tool's contact force on other bodies and the tools' collisions per step
        (:class:`~godobject_drake.systems.contacts.ContactMeter`), logged as ``contacts``.
    soft_loggers : dict[str, VectorLogSink]
        Each soft body's (``deformables``) :class:`~godobject_drake.systems.soft_body.SoftBodyObserver`
        summary, per step, by its name; folded into the metrics per soft body.
    records : dict[str, ToolRecord]
        Each tool resolved once (:class:`~godobject_drake.config.scenario.ToolRecord`): its
        scenario view, its device's kind, its names.
    views : dict[str, Station]
        Each tool's station (:meth:`for_tool`), made once with this one.
    task : tuple | None
        The scenario's task resolved on the plant (:func:`~godobject_drake.task_score.resolve_task`):
        what the run's task score reads; None without a task.
    """

    scenario: sc.Scenario
    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: object
    tools: dict[str, GodObject]
    loggers: dict[str, VectorLogSink]
    meshcat: Meshcat | None = None
    predicted_penetration_m: float | None = None
    sleeper: SleepManager | None = None
    tool_loggers: dict[str, dict[str, str]] = dataclasses.field(default_factory=dict)
    records: dict[str, sc.ToolRecord] = dataclasses.field(default_factory=dict)
    views: dict[str, "Station"] = dataclasses.field(default_factory=dict, repr=False)
    soft_loggers: dict[str, VectorLogSink] = dataclasses.field(default_factory=dict)
    soft_bodies: dict = dataclasses.field(default_factory=dict)
    task: tuple | None = None
    contact_meter: ContactMeter | None = None

    def __post_init__(self):
        if not self.views:
            self.views = {name: self._view(name) for name in self.tools}

    @property
    def god_object(self) -> GodObject:
        """The tool of a scene of one tool (a scene of several: :attr:`tools`, or :meth:`for_tool`)."""
        if len(self.tools) != 1:
            raise AttributeError(
                f"this station has {len(self.tools)} tools ({', '.join(self.tools)}): ask "
                "station.tools[NAME] or station.for_tool(NAME)"
            )
        return next(iter(self.tools.values()))

    def for_tool(self, name: str) -> "Station":
        """The station as the tool ``name`` sees it: its scenario view (its own device, tool, gains),
        itself as the one tool, its loggers under their own names (``state``, ``terms``): what the
        metrics and the studies of one tool read (:attr:`views`)."""
        if name not in self.tools:
            raise KeyError(f"no tool {name!r}; the tools are {', '.join(map(repr, self.tools))}")
        return self.views[name]

    def _view(self, name: str) -> "Station":
        """The tool ``name``'s station (:meth:`for_tool`), made when this one is."""
        if list(self.tools) == [name] and not self.scenario.tools:
            return self  # the one-tool form: the scenario is the tool's
        loggers = {key: self.loggers[full] for key, full in self.tool_loggers[name].items()}
        record = self.records[name]
        view = Station(
            record.view, self.diagram, self.plant, self.scene_graph, {name: self.tools[name]}, loggers,
            self.meshcat, self.predicted_penetration_m, self.sleeper, {name: {k: k for k in loggers}},
            {name: record}, views={name: None}, contact_meter=self.contact_meter,
        )  # fmt: skip
        view.views[name] = view  # its one tool's station is itself
        return view

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
        """Driven from the browser (some tool's device kind says so)."""
        return any(r.device.live for r in self.records.values())
