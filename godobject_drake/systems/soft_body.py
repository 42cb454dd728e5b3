"""Soft bodies (``deformables:``): Drake FEM bodies from a tetrahedral mesh file, a primitive or a
rigid shape of the directives they replace, in any scene; the laparoscopy's FEM organ is one
(``organs: {model: fem}`` stands for its entry: :meth:`~godobject_drake.config.scene.Organs.soft_body`).

:func:`soft_body_mesh` reads a scenario's soft body (a VTK volume mesh, checked by
:mod:`godobject_drake.config.meshes`, or a box, sphere, ellipsoid or capsule meshed here by
:func:`~godobject_drake.systems.tissue.grid_tet_mesh`,
:func:`~godobject_drake.systems.tissue.ellipsoid_tet_mesh` and :func:`capsule_tet_mesh`) and
refuses, before the run, a mesh whose size against the scene's says millimetres, one whose step
would cost too much (:func:`estimated_step_cost_s`) and an attachment that holds no vertex.
:class:`FemSoftBody` registers it with Drake's ``DeformableModel`` and holds its vertices: with
``AddFixedConstraint`` (to the world or a free body), or in place with the wall boundary
condition (``below_top_m``); :class:`SoftBodyObserver` measures it every step from the tools' own
collision geometry (SceneGraph's signed distance from each deformed surface vertex to every rigid
geometry that moves), and its summary is folded per soft body into the metrics.

Measured (Drake 1.51.1 and 1.58): ``AddFixedConstraint``'s ``X_BA`` is the pose in B of the frame
the deformable geometry was registered in (its ``X_WG``), not of the world: a sphere registered at
z = 0.1 m and fixed to the world with ``X_BA = I`` dropped 0.10 m at once; with ``X_BA = X_WG`` its
held vertices stayed within 1e-8 m. The fixed constraint to the world body works in both; to a
body welded to the world Drake refuses ("a clique with zero number of velocities").
"""

import shutil
import tempfile
import weakref
from pathlib import Path

import numpy as np
from pydrake.common import Parallelism
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    AddContactMaterial,
    Box,
    GeometryConfigurationVector,
    GeometryInstance,
    Mesh,
    ProximityProperties,
    QueryObject,
    Role,
    Sphere,
)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import ContactResults, CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import BodyIndex, JointIndex
from pydrake.systems.framework import LeafSystem

from godobject_drake.config.meshes import check_tetrahedra, read_tet_vtk
from godobject_drake.config.scene import SoftBody
from godobject_drake.systems.tissue import (
    body_config,
    capsule_against_surface,
    ellipsoid_tet_mesh,
    free_body,
    graded_axis,
    grid_tet_mesh,
    max_tet_strain,
    orient,
    surface_triangles,
    write_vtk,
)

# A soft body this many times as wide as the scene's workspace (the boxes its devices move in) is
# taken for a mesh in millimetres: no tool could reach round it.
MAX_EXTENT_TO_WORKSPACE = 10.0
# One soft body's cost a plant step against its vertex count n, fitted to
# `python analysis/soft_body_cost.py` (docs/results.md, "A soft body's cost"): seconds =
# COST_S[0] + COST_S[1] n + COST_S[2] n² (Drake's FEM and SAP's Schur complement grow faster than n).
COST_S = (2.0e-4, 1.6e-5, 1.06e-7)


def estimated_step_cost_s(vertices: int) -> float:
    """The CPU time (s) a soft body of ``vertices`` vertices adds to a plant step, estimated from
    the fit measured on a 2-core AMD EPYC (docs/results.md): on an idle machine, about its wall
    time too."""
    a, b, c = COST_S
    return a + b * vertices + c * vertices**2


def vertices_for_cost(cost_s: float) -> int:
    """The most vertices whose estimated step costs at most ``cost_s``."""
    a, b, c = COST_S
    return max(0, int((-b + (b * b + 4 * c * max(cost_s - a, 0.0)) ** 0.5) / (2 * c)))


def pose(spec: SoftBody) -> RigidTransform:
    """The soft body's ``X_WG``: its mesh's frame in W."""
    return RigidTransform(RollPitchYaw(np.radians(spec.rpy_deg)), np.asarray(spec.xyz_m, float))


def soft_body_mesh(spec: SoftBody, where: str, time_step: float, workspace_m: float = 0.35, shape=None):
    """The soft body's rest vertices ``(n, 3)`` in its own frame (m) and tetrahedra ``(m, 4)``,
    read or meshed (``shape``: the primitive a ``replaces`` stands for, as ``(kind, size_m)``),
    checked (module docstring) against the scene's ``workspace_m`` (the diagonal of its devices'
    workspaces); ``ValueError`` naming ``where`` and the fix."""
    if spec.mesh:
        if not Path(spec.mesh).is_file():
            raise ValueError(
                f"{where}.mesh: {spec.mesh} does not exist: give a tetrahedral VTK file (a relative path is "
                "taken from the scenario's folder; package://godobject_models/... from the models)"
            )
        V, T = read_tet_vtk(spec.mesh, f"{where}.mesh: {spec.mesh}")
        V = V * spec.scale
        check_tetrahedra(V, T, f"{where}.mesh: {spec.mesh}")
        used = np.unique(T)
        if len(used) < len(V):
            raise ValueError(
                f"{where}.mesh: {spec.mesh}: {len(V) - len(used)} of its {len(V)} points belong to no "
                "tetrahedron (Drake would leave them hanging): remove them"
            )
    else:
        kind, size = shape or (spec.shape, spec.size_m)
        V, T = primitive_mesh(kind, size, spec)
    extent = float(np.max(V.max(axis=0) - V.min(axis=0)))
    if extent > MAX_EXTENT_TO_WORKSPACE * workspace_m:
        said = f"{spec.mesh}" if spec.mesh else (spec.shape or spec.replaces)
        raise ValueError(
            f"{where}: {said} is {extent:.4g} m across (scale {spec.scale:g}), "
            f"{extent / workspace_m:.3g} times the scene's workspace ({workspace_m:.3g} m across: its "
            "devices' boxes), past "
            f"{MAX_EXTENT_TO_WORKSPACE:g}: a mesh in millimetres? Give scale: 0.001 (it would be "
            f"{extent * 1e-3:.3g} m), or a workspace as large as the scene"
        )
    cost = estimated_step_cost_s(len(V))
    if cost > spec.max_slowdown * time_step:
        raise ValueError(
            f"{where}: {len(V)} vertices: a step of this soft body is estimated at {cost * 1e3:.3g} ms "
            f"(docs/results.md), {cost / time_step:.3g} times the time step h = {time_step:g} s, past "
            f"max_slowdown {spec.max_slowdown:g}: give a coarser mesh (about "
            f"{vertices_for_cost(spec.max_slowdown * time_step)} vertices or fewer), or raise "
            "max_slowdown for a run that need not keep up"
        )
    return V, T


def primitive_mesh(kind: str, size, spec: SoftBody):
    """A box, sphere, ellipsoid or capsule of ``size`` (``SoftBody.size_m``'s meaning) about the
    origin: ``spec.cells`` cells a side, else cells about ``spec.resolution_m`` wide."""
    if kind == "box":
        counts = [spec.cells or max(1, round(s / spec.resolution_m)) for s in size]
        return grid_tet_mesh(*[np.linspace(-s / 2, s / 2, n + 1) for s, n in zip(size, counts, strict=True)])
    if kind == "capsule":
        cells = spec.cells or max(2, 2 * round(size[0] / spec.resolution_m))
        return capsule_tet_mesh(size[0], size[1], cells)
    radii = list(size) * 3 if kind == "sphere" else list(size)
    cells = spec.cells or max(2, 2 * round(max(radii) / spec.resolution_m))
    V, T, _ = ellipsoid_tet_mesh(radii, cells, spec.grading)
    return V, T


def capsule_tet_mesh(radius: float, length: float, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """A tetrahedral capsule along z (radius, cylinder ``length``, m): the ellipsoid's cube grid
    (:func:`~godobject_drake.systems.tissue.ellipsoid_tet_mesh`) cut at its equator with layers
    inserted for the cylinder. The cylinder's layers map each square across it onto the disc
    (``q ‖q‖∞ / ‖q‖₂`` in x, y); each end's half cube maps onto its hemisphere as the ball's does,
    so the two maps agree where they meet."""
    if not (isinstance(cells, int) and cells >= 2 and cells % 2 == 0):
        raise ValueError(f"cells: {cells!r} must be an even integer ≥ 2")
    a = 0.5 * length / radius  # the cylinder's half length in radii
    side = graded_axis(cells, 1.0)
    half = side[cells // 2 :]  # 0 to 1
    middle = np.linspace(-a, a, max(1, round(length / (2.0 * radius / cells))) + 1)
    zs = np.concatenate([-a - half[::-1][:-1], middle, a + half[1:]])
    V, T = grid_tet_mesh(side, side, zs)
    q = V.copy()
    q[:, 2] = np.sign(V[:, 2]) * np.maximum(np.abs(V[:, 2]) - a, 0.0)  # the ends' own cube coordinates
    inf = np.max(np.abs(q), axis=1)
    two = np.linalg.norm(q, axis=1)
    scale = np.divide(inf, two, out=np.zeros_like(inf), where=two > 0)
    mapped = q * scale[:, None]
    mapped[:, 2] += np.sign(V[:, 2]) * np.minimum(np.abs(V[:, 2]), a)
    return mapped * radius, orient(mapped * radius, T)


class FemSoftBody:
    """A scenario's soft body registered in ``plant`` (before ``Finalize``).

    ``scene_graph`` is needed for a body that ``replaces`` a rigid shape (its shape and pose are
    read, its roles removed); ``workspace_m`` is the scene's size the mesh is checked against;
    ``where`` and ``fields`` name the scenario's fields in errors (the laparoscopy's ``organs``
    gives ``organs`` and its own field names, ``{"replaces": "organ", "attach": "attached_below_m"}``).

    Attributes
    ----------
    name, spec :
        Its name and :class:`~godobject_drake.config.scene.SoftBody`.
    body_id, geometry_id, instance :
        Drake's deformable body, its geometry and its model instance (``NAME_fem``).
    X_WG : RigidTransform
        The frame its mesh is registered in.
    rest_W, tets, surface, triangles :
        The rest vertices in W ``(n, 3)``, the tetrahedra, the surface vertices' indices and the
        surface's outward triangles.
    held, attached :
        The vertices its ``attach`` holds (a mask) and how many.
    glued, glued_bodies :
        Each glued body's vertex count, and the glued bodies' full names.
    """

    def __init__(self, plant: MultibodyPlant, name: str, spec: SoftBody, scene_graph=None, *,
                 workspace_m: float = 0.35, where: str = "", fields=None):  # fmt: skip
        self.where, self._fields = where or f"deformables.{name}", dict(fields or {})
        if plant.time_step() <= 0:
            raise ValueError(f"{self.where}: a soft body needs a discrete SAP plant (plant.time_step > 0)")
        self.X_WG, shape = self._place(plant, scene_graph, spec)
        V, T = soft_body_mesh(spec, self.where, plant.time_step(), workspace_m, shape)
        self.name, self.spec, self.tets = name, spec, T
        self.triangles = surface_triangles(T)
        self.surface = np.unique(self.triangles)
        self.vtk_dir = Path(tempfile.mkdtemp(prefix="godobject_soft_"))
        weakref.finalize(self, shutil.rmtree, self.vtk_dir, True)
        path = write_vtk(f"{self.vtk_dir}/{name}.vtk", V, T)  # what was checked is what Drake reads
        instance = GeometryInstance(self.X_WG, Mesh(str(path)), f"{name}_fem")
        props = ProximityProperties()
        friction = CoulombFriction(spec.friction, spec.friction)
        AddContactMaterial(dissipation=None, point_stiffness=None, friction=friction, properties=props)
        props.AddProperty("material", "relaxation_time", spec.relaxation_time_s)
        instance.set_proximity_properties(props)
        model = plant.mutable_deformable_model()
        if spec.threads > 1:  # Drake offers it as a private method only (drake issue 23106)
            model._set_parallelism(Parallelism(spec.threads))
        self.instance = plant.AddModelInstance(f"{name}_fem")
        self.body_id = model.RegisterDeformableBody(instance, self.instance, body_config(spec), 1.0)
        self.geometry_id = model.GetGeometryId(self.body_id)
        self.rest_W = np.asarray(model.GetReferencePositions(self.body_id)).reshape(-1, 3)
        self.held = np.zeros(len(self.rest_W), bool)
        for i, attach in enumerate(spec.attach):
            self.held |= self._attach(plant, attach, self._field("attach", i))
        self.attached = int(self.held.sum())
        self.glued_bodies: set[str] = set()  # their full names: not what presses the body
        self.glued = {body: self._glue(plant, body) for body in spec.glued}

    @property
    def vertex_count(self) -> int:
        return len(self.rest_W)

    @property
    def tet_count(self) -> int:
        return len(self.tets)

    def _field(self, name: str, index: int | None = None) -> str:
        """The scenario's name of the field ``name`` (``[index]`` of a list), for an error."""
        said = self._fields.get(name)
        if said is None:
            said = name if index is None else f"{name}[{index}]"
        return f"{self.where}.{said}"

    def _place(self, plant, scene_graph, spec: SoftBody):
        """``X_WG`` and, for a body that ``replaces`` a rigid shape, that shape as ``(kind,
        size_m)`` (its roles removed: the soft body touches and is drawn in its place)."""
        if not spec.replaces:
            return pose(spec), None
        where = self._field("replaces")
        inspector = scene_graph.model_inspector()
        host, gid = _find_geometry(plant, inspector, spec.replaces, where)
        found = inspector.GetShape(gid)
        kind = type(found).__name__
        sizes = {
            "Ellipsoid": lambda: ("ellipsoid", [found.a(), found.b(), found.c()]),
            "Sphere": lambda: ("sphere", [found.radius()]),
            "Box": lambda: ("box", [found.width(), found.depth(), found.height()]),
        }
        if kind not in sizes:
            raise ValueError(
                f"{where}: {spec.replaces!r} is a {kind}; a soft body replaces an Ellipsoid, Sphere or Box "
                "collision geometry: name one, or give the body a mesh"
            )
        X_WG = _welded_pose(plant, host, where) @ inspector.GetPoseInFrame(gid)
        source = plant.get_source_id()
        for role in (Role.kProximity, Role.kIllustration, Role.kPerception):
            for other in _geometries_named(plant, inspector, host, inspector.GetName(gid)):
                if inspector.GetProperties(other, role) is not None:
                    scene_graph.RemoveRole(source, other, role)
        return X_WG, sizes[kind]()

    def _target(self, plant: MultibodyPlant, scoped: str, where: str):
        """The body ``scoped`` (or the world) and its pose in W."""
        if scoped == "world":
            return plant.world_body(), RigidTransform()
        try:
            body = free_body(plant, scoped)
        except ValueError as e:
            raise ValueError(
                f"{where}: {e} (a body welded to the world cannot hold it: Drake refuses a constraint to "
                "it; attach to: world instead)"
            ) from None
        return body, plant.GetDefaultFloatingBaseBodyPose(body)

    def _fix(self, plant, body, X_WB, shape, X_BS) -> None:
        """Drake's fixed constraint of the vertices inside ``shape`` (posed ``X_BS`` in B) to
        ``body``; ``X_BA`` is the registered geometry frame's pose in B (module docstring)."""
        plant.mutable_deformable_model().AddFixedConstraint(
            self.body_id, body, X_WB.inverse() @ self.X_WG, shape, X_BS
        )

    def _attach(self, plant, attach, where: str) -> np.ndarray:
        if attach.below_top_m > 0:
            return self._hold_below(plant, attach, where)
        body, X_WB = self._target(plant, attach.to, f"{where}.to")
        if attach.within_m > 0:
            inside = np.linalg.norm(self.rest_W - X_WB.translation(), axis=1) <= attach.within_m
            shape, X_WS = Sphere(attach.within_m), X_WB
            at = np.round(X_WB.translation(), 4).tolist()
            what = f"within {attach.within_m * 1e3:g} mm of {attach.to}'s origin {at}"
        else:
            lower, upper = np.asarray(attach.lower_m, float), np.asarray(attach.upper_m, float)
            inside = np.all((self.rest_W >= lower) & (self.rest_W <= upper), axis=1)
            shape, X_WS = Box(*(upper - lower)), RigidTransform(0.5 * (lower + upper))
            what = f"inside the box {attach.lower_m} to {attach.upper_m} m"
        if not inside.any():
            low, high = self.rest_W.min(axis=0), self.rest_W.max(axis=0)
            raise ValueError(
                f"{where}: no vertex of the soft body is {what} (the body spans "
                f"{np.round(low, 4).tolist()} to {np.round(high, 4).tolist()} m in W): move the box onto it"
            )
        self._fix(plant, body, X_WB, shape, X_WB.inverse() @ X_WS)
        return inside

    def _hold_below(self, plant, attach, where: str) -> np.ndarray:
        """The vertices more than ``below_top_m`` under the top, held in place by Drake's wall
        boundary condition (zero displacement below the plane z = top − below_top_m)."""
        top, bottom = float(self.rest_W[:, 2].max()), float(self.rest_W[:, 2].min())
        cut = top - attach.below_top_m
        if not cut > bottom:
            raise ValueError(
                f"{where}: {attach.below_top_m} m reaches below the body's bottom "
                f"({(top - bottom) * 1e3:.1f} mm under its top): give less, so some vertices are held"
            )
        model = plant.mutable_deformable_model()
        model.SetWallBoundaryCondition(self.body_id, np.array([0.0, 0.0, cut]), np.array([0.0, 0.0, 1.0]))
        return self.rest_W[:, 2] < cut

    def _glue(self, plant, scoped: str) -> int:
        """Fix the vertices within a cube of ``glue_size_m`` about the free body ``scoped``'s start to
        that body (Drake's deformable fixed constraint); how many are fixed."""
        where = self._field("glued")
        body, X_WB = self._target(plant, scoped, where)
        size = self.spec.glue_size_m
        inside = np.all(np.abs(self.rest_W - X_WB.translation()) <= 0.5 * size, axis=1)
        if not inside.any():
            raise ValueError(
                f"{where}: {scoped} starts at {np.round(X_WB.translation(), 4).tolist()} m, no vertex "
                f"within {size * 1e3:g} mm (glue_size_m): move it onto the body's surface"
            )
        self._fix(plant, body, X_WB, Box(size, size, size), RigidTransform())
        self.glued_bodies.add(body.scoped_name().get_full())
        return int(inside.sum())

    def connect(self, builder, plant, scene_graph, ignored_bodies=()) -> "SoftBodyObserver":
        """Add its :class:`SoftBodyObserver` (wired to the plant and SceneGraph)."""
        observer = builder.AddNamedSystem(
            f"{self.name}_soft_body_observer", SoftBodyObserver(self, plant, scene_graph, ignored_bodies)
        )
        builder.Connect(
            plant.get_deformable_body_configuration_output_port(),
            observer.GetInputPort("deformable_configuration"),
        )
        builder.Connect(scene_graph.get_query_output_port(), observer.GetInputPort("query_object"))
        builder.Connect(plant.get_contact_results_output_port(), observer.GetInputPort("contact_results"))
        return observer


def _some(names: list[str], n: int = 8) -> str:
    """At most ``n`` of ``names``, and how many there are."""
    shown = ", ".join(names[:n])
    return shown if len(names) <= n else f"{shown}, ... ({len(names)} in all)"


def _find_geometry(plant, inspector, scoped: str, where: str):
    """The body and the id of the collision geometry named ``scoped`` (``model::name``)."""
    names = []
    for i in range(plant.num_bodies()):
        body = plant.get_body(BodyIndex(i))
        for gid in plant.GetCollisionGeometriesForBody(body):
            names.append(inspector.GetName(gid))
            if inspector.GetName(gid) == scoped:
                return body, gid
    raise ValueError(
        f"{where}: {scoped!r} is not a collision geometry of this scene (it has "
        f"{_some(sorted(names))}); a soft body replaces one of them (the laparoscopy scene's "
        "pelvis::uterus)"
    )


def _geometries_named(plant, inspector, body, name):
    """The geometries of ``body`` named ``name`` (each of its roles' own)."""
    frame = plant.GetBodyFrameIdOrThrow(body.index())
    return [g for g in inspector.GetGeometries(frame) if inspector.GetName(g) == name]


def _welded_pose(plant: MultibodyPlant, body, where: str) -> RigidTransform:
    """The pose in W of a body welded to the world (through welds only), before Finalize."""
    X = RigidTransform()
    b = body
    world = plant.world_body().index()
    while b.index() != world:
        joints = [
            plant.get_joint(j)
            for j in plant.GetJointIndices()
            if plant.get_joint(j).child_body().index() == b.index()
        ]
        if not joints or joints[0].type_name() != "weld":
            raise ValueError(
                f"{where}: its body {b.name()!r} is not welded to the world; the soft body takes the place "
                "of a rigid shape that does not move (weld its body in the directives)"
            )
        j = joints[0]
        X = (
            j.frame_on_parent().GetFixedPoseInBodyFrame()
            @ j.X_FM()
            @ j.frame_on_child().GetFixedPoseInBodyFrame().inverse()
            @ X
        )
        b = j.parent_body()
    return X


def moving_geometries(plant: MultibodyPlant, scene_graph, ignored_bodies=()) -> dict:
    """Every rigid collision geometry of a body not welded to the world (the tools, free bodies),
    but those of ``ignored_bodies`` (glued sites): ``{GeometryId: body name}``."""
    welded = {plant.world_body().index()}
    changed = True
    while changed:  # bodies welded to the world, through welds
        changed = False
        for j in range(plant.num_joints()):
            joint = plant.get_joint(JointIndex(j))
            if joint.type_name() == "weld" and joint.parent_body().index() in welded:
                if joint.child_body().index() not in welded:
                    welded.add(joint.child_body().index())
                    changed = True
    out = {}
    for i in range(plant.num_bodies()):
        body = plant.get_body(BodyIndex(i))
        if body.index() in welded or body.scoped_name().get_full() in ignored_bodies:
            continue
        for gid in plant.GetCollisionGeometriesForBody(body):
            out[gid] = body.scoped_name().get_full()
    return out


class SoftBodyObserver(LeafSystem):
    """A soft body's surface and what touches it, per step.

    .. pydrake_system::

        name: SoftBodyObserver
        input_ports:
        - deformable_configuration
        - query_object
        - contact_results
        output_ports:
        - surface_positions
        - summary

    ``summary`` (:data:`~godobject_drake.systems.tissue.TissueObserver.SUMMARY`'s columns): the
    largest surface displacement (m) and tetrahedron strain; how deep a moving rigid geometry (a
    tool) is in it (m): the deeper of the deepest deformed surface vertex inside the geometry and
    the deepest vertex of their contact surface (Drake's deformable contact mesh) inside it, by
    SceneGraph's signed distance to the tool's own shape; whether a moving geometry's origin lies
    inside the deformed surface (1: a tool through it); the net contact force on the body in W (N).
    """

    def __init__(self, body: FemSoftBody, plant, scene_graph, ignored_bodies=()):
        super().__init__()
        self._body = body
        self._gid = body.geometry_id
        self._movers = moving_geometries(plant, scene_graph, ignored_bodies)
        self._config = self.DeclareAbstractInputPort(
            "deformable_configuration", AbstractValue.Make(GeometryConfigurationVector())
        )
        self._query = self.DeclareAbstractInputPort("query_object", AbstractValue.Make(QueryObject()))
        self._contacts = self.DeclareAbstractInputPort(
            "contact_results", AbstractValue.Make(ContactResults())
        )
        self.DeclareVectorOutputPort("surface_positions", 3 * len(body.surface), self._surface)
        self.DeclareVectorOutputPort("summary", 7, self._summary)

    def positions(self, context) -> np.ndarray:
        return np.asarray(self._config.Eval(context).value(self._gid)).reshape(-1, 3)

    def _surface(self, context, output):
        output.SetFromVector(self.positions(context)[self._body.surface].ravel())

    def contact_force(self, context) -> np.ndarray:
        """The net contact force on the soft body (N, W)."""
        return self._contact(context, None)[0]

    def _contact(self, context, query):
        """The net contact force on the soft body (N, W) and, given the ``query`` object, how deep
        the deepest point of its contact surface with a moving geometry lies inside that geometry
        (m: SceneGraph's signed distance to the geometry's own shape)."""
        results = self._contacts.Eval(context)
        f, depth = np.zeros(3), 0.0
        for i in range(results.num_deformable_contacts()):
            info = results.deformable_contact_info(i)
            a, b = info.id_A(), info.id_B()
            if self._gid not in (a, b):
                continue
            f += info.F_Ac_W().translational() if a == self._gid else -info.F_Ac_W().translational()
            other = b if a == self._gid else a
            if query is not None and other in self._movers:
                mesh = info.contact_mesh()  # the soft body's deformed surface inside the mover (W)
                for k in range(mesh.num_vertices()):
                    for d in query.ComputeSignedDistanceToPoint(mesh.vertex(k), 0.0):
                        if d.id_G == other:
                            depth = max(depth, -float(d.distance))
        return f, depth

    def penetration(self, context, p: np.ndarray) -> tuple[float, bool]:
        """The deepest surface vertex inside a moving geometry (m), and whether a moving
        geometry's origin is inside the deformed surface."""
        query = self._query.Eval(context)
        depth = 0.0
        for v in p[self._body.surface]:
            for d in query.ComputeSignedDistanceToPoint(v, 0.0):
                if d.id_G in self._movers:
                    depth = max(depth, -float(d.distance))
        inside = False
        lower, upper = p.min(axis=0), p.max(axis=0)
        for gid in self._movers:
            origin = query.GetPoseInWorld(gid).translation()
            if np.all(origin >= lower) and np.all(origin <= upper):
                _, end_inside = capsule_against_surface(
                    p, self._body.surface, self._body.triangles, origin, np.array([0.0, 0.0, 1.0]), 0.0, 0.0
                )
                inside = inside or end_inside
        return depth, inside

    def _summary(self, context, output):
        p = self.positions(context)
        body = self._body
        u = p - body.rest_W
        displacement = float(np.max(np.linalg.norm(u[body.surface], axis=1)))
        strain = max_tet_strain(body, p) if displacement > 1e-6 else 0.0
        depth, inside = self.penetration(context, p)
        force, under = self._contact(context, self._query.Eval(context))
        output.SetFromVector([displacement, strain, max(depth, under), float(inside), *force])
