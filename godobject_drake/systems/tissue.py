"""FEM tissue's meshes, materials and measures, and the laparoscopy's organ seen from its tools.

The rigid scene models an organ as a rigid shape with a soft point-contact stiffness: its
"penetration" stands for the tissue's indentation, and the organ is drawn undeformed. With
``organs.model: fem`` the organ is a Drake FEM deformable body instead (linear tetrahedra, Drake's
linear corotated material unless ``organs.material`` says otherwise, integrated implicitly in
SAP): the ``deformables:`` entry :meth:`~godobject_drake.config.scene.Organs.soft_body` stands
for, built as any soft body is (:class:`~godobject_drake.systems.soft_body.FemSoftBody`): it
replaces the pelvis's ellipsoid (whose roles are removed), its vertices more than
``attached_below_m`` under its top held in place by Drake's wall boundary condition. Each tool
that presses it measures it from its own capsules (:class:`TissueObserver`, the ``tissue_*``
metrics).

Drake 1.51 meshes a deformable Sphere or Box from a resolution hint but not an Ellipsoid ("We
don't yet generate deformable meshes for Ellipsoid"), so the tetrahedral mesh is made here
(:func:`ellipsoid_tet_mesh`): a cube grid of ``cells`` cells a side, each cell split into Kuhn's six
tetrahedra (which share its main diagonal, so neighbouring cells' faces match), mapped radially
onto the unit ball and scaled to the ellipsoid's radii. It is written as a legacy VTK file
(:func:`write_vtk`), which ``RegisterDeformableBody`` reads through a ``Mesh`` shape. The same
grid, graded, gives the block of the contact-mechanics check
(:mod:`godobject_drake.studies.indentation`).

Measured (Drake 1.51): ``AddFixedConstraint`` to the welded pelvis is accepted at build time but
stops the first step ("Adding constraint to a clique with zero number of velocities is not
allowed"); the wall boundary condition holds the organ to the pelvis, which does not move.
"""

import math
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    Capsule,
    GeometryConfigurationVector,
)
from pydrake.math import RigidTransform
from pydrake.multibody.fem import DeformableBodyConfig, MaterialModel
from pydrake.multibody.plant import ContactResults, MultibodyPlant
from pydrake.multibody.tree import JointIndex
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


def connect_tissue_observer(builder, plant, organ, capsules=(), tool_geometries=None, name=""):
    """Add a :class:`TissueObserver` of ``organ`` (the laparoscopy's soft organ, a
    :class:`~godobject_drake.systems.soft_body.FemSoftBody`) for one tool: its ``capsules``
    (:func:`tool_capsules`) and its contact with the tissue (``tool_geometries``; ``None``: every
    contact); ``name`` prefixes the system's name (one observer per tool)."""
    observer = builder.AddNamedSystem(
        f"{name}{organ.name}_tissue_observer", TissueObserver(organ, capsules, tool_geometries)
    )
    configuration = plant.get_deformable_body_configuration_output_port()
    builder.Connect(configuration, observer.GetInputPort("deformable_configuration"))
    builder.Connect(plant.get_body_poses_output_port(), observer.GetInputPort("body_poses"))
    builder.Connect(plant.get_contact_results_output_port(), observer.GetInputPort("contact_results"))
    return observer


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

    def __init__(self, organ, capsules=(), tool_geometries=None):
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


def max_tet_strain(organ, p: np.ndarray) -> float:
    """The largest principal Green strain magnitude over the tetrahedra of ``organ`` (a
    :class:`~godobject_drake.systems.soft_body.FemSoftBody`) at positions ``p`` (rotation-free)."""
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


def organ_tets(organ) -> np.ndarray:
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
