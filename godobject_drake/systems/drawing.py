"""Meshcat drawing and recording: the god-object solid, the target as a ghost,
the coupling spring between them.

The plant's bodies are drawn by Drake's ``MeshcatVisualizer`` (illustration
role). :class:`GodObjectVisualizer` adds, at the same frame rate and into the
same recording (``time_in_recording``):

- ``/godobject/ghost/<body>``: a semi-transparent copy of the held body at
  its target pose (shown only while that body is held);
- ``/godobject/spring``: a thin cylinder from Go to the target;
- ``/godobject/device``: a small cross (three short bars along the target's axes) at the device
  target when nothing is held: a cross, so that it is not taken for a sleeping body's ball
  (:mod:`godobject_drake.sleeping`).

With ``max_stretch_m`` (the coupling's force cap, as a stretch) the ghost and the spring carry
a force cue: faint blue and faint yellow while the body tracks its target, turning solid magenta
(a colour no shipped model has: the bricks are red) as the stretch reaches the cap
(:func:`cue_level`), live and as animated colours in recordings.

For an articulated tool, :class:`ToolGhostVisualizer` draws the device's
tool (its kinematic copy) as a wireframe under ``/godobject/device_tool``.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import (
    Box,
    Capsule,
    Cylinder,
    Ellipsoid,
    Meshcat,
    MeshcatParams,
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

from godobject_drake.spatial import pose_from_array
from godobject_drake.systems.coupling import graspable_bodies
from godobject_drake.systems.page import DeformingSurface, page_of, start_server, swatch

GHOST_RGBA = Rgba(0.3, 0.6, 1.0, 0.35)
SPRING_RGBA = Rgba(1.0, 0.8, 0.1, 1.0)
DEFAULT_FPS = 64.0
# The force cue (pseudo-haptics): ghost and spring go from these, while tracking, to solid
# magenta at the force cap, by cue_level(stretch / max_stretch). Magenta is no shipped model's colour
# (the bricks are red, the organs pink and yellow; tests/test_legend.py checks each scene's), so the
# cue cannot be taken for a model.
CUE_GHOST_RGBA = (0.3, 0.6, 1.0, 0.15)
CUE_SPRING_RGBA = (1.0, 0.8, 0.1, 0.5)
CUE_CAP_RGBA = (1.0, 0.0, 1.0, 1.0)
# The device point: a cross of three bars this long (m) and this thick (radius, m).
DEVICE_CROSS_M = (0.008, 0.0006)
# Meshcat animates a node's transform and visibility but not its material's colour, so the cue
# is drawn as CUE_LEVELS copies, each in its colour, one visible at a time.
CUE_LEVELS = 8


# Each tool of a scene of several draws its ghost and spring in its own colours (rgb; the opacity
# stays the one above): the first as a scene of one tool does.
PALETTE = (
    ((0.3, 0.6, 1.0), (1.0, 0.8, 0.1)),  # blue ghost, yellow spring
    ((0.2, 0.8, 0.35), (1.0, 0.55, 0.0)),  # green ghost, orange spring (magenta is the force cue's)
    ((0.7, 0.45, 1.0), (0.2, 0.9, 0.9)),  # violet ghost, cyan spring
    ((0.9, 0.9, 0.9), (0.55, 0.9, 0.2)),  # white ghost, lime spring
)


@dataclasses.dataclass(frozen=True)
class Drawing:
    """Where a tool's own drawing goes and in which colours: ``/godobject`` and the first colours for
    a scene of one tool (``tool`` empty); ``/godobject/NAME`` and the ``index``-th colours of
    :data:`PALETTE` for the tool NAME of a scene of several."""

    tool: str = ""
    index: int = 0

    @property
    def prefix(self) -> str:
        return f"/godobject/{self.tool}" if self.tool else "/godobject"

    @property
    def ghost_rgb(self) -> tuple:
        return PALETTE[self.index % len(PALETTE)][0]

    @property
    def spring_rgb(self) -> tuple:
        return PALETTE[self.index % len(PALETTE)][1]


ONE_TOOL = Drawing()  # the drawing of a scene of one tool


def cue_level(ratio: float) -> float:
    """How strongly the force cue shows a stretch ``ratio`` of the force cap: ``√ratio`` clipped
    to [0, 1]. The square root makes small pushes visible: a tenth of the cap shows at 0.32."""
    return float(min(max(ratio, 0.0), 1.0) ** 0.5)


def cue_rgba(level: float, base) -> list[float]:
    """``base`` blended toward solid magenta (:data:`CUE_CAP_RGBA`) by ``level`` in [0, 1] (colour
    and opacity alike)."""
    return [b + level * (c - b) for b, c in zip(base, CUE_CAP_RGBA, strict=True)]


SOLID_SWATCH = swatch((0.55, 0.55, 0.6, 1.0))


def add_legend(meshcat: Meshcat, tool: str = "", *, ghost=None, spring=None, dot=None, wire=None,
               cue: bool = False) -> None:  # fmt: skip
    """The page's legend lines for a tool's drawing (:mod:`~godobject_drake.systems.page`): what
    each mark means, once; in a scene of several tools a line per tool naming its colours."""
    page = page_of(meshcat)
    page.add(
        "solid",
        SOLID_SWATCH,
        "solid: the simulated tool and what it holds (the god-object: contact stops it)",
    )
    if ghost is not None:
        page.add("ghost", ghost, "faint ghost: where the device puts the held body (the target)")
        page.add(
            "spring",
            spring,
            "line: the coupling spring, from the body to its target; its stretch is the force",
        )
        page.add("dot", dot, "small cross: the device point, while nothing is held")
    if wire is not None:
        page.add("wire", wire, "wireframe: where the device puts the tool (the target)")
    if cue:
        page.add("cue", swatch(CUE_CAP_RGBA), "turning magenta: the pull nears the force cap (the device "
                 "is where the tool cannot go)")  # fmt: skip
    if tool:
        marks = [m for m in (ghost, spring, wire) if m is not None]
        page.add(f"tool {tool}", marks, f"tool {tool}")


class GodObjectVisualizer(LeafSystem):
    """Draws the target ghost, the coupling spring and the device marker.

    .. pydrake_system::

        name: GodObjectVisualizer
        input_ports:
        - pose_WT
        - pose_WG
        - held_body

    Connect the ports of the same names on
    :class:`~godobject_drake.systems.coupling.GodObjectCoupling`.
    """

    def __init__(
        self,
        meshcat: Meshcat,
        plant: MultibodyPlant,
        scene_graph: SceneGraph,
        publish_period_s: float = 1.0 / DEFAULT_FPS,
        prefix: str = "/godobject",
        max_stretch_m: float | None = None,
        ghost_rgb=GHOST_RGBA.rgba[:3],
        spring_rgb=SPRING_RGBA.rgba[:3],
        tool: str = "",
    ):
        super().__init__()
        self._meshcat = meshcat
        self._prefix = prefix
        ghost = Rgba(*ghost_rgb, GHOST_RGBA.a())
        add_legend(meshcat, tool, ghost=swatch(ghost, "ghost"), spring=swatch(spring_rgb, "line"),
                   dot=swatch(ghost_rgb, "cross"), cue=max_stretch_m is not None)  # fmt: skip
        cue_ghost, cue_spring = (*ghost_rgb, CUE_GHOST_RGBA[3]), (*spring_rgb, CUE_SPRING_RGBA[3])
        # The force cue: None (off) or the stretch at the coupling's force cap (m).
        self._cue_stretch = max_stretch_m if max_stretch_m and np.isfinite(max_stretch_m) else None
        self._cue_step: int | None = None
        self._pose_WT = self.DeclareVectorInputPort("pose_WT", 7)
        self._pose_WG = self.DeclareVectorInputPort("pose_WG", 7)
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
            levels = range(CUE_LEVELS) if self._cue_stretch is not None else [None]
            for k in levels:
                level = f"{path}/cue_{k}" if k is not None else path
                rgba = Rgba(*cue_rgba(k / (CUE_LEVELS - 1), cue_ghost)) if k is not None else ghost
                for i, gid in enumerate(inspector.GetGeometries(frame, Role.kIllustration)):
                    meshcat.SetObject(f"{level}/{i}", inspector.GetShape(gid), rgba)
                    meshcat.SetTransform(f"{level}/{i}", inspector.GetPoseInFrame(gid))
                if k is not None:
                    meshcat.SetProperty(level, "visible", k == 0)
            meshcat.SetProperty(path, "visible", False)
            self._ghosts[body.index] = (path, body.p_BoBcm_B)
        if self._cue_stretch is None:
            meshcat.SetObject(
                f"{prefix}/spring/cylinder", Cylinder(0.0006, 1.0), Rgba(*spring_rgb, SPRING_RGBA.a())
            )
        else:
            for k in range(CUE_LEVELS):
                rgba = Rgba(*cue_rgba(k / (CUE_LEVELS - 1), cue_spring))
                meshcat.SetObject(f"{prefix}/spring/cylinder/cue_{k}", Cylinder(0.0006, 1.0), rgba)
                meshcat.SetProperty(f"{prefix}/spring/cylinder/cue_{k}", "visible", k == 0)
        add_cross(meshcat, f"{prefix}/device", Rgba(*ghost_rgb, 1.0))
        self._shown: int | None = None

    def _publish(self, context):
        t = context.get_time()
        mc, pre = self._meshcat, self._prefix
        pose_WT, pose_WG = self._pose_WT.Eval(context), self._pose_WG.Eval(context)
        held = int(self._held.Eval(context)[0])
        if held != self._shown or t == 0.0:
            for index, (path, _) in self._ghosts.items():
                mc.SetProperty(path, "visible", index == held, t)
            mc.SetProperty(f"{pre}/spring", "visible", held >= 0, t)
            mc.SetProperty(f"{pre}/device", "visible", held < 0, t)
            self._shown = held
            self._cue_step = None  # a newly shown ghost gets its colour
        R_WT = RotationMatrix(Quaternion(pose_WT[:4] / np.linalg.norm(pose_WT[:4])))
        if held < 0:
            mc.SetTransform(f"{pre}/device", RigidTransform(R_WT, pose_WT[4:]), t)
            return
        path, p_BoBcm_B = self._ghosts[held]
        mc.SetTransform(path, RigidTransform(R_WT, pose_WT[4:] - R_WT.multiply(p_BoBcm_B)), t)
        d = pose_WT[4:] - pose_WG[4:]
        length = float(np.linalg.norm(d))
        z = d / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
        R = RotationMatrix.MakeFromOneVector(z, 2)
        mc.SetTransform(f"{pre}/spring", RigidTransform(R, 0.5 * (pose_WT[4:] + pose_WG[4:])), t)
        mc.SetProperty(f"{pre}/spring/cylinder", "scale", [1.0, 1.0, max(length, 1e-6)], t)
        if self._cue_stretch is not None:
            step = round((CUE_LEVELS - 1) * cue_level(length / self._cue_stretch))
            if step != self._cue_step:
                for k in range(CUE_LEVELS):
                    if k == step or k == self._cue_step or self._cue_step is None:
                        mc.SetProperty(f"{path}/cue_{k}", "visible", k == step, t)
                        mc.SetProperty(f"{pre}/spring/cylinder/cue_{k}", "visible", k == step, t)
                self._cue_step = step


def add_cross(meshcat: Meshcat, path: str, rgba: Rgba) -> None:
    """A small cross at ``path``: three bars (:data:`DEVICE_CROSS_M`) along its frame's axes."""
    length, radius = DEVICE_CROSS_M
    turns = {"x": RotationMatrix.MakeYRotation(np.pi / 2), "y": RotationMatrix.MakeXRotation(np.pi / 2),
             "z": RotationMatrix()}  # fmt: skip
    for axis, R in turns.items():
        meshcat.SetObject(f"{path}/{axis}", Cylinder(radius, length), rgba)
        meshcat.SetTransform(f"{path}/{axis}", RigidTransform(R, np.zeros(3)))


def wire_mesh(shape, n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A coarse triangle mesh ``(vertices 3×N, faces 3×M)`` of a primitive, for wireframes.

    Sphere, Ellipsoid, Capsule, Cylinder and Box, in the shape's own frame.
    """
    lat = np.linspace(0.0, np.pi, n // 2 + 1)
    lon = np.linspace(0.0, 2 * np.pi, n, endpoint=False)

    def grid(rings):  # rings: list of (radius_x, radius_y, z); faces between consecutive rings
        V = np.array([[rx * np.cos(a), ry * np.sin(a), z] for rx, ry, z in rings for a in lon])
        F = []
        for i in range(len(rings) - 1):
            for j in range(n):
                a, b = i * n + j, i * n + (j + 1) % n
                F += [[a, b, b + n], [a, b + n, a + n]]
        return V.T, np.array(F, dtype=np.int32).T

    if isinstance(shape, Box):
        hx, hy, hz = shape.width() / 2, shape.depth() / 2, shape.height() / 2
        V = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        F = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]  # fmt: skip
        return V.T, np.array(F, dtype=np.int32).T
    if isinstance(shape, Cylinder):
        r, h = shape.radius(), shape.length() / 2
        return grid([(0.0, 0.0, -h), (r, r, -h), (r, r, h), (0.0, 0.0, h)])
    if isinstance(shape, Capsule):
        r, h = shape.radius(), shape.length() / 2
        half = len(lat) // 2
        rings = [(r * np.sin(t), r * np.sin(t), -h - r * np.cos(t)) for t in lat[: half + 1]]
        rings += [(r * np.sin(t), r * np.sin(t), h - r * np.cos(t)) for t in lat[half:]]
        return grid(rings)
    if isinstance(shape, Ellipsoid):
        a, b, c = shape.a(), shape.b(), shape.c()
        return grid([(a * np.sin(t), b * np.sin(t), -c * np.cos(t)) for t in lat])
    if isinstance(shape, Sphere):
        r = shape.radius()
        return grid([(r * np.sin(t), r * np.sin(t), -r * np.cos(t)) for t in lat])
    raise ValueError(
        f"no wireframe for {type(shape).__name__}; use Box, Cylinder, Capsule, Ellipsoid or Sphere"
    )


class ToolGhostVisualizer(LeafSystem):
    """Draws the device's tool (the kinematic copy) as a wireframe ghost (paper Fig. 7).

    .. pydrake_system::

        name: ToolGhostVisualizer
        input_ports:
        - q_device

    Every illustration shape of the tool's bodies is drawn as a wireframe
    under ``/godobject/device_tool``, placed by forward kinematics of the
    device's joint values (:class:`~godobject_drake.systems.articulated.ArticulatedTool`);
    the plant's own drawing shows the god-object tool solid.
    """

    def __init__(
        self,
        meshcat: Meshcat,
        tool,
        scene_graph: SceneGraph,
        publish_period_s: float = 1.0 / DEFAULT_FPS,
        prefix: str = "/godobject/device_tool",
        rgb=GHOST_RGBA.rgba[:3],
        name: str = "",
    ):
        super().__init__()
        self._meshcat, self._tool, self._prefix = meshcat, tool, prefix
        wire = Rgba(*rgb, GHOST_RGBA.a())
        add_legend(meshcat, name, wire=swatch(rgb, "wire"))
        self._q = self.DeclareVectorInputPort("q_device", tool.nq_device)
        self.DeclarePeriodicPublishEvent(publish_period_s, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish)
        plant = tool.plant
        inspector = scene_graph.model_inspector()
        self._bodies = []
        for bi in plant.GetBodyIndices(tool.model):
            body = plant.get_body(bi)
            frame = plant.GetBodyFrameIdOrThrow(bi)
            gids = inspector.GetGeometries(frame, Role.kIllustration)
            if not gids:
                continue
            path = f"{prefix}/{body.name()}"
            for i, gid in enumerate(gids):
                V, F = wire_mesh(inspector.GetShape(gid))
                meshcat.SetTriangleMesh(f"{path}/{i}", V, F, wire, wireframe=True)
                meshcat.SetTransform(f"{path}/{i}", inspector.GetPoseInFrame(gid))
            self._bodies.append((path, body))

    def _publish(self, context):
        t = context.get_time()
        plant = self._tool.plant
        ctx = self._tool.set_device_state(self._q.Eval(context))
        for path, body in self._bodies:
            self._meshcat.SetTransform(path, plant.EvalBodyPoseInWorld(ctx, body), t)


SHELL_RGBA = Rgba(0.85, 0.35, 0.3, 1.0)
CORE_RGBA = Rgba(0.2, 0.2, 0.2, 0.6)


class ShellVisualizer(LeafSystem):
    """Draws a deformable god-object (paper Fig. 8): shell, hidden core, device ghost.

    .. pydrake_system::

        name: ShellVisualizer
        input_ports:
        - vertex_positions
        - pose_WC
        - pose_WT

    Connect the first two to :class:`~godobject_drake.systems.shell.ShellObserver`
    and ``pose_WT`` to the coupling's target. Meshcat recordings replay
    transforms and properties but not changing triangle meshes (Drake issue
    #23206), so the shell is drawn as one sphere per surface point, moved
    every frame: the mass–spring nodes at their contact radius, FEM surface
    vertices as markers. Under ``{prefix}/``: ``shell``, ``core`` (hidden;
    tick it in Meshcat's scene tree to show it) and ``device`` (a wireframe
    of the shell's rest shape at the device's target).
    """

    def __init__(
        self,
        meshcat: Meshcat,
        shell,
        publish_period_s: float = 1.0 / DEFAULT_FPS,
        prefix: str | None = None,
    ):
        super().__init__()
        self._meshcat, self._shell = meshcat, shell
        self._prefix = prefix or f"/{shell.name}"
        n = 3 * shell.vertex_count
        self._vertices = self.DeclareVectorInputPort("vertex_positions", n)
        self._pose_WC = self.DeclareVectorInputPort("pose_WC", 7)
        self._pose_WT = self.DeclareVectorInputPort("pose_WT", 7)
        self.DeclarePeriodicPublishEvent(publish_period_s, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish)
        pre, spec = self._prefix, shell.spec
        points = shell.rest_C[shell.surface]
        spacing = np.sqrt(4 * np.pi * spec.radius_m**2 / len(points))
        marker = shell.contact_radius_m or 0.5 * spacing
        for i in range(len(points)):
            meshcat.SetObject(f"{pre}/shell/{i}", Sphere(marker), SHELL_RGBA)
        meshcat.SetObject(f"{pre}/core", Sphere(spec.core_radius_m), CORE_RGBA)
        meshcat.SetProperty(f"{pre}/core", "visible", False)
        V, F = wire_mesh(Sphere(spec.radius_m))
        meshcat.SetTriangleMesh(f"{pre}/device", V, F, GHOST_RGBA, wireframe=True)
        page_of(meshcat).add("shell", swatch(SHELL_RGBA, "dot"),
                             "red dots: the deformable tool's surface, as contact dents it")  # fmt: skip
        add_legend(meshcat, "", wire=swatch(GHOST_RGBA, "wire"))

    def _publish(self, context):
        t = context.get_time()
        mc, pre = self._meshcat, self._prefix
        points = self._vertices.Eval(context).reshape(-1, 3)[self._shell.surface]
        for i, p in enumerate(points):
            mc.SetTransform(f"{pre}/shell/{i}", RigidTransform(p), t)
        mc.SetTransform(f"{pre}/core", pose_from_array(self._pose_WC.Eval(context)), t)
        mc.SetTransform(f"{pre}/device", pose_from_array(self._pose_WT.Eval(context)), t)


class TissueVisualizer(LeafSystem):
    """Draws FEM tissue (:class:`~godobject_drake.systems.tissue.FemOrgan`) as it deforms.

    .. pydrake_system::

        name: TissueVisualizer
        input_ports:
        - surface_positions

    The organ's surface is one triangle mesh at ``/{organ name}_tissue/surface``, drawn at rest
    and then moved each frame as a
    :class:`~godobject_drake.systems.page.DeformingSurface`: re-sent live, and replayed in a
    recording by the script :func:`~godobject_drake.systems.page.save_recording` adds (Meshcat
    recordings replay transforms and properties, not moving vertices: Drake issue #23206).
    """

    def __init__(self, meshcat: Meshcat, organ, publish_period_s: float = 1.0 / DEFAULT_FPS, legend=None):
        super().__init__()
        self._meshcat, self._prefix = meshcat, f"/{organ.name}_tissue"
        self._surface = self.DeclareVectorInputPort("surface_positions", 3 * len(organ.surface))
        # The surface's triangles index rest_W; the port carries the surface vertices in order.
        index = np.full(len(organ.rest_W), -1)
        index[organ.surface] = np.arange(len(organ.surface))
        faces = index[organ.triangles]
        if (faces < 0).any():
            raise ValueError(f"{organ.name}: a surface triangle has a vertex that is not a surface vertex")
        self.surface = DeformingSurface(
            meshcat, f"{self._prefix}/surface", organ.rest_W[organ.surface], faces, TISSUE_RGBA
        )
        # the legend's line: the laparoscopy's organ, or ``(key, text)`` for a soft body of one's own
        key, text = legend or ("tissue", "pink surface: the FEM organ, dented and lifted by the tools")
        page_of(meshcat).add(key, swatch(TISSUE_RGBA), text)
        self.DeclarePeriodicPublishEvent(publish_period_s, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish)

    def _publish(self, context):
        self.surface.publish(context.get_time(), self._surface.Eval(context).reshape(-1, 3))


TISSUE_RGBA = Rgba(0.85, 0.45, 0.5, 1.0)


def soft_body_legend(name: str) -> tuple[str, str]:
    """The legend's key and line of the soft body ``name`` (``deformables:``): named, as it is
    not the laparoscopy's organ (a sponge, a lobe)."""
    return f"soft:{name}", f"pink surface: {name}, a soft body (FEM), as the tools dent and move it"


LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1")


def start_meshcat(host: str = "localhost", port: int | None = None) -> Meshcat:
    """A Meshcat server listening on ``host`` (this machine only, by default) at ``port``.

    ``port`` None takes Drake's default (7000, or the next free one up to 7099); 0 any free
    port (a recording that nobody watches live). Drake's own default host is ``"*"``: every
    network interface, so anyone on the network could open the page, which drives a live
    device (its sliders, grasp and Stop) and, with a haptic device, the forces on a hand.
    Any host but a loopback one is therefore announced loudly on stderr.
    """
    meshcat = start_server(lambda: Meshcat(MeshcatParams(host=host, port=port)))
    if host not in LOOPBACK_HOSTS:
        print(
            f"WARNING: Meshcat is listening on {host} port {meshcat.port()}, reachable from other machines: "
            "anyone who can reach that address can open the page and drive the scene (its device "
            "sliders, Grasp and Stop; with a haptic device, the forces on the user's hand). To watch "
            f"from another machine, keep the default host and tunnel: ssh -N -L {meshcat.port()}:localhost:"
            f"{meshcat.port()} USER@THIS_MACHINE, then open http://localhost:{meshcat.port()} there.",
            file=sys.stderr,
            flush=True,
        )
    return meshcat


def draw_soft_body_here(plant: MultibodyPlant, scene_graph: SceneGraph, geometry_id) -> None:
    """Leave a deformable body's drawing to this package: Drake's ``RegisterDeformableBody`` gives
    the body an illustration role of its own (no colour: white), which ``MeshcatVisualizer`` draws
    as a faceted mesh, and in a recording that mesh stays where the last live frame left it
    (recordings replay no moving vertices: Drake issue #23206), so it z-fights the surface drawn
    here (:class:`TissueVisualizer`, :class:`ShellVisualizer`). Removing that role leaves one
    drawn surface per soft body: the one that deforms in recordings too."""
    if scene_graph.model_inspector().GetProperties(geometry_id, Role.kIllustration) is not None:
        scene_graph.RemoveRole(plant.get_source_id(), geometry_id, Role.kIllustration)


def add_meshcat_visualization(
    builder: DiagramBuilder,
    meshcat: Meshcat,
    scene_graph: SceneGraph,
    publish_period_s: float = 1.0 / DEFAULT_FPS,
) -> MeshcatVisualizer:
    """Drake's MeshcatVisualizer on the illustration role."""
    params = MeshcatVisualizerParams(role=Role.kIllustration, publish_period=publish_period_s)
    return MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)
