"""The FEM organ's stiffness where a tool presses it, from its own mesh (linear statics).

``analyze`` on FEM tissue reads the organ's stiffness at the point the tool's axis meets its rest
surface: the small-strain stiffness matrix of the organ's tetrahedra with the held vertices fixed
(:func:`linear_stiffness_matrix`), a point force shared by the surface triangle's vertices as Drake
applies a contact force (:func:`ray_surface_hit`), and ``k = 1/(wᵀ K⁻¹ w)``
(:func:`contact_stiffness`); docs/theory.md §8. The FEM body itself is a
:class:`~godobject_drake.systems.soft_body.FemSoftBody` (the laparoscopy's organ or one's own).
"""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from godobject_drake.systems.tissue import organ_tets


def linear_stiffness_matrix(V: np.ndarray, T: np.ndarray, youngs_modulus: float, poissons_ratio: float):
    """The small-strain stiffness matrix (3n × 3n, sparse CSR, N/m) of the linear tetrahedra ``T``
    on vertices ``V``: ``Σ vol Bᵀ D B`` per tetrahedron, D isotropic (Lamé λ, μ of E, ν).

    Drake's corotated material has this tangent at rest, so it is the FEM body's stiffness for
    small displacements (docs/theory.md §8).
    """
    V, T = np.asarray(V, float), np.asarray(T, int)
    E, nu = float(youngs_modulus), float(poissons_ratio)
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[np.diag_indices(6)] += np.array([2 * mu] * 3 + [mu] * 3)
    Dm = np.stack([V[T[:, k]] - V[T[:, 0]] for k in (1, 2, 3)], axis=2)  # columns: edges from vertex 0
    vol = np.abs(np.linalg.det(Dm)) / 6.0
    G = np.linalg.inv(Dm)  # rows: gradients of the shape functions of vertices 1..3
    grads = np.concatenate([-G.sum(axis=1, keepdims=True), G], axis=1)  # (m, 4, 3)
    B = np.zeros((len(T), 6, 12))
    for a in range(4):
        bx, by, bz = grads[:, a, 0], grads[:, a, 1], grads[:, a, 2]
        c = 3 * a
        B[:, 0, c], B[:, 1, c + 1], B[:, 2, c + 2] = bx, by, bz
        B[:, 3, c + 1], B[:, 3, c + 2] = bz, by
        B[:, 4, c], B[:, 4, c + 2] = bz, bx
        B[:, 5, c], B[:, 5, c + 1] = by, bx
    Ke = vol[:, None, None] * np.einsum("mji,jk,mkl->mil", B, D, B)
    dofs = (3 * T[:, :, None] + np.arange(3)).reshape(len(T), 12)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    n = 3 * len(V)
    return sp.coo_matrix((Ke.ravel(), (rows, cols)), shape=(n, n)).tocsr()


def static_compliance(K, fixed: np.ndarray, weights: dict[int, float], direction) -> float:
    """``δ/F`` (m/N): the weighted displacement along ``direction`` of a force ``F`` along it,
    spread over the vertices of ``weights`` (vertex → share, summing to 1), the vertices of
    ``fixed`` (a boolean mask) held. The weighted displacement is ``Σ wᵢ uᵢ·n``: for shares that
    are a point's barycentric coordinates on a surface triangle, the displacement of that point.
    """
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    n = K.shape[0] // 3
    free = np.flatnonzero(~np.repeat(np.asarray(fixed, bool), 3))
    f = np.zeros(3 * n)
    for v, w in weights.items():
        f[3 * v : 3 * v + 3] += w * d
    if np.any(f[np.repeat(np.asarray(fixed, bool), 3)] != 0):
        raise ValueError("static_compliance: a loaded vertex is held; load a free vertex")
    u = np.zeros(3 * n)
    u[free] = spla.spsolve(K[free][:, free].tocsc(), f[free])
    return float(f @ u)


def ray_surface_hit(V: np.ndarray, triangles: np.ndarray, origin, direction):
    """The first hit of the ray ``origin + t·direction`` (t ≥ 0) on the triangles (Möller–Trumbore):
    ``(t, triangle index, barycentric weights (3,), outward unit normal)``, or None on a miss."""
    o, d = np.asarray(origin, float), np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    A, B, C = (V[triangles[:, k]] for k in range(3))
    e1, e2 = B - A, C - A
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-18
    inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
    s = o - A
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    eps = 1e-9
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t >= 0)
    if not np.any(hit):
        return None
    i = int(np.flatnonzero(hit)[np.argmin(t[hit])])
    normal = np.cross(e1[i], e2[i])
    w = np.clip(np.array([1.0 - u[i] - v[i], u[i], v[i]]), 0.0, 1.0)
    return float(t[i]), i, w / w.sum(), normal / np.linalg.norm(normal)


def _held_stiffness(organ):
    """The organ's small-strain stiffness matrix (kept on it, assembled once) and the mask of the
    vertices its ``attach`` holds."""
    K = getattr(organ, "_linear_K", None)
    if K is None:
        spec = organ.spec
        K = organ._linear_K = linear_stiffness_matrix(
            organ.rest_W, organ_tets(organ), spec.mesh_youngs_modulus_pa, spec.poissons_ratio
        )
    return K, organ.held


def contact_stiffness(organ, origin, direction) -> dict:
    """The FEM organ's stiffness (N/m) where the ray ``origin + t·direction`` first meets its rest
    surface, for a point force along the ray there (a tool tip far smaller than a surface
    triangle: the force goes to the triangle's vertices by the point's barycentric weights, as
    Drake's contact does). ``organ``: a :class:`~godobject_drake.systems.soft_body.FemSoftBody`,
    its held vertices those its ``attach`` holds. The organ's material and held vertices, linear statics
    (:func:`linear_stiffness_matrix`). Raises ``ValueError`` if the ray misses the organ.
    """
    hit = ray_surface_hit(organ.rest_W, organ.triangles, origin, direction)
    if hit is None:
        raise ValueError(
            f"the ray from {np.round(np.asarray(origin, float), 4).tolist()} m along "
            f"{np.round(np.asarray(direction, float), 3).tolist()} misses the organ {organ.name!r}"
        )
    t, tri, w, normal = hit
    K, fixed = _held_stiffness(organ)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    weights = {int(v): float(x) for v, x in zip(organ.triangles[tri], w, strict=True) if x > 0}
    c = static_compliance(K, fixed, weights, d)
    point = np.asarray(origin, float) + t * d
    return {"stiffness_n_m": 1.0 / c, "point_W": point.tolist(), "normal_W": normal.tolist(),
            "distance_m": t, "vertices": list(weights), "weights": list(weights.values())}  # fmt: skip


class OrganCompliance:
    """:func:`contact_stiffness` for many points of one organ: its stiffness matrix assembled
    and the free vertices' block factorised once (SuperLU), so each point costs two triangular
    solves (the local model asks it at the scene's rate: docs/local_model.md "An articulated
    tool"). The same linear statics, the same held vertices."""

    def __init__(self, organ):
        K, fixed = _held_stiffness(organ)
        self.organ, self.n = organ, K.shape[0]
        self.free = np.flatnonzero(~np.repeat(fixed, 3))
        self._lu = spla.splu(K[self.free][:, self.free].tocsc())

    def stiffness(self, triangle: int, weights, direction) -> float:
        """The organ's stiffness (N/m) for a point force along ``direction`` at the point of
        barycentric ``weights`` on its surface ``triangle`` (:func:`ray_surface_hit`'s)."""
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        f = np.zeros(self.n)
        for v, w in zip(self.organ.triangles[triangle], weights, strict=True):
            f[3 * v : 3 * v + 3] += w * d
        f_free = f[self.free]
        return 1.0 / float(f_free @ self._lu.solve(f_free))
