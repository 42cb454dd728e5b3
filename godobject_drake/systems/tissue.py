"""Deformable organs: FEM tissue in place of a rigid organ (the laparoscopy scene's uterus).

The rigid scene models an organ as a rigid shape with a soft point-contact
stiffness: its "penetration" stands for the tissue's indentation, and the organ
is drawn undeformed. With ``organs.model: fem`` the organ is a Drake FEM
deformable body instead (linear tetrahedra, Drake's linear corotated material
unless ``organs.material`` says otherwise, integrated implicitly in SAP), held
to the pelvis where it attaches, and the tool's contact deforms it.

Drake 1.51 meshes a deformable Sphere or Box from a resolution hint but not an
Ellipsoid ("We don't yet generate deformable meshes for Ellipsoid"), so the
tetrahedral mesh is made here (:func:`ellipsoid_tet_mesh`): a cube grid of
``cells`` cells a side, each cell split into Kuhn's six tetrahedra (which
share its main diagonal, so neighbouring cells' faces match), mapped radially
onto the unit ball and scaled to the ellipsoid's radii. It is written as a
legacy VTK file (:func:`write_vtk`), which ``RegisterDeformableBody`` reads
through a ``Mesh`` shape. The same grid, graded, gives the block of the
contact-mechanics check (:mod:`godobject_drake.studies.indentation`).

The organ replaces the rigid shape's collision and drawing: its proximity and
illustration roles are removed from the pelvis's geometry of that name (the
rigid body and its other organs are untouched), and the FEM body is fixed by
``AddFixedConstraint`` to the pelvis body (welded to the world by the
directives) by a zero-displacement wall boundary condition on every vertex
more than ``attached_below_m`` under the organ's top. (Drake 1.51's
``AddFixedConstraint`` to the welded pelvis is accepted at build time but stops
the first step: "Adding constraint to a clique with zero number of velocities
is not allowed"; to the world body it segfaults.)
"""

import math
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
    Capsule,
    GeometryConfigurationVector,
    GeometryInstance,
    Mesh,
    ProximityProperties,
    Role,
)
from pydrake.math import RigidTransform
from pydrake.multibody.fem import DeformableBodyConfig, MaterialModel
from pydrake.multibody.plant import ContactResults, CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import BodyIndex, JointIndex
from pydrake.systems.framework import LeafSystem

from godobject_drake.config.scene import Organs

# Kuhn's split of a cell into 6 tetrahedra; corners numbered by bits (x = 1, y = 2, z = 4).
# All six share the diagonal 0–7, so the split of a shared face is the same from both cells.
_KUHN = ((0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7))


def grid_tet_mesh(xs, ys, zs) -> tuple[np.ndarray, np.ndarray]:
    """A tetrahedral mesh of the box grid ``xs × ys × zs`` (increasing coordinates, m).

    Returns ``(V (n, 3), T (6 cells, 4))``, every tetrahedron positively oriented
    (``(v1 − v0) × (v2 − v0) · (v3 − v0) > 0``, as Drake's VolumeMesh wants).
    """
    xs, ys, zs = (np.asarray(a, float) for a in (xs, ys, zs))
    for name, a in (("xs", xs), ("ys", ys), ("zs", zs)):
        if a.ndim != 1 or len(a) < 2 or not np.all(np.diff(a) > 0):
            raise ValueError(f"{name}: {a!r} must be ≥ 2 increasing coordinates")
    nx, ny, nz = len(xs), len(ys), len(zs)
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    index = np.arange(nx * ny * nz).reshape(nx, ny, nz)
    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1),
                                              indexing="ij"))  # fmt: skip
    corners = np.stack([index[i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)] for c in range(8)], axis=1)
    T = np.concatenate([corners[:, list(t)] for t in _KUHN])
    return V, orient(V, T)


def tet_volumes(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Signed volumes of the tetrahedra (m³)."""
    a, b, c, d = (V[T[:, m]] for m in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def orient(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``T`` with negatively oriented tetrahedra's two vertices swapped (all volumes > 0)."""
    T = np.array(T)
    negative = tet_volumes(V, T) < 0
    T[negative] = T[negative][:, [0, 2, 1, 3]]
    return T


def graded_axis(cells: int, grading: float, from_top: bool = False) -> np.ndarray:
    """``cells + 1`` grid coordinates on [−1, 1], each cell ``grading`` times as wide as the one
    before it counted from the middle outward (``from_top``: from +1 downward); ``grading`` 1:
    evenly spaced."""
    if grading == 1.0:
        return np.linspace(-1.0, 1.0, cells + 1)
    if from_top:
        widths = grading ** np.arange(cells)
        z = 1.0 - 2.0 * np.cumsum(widths) / widths.sum()
        z[-1] = -1.0  # exactly: the cube's face
        return np.concatenate([[1.0], z])[::-1]
    widths = grading ** np.arange(cells // 2)
    half = np.cumsum(widths) / widths.sum()
    half[-1] = 1.0
    return np.concatenate([-half[::-1], [0.0], half])


def ellipsoid_tet_mesh(radii, cells: int, grading: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tetrahedral ellipsoid of semi-axes ``radii`` (m): a cube grid of ``cells`` a side
    mapped radially onto the ball (``p ‖p‖∞ / ‖p‖₂``), then scaled. ``grading`` > 1 makes the
    cells finest at the top's centre, where instruments reach, and each cell that many times as
    wide as its neighbour toward there (:func:`graded_axis`: x and y from the middle, z from the
    top), so a coarse count keeps fine cells under the tool.

    Returns ``(V, T, surface)``: vertices, tetrahedra and the indices of the surface
    vertices (those on the cube's faces). ``cells`` even, ≥ 2.
    """
    if not (isinstance(cells, int) and cells >= 2 and cells % 2 == 0):
        raise ValueError(f"cells: {cells!r} must be an even integer ≥ 2 (the centre is a grid vertex)")
    s = graded_axis(cells, grading)
    V, T = grid_tet_mesh(s, s, graded_axis(cells, grading, from_top=True))
    inf = np.max(np.abs(V), axis=1)
    two = np.linalg.norm(V, axis=1)
    scale = np.divide(inf, two, out=np.zeros_like(inf), where=two > 0)
    V = V * scale[:, None] * np.asarray(radii, float)
    surface = np.flatnonzero(np.isclose(inf, 1.0))
    return V, orient(V, T), surface


def write_vtk(path: str | Path, V: np.ndarray, T: np.ndarray) -> Path:
    """Write a legacy-ASCII VTK unstructured grid of tetrahedra (cell type 10), as Drake reads."""
    path = Path(path)
    lines = ["# vtk DataFile Version 3.0", "tetrahedral mesh (godobject_drake.systems.tissue)", "ASCII",
             "DATASET UNSTRUCTURED_GRID", f"POINTS {len(V)} double"]  # fmt: skip
    lines += [f"{x:.17g} {y:.17g} {z:.17g}" for x, y, z in V]
    lines.append(f"CELLS {len(T)} {5 * len(T)}")
    lines += [f"4 {a} {b} {c} {d}" for a, b, c, d in T]
    lines.append(f"CELL_TYPES {len(T)}")
    lines += ["10"] * len(T)
    path.write_text("\n".join(lines) + "\n")
    return path


def surface_triangles(T: np.ndarray) -> np.ndarray:
    """The boundary faces of a tetrahedral mesh (faces used by one tetrahedron), outward."""
    faces = np.concatenate([T[:, [1, 2, 3]], T[:, [0, 3, 2]], T[:, [0, 1, 3]], T[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[first[counts == 1]]


class FemOrgan:
    """An organ made a FEM deformable body, added to ``plant`` before ``Finalize()``
    (:func:`~godobject_drake.station.plant.add_plant` does it for ``organs.model: fem``) from a
    checked ``spec`` (``check_scenario`` checks a scenario's; ``spec.check()`` one made by hand).

    Attributes
    ----------
    body_id, geometry_id :
        The deformable body's and its geometry's ids.
    rest_W : (n, 3)
        The mesh's rest vertices in W.
    surface : np.ndarray
        Indices of the surface vertices.
    triangles : (m, 3)
        The surface's triangles (vertex indices into ``rest_W``), outward.
    attached : int
        How many vertices are fixed to the pelvis.
    """

    def __init__(self, plant: MultibodyPlant, scene_graph, spec: Organs, vtk_dir: str | Path | None = None):
        if plant.time_step() <= 0:
            raise ValueError("organs.model: fem needs a discrete SAP plant (plant.time_step > 0)")
        self.spec = spec
        inspector = scene_graph.model_inspector()
        host, gid = _find_geometry(plant, inspector, spec.organ)
        shape = inspector.GetShape(gid)
        if type(shape).__name__ != "Ellipsoid":
            raise ValueError(
                f"organs.organ: {spec.organ!r} is a {type(shape).__name__}; the FEM organ is meshed from an "
                "Ellipsoid collision geometry: name one"
            )
        radii = (shape.a(), shape.b(), shape.c())
        X_BG = inspector.GetPoseInFrame(gid)
        X_WB = _welded_pose(plant, host)
        X_WG = self.X_WG = X_WB @ X_BG  # the frame the FEM body is registered in
        # The rigid organ stops touching and being drawn; the FEM body takes its place.
        source = plant.get_source_id()
        for role in (Role.kProximity, Role.kIllustration, Role.kPerception):
            for other in _geometries_named(plant, inspector, host, inspector.GetName(gid)):
                if inspector.GetProperties(other, role) is not None:
                    scene_graph.RemoveRole(source, other, role)
        V, T, self.surface = ellipsoid_tet_mesh(radii, spec.cells, spec.grading)
        self.tets = T
        self.triangles = surface_triangles(T)
        self.tet_count = len(T)
        if vtk_dir is None:  # a folder of this organ's own, removed with it (or at exit)
            vtk_dir = tempfile.mkdtemp(prefix="godobject_tissue_")
            weakref.finalize(self, shutil.rmtree, vtk_dir, True)
        vtk_dir = Path(vtk_dir)
        self.vtk_dir = vtk_dir
        name = spec.organ.split("::")[-1]
        graded = f"_g{spec.grading:g}" if spec.grading != 1.0 else ""
        path = write_vtk(vtk_dir / f"{name}_{spec.cells}{graded}.vtk", V, T)
        instance = GeometryInstance(X_WG, Mesh(str(path)), f"{name}_fem")
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
        # The attachment: a box under the organ, from its bottom to attached_below_m under its top.
        top = float(self.rest_W[:, 2].max())
        cut = top - spec.attached_below_m
        bottom = float(self.rest_W[:, 2].min())
        if not cut > bottom:
            raise ValueError(
                f"organs.attached_below_m: {spec.attached_below_m} m reaches below the organ's bottom "
                f"({(top - bottom) * 1e3:.1f} mm under its top): give less, so some vertices are held"
            )
        # Held by Drake's wall boundary condition (zero displacement below the plane z = cut).
        # AddFixedConstraint to the welded pelvis builds but fails at the first step in Drake 1.51:
        # "Adding constraint to a clique with zero number of velocities is not allowed" (a welded
        # body is in the world's clique); the pelvis does not move, so the wall condition is the same.
        model.SetWallBoundaryCondition(self.body_id, np.array([0.0, 0.0, cut]), np.array([0.0, 0.0, 1.0]))
        self.attached = int(np.count_nonzero(self.rest_W[:, 2] < cut))
        if self.attached == 0:
            raise ValueError("organs.attached_below_m: no vertex is held; give a larger value")
        self.name = name
        self.glued = {body: self._glue(plant, body) for body in spec.glued}

    def _glue(self, plant: MultibodyPlant, scoped: str) -> int:
        """Fix the organ's vertices within a cube of ``glue_size_m`` about the free body ``scoped``'s
        start to that body (Drake's deformable fixed constraint); how many are fixed. Drake's
        ``X_BA`` is the pose in B of the frame the organ was registered in (``X_WG``), not of the
        world: an organ away from the origin glued with ``X_BW`` would hold the wrong vertices."""
        try:
            body = free_body(plant, scoped)
        except ValueError as e:
            raise ValueError(f"organs.glued: {e}") from None
        X_WB = plant.GetDefaultFloatingBaseBodyPose(body)
        size = self.spec.glue_size_m
        inside = np.all(np.abs(self.rest_W - X_WB.translation()) <= 0.5 * size, axis=1)
        if not inside.any():
            raise ValueError(
                f"organs.glued: {scoped} starts at {np.round(X_WB.translation(), 4).tolist()} m, no vertex "
                f"of the organ within {size * 1e3:g} mm (glue_size_m): move it onto the organ's surface"
            )
        plant.mutable_deformable_model().AddFixedConstraint(
            self.body_id, body, X_WB.inverse() @ self.X_WG, Box(size, size, size), RigidTransform()
        )
        return int(inside.sum())

    @property
    def vertex_count(self) -> int:
        return len(self.rest_W)

    def connect(self, builder, plant, capsules=(), tool_geometries=None, name="") -> "TissueObserver":
        """Add a :class:`TissueObserver` of the tool's ``capsules`` (:func:`tool_capsules`) and its
        contact with the tissue (``tool_geometries``; ``None``: every contact); ``name`` prefixes
        the system's name (one observer per tool)."""
        observer = builder.AddNamedSystem(
            f"{name}{self.name}_tissue_observer", TissueObserver(self, capsules, tool_geometries)
        )
        builder.Connect(
            plant.get_deformable_body_configuration_output_port(),
            observer.GetInputPort("deformable_configuration"),
        )
        builder.Connect(plant.get_body_poses_output_port(), observer.GetInputPort("body_poses"))
        builder.Connect(plant.get_contact_results_output_port(), observer.GetInputPort("contact_results"))
        return observer


def free_body(plant: MultibodyPlant, scoped: str, *, welded_ok: bool = False):
    """The free body ``model::body`` (or a model whose one body it is) of ``plant`` (before
    ``Finalize``); ``welded_ok``: or a body welded to the world (a rigid organ's glued site)."""
    model, _, name = scoped.rpartition("::")
    try:
        body = plant.GetBodyByName(name, plant.GetModelInstanceByName(model)) if model else None
        if body is None:
            (index,) = plant.GetBodyIndices(plant.GetModelInstanceByName(scoped))
            body = plant.get_body(index)
    except (RuntimeError, ValueError):
        raise ValueError(
            f"{scoped!r}: no such body; give a free body of the directives as model::body"
        ) from None
    jointed = {plant.get_joint(JointIndex(j)).child_body().index() for j in range(plant.num_joints())}
    welded = welded_ok and any(
        plant.get_joint(JointIndex(j)).child_body().index() == body.index()
        and plant.get_joint(JointIndex(j)).type_name() == "weld"
        and plant.get_joint(JointIndex(j)).parent_body().index() == plant.world_body().index()
        for j in range(plant.num_joints())
    )
    if body.index() in jointed and not welded:  # before Finalize a free body has no joint yet
        raise ValueError(f"{scoped}: a jointed or welded body; give a free body")
    return body


def weld_glued(plant: MultibodyPlant, organs: Organs) -> None:
    """Rigid organs cannot move: each body glued to the organ (``organs.glued``) is welded where it
    starts (before ``Finalize``)."""
    for scoped in organs.glued:
        try:
            body = free_body(plant, scoped)
        except ValueError as e:
            raise ValueError(f"organs.glued: {e}") from None
        plant.WeldFrames(plant.world_frame(), body.body_frame(), plant.GetDefaultFloatingBaseBodyPose(body))


MATERIALS = {
    "linear_corotated": MaterialModel.kLinearCorotated,
    "corotated": MaterialModel.kCorotated,
    "neohookean": MaterialModel.kNeoHookean,
    "linear": MaterialModel.kLinear,
}


def body_config(organs: Organs) -> DeformableBodyConfig:
    """Drake's FEM material and Rayleigh damping of the organs' tissue."""
    config = DeformableBodyConfig()
    config.set_youngs_modulus(organs.mesh_youngs_modulus_pa)
    config.set_poissons_ratio(organs.poissons_ratio)
    config.set_mass_density(organs.density_kg_m3)
    config.set_mass_damping_coefficient(organs.mass_damping_per_s)
    config.set_stiffness_damping_coefficient(organs.stiffness_damping_s)
    config.set_material_model(MATERIALS[organs.material])
    return config


def _some(names: list[str], n: int = 8) -> str:
    """At most ``n`` of ``names``, and how many there are."""
    shown = ", ".join(names[:n])
    return shown if len(names) <= n else f"{shown}, ... ({len(names)} in all)"


def _find_geometry(plant, inspector, scoped: str):
    names = []
    for i in range(plant.num_bodies()):
        body = plant.get_body(BodyIndex(i))
        for gid in plant.GetCollisionGeometriesForBody(body):
            names.append(inspector.GetName(gid))
            if inspector.GetName(gid) == scoped:
                return body, gid
    raise ValueError(
        f"organs.organ: {scoped!r} is not a collision geometry of this scene (it has "
        f"{_some(sorted(names))}); organs.model: fem replaces one of them (the laparoscopy scene's "
        "pelvis::uterus)"
    )


def _geometries_named(plant, inspector, body, name):
    frame = plant.GetBodyFrameIdOrThrow(body.index())
    return [g for g in inspector.GetGeometries(frame) if inspector.GetName(g) == name]


def _welded_pose(plant: MultibodyPlant, body) -> RigidTransform:
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
                f"organs.organ: its body {b.name()!r} is not welded to the world; the FEM organ is held to a "
                "welded body (weld it in the directives)"
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


class TissueObserver(LeafSystem):
    """The tissue's surface and what the tool does to it, per step.

    .. pydrake_system::

        name: TissueObserver
        input_ports:
        - deformable_configuration
        - body_poses
        - contact_results
        output_ports:
        - surface_positions
        - summary

    ``surface_positions``: the surface vertices in W ``[x0 y0 z0 x1 ...]``.
    ``summary`` (:data:`SUMMARY`): the largest surface displacement (m) and
    tetrahedron strain (largest principal Green strain); the tool's
    penetration into the deformed surface (m: the deepest surface vertex
    inside any of the tool's capsules, its radius minus its distance to the
    capsule's axis); whether a capsule's end lies inside the deformed surface
    (1: a pop-through); and the contact force on the tissue in W (N, from
    Drake's contact results: the tool feels its opposite), of the contacts with
    ``tool_geometries`` only when given (a scene of several tools: each its own).
    """

    SUMMARY = ("max_displacement_m", "max_strain", "tool_penetration_m", "tip_inside", "fx_N", "fy_N", "fz_N")

    def __init__(self, organ: FemOrgan, capsules=(), tool_geometries=None):
        super().__init__()
        self._organ = organ
        self._tool_geometries = None if tool_geometries is None else frozenset(tool_geometries)
        self._gid = organ.geometry_id
        self._config = self.DeclareAbstractInputPort(
            "deformable_configuration", AbstractValue.Make(GeometryConfigurationVector())
        )
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self._contacts = self.DeclareAbstractInputPort(
            "contact_results", AbstractValue.Make(ContactResults())
        )
        self._capsules = list(capsules)  # (body index, X_BG, radius, half length): capsules along G's z
        self.DeclareVectorOutputPort("surface_positions", 3 * len(organ.surface), self._surface)
        self.DeclareVectorOutputPort("summary", len(self.SUMMARY), self._summary)

    def positions(self, context) -> np.ndarray:
        return np.asarray(self._config.Eval(context).value(self._gid)).reshape(-1, 3)

    def _surface(self, context, output):
        output.SetFromVector(self.positions(context)[self._organ.surface].ravel())

    def contact_force(self, context) -> np.ndarray:
        """The net contact force on the tissue (N, W), of the tool's contacts when given."""
        results = self._contacts.Eval(context)
        mine = self._tool_geometries
        f = np.zeros(3)
        for i in range(results.num_deformable_contacts()):
            info = results.deformable_contact_info(i)
            a, b = info.id_A(), info.id_B()
            if a == self._gid and (mine is None or b in mine):
                f += info.F_Ac_W().translational()
            elif b == self._gid and (mine is None or a in mine):
                f -= info.F_Ac_W().translational()
        return f

    def _summary(self, context, output):
        p = self.positions(context)
        organ = self._organ
        u = p - organ.rest_W
        displacement = float(np.max(np.linalg.norm(u[organ.surface], axis=1)))
        strain = max_tet_strain(organ, p) if displacement > 1e-6 else 0.0  # at rest: none
        depth, inside = 0.0, False
        if self._capsules:
            poses = self._poses.Eval(context)
            lower, upper = p.min(axis=0), p.max(axis=0)
            for index, X_BG, radius, half in self._capsules:
                X_WG = poses[index] @ X_BG
                a, axis = X_WG.translation(), X_WG.rotation().matrix()[:, 2]
                ends = np.array([a - half * axis, a + half * axis])
                if np.any(ends.max(axis=0) + radius < lower) or np.any(ends.min(axis=0) - radius > upper):
                    continue  # the capsule's box misses the organ's: nothing to measure
                d, i = capsule_against_surface(p, organ.surface, organ.triangles, a, axis, radius, half)
                depth, inside = max(depth, d), inside or i
        output.SetFromVector([displacement, strain, depth, float(inside), *self.contact_force(context)])


def tool_capsules(plant: MultibodyPlant, scene_graph, model) -> list:
    """``(body index, X_BG, radius, half length)`` of every capsule collision geometry of ``model``."""
    inspector = scene_graph.model_inspector()
    out = []
    for b in plant.GetBodyIndices(model):
        for gid in plant.GetCollisionGeometriesForBody(plant.get_body(b)):
            shape = inspector.GetShape(gid)
            if isinstance(shape, Capsule):
                out.append((int(b), inspector.GetPoseInFrame(gid), shape.radius(), 0.5 * shape.length()))
    return out


def max_tet_strain(organ: FemOrgan, p: np.ndarray) -> float:
    """The largest principal Green strain magnitude over the tetrahedra (rotation-free)."""
    cache = getattr(organ, "_strain_cache", None)
    if cache is None:
        T = organ_tets(organ)
        X = organ.rest_W
        Dm = np.stack([X[T[:, k]] - X[T[:, 0]] for k in (1, 2, 3)], axis=2)
        organ._strain_cache = cache = (T, np.linalg.inv(Dm))
    T, Dm_inv = cache
    Ds = np.stack([p[T[:, k]] - p[T[:, 0]] for k in (1, 2, 3)], axis=2)
    F = Ds @ Dm_inv
    E = 0.5 * (np.swapaxes(F, 1, 2) @ F - np.eye(3))
    return float(np.max(symmetric_extreme_eigenvalues(E)))


def symmetric_extreme_eigenvalues(A: np.ndarray) -> np.ndarray:
    """``max(|λ_max|, |λ_min|)`` of each symmetric 3×3 matrix of ``A`` (m, 3, 3), in closed form
    (the trigonometric solution of the characteristic cubic): what ``np.abs(eigvalsh(A)).max(-1)``
    gives, a few times faster for the hundreds of small matrices a step of the tissue has."""
    a00, a11, a22 = A[:, 0, 0], A[:, 1, 1], A[:, 2, 2]
    a01, a02, a12 = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0)
    safe = np.where(p > 0.0, p, 1.0)
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    r = np.clip(det / (2.0 * safe**3), -1.0, 1.0)
    phi = np.arccos(r) / 3.0
    largest = q + 2.0 * p * np.cos(phi)
    smallest = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    return np.maximum(np.abs(largest), np.abs(smallest))


def organ_tets(organ: FemOrgan) -> np.ndarray:
    return organ.tets


def capsule_against_surface(p, surface, triangles, a, axis, radius, half) -> tuple[float, bool]:
    """How deep the deepest surface vertex is inside a capsule (centre ``a``, unit ``axis``,
    ``radius``, half length ``half``), and whether its lower end lies inside the closed surface
    (generalized winding number of the triangles ``triangles`` of positions ``p``)."""
    q = p[surface] - a
    t = np.clip(q @ axis, -half, half)
    d = np.linalg.norm(q - t[:, None] * axis, axis=1)
    depth = float(max(0.0, radius - d.min()))
    end = a - half * axis
    A, B, C = (p[triangles[:, k]] - end for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (A, B, C))
    det = np.einsum("ij,ij->i", A, np.cross(B, C))
    den = la * lb * lc + np.einsum("ij,ij->i", A, B) * lc + np.einsum("ij,ij->i", B, C) * la
    den += np.einsum("ij,ij->i", C, A) * lb
    winding = np.sum(np.arctan2(det, den)) / (2.0 * math.pi)
    return depth, bool(winding > 0.5)


# -- the tissue's stiffness at a contact, from the FEM model (linear statics) ------------------------------
