"""The deformable god-object kind: a rigid core (a god-object) carrying a deformable shell (paper Fig. 4).

:func:`add_deformable` adds the shell's observer and a rigid coupling on the core, its gains and
gravity compensation scaled by core and shell; :class:`DeformableGodObject` logs and draws the
shell, measures its deformation and the core's penetration, and in position mode imposes the core
and carries the shell with it.
"""

import dataclasses
from typing import TYPE_CHECKING, ClassVar

from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config import scenario as sc
from godobject_drake.config.gains import CouplingGains, FeedbackGains
from godobject_drake.devices.sources import DeviceSource, first_pose
from godobject_drake.metrics import ShellMetrics
from godobject_drake.station.rigid_tool import RigidGodObject, add_god_object, impose_target
from godobject_drake.systems.contacts import ToolParts
from godobject_drake.systems.drawing import ONE_TOOL, Drawing, ShellVisualizer, draw_soft_body_here
from godobject_drake.systems.shell import add_deformable_god_object, obstacle_geometries

if TYPE_CHECKING:
    from godobject_drake.systems.shell import Shell, ShellObserver


@dataclasses.dataclass
class DeformableGodObject(RigidGodObject):
    """A deformable god-object (:func:`add_deformable`): the rigid coupling on the core, and

    Attributes
    ----------
    shell, observer :
        The shell and its :class:`~godobject_drake.systems.shell.ShellObserver`.
    """

    shell: "Shell | None" = None
    observer: "ShellObserver | None" = None

    kind: ClassVar[str] = "deformable"
    predicts_penetration: ClassVar[bool] = False
    no_prediction_reason: ClassVar[str] = (
        "deformable tool: the core has no collision geometry; its shell deforms instead"
    )

    @classmethod
    def add_to_plant(cls, plant, scene_graph, scenario, device, *, check_gains=True, name="") -> dict:
        """The core and its shell, at the device's first pose (the gains checked before meshing)."""
        config = scenario.god_object
        if check_gains:
            config.gains.check(scenario.time_step)  # before meshing anything
        shell = add_deformable_god_object(plant, scene_graph, config.shell, config.spec, first_pose(device),
                                          config.name)  # fmt: skip
        return {"shell": shell}

    @classmethod
    def build(cls, builder, scene, scenario, device, added: dict, *, check_gains=True):
        return add_deformable(
            builder, scene.plant, added["shell"], device, scenario.god_object.gains, scenario.feedback,
            haptic=scenario.haptic, connect_forces=scenario.simulation.mode == "god_object",
            check_gains=check_gains, forces=scene.forces,
        )  # fmt: skip

    def logged_ports(self, plant):
        ports = {"state": plant.get_state_output_port(), "pose_WT": self.coupling.GetOutputPort("pose_WT")}
        for name in ("vertex_positions", "rest_positions", "pose_WC"):
            ports[name] = self.observer.GetOutputPort(name)
        return ports

    def add_drawing(self, builder, meshcat, scene, scenario, drawing: Drawing = ONE_TOOL) -> None:
        period = scenario.visualization.publish_period_s
        prefix = f"{drawing.prefix}/{self.shell.name}" if drawing.tool else None  # None: the probe's name
        shell = builder.AddNamedSystem(
            "shell_visualizer", ShellVisualizer(meshcat, self.shell, period, prefix)
        )
        builder.Connect(
            self.observer.GetOutputPort("vertex_positions"), shell.GetInputPort("vertex_positions")
        )
        builder.Connect(self.observer.GetOutputPort("pose_WC"), shell.GetInputPort("pose_WC"))
        builder.Connect(self.coupling.GetOutputPort("pose_WT"), shell.GetInputPort("pose_WT"))
        geometry = getattr(self.shell, "geometry_id", None)  # the FEM shell's (a mass-spring one has none)
        if geometry is not None:
            draw_soft_body_here(scene.plant, scene.scene_graph, geometry)

    def new_metrics(self, station):
        return _ShellFold(station, self)

    def contact_parts(self, plant, scene_graph) -> ToolParts:
        """Its shell: an FEM shell's deformable geometry, a mass-spring shell's node bodies."""
        geometry = getattr(self.shell, "geometry_id", None)
        if geometry is not None:
            return ToolParts(deformable_geometries=frozenset([geometry]))
        inspector = scene_graph.model_inspector()
        ids = getattr(self.shell, "geometry_ids", ())
        bodies = {int(plant.GetBodyFromFrameId(inspector.GetFrameId(g)).index()) for g in ids}
        return ToolParts(bodies=frozenset(bodies))

    def held_body_port(self):
        return None

    def tip_reference(self, data: dict):
        return None  # its core, throughout

    def predict_penetration(self, scene, penetration_allowance: float = 1e-3, duration_s=None):
        return None

    def configuration(self, scenario, station) -> dict:
        config = scenario.god_object
        return {
            **super().configuration(scenario, station),
            "shell": config.shell,
            "shell_vertices": self.shell.vertex_count,
            "youngs_modulus_pa": config.spec.youngs_modulus_pa,
        }

    def _impose(self, plant, plant_context, coupling_context) -> None:
        self.shell.impose_core(
            plant, plant_context, lambda: impose_target(plant, plant_context, self.coupling, coupling_context)
        )


class _ShellFold:
    """The deformable kind's metrics (:class:`~godobject_drake.metrics.ShellMetrics`)."""

    def __init__(self, station, god):

        plant, scene_graph = station.plant, station.scene_graph
        self._acc = ShellMetrics(
            station.diagram, plant, god.shell, obstacle_geometries(scene_graph, god.shell, plant)
        )

    def fold(self, rows: dict, data: dict, finite):
        self._acc.update(rows["state"], rows["vertex_positions"], rows["rest_positions"], rows["pose_WC"],
                         rows["pose_WT"])  # fmt: skip
        return data["pose_WT"][:, 4:], data["pose_WC"][:, 4:]

    def result(self) -> dict:
        return {"max_other_body_speed_mps": None, **self._acc.result()}


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
    forces=None,
) -> DeformableGodObject:
    """A deformable god-object: its shell's observer, and :func:`add_god_object` on its core,
    with gains and gravity compensation scaled by core + shell (``carried``).

    ``shell`` comes from :func:`~godobject_drake.systems.shell.add_deformable_god_object`,
    called before ``plant.Finalize()`` (:func:`add_plant`'s ``before_finalize``).
    """
    observer = shell.connect(builder, plant)
    god = add_god_object(
        builder, plant, device, gains, feedback_gains, haptic=haptic, connect_forces=connect_forces,
        carried={shell.grasp_name: shell.shell_inertia()}, check_gains=check_gains, forces=forces,
    )  # fmt: skip
    parts = {f.name: getattr(god, f.name) for f in dataclasses.fields(god)}
    return DeformableGodObject(**parts, shell=shell, observer=observer)
