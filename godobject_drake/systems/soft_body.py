"""Soft bodies of the user's own (``deformables:``): Drake FEM bodies from a tetrahedral mesh file
or a primitive, in any scene.

:func:`soft_body_mesh` reads a scenario's soft body (a legacy-ASCII VTK volume mesh, checked by
:mod:`godobject_drake.config.meshes`, or a box, sphere or ellipsoid meshed here by
:func:`~godobject_drake.systems.tissue.grid_tet_mesh` and
:func:`~godobject_drake.systems.tissue.ellipsoid_tet_mesh`) and refuses, before the run, a mesh
whose size says millimetres, one whose step would cost too much (:func:`estimated_step_cost_s`)
and an attachment that holds no vertex. :class:`FemSoftBody` registers it with Drake's
``DeformableModel`` and fixes its held vertices with ``AddFixedConstraint`` (to the world or a
free body); :class:`SoftBodyObserver` measures it every step from the tools' own collision
geometry (SceneGraph's signed distance from each deformed surface vertex to every rigid geometry
that moves), and its summary is folded per soft body into the metrics.

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
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    AddContactMaterial,
    Box,
    GeometryConfigurationVector,
    GeometryInstance,
    Mesh,
    ProximityProperties,
    QueryObject,
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
    grid_tet_mesh,
    max_tet_strain,
    surface_triangles,
    write_vtk,
)

# A soft body larger than this (m, its longest side) is taken for a mesh in millimetres: a whole
# human torso is 0.7 m, the shipped scenes' workspaces 0.3 m.
MAX_SOFT_BODY_EXTENT_M = 2.0
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


def soft_body_mesh(spec: SoftBody, where: str, time_step: float):
    """The soft body's rest vertices ``(n, 3)`` in its own frame (m) and tetrahedra ``(m, 4)``,
    read or meshed, checked (module docstring); ``ValueError`` naming ``where`` and the fix."""
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
        V, T = primitive_mesh(spec)
    extent = float(np.max(V.max(axis=0) - V.min(axis=0)))
    if extent > MAX_SOFT_BODY_EXTENT_M:
        said = f"{spec.mesh}" if spec.mesh else spec.shape
        raise ValueError(
            f"{where}: {said} is {extent:.4g} m across (scale {spec.scale:g}), past the "
            f"{MAX_SOFT_BODY_EXTENT_M:g} m a soft body of a haptic scene may be: a mesh in millimetres? "
            f"Give scale: 0.001 (it would be {extent * 1e-3:.3g} m)"
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


def primitive_mesh(spec: SoftBody):
    """A box, sphere or ellipsoid about the origin, cells about ``resolution_m`` wide."""
    if spec.shape == "box":
        axes = [np.linspace(-s / 2, s / 2, max(1, round(s / spec.resolution_m)) + 1) for s in spec.size_m]
        return grid_tet_mesh(*axes)
    radii = spec.size_m * 3 if spec.shape == "sphere" else spec.size_m
    cells = max(2, 2 * round(max(radii) / spec.resolution_m))
    V, T, _ = ellipsoid_tet_mesh(radii, cells)
    return V, T


class FemSoftBody:
    """A scenario's soft body registered in ``plant`` (before ``Finalize``): attributes as
    :class:`~godobject_drake.systems.tissue.FemOrgan`'s (``name``, ``spec``, ``body_id``,
    ``geometry_id``, ``rest_W``, ``tets``, ``surface``, ``triangles``), ``attached`` the vertices
    held and ``glued`` each glued body's vertex count."""

    def __init__(self, plant: MultibodyPlant, name: str, spec: SoftBody):
        where = f"deformables.{name}"
        V, T = soft_body_mesh(spec, where, plant.time_step())
        self.name, self.spec, self.tets = name, spec, T
        self.triangles = surface_triangles(T)
        self.surface = np.unique(self.triangles)
        self.vtk_dir = tempfile.mkdtemp(prefix="godobject_soft_")
        weakref.finalize(self, shutil.rmtree, self.vtk_dir, True)
        path = write_vtk(f"{self.vtk_dir}/{name}.vtk", V, T)  # what was checked is what Drake reads
        self.X_WG = pose(spec)
        instance = GeometryInstance(self.X_WG, Mesh(str(path)), f"{name}_fem")
        props = ProximityProperties()
        friction = CoulombFriction(spec.friction, spec.friction)
        AddContactMaterial(dissipation=None, point_stiffness=None, friction=friction, properties=props)
        props.AddProperty("material", "relaxation_time", spec.relaxation_time_s)
        instance.set_proximity_properties(props)
        model = plant.mutable_deformable_model()
        self.instance = plant.AddModelInstance(f"{name}_fem")
        self.body_id = model.RegisterDeformableBody(instance, self.instance, body_config(spec), 1.0)
        self.geometry_id = model.GetGeometryId(self.body_id)
        self.rest_W = np.asarray(model.GetReferencePositions(self.body_id)).reshape(-1, 3)
        self.held = np.zeros(len(self.rest_W), bool)
        for i, attach in enumerate(spec.attach):
            self.held |= self._attach(plant, attach, f"{where}.attach[{i}]")
        self.attached = int(self.held.sum())
        self.glued_bodies: set[str] = set()  # their full names: not what presses the body
        self.glued = {body: self._glue(plant, body, where) for body in spec.glued}

    @property
    def vertex_count(self) -> int:
        return len(self.rest_W)

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

    def _fix(self, plant, body, X_WB, shape, X_WS) -> None:
        """Drake's fixed constraint of the vertices inside ``shape`` (posed ``X_WS``) to ``body``;
        ``X_BA`` is the registered geometry frame's pose in B (module docstring)."""
        X_BW = X_WB.inverse()
        plant.mutable_deformable_model().AddFixedConstraint(
            self.body_id, body, X_BW @ self.X_WG, shape, X_BW @ X_WS
        )

    def _attach(self, plant, attach, where: str) -> np.ndarray:
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
        self._fix(plant, body, X_WB, shape, X_WS)
        return inside

    def _glue(self, plant, scoped: str, where: str) -> int:
        body, X_WB = self._target(plant, scoped, f"{where}.glued")
        size = self.spec.glue_size_m
        inside = np.all(np.abs(self.rest_W - X_WB.translation()) <= 0.5 * size, axis=1)
        if not inside.any():
            raise ValueError(
                f"{where}.glued: {scoped} starts at {np.round(X_WB.translation(), 4).tolist()} m, no vertex "
                f"within {size * 1e3:g} mm (glue_size_m): move it onto the body's surface"
            )
        self._fix(plant, body, X_WB, Box(size, size, size), X_WB)
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
