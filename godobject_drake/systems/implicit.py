"""The implicit coupling (``god_object.coupling: implicit``): the paper's spring integrated by SAP.

The explicit coupling (:class:`~godobject_drake.systems.coupling.GodObjectCoupling`) computes the PD
wrench in Python at every plant step and hands it to the plant as an applied force, so the
discrete plant integrates it explicitly: stable only while ``ωn h < 2(√(1+ζ²) − ζ)``
(docs/theory.md §1), and a Python call in every step. Here the same spring is made of
**compliant distance constraints** between points fixed in the world and points of the held
body, which Drake's SAP solver integrates implicitly inside its convex step: three springs along
x, y and z of the world at each of five points of the body (its centre of mass and four on a
tetrahedron about it, :func:`spring_layout`), each spring :data:`LENGTH_M` long at rest with its
world end that far beyond its target point along its axis. A distance constraint acts and damps
along its own line only; these lines stay along the world axes to within the error over
:data:`LENGTH_M` (2e-6 rad at the 0.2 m force cap), so each spring is linear along its axis, the
three at a point are a zero-length spring with the same stiffness and damping in every
direction, and the sums are the paper's
``k = m ωn²`` and ``γ = 2 ζ m ωn`` in translation and ``I ωr²`` and ``2 ζr ωr I`` in rotation.

Drake keeps a distance constraint's bodies, points, stiffness and damping in the context
(``SetDistanceConstraintParams``), so one set of springs is retargeted to whichever body a
grasp takes and moved with the target, without changing the plant. Python runs at the device
rate only: :class:`ImplicitCoupling`'s discrete update computes the target ``T`` at each device
sample, and :class:`SpringHook` writes the springs' world points into the plant's context before
the next plant step (a comparison per step otherwise, inside the safeguards' monitor, which is
Python per step anyway: docs/design.md "The implicit coupling").

**The target's velocity** enters as a lead: a world point held still between samples damps the
body toward rest, not toward the target's velocity. Each spring's world end is put at
``P_j + (γ_j / k_j) V_j`` (``P_j``, ``V_j`` the target's point and its velocity), so
``k_j (P_j + (γ_j/k_j) V_j − x_j) − γ_j ẋ_j = k_j (P_j − x_j) + γ_j (V_j − ẋ_j)``: the paper's
spring-damper along each spring's axis, so in every direction.

**The force cap** is on the stretch, not on the force: at each device sample the target is held
within ``max_stretch_m`` of the held body's centre of mass (and within ``max_twist_rad`` of its
orientation), so the spring force is at most ``k · max_stretch_m`` plus damping, as the explicit
coupling's cap. **Gravity compensation** raises every world point by ``g/ωn²``, so the springs
carry ``m g`` with the body at its target (the same raise at every point: no torque).

**Orientation** is carried by the points themselves (``P_j = p_WT + R_WT a_j``): no angles, so
no singularity in any pose.

**What is not the same as the explicit coupling** (measured in tests/test_implicit.py and
docs/theory.md §7): the spring is integrated by backward Euler, not explicitly; the target is
sampled at the device rate (as the explicit coupling sees a held device), not per step; the
logged coupling wrench (``terms``' ``F_Go_W``) is the springs' force evaluated at each logged
state after the run (:func:`implicit_terms`), not the impulse SAP applied inside its step. Until
the springs were laid along the three axes (seven springs, all vertical), the coupling did not
damp across them: a moving body sagged and led by millimetres (docs/results.md, "Seven vertical
springs against fifteen along the world axes").
"""

import dataclasses
import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.plant import DistanceConstraintParams, MultibodyPlant
from pydrake.multibody.tree import BodyIndex, JointIndex, SpatialInertia
from pydrake.systems.framework import LeafSystem

from godobject_drake.config.gains import CouplingGains
from godobject_drake.spatial import (
    cross_rows,
    pose_arrays,
    quat_conjugate,
    quat_multiply,
    quat_to_rotation,
    quats_to_rotations,
)
from godobject_drake.systems.coupling import _TERMS, TERMS_LAYOUT, GraspableBody, GraspingCoupling

# Each spring's length at rest (m). A spring of stiffness k_j along the world axis e, its world end
# LENGTH_M beyond its target point P along e and its rest length LENGTH_M, pulls its body point x
# with k_j (e·(P − x)) e and damps the point's velocity along e with γ_j, up to |P − x|/LENGTH_M:
# across e its length changes by |P − x|² / (2 LENGTH_M) and its line tilts by |P − x| / LENGTH_M.
# Three such springs along x, y and z at one point are a zero-length spring there, the same in
# every direction, integrated implicitly by SAP along all three axes. Long because the world end
# leads the target by (γ/k) V, which a device step makes large for one sample (2 m for a 2 cm step
# in 1 ms at ωn = 20 rad/s): the body of tests/test_implicit.py's step then moved sideways by
# 136 µm with 100 m springs, 1.4 µm with 10 km, 0.14 µm with 100 km. A double resolves 1.5e-11 m
# at 100 km, and Drake's zero-distance singularity is far away.
LENGTH_M = 1e5
AXIS_SHARE = 0.75  # the vertex points' share of k and γ when the centre must take the remainder of one
POINTS = 5  # the centre of mass and four points on a tetrahedron about it
N_SPRINGS = 3 * POINTS
# A regular tetrahedron's vertices: Σ t = 0, Σ t tᵀ = (4/3) I.
_TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) / math.sqrt(3.0)
ANCHOR_NAME = "god_object_spring_anchor"  # the massless body, welded to the world, the springs start on

# The coupling's logged state (``coupling_state``): what :func:`implicit_terms` needs per row.
_HELD, _QDG, _PDG, _XT, _VT, _CAP, _GEN = 0, slice(1, 5), slice(5, 8), slice(8, 15), slice(15, 21), 21, 22
_N_STATE = 23
STATE_LAYOUT = {
    "held_body": _HELD, "q_DG": _QDG, "p_DoGo_D": _PDG, "pose_WT": _XT, "V_WT": _VT, "capped": _CAP,
    "sample": _GEN,
}  # fmt: skip


class ImplicitCouplingError(ValueError):
    """A scene the implicit coupling cannot drive (admittance, position baseline, a carried shell)."""


def anchor_name(tool: str = "") -> str:
    """The springs' anchor body (and model instance) of a tool: :data:`ANCHOR_NAME`, suffixed by the
    tool's name in a scene of several."""
    return f"{ANCHOR_NAME}_{tool}" if tool else ANCHOR_NAME


def add_springs(plant: MultibodyPlant, tool: str = "") -> tuple:
    """Add the implicit coupling's springs (:data:`N_SPRINGS`) to ``plant`` (before ``Finalize``); their ids.
    ``tool``: the tool's name in a scene of several (each has its own anchor, :func:`anchor_name`).

    They join the world to the first body for now, and :meth:`ImplicitGodObject.prepare` switches
    them off; a grasp retargets them (:class:`SpringHook`).
    """
    if plant.is_finalized():
        raise ImplicitCouplingError("add_springs() needs a plant not yet finalized")
    jointed = {plant.get_joint(JointIndex(j)).child_body().index() for j in range(plant.num_joints())}
    free = [BodyIndex(i) for i in range(1, plant.num_bodies()) if BodyIndex(i) not in jointed]
    if not free:
        raise ImplicitCouplingError(
            "the implicit coupling holds free bodies; the plant has none yet (each body is jointed or welded)"
        )
    # The springs' fixed ends are on a body welded to the world, not on the world body: Drake 1.51.1
    # and 1.58.0 end the process (a segmentation fault in the first SAP step) on an active distance
    # constraint whose body A is the world (tests/test_implicit.py keeps the minimal case).
    instance = plant.AddModelInstance(anchor_name(tool))
    anchor = plant.AddRigidBody(anchor_name(tool), instance, SpatialInertia.SolidSphereWithMass(1e-6, 1e-3))
    plant.WeldFrames(plant.world_frame(), anchor.body_frame())
    first = plant.get_body(free[0])
    return tuple(
        plant.AddDistanceConstraint(
            anchor, np.array([LENGTH_M, 0.0, 0.0]), first, np.zeros(3), LENGTH_M, 1.0, 0.0
        )
        for _ in range(N_SPRINGS)
    )


@dataclasses.dataclass(frozen=True)
class SpringLayout:
    """The springs for one body (:func:`spring_layout`): three per point, along x, y, z of W."""

    offsets_B: np.ndarray  # N×3: each spring's point on the body, from its centre of mass, in B (m)
    stiffness: np.ndarray  # N (N/m)
    damping: np.ndarray  # N (N·s/m)
    axis_W: np.ndarray  # N×3: the world axis along which each spring's world end lies beyond its target point

    @property
    def lead_s(self) -> np.ndarray:
        """Each spring's γ/k (s): how far ahead of its target point, times the point's velocity,
        its world end is put (0 for a spring of no stiffness, which stays off)."""
        return np.divide(
            self.damping, self.stiffness, out=np.zeros(len(self.stiffness)), where=self.stiffness > 0
        )


def spring_layout(body: GraspableBody, gains: CouplingGains) -> SpringLayout:
    """Stiffnesses and points of the springs that make the paper's spring on ``body``.

    Each point ``r_p`` (from the centre of mass) holds three springs along x, y, z of the world:
    a zero-length spring of isotropic stiffness ``k_p`` and damping ``c_p``. Points with
    ``Σ k_p r_p = 0`` give no coupling between translation and rotation, a translational stiffness
    ``Σ k_p`` and a rotational one ``Σ k_p (|r_p|² I − r_p r_pᵀ)``. Four points ``U diag(s) t_v``
    on a tetrahedron (``t_v`` its unit vertices, ``U`` the principal axes of inertia) with ``k_t``
    each give ``Σ k_t r rᵀ = (4/3) k_t U diag(s²) Uᵀ``; with ``s_i² = 3 ωr² μ_i / (4 k_t)``, ``μ_i
    = (λ_j + λ_l − λ_i)/2`` (the body's second moment along axis i, ≥ 0 by the triangle inequality
    of inertia), that is ``I ωr²`` about every axis. Their damping ``c_t = (2 ζr / ωr) k_t`` gives
    ``2 ζr ωr I``. The centre point takes the rest of ``k = m ωn²`` and ``γ = 2 ζ m ωn``; when
    ``γ/k = 2 ζr/ωr`` (the same gains in rotation and translation) the vertices take all of both
    and the centre's springs stay off, otherwise the vertices take :data:`AXIS_SHARE` of the
    tighter one (Drake refuses a spring of zero stiffness with damping).
    """
    m = body.mass
    lam, U = np.linalg.eigh(body.I_Bcm_B)
    lam = np.maximum(lam, 0.0)
    mu = np.maximum(0.5 * lam.sum() - lam, 0.0)
    k, gamma = gains.translational(m)
    wr, zr = gains.omega_r, gains.zeta_r
    ratio = 2.0 * zr / wr  # c/k of the vertex springs
    balanced = math.isclose(gamma, ratio * k, rel_tol=1e-9)
    limit = k if (ratio == 0.0 or gamma <= 0.0) else min(k, gamma / ratio)
    kt = 0.25 * limit * (1.0 if balanced else AXIS_SHARE)
    ct = ratio * kt
    k0, c0 = (0.0, 0.0) if balanced else (k - 4.0 * kt, max(gamma - 4.0 * ct, 0.0))
    s = np.sqrt(3.0 * wr**2 * mu / (4.0 * kt))
    points = np.vstack([np.zeros(3), (_TETRAHEDRON * s) @ U.T])
    kp, cp = np.array([k0, kt, kt, kt, kt]), np.array([c0, ct, ct, ct, ct])
    return SpringLayout(
        np.repeat(points, 3, axis=0), np.repeat(kp, 3), np.repeat(cp, 3), np.tile(np.eye(3), (POINTS, 1))
    )


class ImplicitCoupling(GraspingCoupling, LeafSystem):
    """The implicit coupling's device-rate half: the grasp and the target, in discrete state.

    .. pydrake_system::

        name: ImplicitCoupling
        input_ports:
        - plant_state
        - X_WD
        - V_WD
        - grasp
        output_ports:
        - coupling_state
        - pose_WT
        - V_WT
        - pose_WG
        - V_WG
        - held_body

    At each device sample (half a plant step after it, as the explicit coupling looks at
    ``grasp``) it reads the device and, on a grasp change, stores the grasp offset ``X_DG`` (so
    the springs start at rest); then it computes the target ``T``, held within the caps of the
    body's centre of mass and orientation, and counts the sample (``sample``: what tells
    :class:`SpringHook` to move the springs). ``coupling_state`` goes to a logger straight from the
    state (C++, no Python per step); ``pose_WT``/``V_WT``/``pose_WG``/``V_WG``/``held_body`` mean
    what the explicit coupling's do (:class:`~godobject_drake.systems.coupling.GodObjectCoupling`) and are
    computed when read (the feedback port and the drawing read them at their own rates).
    """

    # SAP integrates its springs by backward Euler: what a twin of the coupling (the scene's free
    # lag, godobject_drake.link.scene_model.FreeLag) integrates it with
    integrates_implicitly = True

    def __init__(
        self,
        plant: MultibodyPlant,
        gains: CouplingGains,
        springs: tuple,
        device_period_s: float,
        gravity_compensation: bool = True,
        grasp_reach_m: float = 0.05,
        max_stretch_m: float = 0.2,
        max_twist_rad: float = math.pi,
        graspable=None,
    ):
        LeafSystem.__init__(self)
        gains.check(0.0)  # its numbers and the paper's damping range; no step limit
        self._setup_bodies(
            plant, gains, gravity_compensation, None, grasp_reach_m, max_stretch_m, max_twist_rad, graspable
        )
        if len(springs) != N_SPRINGS:
            raise ImplicitCouplingError(f"{len(springs)} springs given; add_springs() adds {N_SPRINGS}")
        self.springs = tuple(springs)
        h = plant.time_step()
        if not h > 0.0:
            raise ImplicitCouplingError(
                "the implicit coupling needs a discrete plant (plant.time_step > 0): SAP"
            )
        self.layouts = {i: spring_layout(b, gains) for i, b in self._by_index.items()}
        self.raise_W = -self._g / self._wn2  # the springs' world ends above T: they then carry m g
        n = plant.num_multibody_states()
        self._state_port = self.DeclareVectorInputPort("plant_state", n)
        self._X_WD_port = self.DeclareAbstractInputPort("X_WD", AbstractValue.Make(RigidTransform()))
        self._V_WD_port = self.DeclareVectorInputPort("V_WD", 6)
        self._grasp_port = self.DeclareAbstractInputPort("grasp", AbstractValue.Make(""))
        self._declare_held_elsewhere()
        s0 = np.zeros(_N_STATE)
        s0[_HELD] = -1.0
        s0[_QDG] = (1.0, 0.0, 0.0, 0.0)
        s0[_XT.start] = 1.0
        self._state = self.DeclareDiscreteState(s0)
        self._grasp_state = self._state  # its entry 0 is the held body, as the explicit coupling's
        self.period_s = float(device_period_s)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.5 * h, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self.DeclareStateOutputPort("coupling_state", self._state)
        state_ticket = {self.xd_ticket()}
        for name, sl in (("pose_WT", _XT), ("V_WT", _VT)):
            self.DeclareVectorOutputPort(name, sl.stop - sl.start, self._slice(sl), state_ticket)
        self.DeclareVectorOutputPort("held_body", 1, self._slice(slice(0, 1)), state_ticket)
        both = {self.xd_ticket(), self._state_port.ticket()}
        self.DeclareVectorOutputPort("pose_WG", 7, lambda c, o: o.SetFromVector(self._god(c)[0]), both)
        self.DeclareVectorOutputPort("V_WG", 6, lambda c, o: o.SetFromVector(self._god(c)[1]), both)

    def _slice(self, sl):
        def calc(context, output):
            output.SetFromVector(context.get_discrete_state(self._state).get_value()[sl])

        return calc

    def state(self, context) -> np.ndarray:
        """The coupling's state vector (:data:`STATE_LAYOUT`)."""
        return context.get_discrete_state(self._state).get_value()

    def _god(self, context) -> tuple[np.ndarray, np.ndarray]:
        """``(pose_WG, V_WG)`` of the held body now; the target's when nothing is held."""
        s = self.state(context)
        held = int(s[_HELD])
        if held < 0:
            return s[_XT].copy(), s[_VT].copy()
        body = self._by_index[held]
        x = self._state_port.Eval(context)
        q, p_WG = self._body_state(body, x)
        v = x[body.v_start : body.v_start + 6]
        r = quat_to_rotation(q) @ body.p_BoBcm_B
        return np.concatenate([q, p_WG]), np.concatenate([v[:3], v[3:] + cross_rows(v[:3], r)])

    def _update(self, context, discrete_state):
        s = self.state(context).copy()
        held = int(s[_HELD])
        changed, body = self._grasp_change(context, held)
        q_WD, p_WD, R_WD = pose_arrays(self._X_WD_port.Eval(context))
        V = self._V_WD_port.Eval(context)
        x = self._state_port.Eval(context)
        if changed:
            held = -1 if body is None else body.index
            if body is not None:
                q_WG, p_WG = self._body_state(body, x)
                s[_QDG] = quat_multiply(quat_conjugate(q_WD), q_WG)
                s[_PDG] = R_WD.T @ (p_WG - p_WD)
            s[_HELD] = held
        s[_CAP] = 0.0
        if held < 0:
            s[_XT] = np.concatenate([q_WD, p_WD])
            s[_VT] = V
            if changed:
                s[_GEN] += 1.0  # a release: the springs go off
        else:
            body = self._by_index[held]
            e = R_WD @ s[_PDG]
            q_WT = quat_multiply(q_WD, s[_QDG])
            p_WT = p_WD + e
            q_WG, p_WG = self._body_state(body, x)
            stretch = float(np.linalg.norm(p_WT - p_WG))
            if stretch > self.max_stretch_m:  # the force cap: the target within reach of the body
                p_WT = p_WG + (p_WT - p_WG) * (self.max_stretch_m / stretch)
                s[_CAP] = 1.0
            q_WT, twisted = _within_twist(q_WT, q_WG, self.max_twist_rad)
            if twisted:
                s[_CAP] = 1.0
            s[_XT] = np.concatenate([q_WT, p_WT])
            s[_VT] = np.concatenate([V[:3], V[3:] + cross_rows(V[:3], e)])
            s[_GEN] += 1.0  # a new target: the springs move
        discrete_state.get_mutable_vector(self._state).SetFromVector(s)

    def world_points(self, held: int, pose_WT: np.ndarray, V_WT: np.ndarray) -> np.ndarray:
        """The springs' world ends (N×3) for a target ``pose_WT`` moving at ``V_WT``: each target
        point ``P_j = p_WT + R_WT a_j``, led by ``(γ_j/k_j) V_j``, raised by gravity compensation,
        and :data:`LENGTH_M` beyond it along the spring's world axis."""
        layout = self.layouts[held]
        R = quat_to_rotation(pose_WT[:4] / np.linalg.norm(pose_WT[:4]))
        arms = layout.offsets_B @ R.T
        velocities = V_WT[3:] + cross_rows(V_WT[:3], arms)
        lead = layout.lead_s
        return pose_WT[4:] + arms + lead[:, None] * velocities + self.raise_W + LENGTH_M * layout.axis_W


def _within_twist(q_WT: np.ndarray, q_WG: np.ndarray, max_twist: float) -> tuple[np.ndarray, bool]:
    """``q_WT`` turned back toward ``q_WG`` to at most ``max_twist`` (rad) from it (slerp)."""
    if max_twist >= math.pi:
        return q_WT, False
    d = quat_multiply(quat_conjugate(q_WG), q_WT)
    if d[0] < 0.0:
        d = -d
    angle = 2.0 * math.atan2(float(np.linalg.norm(d[1:])), float(d[0]))
    if angle <= max_twist:
        return q_WT, False
    axis = d[1:] / np.linalg.norm(d[1:])
    half = 0.5 * max_twist
    return quat_multiply(q_WG, np.concatenate([[math.cos(half)], math.sin(half) * axis])), True


class SpringHook:
    """Writes the coupling's target into the plant's springs, between plant steps.

    Called before every plant step (the safeguards' monitor), it returns at once (a time
    comparison) until the coupling's next update is due: the coupling changes its state only at
    its periodic update, half a plant step after each device sample. At the first step after an
    update it compares the coupling's sample count with the last it applied; when they differ,
    the springs go off (nothing held), or point at the held body (:func:`spring_layout`) with
    their world ends at the new target (:meth:`ImplicitCoupling.world_points`). The springs are
    set at the same steps as when the hook compared at every step (which read the coupling's
    context and state: 2.4–3.3 µs a step against 0.3 µs now, docs/results.md "What was
    cut").
    """

    def __init__(self, plant: MultibodyPlant, coupling: ImplicitCoupling):
        self.plant, self.coupling = plant, coupling
        # the springs start on their anchor, welded at the world's origin (one per tool: add_springs)
        self.anchor = plant.GetDefaultDistanceConstraintParams()[coupling.springs[0]].bodyA()
        h = plant.time_step()
        # the coupling's updates: at offset + j period (its DeclarePeriodicDiscreteUpdateEvent)
        self._offset, self._period, self._margin = 0.5 * h, coupling.period_s, 0.25 * h
        self.reset()

    def reset(self) -> None:
        """A new context: nothing applied yet."""
        self.applied, self.held = 0.0, -1
        self.moves = 0
        self.last_logged_row = None  # the coupling's last logged row (implicit_terms' ``previous``)
        self._due = -math.inf  # the earliest time the coupling's state may have changed since the last look

    def _next_update(self, t: float) -> float:
        """The time of the coupling's first update at or after ``t`` (to rounding)."""
        j = math.ceil((t - self._offset) / self._period)
        return self._offset + max(j, 0) * self._period

    def deactivate(self, plant_context) -> None:
        for cid in self.coupling.springs:
            self.plant.SetConstraintActiveStatus(plant_context, cid, False)
        self.held = -1

    def __call__(self, plant_context, root_context) -> None:
        t = root_context.get_time()
        if t < self._due:
            return  # no update of the coupling since the last look
        s = self.coupling.state(self.coupling.GetMyContextFromRoot(root_context))
        if s[_GEN] != self.applied:
            self.apply(plant_context, s)
        # Every update before t is seen now. The next one, at u ≥ t, is seen at the first step
        # after u; looking from a quarter step before u on covers u's rounding: a look before u
        # finds nothing new and sets the same due time, so the next step looks again.
        self._due = self._next_update(t) - self._margin

    def apply(self, plant_context, s: np.ndarray) -> None:
        coupling, plant = self.coupling, self.plant
        held = int(s[_HELD])
        self.applied = float(s[_GEN])
        if held < 0:
            self.deactivate(plant_context)
            return
        layout = coupling.layouts[held]
        points_W = coupling.world_points(held, s[_XT], s[_VT])
        points_B = layout.offsets_B + coupling._by_index[held].p_BoBcm_B
        anchor, body = self.anchor, BodyIndex(held)
        # A point of zero stiffness (the centre, when the vertices take all) stays off: Drake refuses k = 0.
        on = layout.stiffness > 0.0
        for j, cid in enumerate(coupling.springs):
            if on[j]:
                params = DistanceConstraintParams(
                    anchor,
                    points_W[j],
                    body,
                    points_B[j],
                    LENGTH_M,
                    float(layout.stiffness[j]),
                    float(layout.damping[j]),
                )
                plant.SetDistanceConstraintParams(plant_context, cid, params)
            if held != self.held:
                plant.SetConstraintActiveStatus(plant_context, cid, bool(on[j]))
        self.held = held
        self.moves += 1


def implicit_terms(
    coupling: ImplicitCoupling, plant_states: np.ndarray, coupling_states: np.ndarray, previous=None
) -> np.ndarray:
    """The explicit coupling's ``terms`` rows (:data:`~godobject_drake.systems.coupling.TERMS_LAYOUT`)
    computed after the run from the logged plant and coupling states, vectorized.

    Row ``i``'s wrench is the springs' at state ``i`` with the target that was in force during the
    plant step that ended there: the coupling's row ``i − 1`` (its update comes half a step after
    a device sample; :class:`SpringHook` hands it to the plant's next step). ``previous`` is the
    coupling row before the first (the last of the previous chunk of logs; None at t = 0: row 0).

    ``F_Go_W`` is the springs' wrench on the held body at its centre of mass, in W: each
    spring's ``(k (d − d0) + γ ḋ) u`` at the logged state, ``u`` from the body's point to the
    spring's world end (:meth:`ImplicitCoupling.world_points` of the logged target).
    ``pose_WG``/``V_WG`` are the held body's centre-of-mass frame; nothing held: T's.
    """

    n = len(plant_states)
    out = np.zeros((n, _TERMS))
    if n == 0:
        return out
    first = coupling_states[:1] if previous is None else np.asarray(previous).reshape(1, -1)
    S = np.concatenate([first, coupling_states[:-1]])
    held = S[:, _HELD].round().astype(int)
    out[:, TERMS_LAYOUT["held_body"]] = held
    for key, sl in (("pose_WT", _XT), ("V_WT", _VT), ("pose_WG", _XT), ("V_WG", _VT)):
        out[:, TERMS_LAYOUT[key]] = S[:, sl]
    out[:, TERMS_LAYOUT["capped"]] = S[:, _CAP]
    for index in np.unique(held[held >= 0]):
        rows = np.flatnonzero(held == index)
        body, layout = coupling._by_index[int(index)], coupling.layouts[int(index)]
        x = plant_states[rows]
        q = x[:, body.q_start : body.q_start + 4]
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        R_WB = quats_to_rotations(q)
        p_WBo = x[:, body.q_start + 4 : body.q_start + 7]
        w_B, v_Bo = x[:, body.v_start : body.v_start + 3], x[:, body.v_start + 3 : body.v_start + 6]
        r_cm = R_WB @ body.p_BoBcm_B
        p_WG = p_WBo + r_cm
        # the springs' world ends, row by row as the hook placed them (the logged target)
        qT = S[rows][:, _XT][:, :4]
        R_WT = quats_to_rotations(qT / np.linalg.norm(qT, axis=1, keepdims=True))
        V_WT = S[rows][:, _VT]
        lead = layout.lead_s
        F, T = np.zeros((len(rows), 3)), np.zeros((len(rows), 3))
        for j in range(N_SPRINGS):
            arm_T = R_WT @ layout.offsets_B[j]
            P_W = (
                S[rows][:, _XT][:, 4:] + arm_T + lead[j] * (V_WT[:, 3:] + cross_rows(V_WT[:, :3], arm_T))
                + coupling.raise_W + LENGTH_M * layout.axis_W[j]
            )  # fmt: skip
            r_B = R_WB @ layout.offsets_B[j] + r_cm
            P_B = p_WBo + r_B
            d_vec = P_W - P_B
            d = np.linalg.norm(d_vec, axis=1)
            u = d_vec / np.maximum(d, 1e-15)[:, None]
            d_dot = -np.sum(u * (v_Bo + cross_rows(w_B, r_B)), axis=1)
            f = (layout.stiffness[j] * (d - LENGTH_M) + layout.damping[j] * d_dot)[:, None] * u
            F += f
            T += cross_rows(P_B - p_WG, f)
        out[rows, TERMS_LAYOUT["pose_WG"]] = np.concatenate([q, p_WG], axis=1)
        out[rows, TERMS_LAYOUT["V_WG"]] = np.concatenate([w_B, v_Bo + cross_rows(w_B, r_cm)], axis=1)
        out[rows, TERMS_LAYOUT["F_Go_W"]] = np.concatenate([T, F], axis=1)
    return out


__all__ = [
    "ImplicitCoupling",
    "ImplicitCouplingError",
    "SpringHook",
    "SpringLayout",
    "add_springs",
    "implicit_terms",
    "spring_layout",
]
