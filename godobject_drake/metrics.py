"""Run metrics, measured on true shapes, and the table printed after a run.

Penetration between true box shapes is computed by the separating-axis
test over the 15 candidate axes of two boxes (3 + 3 face normals, 9 edge
cross products). For overlapping convex polyhedra the smallest overlap over
those axes *is* the penetration depth (minimum translational distance); for
separated boxes the largest gap is a lower bound on their distance.
``tests/test_metrics.py`` checks it against Drake's own signed distance, which
measures every other pair of shapes (:class:`TrueShapeMetrics`).
"""

from __future__ import annotations

import dataclasses
import math
import textwrap
import warnings
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    Box,
    Capsule,
    CollisionFilterDeclaration,
    Cylinder,
    Ellipsoid,
    GeometrySet,
    HalfSpace,
    Role,
    SceneGraph,
    Sphere,
)
from pydrake.multibody.plant import MultibodyPlant

from godobject_drake.config.scenario import tool_records
from godobject_drake.config.scene import is_proxy
from godobject_drake.limits import explicit_limit_omega_h
from godobject_drake.outputs import dumps_metrics, write_atomically
from godobject_drake.spatial import quats_to_rotations
from godobject_drake.systems.coupling import GraspableBody, graspable_bodies
from godobject_drake.task_metrics import CameraView, CollisionFold, ForceFold, TipMotion


class PenetrationBudgetWarning(UserWarning):
    """A god-object can go, or went, deeper into an obstacle than the scene's budget
    (``metrics.penetration_budget_m``): said at build for the capped pull's static depth, and at
    the end of a run past it."""


def _rotations(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` of logged quaternions ``(N, 4)``, normalised first (they drift)."""
    return quats_to_rotations(q / np.linalg.norm(q, axis=1, keepdims=True))


# Keys every scene's metrics JSON has, in table order (docs/metrics.md).
METRIC_KEYS = (
    "scene",
    "mode",
    "time_step_s",
    "sim_time_s",
    "wall_time_s",
    "real_time_factor",
    "max_penetration_m",
    "rms_tracking_error_m",
    "max_other_body_speed_mps",
    "diverged",
)
FREE_SPACE_MARGIN_M = 0.002  # "free space": ≥ 2 mm from every other true shape.


@dataclasses.dataclass(frozen=True)
class TrueShape:
    """A true (non-proxy) collision shape: on body ``body_index`` (None = anchored).

    Boxes keep their pose ``X_BG`` (in the body, or in the world when anchored) and half sizes
    for the separating-axis test; other shapes are measured by Drake's signed distance, or
    against a half space by their support function (:func:`half_space_overlap`).
    """

    name: str
    geometry_id: object
    body_index: int | None
    shape: object = None
    R_BG: np.ndarray | None = None
    p_BG: np.ndarray | None = None
    half: np.ndarray | None = None

    @property
    def is_box(self) -> bool:
        return self.half is not None


def true_shapes(plant: MultibodyPlant, scene_graph: SceneGraph) -> list[TrueShape]:
    """Every non-proxy proximity geometry of ``plant`` (rigid ones: a deformable body's are skipped)."""
    inspector = scene_graph.model_inspector()
    world = plant.world_body()
    context = plant.CreateDefaultContext()
    shapes = []
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        name = inspector.GetName(gid)
        if is_proxy(name) or inspector.IsDeformableGeometry(gid):
            continue
        body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
        anchored = body.index() == world.index() or not body.is_floating_base_body()
        index = None if anchored else int(body.index())
        shape = inspector.GetShape(gid)
        if not isinstance(shape, Box):
            shapes.append(TrueShape(name, gid, index, shape))
            continue
        X_BG = inspector.GetPoseInFrame(gid)
        if anchored:  # welded: store its pose in the world once
            X_BG = body.EvalPoseInWorld(context).multiply(X_BG)
        R, p, half = X_BG.rotation().matrix(), X_BG.translation(), np.array(shape.size()) / 2
        shapes.append(TrueShape(name, gid, index, shape, R_BG=R, p_BG=p, half=half))
    return shapes


def box_overlap(cA, RA, hA, cB, RB, hB) -> np.ndarray:
    """Smallest overlap over the separating axes of boxes A and B, per sample.

    Arrays carry a leading sample axis: centres ``(N, 3)``, rotations
    ``(N, 3, 3)`` whose columns are the box axes in W, half sizes ``(3,)``.
    A positive result is the penetration depth (m); a negative one is minus
    a lower bound on the distance between the boxes.
    """
    d = cB - cA
    axes = [RA[:, :, i] for i in range(3)] + [RB[:, :, j] for j in range(3)]
    for i in range(3):
        for j in range(3):
            axes.append(np.cross(RA[:, :, i], RB[:, :, j]))
    best = np.full(len(d), np.inf)
    for L in axes:
        n = np.linalg.norm(L, axis=1)
        ok = n > 1e-9  # parallel edges give no new axis
        L = L / np.where(ok, n, 1.0)[:, None]
        rA = np.abs(np.einsum("ni,nij->nj", L, RA)) @ hA
        rB = np.abs(np.einsum("ni,nij->nj", L, RB)) @ hB
        overlap = rA + rB - np.abs(np.einsum("ni,ni->n", L, d))
        best = np.where(ok, np.minimum(best, overlap), best)
    return best


class TrueShapeMetrics:
    """Penetration and clearance of free bodies on their true shapes.

    Box against box: the separating-axis test on the logged states (vectorised, exact for
    overlapping boxes). Any pair with another shape (a cylinder, a capsule, a mesh's convex
    hull...): Drake's signed distance, evaluated on ``diagram``'s SceneGraph at each logged
    state. ``diagram`` is needed only when the scene has such shapes.
    """

    def __init__(self, plant: MultibodyPlant, scene_graph: SceneGraph, diagram=None):
        self.plant = plant
        self.shapes = true_shapes(plant, scene_graph)
        self.boxes = [s for s in self.shapes if s.is_box]
        self.bodies: dict[int, GraspableBody] = {b.index: b for b in graspable_bodies(plant).values()}
        self._diagram = diagram

    def _box_in_world(self, box: TrueShape, states: np.ndarray):
        n = len(states)
        if box.body_index is None:
            return np.broadcast_to(box.p_BG, (n, 3)), np.broadcast_to(box.R_BG, (n, 3, 3))
        b = self.bodies[box.body_index]
        R_WB = _rotations(states[:, b.q_start : b.q_start + 4])
        p_WB = states[:, b.q_start + 4 : b.q_start + 7]
        return p_WB + R_WB @ box.p_BG, R_WB @ box.R_BG

    def overlaps(self, body_index: int, states: np.ndarray) -> np.ndarray:
        """``(N, M)`` overlaps of ``body_index``'s true shapes against the M others (m; < 0: apart)."""
        own = [s for s in self.shapes if s.body_index == body_index]
        others = [s for s in self.shapes if s.body_index != body_index]
        out = np.full((len(states), len(others)), -np.inf)
        drake_pairs = []
        for a in own:
            for j, o in enumerate(others):
                if a.is_box and o.is_box:
                    cA, RA = self._box_in_world(a, states)
                    cB, RB = self._box_in_world(o, states)
                    out[:, j] = np.maximum(out[:, j], box_overlap(cA, RA, a.half, cB, RB, o.half))
                else:
                    drake_pairs.append((a, j, o))
        if drake_pairs and len(states):
            out = np.maximum(out, self._signed_distance_overlaps(drake_pairs, states, len(others)))
        return out

    def _signed_distance_overlaps(self, pairs, states: np.ndarray, m: int) -> np.ndarray:
        if self._diagram is None:
            a, _, o = pairs[0]
            raise ValueError(
                f"{a.name} against {o.name} needs Drake's signed distance: give TrueShapeMetrics the diagram"
            )
        context = self._diagram.CreateDefaultContext()
        plant_context = self.plant.GetMyMutableContextFromRoot(context)
        port = self.plant.get_geometry_query_input_port()
        nq = self.plant.num_positions()
        out = np.full((len(states), m), -np.inf)
        for k, x in enumerate(states):
            self.plant.SetPositions(plant_context, x[:nq])
            query = port.Eval(plant_context)
            for a, j, o in pairs:
                if isinstance(o.shape, HalfSpace) or isinstance(a.shape, HalfSpace):
                    plane, solid = (o, a) if isinstance(o.shape, HalfSpace) else (a, o)
                    overlap = half_space_overlap(
                        solid.shape,
                        query.GetPoseInWorld(solid.geometry_id),
                        query.GetPoseInWorld(plane.geometry_id),
                    )
                    if overlap is None:
                        raise ValueError(
                            f"penetration of {solid.name} into the half space {plane.name}: no support "
                            f"function for a {type(solid.shape).__name__} (and Drake's signed distance "
                            "takes only spheres against half spaces); use a box, sphere, cylinder, capsule "
                            "or ellipsoid, or a thick box for the floor"
                        )
                    out[k, j] = max(out[k, j], overlap)
                    continue
                try:
                    d = query.ComputeSignedDistancePairClosestPoints(a.geometry_id, o.geometry_id).distance
                except RuntimeError as e:
                    raise ValueError(
                        f"penetration of {a.name} into {o.name}: Drake cannot measure this pair ({e}); "
                        "give one of them a primitive collision shape (box, sphere, cylinder, capsule, "
                        "ellipsoid)"
                    ) from None
                out[k, j] = max(out[k, j], -d)
        return out


def half_space_overlap(shape, X_WG, X_WH) -> float | None:
    """How deep a convex primitive at ``X_WG`` goes into the half space ``z ≤ 0`` of frame H (m).

    Positive: penetration; negative: minus the clearance. With ``n`` the half space's outward
    normal (H's z axis) and ``c`` the shape's centre, the deepest point of the shape lies
    ``h(n)`` below ``c`` along ``n``, where ``h`` is its support radius: a box's
    ``Σ |n·Rᵢ| halfᵢ``, a sphere's ``r``, an ellipsoid's ``√Σ (aᵢ n·Rᵢ)²``, a cylinder's
    ``r √(1 − (n·a)²) + (L/2)|n·a|`` and a capsule's ``r + (L/2)|n·a|`` (``a`` its axis).
    None for another shape.
    """
    n = X_WH.rotation().col(2)
    R = X_WG.rotation().matrix()
    along = n @ R  # n in the shape's axes
    if isinstance(shape, Box):
        h = float(np.abs(along) @ (np.array(shape.size()) / 2))
    elif isinstance(shape, Sphere):
        h = shape.radius()
    elif isinstance(shape, Ellipsoid):
        h = float(np.linalg.norm(np.array([shape.a(), shape.b(), shape.c()]) * along))
    elif isinstance(shape, Cylinder):
        c = abs(along[2])
        h = shape.radius() * math.sqrt(max(0.0, 1.0 - c * c)) + 0.5 * shape.length() * c
    elif isinstance(shape, Capsule):
        h = shape.radius() + 0.5 * shape.length() * abs(along[2])
    else:
        return None
    return h - float(n @ (X_WG.translation() - X_WH.translation()))


class RigidMetrics:
    """Penetration, free-space tracking error and other bodies' speed, folded in chunk by chunk.

    :meth:`update` takes a run's logs a chunk at a time (any split gives the same maxima and
    counts, and sums equal to the last bits), so a long run keeps no more than a chunk;
    :meth:`result` reads the running values (it may be called at any time).
    """

    def __init__(self, shapes: TrueShapeMetrics):
        self.shapes = shapes
        self.max_pen, self.sq_err, self.n_free, self.max_speed = 0.0, 0.0, 0, 0.0

    def update(self, states: np.ndarray, held: np.ndarray, p_WT: np.ndarray) -> None:
        """``states`` (N, nq+nv) plant states; ``held`` (N,) held BodyIndex (−1: none); ``p_WT``
        (N, 3) target of the held body's centre of mass (m)."""
        shapes = self.shapes
        speed = np.zeros(len(states))
        for index, body in shapes.bodies.items():
            when = held == index
            cm = _cm_positions(body, states[when]) if when.any() else None
            if cm is not None:
                ov = shapes.overlaps(index, states[when])
                self.max_pen = max(self.max_pen, float(np.max(ov, initial=0.0)))
                free = np.all(ov < -FREE_SPACE_MARGIN_M, axis=1)
                self.sq_err += float(np.sum(np.sum((p_WT[when][free] - cm[free]) ** 2, axis=1)))
                self.n_free += int(free.sum())
            v = np.linalg.norm(_cm_velocities(body, states), axis=1)
            speed = np.maximum(speed, np.where(held == index, 0.0, v))
        self.max_speed = max(self.max_speed, float(speed.max(initial=0.0)))

    def result(self) -> dict:
        return {
            "max_penetration_m": self.max_pen,
            "rms_tracking_error_m": math.sqrt(self.sq_err / self.n_free) if self.n_free else None,
            "free_space_samples": self.n_free,
            "max_other_body_speed_mps": self.max_speed,
        }


def _cm_positions(body: GraspableBody, states: np.ndarray) -> np.ndarray:
    R = _rotations(states[:, body.q_start : body.q_start + 4])
    return states[:, body.q_start + 4 : body.q_start + 7] + R @ body.p_BoBcm_B


def _cm_velocities(body: GraspableBody, states: np.ndarray) -> np.ndarray:
    R = _rotations(states[:, body.q_start : body.q_start + 4])
    w = states[:, body.v_start : body.v_start + 3]
    return states[:, body.v_start + 3 : body.v_start + 6] + np.cross(w, R @ body.p_BoBcm_B)


TEXT_WIDTH = 72  # a text in the metrics table (a warning) is wrapped to this many characters


def format_table(rows: list[dict]) -> str:
    """A plain-text table of metrics, one column per run; a run of several tools gives the scene's
    column and one per tool (its ``tools``)."""
    columns, headers, split = [], [], []  # split: a key the column lacks is the other part's, left blank
    for i, r in enumerate(rows):
        tools = r.get("tools") if isinstance(r.get("tools"), dict) else None
        columns.append({k: v for k, v in r.items() if k != "tools"})
        headers.append(str(r.get("mode", f"run {i}")) if tools is None else "scene")
        split.append(tools is not None)
        for name, m in (tools or {}).items():
            columns.append(m)
            headers.append(name)
            split.append(True)
    keys = [k for k in METRIC_KEYS if any(k in c for c in columns)]
    keys += sorted({k for c in columns for k in c} - set(keys))

    def fmt(v):
        if isinstance(v, bool) or v is None or isinstance(v, str):
            return str(v)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, list | tuple):
            return ",".join(fmt(x) for x in v) or "[]"
        return f"{v:.4g}"

    cells = [["metric", *headers]]
    cells += [[k] + [fmt(c.get(k)) if k in c or not s else "" for c, s in zip(columns, split, strict=True)]
              for k in keys]  # fmt: skip
    # a long text (a warning) wrapped within its column, on lines of its own below the metric's name
    wrapped = [[textwrap.wrap(c, TEXT_WIDTH, break_on_hyphens=False) or [""] for c in row] for row in cells]
    widths = [max(len(line) for row in wrapped for line in row[i]) for i in range(len(cells[0]))]
    lines = []
    for row in wrapped:
        for j in range(max(len(c) for c in row)):
            parts = [(c[j] if j < len(c) else "").ljust(w) for c, w in zip(row, widths, strict=True)]
            lines.append("  ".join(parts).rstrip())
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def write_metrics(path: str | Path, metrics: dict | list) -> None:
    """Write metrics as strict JSON, all at once (:mod:`godobject_drake.outputs`): a non-finite
    value is ``null`` and listed under ``non_finite``; a failed write raises
    :class:`~godobject_drake.outputs.OutputError` and leaves the previous file."""

    write_atomically(path, dumps_metrics(metrics))


class TissueMetrics:
    """FEM tissue under an articulated tool (:class:`~godobject_drake.systems.tissue.TissueObserver`'s
    summary rows), folded chunk by chunk: the deepest, largest and longest over the run."""

    def __init__(self):
        self.max_disp = self.max_strain = self.max_pen = self.max_force = 0.0
        self.inside_steps = self.steps = 0
        self.force_at_max = np.zeros(3)

    def update(self, rows: np.ndarray) -> None:
        rows = np.asarray(rows, float).reshape(-1, 7)
        if not len(rows):
            return
        self.steps += len(rows)
        self.max_disp = max(self.max_disp, float(rows[:, 0].max()))
        self.max_strain = max(self.max_strain, float(rows[:, 1].max()))
        self.max_pen = max(self.max_pen, float(rows[:, 2].max()))
        self.inside_steps += int(np.count_nonzero(rows[:, 3] > 0.5))
        force = np.linalg.norm(rows[:, 4:7], axis=1)
        k = int(np.argmax(force))
        if force[k] > self.max_force:
            self.max_force, self.force_at_max = float(force[k]), -rows[k, 4:7]

    def result(self) -> dict:
        return {
            "tissue_max_displacement_m": self.max_disp,
            "tissue_max_strain": self.max_strain,
            "tool_penetration_into_tissue_m": self.max_pen,
            "tool_tip_inside_tissue_steps": self.inside_steps,
            "max_tissue_contact_force_N": self.max_force,
            "tool_force_at_max_N": [float(v) for v in self.force_at_max],
        }


def soft_body_result(measured: TissueMetrics) -> dict:
    """A soft body's metrics (``deformables``; the run's metrics give them its name first,
    ``lobe_max_displacement_m``), from its
    :class:`~godobject_drake.systems.soft_body.SoftBodyObserver`'s rows folded by ``measured``."""
    return {
        "max_displacement_m": measured.max_disp,
        "max_strain": measured.max_strain,
        "rigid_penetration_m": measured.max_pen,  # the deepest a moving body's shape is inside it
        "rigid_inside_steps": measured.inside_steps,  # steps a moving body's origin was inside it
        "max_contact_force_N": measured.max_force,
        "force_at_max_N": [float(-v) for v in measured.force_at_max],  # on the soft body
        "steps": measured.steps,
    }


class ToolMetrics:
    """Penetration, tip tracking and trocar offset of an articulated tool, folded in chunk by chunk.

    Penetration is Drake's signed distance between the tool's collision
    shapes and every other collision shape (capsules, ellipsoids and
    spheres here: exact shapes, no proxies), the deepest over the run. A
    step is in free space when every such distance is at least
    ``FREE_SPACE_MARGIN_M``; there the tip (origin of ``tip_body``) is
    compared with the device's tip (the same point on the kinematic copy at
    ``q_device``). With ``pivot_body`` (welded at the insertion point P),
    ``max_trocar_offset_m`` is the largest distance of P from the tip
    body's z axis (the tube's axis). Rows are measured one by one in order,
    so any split into chunks gives the very same numbers.
    """

    def __init__(self, diagram, plant: MultibodyPlant, scene_graph: SceneGraph, tool, tip_body: str,
                 pivot_body: str | None = None):  # fmt: skip
        self.plant, self.tool = plant, tool
        self._context = diagram.CreateDefaultContext()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._query_port = plant.get_geometry_query_input_port()
        self._inspector = scene_graph.model_inspector()
        self._tool_frames = {plant.GetBodyFrameIdOrThrow(b) for b in plant.GetBodyIndices(tool.model)}
        self._only_tool_pairs(scene_graph)
        self._tip = plant.GetBodyByName(tip_body, tool.model)
        self._p_WP = None
        if pivot_body is not None:
            pivot = plant.GetBodyByName(pivot_body, tool.model)
            self._p_WP = plant.EvalBodyPoseInWorld(self._plant_context, pivot).translation()
        self.max_pen, self.sq_err, self.n_free, self.max_offset, self.k_max, self.rows = (
            0.0,
            0.0,
            0,
            0.0,
            0,
            0,
        )
        self._device_tip, self._last_q = None, None
        self._sep_tip, self._sep_q = None, None  # the device's tip at every row, for the separation
        self._tips: list[tuple[np.ndarray, np.ndarray]] = []

    def _only_tool_pairs(self, scene_graph: SceneGraph) -> None:
        """In this measure's own context, filter every pair of rigid shapes but the tool's against
        the rest: the penetration reads only those, and the query's broad phase then skips the
        scene's own contacts (the peg transfer's beads resting on the board and around the pegs;
        the cost saved: docs/results.md "The peg transfer, measured"). The distances of the pairs
        kept are the same, bit for bit."""
        tool, rest = [], []
        for g in self._inspector.GetAllGeometryIds(Role.kProximity):
            if not self._inspector.IsDeformableGeometry(g):
                (tool if self._inspector.GetFrameId(g) in self._tool_frames else rest).append(g)
        context = scene_graph.GetMyMutableContextFromRoot(self._context)
        scene_graph.collision_filter_manager(context).Apply(
            CollisionFilterDeclaration().ExcludeWithin(GeometrySet(rest)).ExcludeWithin(GeometrySet(tool))
        )

    def take_tips(self, n: int, finite: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The device's and the tool's tip positions (N, 3) at the last :meth:`update`'s rows,
        laid out over ``n`` rows of which ``finite`` were measured (NaN elsewhere)."""
        device, tool = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
        if self._tips:
            device[finite], tool[finite] = (np.array(v) for v in zip(*self._tips, strict=True))
        self._tips = []
        return device, tool

    def update(self, states: np.ndarray, q_device: np.ndarray) -> None:
        """``states`` (N, nq+nv) plant states; ``q_device`` (N, nq_device) the device's joint values."""
        plant, ctx, inspector = self.plant, self._plant_context, self._inspector
        nq = plant.num_positions()
        self._tips = []
        for x, qd in zip(states, q_device, strict=True):
            plant.SetPositions(ctx, x[:nq])
            query = self._query_port.Eval(ctx)
            closest = FREE_SPACE_MARGIN_M
            for pair in query.ComputeSignedDistancePairwiseClosestPoints(FREE_SPACE_MARGIN_M):
                a = inspector.GetFrameId(pair.id_A) in self._tool_frames
                b = inspector.GetFrameId(pair.id_B) in self._tool_frames
                if a != b:
                    closest = min(closest, pair.distance)
            if -closest > self.max_pen:
                self.max_pen, self.k_max = -closest, self.rows
            X_WTip = plant.EvalBodyPoseInWorld(ctx, self._tip)
            if self._sep_q is None or not np.array_equal(qd, self._sep_q):
                device = self.tool.set_device_state(qd, None, x)
                self._sep_tip, self._sep_q = plant.EvalBodyPoseInWorld(device, self._tip).translation(), qd
            self._tips.append((self._sep_tip, X_WTip.translation()))
            if self._p_WP is not None:
                a, b = self._p_WP - X_WTip.translation(), X_WTip.rotation().col(2)
                # a × b, as np.cross computes it (each product rounded, then the difference), at a
                # tenth of its cost on one pair of 3-vectors: the same number, bit for bit
                a_x_b = np.array(
                    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
                )
                offset = float(np.linalg.norm(a_x_b))
                self.max_offset = max(self.max_offset, offset)
            if closest >= FREE_SPACE_MARGIN_M:
                if self._last_q is None or not np.array_equal(qd, self._last_q):
                    device = self.tool.set_device_state(qd, None, x)
                    self._device_tip = plant.EvalBodyPoseInWorld(device, self._tip).translation()
                    self._last_q = qd
                self.sq_err += float(np.sum((X_WTip.translation() - self._device_tip) ** 2))
                self.n_free += 1
            self.rows += 1

    def result(self) -> dict:
        out = {
            "max_penetration_m": self.max_pen,
            "max_penetration_step": self.k_max,
            "tip_tracking_rms_m": math.sqrt(self.sq_err / self.n_free) if self.n_free else None,
            "free_space_samples": self.n_free,
        }
        if self._p_WP is not None:
            out["max_trocar_offset_m"] = self.max_offset
        return out


class ShellMetrics:
    """Deformation and penetration of a deformable god-object, folded in chunk by chunk.

    ``max_shell_deformation_m``: the largest distance of a tracked shell
    point from its rest position on the core. ``final_shell_deformation_m``:
    the same at the last step. ``max_penetration_m``: the deepest any
    shell point's contact sphere (radius ``shell.contact_radius_m``; 0 for
    FEM vertices) goes into an obstacle, by Drake's signed distance to the
    true obstacle shape. ``max_core_penetration_m``: the same for the core
    sphere (radius rc). ``rms_tracking_error_m``: core centre against the
    target, over the steps where the whole shell is at least
    ``FREE_SPACE_MARGIN_M`` from every obstacle. ``obstacles``: the rigid
    geometries (GeometryIds) that count as obstacles. Rows are measured one
    by one in order, so any split into chunks gives the very same numbers.
    """

    def __init__(self, diagram, plant: MultibodyPlant, shell, obstacles: set):
        self.plant, self.shell, self.obstacles = plant, shell, obstacles
        self._context = diagram.CreateDefaultContext()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._query_port = plant.get_geometry_query_input_port()
        self._rn, self._rc = shell.contact_radius_m, shell.spec.core_radius_m
        self._reach = max(self._rn, self._rc) + FREE_SPACE_MARGIN_M
        self.max_pen = self.max_core = 0.0
        self.sq_err, self.n_free, self.k_max, self.rows = 0.0, 0, 0, 0
        self.max_deformation = self.final_deformation = None

    def _depth(self, query, p, radius):  # deepest of a sphere at p into an obstacle (< 0: clearance)
        deepest = -FREE_SPACE_MARGIN_M
        for d in query.ComputeSignedDistanceToPoint(p, self._reach):
            if d.id_G in self.obstacles:
                deepest = max(deepest, radius - d.distance)
        return deepest

    def update(self, states, vertices, rest, pose_WC, pose_WT) -> None:
        """Plant states, shell points and their rest positions (W, flattened), core and target
        poses ``[qw qx qy qz x y z]``, at the same steps: (N, ·) each."""
        n = len(states)
        if n == 0:
            return
        deformation = np.linalg.norm((vertices - rest).reshape(n, -1, 3), axis=2).max(axis=1)
        top = float(deformation.max())
        self.max_deformation = top if self.max_deformation is None else max(self.max_deformation, top)
        self.final_deformation = float(deformation[-1])
        plant, ctx, nq = self.plant, self._plant_context, self.plant.num_positions()
        for k in range(n):
            plant.SetPositions(ctx, states[k, :nq])
            query = self._query_port.Eval(ctx)
            points = vertices[k].reshape(-1, 3)[self.shell.surface]
            shell_depth = max(self._depth(query, p, self._rn) for p in points)
            if shell_depth > self.max_pen:
                self.max_pen, self.k_max = shell_depth, self.rows
            self.max_core = max(self.max_core, self._depth(query, pose_WC[k, 4:], self._rc))
            if shell_depth <= -FREE_SPACE_MARGIN_M:
                self.sq_err += float(np.sum((pose_WC[k, 4:] - pose_WT[k, 4:]) ** 2))
                self.n_free += 1
            self.rows += 1

    def result(self) -> dict:
        return {
            "max_penetration_m": self.max_pen,
            "max_penetration_step": self.k_max,
            "max_core_penetration_m": self.max_core,
            "max_shell_deformation_m": self.max_deformation,
            "final_shell_deformation_m": self.final_deformation,
            "rms_tracking_error_m": math.sqrt(self.sq_err / self.n_free) if self.n_free else None,
            "free_space_samples": self.n_free,
        }


REVERSAL_MOVE_M = 1e-3  # the god-object has answered a reversal once it moved this far back


class SeparationMetrics:
    """How far the target runs from the god-object, and how long the tool takes to turn back.

    ``max_target_separation_m`` is the largest distance between the target T and the
    god-object G; ``impossible_pose_time_s`` the time T spends farther than
    ``distance_m`` from G (the paper's "impossible position" of the tool). For a relative
    device, ``reversals`` are the device samples ``(t, d)`` where it turns back (its increment
    points more than 90° from the last one, ``d`` its unit direction); the latency of one is
    the time from ``t`` to G having moved :data:`REVERSAL_MOVE_M` along ``d``, and
    ``reversal_latency_max_s`` the longest. A reversal G has not answered by the next one (or
    the run's end) is counted in ``reversals_unanswered`` instead. Rows come in order, a
    chunk at a time; any split gives the same numbers.
    """

    def __init__(
        self,
        h: float,
        distance_m: float,
        reversals: list[tuple[float, np.ndarray]] | None = None,
        tether_m: float = math.inf,
        device_period_s: float = 0.0,
    ):
        self.h, self.distance_m = h, distance_m
        self.tether_m = tether_m
        # rows back to the god-object a device sample read: the last sample is less than one device
        # period ago, and it read the state of a plant step at most one step before it
        self._window = math.ceil(device_period_s / h - 1e-9) + 2 if math.isfinite(tether_m) else 0
        self._recent = np.zeros((0, 3))  # the last rows of p_G, for the window across chunks
        self.max_travel, self.bound_violations = 0.0, 0
        self.max_sep, self.far_rows, self.rows = 0.0, 0, 0
        self.reversals = list(reversals) if reversals is not None else None
        self._next = 0  # the next reversal to start waiting for
        self._waiting: tuple[float, np.ndarray, np.ndarray] | None = None  # (t, d, p_G at t)
        self.latencies: list[float] = []
        self.unanswered = 0

    def update(self, separation: np.ndarray, p_WG: np.ndarray) -> None:
        """``separation`` (N,) |p_T − p_G| (m) and ``p_WG`` (N, 3), one row per plant step."""
        n = len(separation)
        if n:
            self.max_sep = max(self.max_sep, float(np.max(separation)))
            self.far_rows += int(np.sum(separation > self.distance_m))
        if self.reversals is not None:
            for i in range(n):
                self._follow(self.rows + i, p_WG[i])
        if self._window and n:
            self._tether(separation, p_WG)
        self.rows += n

    def _tether(self, separation: np.ndarray, p_WG: np.ndarray) -> None:
        """The tether holds at each device sample; between samples the target is held while G
        moves on, so ``|p_T − p_G(t)| ≤ tether + |p_G(t) − p_G(t_k)|``, ``t_k`` the last sample.
        ``travel(t)``, the farthest G has been within the window, bounds that second term."""
        w = self._window
        p = np.vstack([self._recent, p_WG])
        need = w - 1 - len(self._recent)  # the run's first rows: G stood at its start before them
        if need > 0:
            p = np.vstack([np.repeat(p[:1], need, axis=0), p])
        windows = np.lib.stride_tricks.sliding_window_view(p, w, axis=0)  # (rows, 3, w): row i's last w
        travel = np.max(np.linalg.norm(windows - p_WG[:, :, None], axis=1), axis=1)
        travel = np.where(np.isfinite(travel), travel, 0.0)  # a diverged row: its separation is 0 too
        self.max_travel = max(self.max_travel, float(np.max(travel)))
        excess = separation - self.tether_m - travel
        self.bound_violations += int(np.sum(excess > 1e-12 * max(self.tether_m, 1.0)))
        self._recent = p[-(w - 1) :]

    def _follow(self, row: int, p: np.ndarray) -> None:
        t = row * self.h
        rev = self.reversals
        if self._next < len(rev) and t >= rev[self._next][0] - 1e-9:
            if self._waiting is not None:
                self.unanswered += 1
            self._waiting = (t, rev[self._next][1], p.copy())
            self._next += 1
        if self._waiting is not None:
            t0, d, p0 = self._waiting
            if float((p - p0) @ d) >= REVERSAL_MOVE_M:
                self.latencies.append(t - t0)
                self._waiting = None

    def result(self) -> dict:
        out = {
            "max_target_separation_m": self.max_sep,
            "impossible_pose_time_s": self.far_rows * self.h,
            "impossible_pose_distance_m": self.distance_m,
        }
        if self.reversals is not None:
            out["reversals"] = len(self.latencies) + self.unanswered + (self._waiting is not None)
            out["reversal_latency_max_s"] = max(self.latencies) if self.latencies else None
            out["reversals_unanswered"] = self.unanswered + (self._waiting is not None)
        if self._window:
            out["tether_bound_m"] = self.tether_m + self.max_travel
            out["tether_bound_violations"] = self.bound_violations
        return out


TRACE_PERIOD_S = 0.01  # a kept trace's rows (SceneMetrics(trace=True)): one every 10 ms


class SceneMetrics:
    """A station's metrics (by god-object kind), folded in from its logs chunk by chunk.

    Every kind gives ``max_penetration_m``, ``rms_tracking_error_m``, ``free_space_samples``
    and ``max_other_body_speed_mps`` (None where nothing else moves); rigid adds
    ``coupling_capped_steps``; articulated :class:`ToolMetrics`' keys; deformable
    :class:`ShellMetrics`'. Every kind adds the tip's motion scores, its contact forces on other
    bodies and its collisions with other tools (:mod:`godobject_drake.task_metrics`), its tip being
    the point the kind's fold follows (a rigid god-object's G, an articulated tool's tip body's
    origin, a deformable one's core). Rows with a non-finite value (a run stopped as diverged) are
    left out. ``update(data)`` takes a dict of logs (one row per plant step, the station's logger
    names); ``result()`` reads the values so far. ``trace``: keep the tip's position and force
    every :data:`TRACE_PERIOD_S` (:meth:`trace`), for plots.
    """

    def __init__(self, station, trace: bool = False):
        god, plant = station.god_object, station.plant
        reversals = god.source.reversals(2 * REVERSAL_MOVE_M)  # None: a device that does not say
        aids = getattr(god.source, "aids", None)  # a relative device's tether (devices.RelativeAids)
        h = plant.time_step()
        self._sep = SeparationMetrics(
            h, station.scenario.metrics.impossible_pose_distance_m, reversals,
            tether_m=aids.tether_m if aids is not None else math.inf, device_period_s=god.source.period_s,
        )  # fmt: skip
        self._acc = god.new_metrics(station)  # the god-object kind's own fold
        self._god, self._name, self.h = god, next(iter(station.tools)), h
        camera = station.scenario.visualization.camera
        view = CameraView(tuple(camera.position_m), tuple(camera.target_m)) if camera is not None else None
        config = station.scenario.metrics
        self._tip = TipMotion(h, view, config.idle_speed_mps, config.smoothing_window_s)
        self._meter = getattr(station, "contact_meter", None)
        self._forces, self._collisions = ForceFold(h), CollisionFold(h)
        self._reference = None  # the tip's last reference point (tip_reference)
        self._rows = 0
        self._trace = [] if trace else None

    def update(self, data: dict) -> None:
        if not data or len(data["state"]) == 0:
            return
        finite = np.all(np.concatenate([np.isfinite(d) for d in data.values()], axis=1), axis=1)
        rows = {name: d[finite] for name, d in data.items()}
        p_WT, p_WG = self._acc.fold(rows, data, finite)
        # every row, so that row k is at t = k h (a non-finite row gives a NaN, never the maximum)
        separation = np.linalg.norm(p_WT - p_WG, axis=1)
        self._sep.update(np.where(np.isfinite(separation), separation, 0.0), p_WG)
        self._task(rows, p_WG, finite)
        self._rows += len(finite)

    def _task(self, rows: dict, p_WG: np.ndarray, finite: np.ndarray) -> None:
        """The tip's motion, the tool's forces and collisions, on the finite rows."""
        tip = np.asarray(p_WG, float)[finite]
        reference = self._god.tip_reference(rows)
        switched = None
        if reference is not None and len(reference):
            before = np.concatenate([[reference[0] if self._reference is None else self._reference],
                                     reference[:-1]])  # fmt: skip
            switched, self._reference = reference != before, reference[-1]
        self._tip.update(tip, switched)
        force = np.zeros((len(tip), 3))
        if self._meter is not None and "contacts" in rows:
            columns = rows["contacts"][:, self._meter.columns(self._name)]
            force = columns[:, :3]
            self._forces.update(force, columns[:, 3])
            pairs = self._meter.pair_columns(self._name)
            if pairs:
                self._collisions.update(np.max(rows["contacts"][:, pairs], axis=1))
        if self._trace is not None:
            every = max(1, round(TRACE_PERIOD_S / self.h))
            k = np.flatnonzero(finite)
            keep = (self._rows + k) % every == 0
            t = (self._rows + k[keep]) * self.h
            self._trace.append(np.column_stack([t, tip[keep], np.linalg.norm(force[keep], axis=1)]))

    def trace(self) -> np.ndarray:
        """The kept trace (``trace=True``): rows ``[t, x, y, z, |F|]`` of the tip's position (m) and
        the tool's net contact force on other bodies (N), every :data:`TRACE_PERIOD_S`."""
        if self._trace is None:
            raise ValueError("this fold keeps no trace: SceneMetrics(station, trace=True) keeps one")
        return np.concatenate(self._trace) if self._trace else np.zeros((0, 5))

    def result(self) -> dict:
        out = {**self._acc.result(), **self._sep.result(), **self._tip.result()}
        if self._meter is not None:
            out.update(self._forces.result())
            if len(self._meter.tools) > 1:  # against any other tool
                out.update(self._collisions.result("tool_"))
        return out


def penetration_verdict(metrics: dict, scenario) -> dict:
    """The run's deepest penetration against its budget (``metrics.penetration_budget_m``): the keys
    ``penetration_budget_m`` and ``over_penetration_budget``, and a
    :class:`~godobject_drake.metrics.PenetrationBudgetWarning` past it naming what is near
    its limit, whatever got it there (the build's warning only covers the capped pull's static
    depth: a coupling ringing near its explicit limit goes deeper with no warning at build). A run
    that measures no penetration (None) gives nothing. The position baseline (``simulation.mode:
    position``, the device's pose imposed) goes into obstacles by design: the keys, no warning.
    """
    return verdict(metrics, scenario, tool_records(scenario))


def verdict(metrics: dict, scenario, records: dict) -> dict:
    """:func:`penetration_verdict`, given the scenario's tools' records (a run's: ``Station.records``)."""
    depth, budget = metrics.get("max_penetration_m"), scenario.metrics.penetration_budget_m
    if depth is None or not math.isfinite(depth):
        return {}
    out = {"penetration_budget_m": budget, "over_penetration_budget": bool(depth > budget)}
    if depth > budget and scenario.simulation.mode != "position":  # the baseline goes in: its point
        predicted = metrics.get("predicted_static_penetration_m")
        near = _what_is_near_its_limit(scenario.time_step, records)
        said = (
            f" (the capped pull's static depth predicted at build: {predicted * 1e3:.3g} mm)"
            if predicted
            else ""
        )
        warnings.warn(
            f"the run went {depth * 1e3:.3g} mm into an obstacle, past its budget "
            f"metrics.penetration_budget_m = {budget * 1e3:.3g} mm{said}. {near}",
            PenetrationBudgetWarning,
            stacklevel=3,
        )
    return out


def _what_is_near_its_limit(h: float, records: dict) -> str:
    """Each tool's coupling bandwidths as a share of their explicit limit at the run's step ``h``: a
    gain near 100 % rings, and its overshoot is what drives the god-object deeper."""
    parts = []
    for record in records.values():
        gains = getattr(record.view.god_object, "gains", None)
        if not all(hasattr(gains, a) for a in ("omega_n", "omega_r", "zeta", "zeta_r")):
            continue
        for label, w, z in (
            ("omega_n", gains.omega_n, gains.zeta),
            ("omega_n_rot", gains.omega_r, gains.zeta_r),
        ):
            share = w * h / explicit_limit_omega_h(z)
            parts.append((share, f"{record.who}{label} {w:g} rad/s is at {100 * share:.4g} %"))
    if not parts:
        return "Lower the time step or the coupling's gains, or stiffen the contact"
    parts.sort(reverse=True)
    worst = parts[0][0]
    ringing = " (near 100 % the coupling rings and overshoots into what it meets)" if worst > 0.8 else ""
    return (
        f"At time_step {h:g} s, {'; '.join(p for _, p in parts)} of its explicit stability limit{ringing}. "
        "Lower the time step or that gain, or raise the budget if the depth is acceptable"
    )


def worst_of(tools: dict[str, dict]) -> dict:
    """The scene's figures from its tools': the deepest penetration, the worst tracking, the fastest
    other body, the free-space samples of all (a tool that does not measure one: left out)."""
    out = {}
    for key, pick in (("max_penetration_m", max), ("rms_tracking_error_m", max),
                      ("max_other_body_speed_mps", max), ("free_space_samples", sum)):  # fmt: skip
        values = [m[key] for m in tools.values() if m.get(key) is not None]
        out[key] = pick(values) if values else None
    return out


def scene_configuration(station) -> dict:
    """The metrics' configuration keys of a run: a scene of one tool's, flat (:func:`configuration`
    of its own view); a scene of several, what its tools share, each tool's own under its name
    (``tools: {NAME: ...}``, :meth:`_Run.tool_metrics`)."""
    if len(station.tools) == 1:
        view = next(iter(station.views.values()))
        return configuration(view.scenario, view)
    scenario = station.scenario
    return {
        "contact": scenario.contact.geometry,
        "contact_approximation": scenario.plant.discrete_contact_approximation,
        "seed": scenario.random_seed,
        "sleep": station.sleeper is not None,
        "free_bodies": len(station.plant.GetFloatingBaseBodies()),
        "tool_names": list(station.tools),
    }


def configuration(scenario, station) -> dict:
    """The metrics' configuration keys: what was run."""
    god = scenario.god_object
    out = {
        "contact": scenario.contact.geometry,
        "contact_approximation": scenario.plant.discrete_contact_approximation,
        "device": station.records[next(iter(station.tools))].device.name,
        "device_rate_hz": scenario.device.rate_hz,
        "omega_n_rad_s": god.gains.omega_n,
        "omega_n_rot_rad_s": god.gains.omega_r,
        "zeta": god.gains.zeta,
        "seed": scenario.random_seed,
        "sleep": station.sleeper is not None,
        "free_bodies": len(station.plant.GetFloatingBaseBodies()),
    }
    out.update(next(iter(station.tools.values())).configuration(scenario, station))  # the kind's own keys
    return out
