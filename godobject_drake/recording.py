"""Meshcat drawing and recording: the god-object solid, the target as a ghost,
the coupling spring between them.

The plant's bodies are drawn by Drake's ``MeshcatVisualizer`` (illustration
role). :class:`GodObjectVisualizer` adds, at the same frame rate and into the
same recording (``time_in_recording``):

- ``/godobject/ghost/<body>``: a semi-transparent copy of the held body at
  its target pose (shown only while that body is held);
- ``/godobject/spring``: a thin cylinder from Go to the target;
- ``/godobject/device``: a small sphere at the device target when nothing
  is held.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import (
    Cylinder,
    Meshcat,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Rgba,
    Role,
    SceneGraph,
    Sphere,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from godobject_drake.coupling import graspable_bodies

GHOST_RGBA = Rgba(0.3, 0.6, 1.0, 0.35)
SPRING_RGBA = Rgba(1.0, 0.8, 0.1, 1.0)
DEFAULT_FPS = 64.0


class GodObjectVisualizer(LeafSystem):
    """Draws the target ghost, the coupling spring and the device marker.

    .. pydrake_system::

        name: GodObjectVisualizer
        input_ports:
        - X_WT
        - X_WG
        - held_body

    Connect the ports of the same names on
    :class:`~godobject_drake.coupling.GodObjectCoupling`.
    """

    def __init__(
        self,
        meshcat: Meshcat,
        plant: MultibodyPlant,
        scene_graph: SceneGraph,
        publish_period_s: float = 1.0 / DEFAULT_FPS,
        prefix: str = "/godobject",
    ):
        super().__init__()
        self._meshcat = meshcat
        self._prefix = prefix
        self._X_WT = self.DeclareVectorInputPort("X_WT", 7)
        self._X_WG = self.DeclareVectorInputPort("X_WG", 7)
        self._held = self.DeclareVectorInputPort("held_body", 1)
        self.DeclarePeriodicPublishEvent(publish_period_s, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish)

        inspector = scene_graph.model_inspector()
        self._ghosts: dict[int, tuple[str, np.ndarray]] = {}
        for name, body in graspable_bodies(plant).items():
            if "::" not in name or body.index in self._ghosts:
                continue
            path = f"{prefix}/ghost/{name.replace('::', '/')}"
            frame = plant.GetBodyFrameIdOrThrow(BodyIndex(body.index))
            for i, gid in enumerate(inspector.GetGeometries(frame, Role.kIllustration)):
                meshcat.SetObject(f"{path}/{i}", inspector.GetShape(gid), GHOST_RGBA)
                meshcat.SetTransform(f"{path}/{i}", inspector.GetPoseInFrame(gid))
            meshcat.SetProperty(path, "visible", False)
            self._ghosts[body.index] = (path, body.p_BoBcm_B)
        meshcat.SetObject(f"{prefix}/spring/cylinder", Cylinder(0.0006, 1.0), SPRING_RGBA)
        meshcat.SetObject(f"{prefix}/device", Sphere(0.003), GHOST_RGBA)
        self._shown: int | None = None

    def _publish(self, context):
        t = context.get_time()
        mc, pre = self._meshcat, self._prefix
        X_WT, X_WG = self._X_WT.Eval(context), self._X_WG.Eval(context)
        held = int(self._held.Eval(context)[0])
        if held != self._shown or t == 0.0:
            for index, (path, _) in self._ghosts.items():
                mc.SetProperty(path, "visible", index == held, t)
            mc.SetProperty(f"{pre}/spring", "visible", held >= 0, t)
            mc.SetProperty(f"{pre}/device", "visible", held < 0, t)
            self._shown = held
        R_WT = RotationMatrix(Quaternion(X_WT[:4] / np.linalg.norm(X_WT[:4])))
        if held < 0:
            mc.SetTransform(f"{pre}/device", RigidTransform(R_WT, X_WT[4:]), t)
            return
        path, p_BoBcm_B = self._ghosts[held]
        mc.SetTransform(path, RigidTransform(R_WT, X_WT[4:] - R_WT.multiply(p_BoBcm_B)), t)
        d = X_WT[4:] - X_WG[4:]
        length = float(np.linalg.norm(d))
        z = d / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
        R = RotationMatrix.MakeFromOneVector(z, 2)
        mc.SetTransform(f"{pre}/spring", RigidTransform(R, 0.5 * (X_WT[4:] + X_WG[4:])), t)
        mc.SetProperty(f"{pre}/spring/cylinder", "scale", [1.0, 1.0, max(length, 1e-6)], t)


def add_meshcat_visualization(
    builder: DiagramBuilder,
    meshcat: Meshcat,
    scene_graph: SceneGraph,
    publish_period_s: float = 1.0 / DEFAULT_FPS,
) -> MeshcatVisualizer:
    """Drake's MeshcatVisualizer on the illustration role."""
    params = MeshcatVisualizerParams(role=Role.kIllustration, publish_period=publish_period_s)
    return MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)


def save_recording(meshcat: Meshcat, path: str | Path) -> int:
    """Stop and publish the recording, write Meshcat's self-contained HTML; return its size (bytes)."""
    meshcat.StopRecording()
    meshcat.PublishRecording()
    html = meshcat.StaticHtml()
    Path(path).write_text(html)
    return len(html.encode())
