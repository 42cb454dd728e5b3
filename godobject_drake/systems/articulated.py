"""Articulated god-objects (paper "Articulated rigid body", Eq. 4–9).

A tree-structured model (SDF/URDF) becomes a god-object: a device gives
absolute values for all or some of its joints; the god-object is the same
model simulated in the plant, pulled toward a *kinematic copy* of the device
(forward kinematics of the device's joint values, on a scratch context of
the same plant: no second model is simulated). The joints the device does
not drive are left to the simulation, and so are the bodies below them.

Three couplings, one call (:func:`godobject_drake.station.loop.add_joint_coupling`):

``cartesian``
    paper Eq. 6: every coupled body B is pulled toward the same body of the
    kinematic copy by a translational spring-damper at its centre of mass
    and a rotational one, with gains scaled by B's own mass and inertia
    (``k = m ωn²``, ``kr = I ωr²``). Explicit (``applied_spatial_force``).
``joint_pd``
    joint-space PD on each driven 1-DoF joint, ``τ = K (q_T − q) + D (v_T − v)``
    with ``K = ωn² M_jj``, ``D = 2 ζ ωn M_jj`` (``M_jj``: the joint's diagonal
    mass-matrix entry at the reference configuration). Explicit
    (``applied_generalized_force``).
``joint_pd_sap``
    the same gains as Drake's PD-controlled joint actuators, which SAP
    solves implicitly (``desired_state``): stable at any gain.

Gravity on the coupled bodies is compensated by ``−m g`` at each centre of
mass in every mode, as for the rigid god-object. The paper's gyroscopic
term ``(I Ω) × Ω`` in Eq. 6 is part of each body's own dynamics, which
Drake integrates; the coupling does not add it.

The paper enforces the joints with Lagrange multipliers and Baumgarte
stabilisation (Eq. 4, 5), so its links drift apart by the constraint error
Baumgarte lets through and pulls back. Drake's MultibodyPlant uses reduced
(joint) coordinates: a joint cannot open, so the trocar's pivot holds to
rounding error (the laparoscopy scene measures it: ``max_trocar_offset_m``),
and there are no multipliers to solve.

Joints the device drives can instead be *imposed* (the paper's jaws: "we
choose not to simulate them but instead impose their overture"): they are
locked in the plant (SAP removes their velocities, so contact on the jaws
acts on the tube rigidly) and set to the device's value before every plant
step (:meth:`ArticulatedCoupling.impose`, which the safeguards' monitor calls
through :meth:`godobject_drake.station.build.GodObject.before_step`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce, SpatialVelocity
from pydrake.multibody.plant import ExternallyAppliedSpatialForce, MultibodyPlant
from pydrake.multibody.tree import (
    BodyIndex,
    JacobianWrtVariable,
    JointIndex,
    ModelInstanceIndex,
    PdControllerGains,
)
from pydrake.systems.framework import LeafSystem, ValueProducer

from godobject_drake.config.gains import CouplingGainError, CouplingGains, FeedbackGains
from godobject_drake.limits import symplectic_euler_radius
from godobject_drake.spatial import (
    cross3,
    quat_of_rotation_entries,
    rotation_error,
    rotation_to_quat,
    rotation_vector_between,
)

COUPLINGS = ("cartesian", "joint_pd", "joint_pd_sap")
ONE_DOF_JOINTS = ("revolute", "prismatic")
_TARGET = 13  # per body: q_WB [w x y z], p_WBcm, w_WB, v_WBcm


@dataclasses.dataclass(frozen=True)
class ToolBody:
    """A body of the tool: its index, mass and inertia about its centre of mass."""

    name: str
    index: int
    mass: float  # kg
    p_BoBcm_B: np.ndarray  # m
    I_Bcm_B: np.ndarray  # kg·m², 3×3
    parent: int  # index in ArticulatedTool.bodies of the parent tool body, −1 for none


@dataclasses.dataclass(frozen=True)
class ToolJoint:
    """A joint the device gives values for."""

    name: str
    index: int
    type: str  # Drake's type_name(): revolute, prismatic, ball_rpy, ...
    q: slice  # its positions in the plant's q
    v: slice  # its velocities in the plant's v
    imposed: bool


class ArticulatedTool:
    """A tree model seen as a god-object: the joints a device drives and the bodies that follow.

    Parameters
    ----------
    plant : MultibodyPlant
        A finalized plant holding the model.
    model : str | ModelInstanceIndex
        The tool's model instance.
    device_joints : sequence of str
        The joints the device gives values for, in the device's order
        (``q_device`` concatenates their positions).
    imposed_joints : sequence of str
        Those of ``device_joints`` that are imposed instead of coupled.

    A body is *coupled* when every joint between it and the world is a
    device joint or a weld (at least one device joint), and it has mass: its
    pose is then fixed by the device's values and moves with them. The
    others (below an undriven joint) are simulated only.
    """

    def __init__(self, plant: MultibodyPlant, model, device_joints, imposed_joints=()):
        if not plant.is_finalized():
            raise RuntimeError("ArticulatedTool needs a finalized plant; call plant.Finalize() first")
        self.plant = plant
        self.model = model if isinstance(model, ModelInstanceIndex) else plant.GetModelInstanceByName(model)
        joints = [plant.get_joint(i) for i in plant.GetJointIndices(self.model)]
        by_name = {j.name(): j for j in joints}
        movable = sorted(j.name() for j in joints if j.num_velocities() > 0)
        unknown = [n for n in list(device_joints) + list(imposed_joints) if n not in by_name]
        if unknown:
            raise ValueError(
                f"joints {unknown} are not in model {plant.GetModelInstanceName(self.model)!r}; "
                f"its movable joints are {movable}"
            )
        stray = sorted(set(imposed_joints) - set(device_joints))
        if stray:
            raise ValueError(f"imposed joints {stray} must also be device joints {list(device_joints)}")
        if len(set(device_joints)) != len(list(device_joints)):
            raise ValueError(f"device_joints {list(device_joints)} name a joint twice")
        nq = plant.num_positions()
        self.joints = []
        for name in device_joints:
            j = by_name[name]
            if j.num_velocities() == 0:
                raise ValueError(f"joint {name!r} is a weld: a device cannot drive it")
            self.joints.append(
                ToolJoint(
                    name,
                    int(j.index()),
                    j.type_name(),
                    slice(j.position_start(), j.position_start() + j.num_positions()),
                    slice(j.velocity_start(), j.velocity_start() + j.num_velocities()),
                    name in set(imposed_joints),
                )
            )
        self.nq_device = sum(j.q.stop - j.q.start for j in self.joints)
        self.q_device = np.concatenate([np.arange(nq)[j.q] for j in self.joints]).astype(int)
        self.v_device = np.concatenate([np.arange(plant.num_velocities())[j.v] for j in self.joints]).astype(
            int
        )
        self.coupled = [j for j in self.joints if not j.imposed]
        self.imposed = [j for j in self.joints if j.imposed]
        self._find_bodies(device_joints)
        self._context = plant.CreateDefaultContext()
        self._body_objs = [plant.get_body(BodyIndex(b.index)) for b in self.bodies]

    def _find_bodies(self, device_joints) -> None:
        """The coupled bodies (:attr:`bodies`), their parents among them, and their order from the
        leaves in (:attr:`leaves_first`)."""
        plant = self.plant
        # Bodies whose path to the world runs through device joints and welds only.
        device_set = {j.index for j in self.joints}
        inboard = {}
        for i in range(plant.num_joints()):
            j = plant.get_joint(JointIndex(i))
            inboard[int(j.child_body().index())] = j
        world = int(plant.world_body().index())

        def driven_path(b: int) -> bool:
            """Only device joints and welds between b and the world, and at least one device joint."""
            moved = False
            while b != world:
                j = inboard.get(b)
                if j is None or (j.num_velocities() > 0 and int(j.index()) not in device_set):
                    return False
                moved = moved or j.num_velocities() > 0
                b = int(j.parent_body().index())
            return moved

        self.bodies: list[ToolBody] = []
        position = {}
        for bi in plant.GetBodyIndices(self.model):
            body = plant.get_body(bi)
            if not (driven_path(int(bi)) and body.default_mass() > 0.0):
                continue
            M = body.default_spatial_inertia()
            p = np.asarray(M.get_com()).copy()
            position[int(bi)] = len(self.bodies)
            self.bodies.append(
                ToolBody(
                    body.scoped_name().get_full(),
                    int(bi),
                    float(body.default_mass()),
                    p,
                    M.Shift(p).CalcRotationalInertia().CopyToFullMatrix3(),
                    -1,
                )
            )
        # Parents among the coupled bodies (massless links in between are skipped).
        for k, b in enumerate(self.bodies):
            p = int(inboard[b.index].parent_body().index())
            while p != world and p not in position:
                p = int(inboard[p].parent_body().index())
            self.bodies[k] = dataclasses.replace(b, parent=position.get(p, -1))
        if not self.bodies:
            raise ValueError(
                f"no body of {plant.GetModelInstanceName(self.model)!r} is fixed by the device joints "
                f"{list(device_joints)}: drive the joints between the world and the tool"
            )
        depth = []
        for b in self.bodies:
            d, p = 0, b.parent
            while p >= 0:
                d, p = d + 1, self.bodies[p].parent
            depth.append(d)
        self.leaves_first = sorted(range(len(self.bodies)), key=lambda k: -depth[k])

    # -- kinematics of the device (the kinematic copy) --------------------------------
    def set_device_state(self, q_device: np.ndarray, qdot_device: np.ndarray | None = None, x=None):
        """Put the kinematic copy at the device's joint values; return its scratch context.

        ``x`` (the plant's ``[q; v]``) gives the joints the device does not
        drive; the plant's default positions otherwise.
        """
        plant, ctx = self.plant, self._context
        q = plant.GetDefaultPositions() if x is None else np.array(x[: plant.num_positions()])
        q[self.q_device] = q_device
        plant.SetPositions(ctx, q)
        qdot = np.zeros(plant.num_positions())
        if qdot_device is not None:
            qdot[self.q_device] = qdot_device
        plant.SetVelocities(ctx, plant.MapQDotToVelocity(ctx, qdot))
        return ctx

    def body_targets(self, q_device, qdot_device=None, x=None) -> np.ndarray:
        """Per coupled body ``[q_WB (4), p_WBcm (3), w_WB (3), v_WBcm (3)]`` of the kinematic copy."""
        ctx = self.set_device_state(q_device, qdot_device, x)
        out = np.empty(_TARGET * len(self.bodies))
        for k, (b, body) in enumerate(zip(self.bodies, self._body_objs, strict=True)):
            X = self.plant.EvalBodyPoseInWorld(ctx, body)
            V = self.plant.EvalBodySpatialVelocityInWorld(ctx, body)
            R = X.rotation().matrix()
            p_cm = R @ b.p_BoBcm_B
            w = V.rotational()
            out[_TARGET * k : _TARGET * (k + 1)] = np.concatenate(
                [rotation_to_quat(R), X.translation() + p_cm, w, V.translational() + np.cross(w, p_cm)]
            )
        return out

    def mass_matrix(self, q_device, x=None) -> np.ndarray:
        """The plant's mass matrix at the device's joint values (kg, kg·m²)."""
        return self.plant.CalcMassMatrix(self.set_device_state(q_device, None, x))

    def com_jacobians(self, q_device, x=None) -> list[np.ndarray]:
        """Per coupled body, the 6×nv Jacobian of ``[w_WB; v_WBcm]`` at the device's values."""
        ctx = self.set_device_state(q_device, None, x)
        W = self.plant.world_frame()
        return [
            self.plant.CalcJacobianSpatialVelocity(
                ctx, JacobianWrtVariable.kV, body.body_frame(), b.p_BoBcm_B, W, W
            )
            for b, body in zip(self.bodies, self._body_objs, strict=True)
        ]

    def joint_inertia(self, q_reference) -> np.ndarray:
        """Diagonal mass-matrix entries of the coupled joints' velocities at ``q_reference``."""
        M = self.mass_matrix(q_reference)
        return np.concatenate([np.diag(M)[j.v] for j in self.coupled]) if self.coupled else np.zeros(0)

    def coupled_v(self) -> np.ndarray:
        """Indices in the plant's v of the coupled (not imposed) device joints."""
        return np.concatenate([np.arange(self.plant.num_velocities())[j.v] for j in self.coupled]).astype(int)

    def tool_free_v(self) -> np.ndarray:
        """Indices in v of the tool's joints that are neither imposed nor welded (coupled or free)."""
        imposed = {i for j in self.imposed for i in range(j.v.start, j.v.stop)}
        out = []
        for ji in self.plant.GetJointIndices(self.model):
            j = self.plant.get_joint(ji)
            out += [
                i
                for i in range(j.velocity_start(), j.velocity_start() + j.num_velocities())
                if i not in imposed
            ]
        return np.array(sorted(out), dtype=int)


@dataclasses.dataclass(frozen=True)
class JointSpaceLoop:
    """The coupling as a joint-space spring-damper about a configuration (for the explicit check).

    ``M``, ``K``, ``D`` act on the tool's non-imposed velocities; ``radius``
    is the spectral radius of the symplectic Euler step of
    ``M v̇ = −K q − D v`` at ``time_step`` (< 1: stable).
    """

    M: np.ndarray
    K: np.ndarray
    D: np.ndarray
    time_step: float
    radius: float
    omega_max: float  # rad/s, fastest mode √λmax(M⁻¹K)


def joint_space_loop(tool: ArticulatedTool, coupling: str, gains: CouplingGains, q, time_step: float):
    """Linearize an explicit coupling about the device configuration ``q`` (joint space).

    On the coupled joints' velocities: ``cartesian`` gives
    ``K = Σ Jᵢᵀ diag(I_Wᵢ ωr², mᵢ ωn²) Jᵢ`` (D alike with ``2ζω``) with the
    com Jacobians Jᵢ; ``joint_pd`` the diagonal joint gains. Imposed joints
    are locked (dropped); the tool's undriven joints are free, so M is the
    Schur complement of their block (the inertia the coupling sees).
    """
    c = tool.coupled_v()
    u = np.setdiff1d(tool.tool_free_v(), c)
    M_full = tool.mass_matrix(q)
    M = M_full[np.ix_(c, c)]
    if len(u):
        M = M - M_full[np.ix_(c, u)] @ np.linalg.solve(M_full[np.ix_(u, u)], M_full[np.ix_(u, c)])
    n = len(c)
    K, D = np.zeros((n, n)), np.zeros((n, n))
    wn, wr, zn, zr = gains.omega_n, gains.omega_r, gains.zeta, gains.zeta_r
    if coupling == "cartesian":
        for b, body, J in zip(tool.bodies, tool._body_objs, tool.com_jacobians(q), strict=True):
            Jw, Jv = J[:3, c], J[3:, c]
            R = tool.plant.EvalBodyPoseInWorld(tool._context, body).rotation().matrix()
            I_W = R @ b.I_Bcm_B @ R.T
            K += wn**2 * b.mass * Jv.T @ Jv + wr**2 * Jw.T @ I_W @ Jw
            D += 2 * zn * wn * b.mass * Jv.T @ Jv + 2 * zr * wr * Jw.T @ I_W @ Jw
    else:
        m = tool.joint_inertia(q)
        K[np.diag_indices(n)] = wn**2 * m
        D[np.diag_indices(n)] = 2 * zn * wn * m
    lam = np.linalg.eigvals(np.linalg.solve(M, K)).real
    radius = symplectic_euler_radius(M, K, D, time_step)
    return JointSpaceLoop(M, K, D, time_step, radius, float(math.sqrt(max(lam.max(initial=0.0), 0.0))))


class ArticulatedCoupling(LeafSystem):
    """Couples an articulated tool to a joint-space device (paper Eq. 6 or joint PD).

    .. pydrake_system::

        name: ArticulatedCoupling
        input_ports:
        - plant_state
        - body_poses
        - body_spatial_velocities
        - q_device
        - v_device
        output_ports:
        - spatial_forces
        - generalized_force
        - desired_state
        - targets
        - q_target

    ``plant_state``, ``body_poses`` and ``body_spatial_velocities`` come from
    the plant; ``q_device``/``v_device`` from a
    :class:`~godobject_drake.devices.sources.JointDevice` (positions of the device
    joints, and their time derivatives). Once per device period (half a
    plant step after the device samples) the coupling puts the kinematic
    copy at the device's values and stores each coupled body's target
    ``[q_WB, p_WBcm, w_WB, v_WBcm]`` (``targets``, 13 per body, in
    ``tool.bodies`` order) and the joint targets (``q_target``: positions
    of the device joints; velocities alongside).

    ``spatial_forces`` (to ``applied_spatial_force``): the Cartesian
    springs in ``cartesian`` mode and, in every mode, ``−m g`` at each
    coupled body's centre of mass. ``generalized_force`` (to
    ``applied_generalized_force``, plant-wide v): the joint PD in
    ``joint_pd`` mode, zero otherwise. ``desired_state`` (to the model's
    ``desired_state`` input, actuator order): ``[q_T; v_T]`` for
    ``joint_pd_sap``.
    """

    def __init__(
        self,
        tool: ArticulatedTool,
        coupling: str,
        gains: CouplingGains,
        device_period_s: float,
        q_reference: np.ndarray,
        q_check=None,
        gravity_compensation: bool = True,
        check_gains: bool = True,
    ):
        super().__init__()
        if coupling not in COUPLINGS:
            raise ValueError(f"coupling={coupling!r}; choose one of {COUPLINGS}")
        plant = tool.plant
        h = plant.time_step()
        self.tool, self.coupling, self.gains = tool, coupling, gains
        q_reference = np.asarray(q_reference, dtype=float)
        if q_reference.shape != (tool.nq_device,):
            raise ValueError(
                f"q_reference has shape {q_reference.shape}; the device gives {tool.nq_device} values"
            )
        if coupling != "cartesian":
            bad = [f"{j.name} ({j.type})" for j in tool.coupled if j.type not in ONE_DOF_JOINTS]
            if bad:
                raise ValueError(
                    f"coupling={coupling!r} needs 1-DoF (revolute, prismatic) joints; {bad} are not. "
                    "Use coupling='cartesian' for ball or floating joints."
                )
        gains.check(0.0)  # positive bandwidths; warns outside the paper's damping range
        self.joint_inertia = tool.joint_inertia(q_reference)
        self.K = gains.omega_n**2 * self.joint_inertia
        self.D = 2.0 * gains.zeta * gains.omega_n * self.joint_inertia
        self.loops = self._check_loops(q_reference, q_check) if check_gains and h > 0 else []
        if coupling == "joint_pd_sap":
            self._setup_actuators()

        nb = len(tool.bodies)
        self._g = np.asarray(plant.gravity_field().gravity_vector()) if gravity_compensation else np.zeros(3)
        self._wn2, self._2zwn = gains.omega_n**2, 2.0 * gains.zeta * gains.omega_n
        self._wr2, self._2zwr = gains.omega_r**2, 2.0 * gains.zeta_r * gains.omega_r
        self._index = [b.index for b in tool.bodies]
        self._g_list = self._g.tolist()
        # per body, as floats: (BodyIndex, mass, p_BoBcm_B, I_Bcm_B row-major)
        self._fast = [
            (b.index, float(b.mass), tuple(np.asarray(b.p_BoBcm_B, float).tolist()),
             tuple(np.asarray(b.I_Bcm_B, float).ravel().tolist()))
            for b in tool.bodies
        ]  # fmt: skip
        self._forces = [ExternallyAppliedSpatialForce() for _ in tool.bodies]
        for f, b in zip(self._forces, tool.bodies, strict=True):
            f.body_index = BodyIndex(b.index)
            f.p_BoBq_B = b.p_BoBcm_B
            f.F_Bq_W = SpatialForce(np.zeros(3), -b.mass * self._g)  # the joint modes' constant load
        self._cv = tool.coupled_v()
        self._cq = np.concatenate(
            [np.arange(tool.nq_device)[self._device_slice(j)] for j in tool.coupled]
        ).astype(int) if tool.coupled else np.zeros(0, int)  # fmt: skip
        self._nq = plant.num_positions()
        self._cv_in_device = np.array([list(tool.v_device).index(v) for v in self._cv], dtype=int)

        n = plant.num_multibody_states()
        self._state = self.DeclareVectorInputPort("plant_state", n)
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self._vels = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self._q_dev = self.DeclareVectorInputPort("q_device", tool.nq_device)
        self._v_dev = self.DeclareVectorInputPort("v_device", tool.nq_device)

        # [body targets (13 nb), q_target, qdot_target (nq_device each), v_target (device joints' v)]
        self._nt = _TARGET * nb
        nvd = len(tool.v_device)
        x0 = np.concatenate(
            [tool.body_targets(q_reference), q_reference, np.zeros(tool.nq_device), np.zeros(nvd)]
        )
        self._targets = self.DeclareDiscreteState(x0)
        offset = 0.5 * h if h > 0 else 1e-6
        self.DeclarePeriodicDiscreteUpdateEvent(device_period_s, offset, self._update_targets)

        self.DeclareAbstractOutputPort(
            "spatial_forces",
            lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
            self._calc_spatial_forces,
            {self.xd_ticket(), self._poses.ticket(), self._vels.ticket()},
        )
        self.DeclareVectorOutputPort(
            "generalized_force", plant.num_velocities(), self._calc_generalized_force,
            {self.xd_ticket(), self._state.ticket()},
        )  # fmt: skip
        n_act = plant.num_actuated_dofs(tool.model)
        self._act_q, self._act_v = self._actuated_targets() if coupling == "joint_pd_sap" else ([], [])
        self.DeclareVectorOutputPort("desired_state", 2 * n_act, self._calc_desired_state, {self.xd_ticket()})
        self.DeclareVectorOutputPort("targets", self._nt, self._calc_targets, {self.xd_ticket()})
        self.DeclareVectorOutputPort("q_target", tool.nq_device, self._calc_q_target, {self.xd_ticket()})

    # -- setup -------------------------------------------------------------------
    def _check_loops(self, q_reference, q_check) -> list[JointSpaceLoop]:
        """The explicit modes' joint-space loop at each device configuration to check (the
        reference by default); gains whose loop has spectral radius ≥ 1 somewhere are refused."""
        if self.coupling == "joint_pd_sap":
            return []
        tool, coupling, gains, h = self.tool, self.coupling, self.gains, self.tool.plant.time_step()
        loops = []
        for q in [q_reference] if q_check is None else q_check:
            loop = joint_space_loop(tool, coupling, gains, np.asarray(q, float), h)
            loops.append(loop)
            if loop.radius >= 1.0:
                raise CouplingGainError(
                    f"coupling={coupling!r} with omega_n={gains.omega_n:g}, omega_n_rot="
                    f"{gains.omega_r:g} rad/s at time_step={h:g} s is unstable at the device "
                    f"configuration q={np.round(q, 4).tolist()}: the explicit (symplectic Euler) "
                    f"joint-space loop has spectral radius {loop.radius:.4f} ≥ 1 (fastest mode "
                    f"{loop.omega_max:.4g} rad/s, ω·h = {loop.omega_max * h:.3g}). Lower the "
                    f"bandwidths or time_step, or use coupling='joint_pd_sap' (implicit)."
                )
        return loops

    def _device_slice(self, joint: ToolJoint) -> slice:
        start = 0
        for j in self.tool.joints:
            n = j.q.stop - j.q.start
            if j is joint:
                return slice(start, start + n)
            start += n
        raise KeyError(joint.name)

    def _setup_actuators(self):
        plant, tool = self.tool.plant, self.tool
        by_joint = {}
        for ai in plant.GetJointActuatorIndices(tool.model):
            a = plant.get_joint_actuator(ai)
            by_joint[int(a.joint().index())] = a
        for j, k, d in zip(tool.coupled, self.K, self.D, strict=True):
            a = by_joint.get(j.index)
            if a is None:
                raise ValueError(
                    f"coupling='joint_pd_sap' needs an actuator on joint {j.name!r}; add one before "
                    "Finalize (plant.AddJointActuator; SDF joints get one by default)"
                )
            a.set_controller_gains(PdControllerGains(p=float(k), d=float(d)))

    def _actuated_targets(self):
        """Where each actuator of the model finds its desired q and v in the target state."""
        plant, tool = self.tool.plant, self.tool
        nq_d = tool.nq_device
        q_idx, v_idx = [], []
        for ai in plant.GetJointActuatorIndices(tool.model):
            j = plant.get_joint_actuator(ai).joint()
            match = [t for t in tool.coupled if t.index == int(j.index())]
            if match:
                s = self._device_slice(match[0])
                q_idx.append(self._nt + s.start)
                v_idx.append(self._nt + 2 * nq_d + list(tool.v_device).index(j.velocity_start()))
            else:
                q_idx.append(-1)
                v_idx.append(-1)
        return np.array(q_idx, int), np.array(v_idx, int)

    # -- device samples ---------------------------------------------------------
    def _update_targets(self, context, discrete_state):
        q = self._q_dev.Eval(context)
        qdot = self._v_dev.Eval(context)
        x = self._state.Eval(context)
        tool = self.tool
        body = tool.body_targets(q, qdot, x)
        v_full = tool.plant.GetVelocities(tool._context)
        discrete_state.get_mutable_vector(self._targets).SetFromVector(
            np.concatenate([body, q, qdot, v_full[tool.v_device]])
        )

    # -- the hot path -------------------------------------------------------------
    # Plain Python floats, as the rigid coupling: on 3-vectors one numpy call costs about as much
    # as the float expression, and this ran 8 numpy calls per body per step (half the laparoscopy
    # scene's time). The same formulas: f = m (ωn² (p_T − p_G) + 2ζωn (v_T − v_G) − g),
    # τ = R I_B Rᵀ (ωr² α u + 2ζr ωr (w_T − w)).
    def _calc_spatial_forces(self, context, output):
        if self.coupling != "cartesian":  # gravity compensation only: constant, set at construction
            output.set_value(self._forces)
            return
        s = context.get_discrete_state(self._targets).get_value().tolist()
        poses, vels = self._poses.Eval(context), self._vels.Eval(context)
        wn2, c, wr2, cr = self._wn2, self._2zwn, self._wr2, self._2zwr
        g0, g1, g2 = self._g_list
        for k, (b, force) in enumerate(zip(self._fast, self._forces, strict=True)):
            index, m, (c0, c1, c2), J = b
            M = poses[index].GetAsMatrix34().tolist()
            R = (M[0][0], M[0][1], M[0][2], M[1][0], M[1][1], M[1][2], M[2][0], M[2][1], M[2][2])
            w0, w1, w2, v0, v1, v2 = vels[index].get_coeffs().tolist()
            r0 = R[0] * c0 + R[1] * c1 + R[2] * c2  # p_BoBcm in W
            r1 = R[3] * c0 + R[4] * c1 + R[5] * c2
            r2 = R[6] * c0 + R[7] * c1 + R[8] * c2
            t = s[_TARGET * k : _TARGET * (k + 1)]
            f = SpatialForce(
                self._torque(R, t, w0, w1, w2, J, wr2, cr),
                [
                    m * (wn2 * (t[4] - M[0][3] - r0) + c * (t[10] - v0 - w1 * r2 + w2 * r1) - g0),
                    m * (wn2 * (t[5] - M[1][3] - r1) + c * (t[11] - v1 - w2 * r0 + w0 * r2) - g1),
                    m * (wn2 * (t[6] - M[2][3] - r2) + c * (t[12] - v2 - w0 * r1 + w1 * r0) - g2),
                ],
            )
            force.F_Bq_W = f
        output.set_value(self._forces)

    @staticmethod
    def _torque(R, t, w0, w1, w2, J, wr2, cr) -> list:
        e = rotation_vector_between((t[0], t[1], t[2], t[3]), quat_of_rotation_entries(R))
        u0 = wr2 * e[0] + cr * (t[7] - w0)
        u1 = wr2 * e[1] + cr * (t[8] - w1)
        u2 = wr2 * e[2] + cr * (t[9] - w2)
        y0 = R[0] * u0 + R[3] * u1 + R[6] * u2  # Rᵀ u
        y1 = R[1] * u0 + R[4] * u1 + R[7] * u2
        y2 = R[2] * u0 + R[5] * u1 + R[8] * u2
        z0 = J[0] * y0 + J[1] * y1 + J[2] * y2  # I_B Rᵀ u
        z1 = J[3] * y0 + J[4] * y1 + J[5] * y2
        z2 = J[6] * y0 + J[7] * y1 + J[8] * y2
        return [
            R[0] * z0 + R[1] * z1 + R[2] * z2,
            R[3] * z0 + R[4] * z1 + R[5] * z2,
            R[6] * z0 + R[7] * z1 + R[8] * z2,
        ]

    def _calc_generalized_force(self, context, output):
        out = np.zeros(self.tool.plant.num_velocities())
        if self.coupling == "joint_pd" and len(self._cv):
            s = context.get_discrete_state(self._targets).get_value()
            x = self._state.Eval(context)
            nq_d = self.tool.nq_device
            q_T = s[self._nt : self._nt + nq_d][self._cq]
            v_T = s[self._nt + 2 * nq_d :][self._cv_in_device]
            q = x[self.tool.q_device][self._cq]
            v = x[self._nq + self._cv]
            out[self._cv] = self.K * (q_T - q) + self.D * (v_T - v)
        output.SetFromVector(out)

    def _calc_desired_state(self, context, output):
        s = context.get_discrete_state(self._targets).get_value()
        q = np.where(self._act_q >= 0, s[np.maximum(self._act_q, 0)], 0.0) if len(self._act_q) else []
        v = np.where(self._act_v >= 0, s[np.maximum(self._act_v, 0)], 0.0) if len(self._act_v) else []
        output.SetFromVector(np.concatenate([q, v]) if len(self._act_q) else np.zeros(output.size()))

    def _calc_targets(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._targets).get_value()[: self._nt])

    def _calc_q_target(self, context, output):
        s = context.get_discrete_state(self._targets).get_value()
        output.SetFromVector(s[self._nt : self._nt + self.tool.nq_device])

    # -- imposing joints (the station's articulated tool calls these) ------------
    def lock_imposed(self, plant_context) -> None:
        """Lock the imposed joints (call once on the simulator's plant context)."""
        for j in self.tool.imposed:
            self.tool.plant.get_joint(JointIndex(j.index)).Lock(plant_context)

    def impose(self, plant_context, coupling_context, everything: bool = False) -> None:
        """Set joints to the device's latest values: the imposed ones, or all of them (position baseline)."""
        plant, tool = self.tool.plant, self.tool
        s = coupling_context.get_discrete_state(self._targets).get_value()
        nq_d = tool.nq_device
        q_T = s[self._nt : self._nt + nq_d]
        v_T = s[self._nt + 2 * nq_d :]
        q = plant.GetPositions(plant_context)
        v = plant.GetVelocities(plant_context)
        joints = tool.joints if everything else tool.imposed
        vd = list(tool.v_device)
        for j in joints:
            q[j.q] = q_T[self._device_slice(j)]
            v[j.v] = (
                0.0
                if j.imposed and not everything
                else v_T[[vd.index(i) for i in range(j.v.start, j.v.stop)]]
            )
        plant.SetPositions(plant_context, q)
        plant.SetVelocities(plant_context, v)


class ArticulatedFeedback(LeafSystem):
    """Feedback to an articulated device (paper Eq. 8, 9).

    .. pydrake_system::

        name: ArticulatedFeedback
        input_ports:
        - body_poses
        - body_spatial_velocities
        - targets
        - q_device
        output_ports:
        - F_feedback_W
        - F_subtree_W
        - tau_device

    Eq. 8, per coupled body i (at its target centre of mass, in W)::

        f_i = kd (x_i − x_Ti) + γd (v_i − v_Ti)
        τ_i = kd_r αu(q_i q_Ti⁻¹) + γd_r (Ω_i − Ω_Ti)

    ``F_feedback_W`` stacks ``[τ_i; f_i]`` in ``tool.bodies`` order.
    ``F_subtree_W`` is Eq. 9: each body's wrench plus its descendants',
    moved to its own target centre of mass (``T += T_c + (x_c − x) × F_c``),
    what a device API that takes one wrench per link expects.
    ``tau_device`` are the generalized forces on the device's joints,
    ``Σ J_iᵀ [τ_i; f_i]`` with the com Jacobians of the device's own
    configuration, in the device joints' velocity order. Zero gains (a
    non-haptic device) give zeros at no cost.
    """

    def __init__(self, tool: ArticulatedTool, gains: FeedbackGains | None = None):
        super().__init__()
        self.tool = tool
        self.gains = gains or FeedbackGains()
        nb = len(tool.bodies)
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self._vels = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self._targets = self.DeclareVectorInputPort("targets", _TARGET * nb)
        self._q_dev = self.DeclareVectorInputPort("q_device", tool.nq_device)
        self._zero = all(getattr(self.gains, f.name) == 0.0 for f in dataclasses.fields(self.gains))
        self.has_gains = not self._zero
        # Eq. 8 once per evaluation, shared by the three outputs.
        self._F = self.DeclareCacheEntry(
            "feedback wrenches",
            ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros((nb, 6))), calc=self._calc_cache),
            {self._poses.ticket(), self._vels.ticket(), self._targets.ticket()},
        )
        after = {self._F.ticket()}
        self.DeclareVectorOutputPort("F_feedback_W", 6 * nb, self._calc_wrenches, after)
        self.DeclareVectorOutputPort(
            "F_subtree_W", 6 * nb, self._calc_subtree, after | {self._targets.ticket()}
        )
        self.DeclareVectorOutputPort(
            "tau_device", len(tool.v_device), self._calc_tau, after | {self._q_dev.ticket()}
        )

    def wrenches(self, poses, vels, targets) -> np.ndarray:
        """Eq. 8 for every coupled body: ``(nb, 6)`` rows ``[τ; f]`` (N·m, N)."""
        g = self.gains
        out = np.zeros((len(self.tool.bodies), 6))
        for k, b in enumerate(self.tool.bodies):
            X, V = poses[b.index], vels[b.index]
            t = targets[_TARGET * k : _TARGET * (k + 1)]
            R = X.rotation().matrix()
            p_cm = R @ b.p_BoBcm_B
            w = V.rotational()
            x_cm = X.translation() + p_cm
            v_cm = V.translational() + cross3(w, p_cm)
            f = g.kd * (x_cm - t[4:7]) + g.gamma_d * (v_cm - t[10:13])
            tau = g.kd_rot * rotation_error(rotation_to_quat(R), t[:4]) + g.gamma_d_rot * (w - t[7:10])
            out[k] = np.concatenate([tau, f])
        return out

    def _calc_cache(self, context, value):
        if not self._zero:
            poses, vels = self._poses.Eval(context), self._vels.Eval(context)
            value.set_value(self.wrenches(poses, vels, self._targets.Eval(context)))

    def _calc_wrenches(self, context, output):
        output.SetFromVector(self._F.Eval(context).ravel())

    def _calc_subtree(self, context, output):
        if self._zero:
            output.SetFromVector(np.zeros(output.size()))
            return
        F = self._F.Eval(context)
        output.SetFromVector(propagate_to_parents(self.tool, F, self._targets.Eval(context)).ravel())

    def _calc_tau(self, context, output):
        if self._zero:
            output.SetFromVector(np.zeros(output.size()))
            return
        output.SetFromVector(generalized_forces(self.tool, self._F.Eval(context), self._q_dev.Eval(context)))


def propagate_to_parents(tool: ArticulatedTool, wrenches: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Paper Eq. 9: sum each body's wrench with its descendants', about its own target com.

    ``wrenches`` (nb, 6) rows ``[τ; f]`` at each body's target com; returns
    the (nb, 6) subtree wrenches, one sweep from the leaves to the root.
    """
    x = targets.reshape(-1, _TARGET)[:, 4:7]
    out = np.array(wrenches, dtype=float)
    for k in tool.leaves_first:
        p = tool.bodies[k].parent
        if p >= 0:
            out[p, 3:] += out[k, 3:]
            out[p, :3] += out[k, :3] + np.cross(x[k] - x[p], out[k, 3:])
    return out


def generalized_forces(tool: ArticulatedTool, wrenches: np.ndarray, q_device) -> np.ndarray:
    """``Σ Jᵢᵀ [τᵢ; fᵢ]`` on the device joints' velocities, Jacobians at ``q_device``."""
    tau = np.zeros(tool.plant.num_velocities())
    for J, F in zip(tool.com_jacobians(np.asarray(q_device, float)), wrenches, strict=True):
        tau += J.T @ F
    return tau[tool.v_device]


__all__ = [
    "COUPLINGS",
    "ArticulatedCoupling",
    "ArticulatedFeedback",
    "ArticulatedTool",
    "JointSpaceLoop",
    "ToolBody",
    "ToolJoint",
    "generalized_forces",
    "joint_space_loop",
    "propagate_to_parents",
]
