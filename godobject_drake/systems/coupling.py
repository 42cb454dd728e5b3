"""The god-object coupling (paper Eq. 2): a damped zero-length spring to the target.

The held body B is pulled toward the device's target by a translational and
a rotational spring-damper. G is the god-object frame: origin Go at B's
centre of mass Bcm, axes of B. Acting at Go decouples translation from
rotation, so in free space each axis obeys paper Eq. 3 exactly.

Gains are given by bandwidth and damping ratio and scaled by the held body's
own mass and rotational inertia (about Bcm, expressed in W)::

    F = m (ωn² e_t + 2 ζ ωn (v_T − v_G))                 [+ m g compensation]
    T = I_W (ωr² α u + 2 ζr ωr (w_T − w_G))

so ``k = m ωn²``, ``γ = 2 ζ m ωn`` and ``γ/√(mk) = 2ζ`` (the paper's
1.4 … 2 is ζ ∈ [0.7, 1]). The force enters the plant through
``applied_spatial_force`` and is therefore explicit: the discrete plant
integrates the coupled body with symplectic Euler, stable only while
``ωn h < 2(√(1+ζ²) − ζ)`` (docs/theory.md §1). The constructor refuses gains
past that limit.
"""

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce, MultibodyPlant
from pydrake.multibody.tree import BodyIndex, SpatialInertia
from pydrake.systems.framework import LeafSystem, ValueProducer

from godobject_drake.config.gains import (
    DEFAULT_MAX_STRETCH_M,
    DEFAULT_MAX_TWIST_RAD,
    GRASP_NEAREST,
    CouplingGains,
)
from godobject_drake.spatial import (
    pose_arrays,
    quat_conjugate,
    quat_multiply,
    quat_of_rotation_entries,
    quat_product,
    quat_to_rotation,
    rotation_entries,
    rotation_vector_between,
)


@dataclasses.dataclass(frozen=True)
class GraspableBody:
    """What the coupling needs of a free body, read once from the plant."""

    name: str
    index: int
    mass: float  # kg
    p_BoBcm_B: np.ndarray  # m
    I_Bcm_B: np.ndarray  # kg·m², 3×3
    q_start: int  # first of [qw qx qy qz x y z] in the plant's q
    v_start: int  # first of [wx wy wz vx vy vz] in the plant's v


def graspable_bodies(plant: MultibodyPlant) -> dict[str, GraspableBody]:
    """Free bodies of a finalized plant, by every name a device may use.

    A body is reachable as ``model::body`` and, where unambiguous, by its
    body name and by its model instance name when the instance has one body
    (so ``brick_0`` names the body of model instance ``brick_0``).
    """
    if not plant.is_finalized():
        raise RuntimeError("graspable_bodies() needs a finalized plant; call plant.Finalize() first")
    found: dict[str, GraspableBody] = {}
    counts: dict[str, int] = {}
    nq = plant.num_positions()
    for i in range(plant.num_bodies()):
        body = plant.get_body(BodyIndex(i))
        if not body.is_floating_base_body() or not body.has_quaternion_dofs():
            continue
        M = body.default_spatial_inertia()
        p = np.asarray(M.get_com()).copy()
        info = GraspableBody(
            name=body.scoped_name().get_full(),
            index=int(body.index()),
            mass=float(body.default_mass()),
            p_BoBcm_B=p,
            I_Bcm_B=M.Shift(p).CalcRotationalInertia().CopyToFullMatrix3(),
            q_start=int(body.floating_positions_start()),
            v_start=nq + int(body.floating_velocities_start_in_v()),
        )
        if not info.mass > 0.0:
            raise ValueError(f"free body {info.name} has mass {info.mass}; a god-object needs m > 0")
        instance = plant.GetModelInstanceName(body.model_instance())
        aliases = [info.name, body.name()]
        if len(plant.GetBodyIndices(body.model_instance())) == 1:
            aliases.append(instance)
        for alias in dict.fromkeys(aliases):
            counts[alias] = counts.get(alias, 0) + 1
            found[alias] = info
    return {k: v for k, v in found.items() if counts[k] == 1 or k == v.name}


def fixed_bodies(plant: MultibodyPlant) -> dict[str, str]:
    """Bodies that are not free, by the names a device might use, with why they cannot be grasped."""
    out = {}
    for i in range(1, plant.num_bodies()):
        body = plant.get_body(BodyIndex(i))
        if body.is_floating_base_body() and body.has_quaternion_dofs():
            continue
        why = (
            "is welded to the world (an obstacle)"
            if plant.IsAnchored(body)
            else "is a link of an articulated model "
            "(use godobject_drake.station.loop.add_joint_coupling for it)"
        )
        instance = plant.GetModelInstanceName(body.model_instance())
        aliases = [body.scoped_name().get_full(), body.name()]
        if len(plant.GetBodyIndices(body.model_instance())) == 1:
            aliases.append(instance)
        for alias in aliases:
            out.setdefault(alias, f"{body.scoped_name().get_full()} {why}")
    return out


def with_carried_inertia(body: GraspableBody, M_BBo_B: SpatialInertia) -> GraspableBody:
    """``body`` as the coupling sees it when it carries ``M_BBo_B`` (about Bo, in B).

    For what moves with a body without being part of it in the plant: a
    deformable shell held to its core. The coupling's gains (``k = m ωn²``,
    ``kr = I ωr²``) and its gravity compensation then use the total mass and
    inertia, so the pair keeps the bandwidth and damping asked for and does
    not sag under the carried weight.
    """
    m1, m2 = body.mass, float(M_BBo_B.get_mass())
    if not (math.isfinite(m2) and m2 >= 0.0):
        raise ValueError(f"carried mass {m2!r} kg must be finite and ≥ 0")
    p1, p2 = body.p_BoBcm_B, np.asarray(M_BBo_B.get_com())
    m = m1 + m2
    p = (m1 * p1 + m2 * p2) / m

    def about_bo(mass, p_cm, I_cm):  # parallel axis: from Bcm to Bo
        return I_cm + mass * (p_cm @ p_cm * np.eye(3) - np.outer(p_cm, p_cm))

    I2_Bo = M_BBo_B.CalcRotationalInertia().CopyToFullMatrix3()
    I_Bo = about_bo(m1, p1, body.I_Bcm_B) + I2_Bo
    I_cm = I_Bo - m * (p @ p * np.eye(3) - np.outer(p, p))
    return dataclasses.replace(body, mass=m, p_BoBcm_B=p, I_Bcm_B=I_cm)


# Layout of the coupling's cached result vector (also its ``terms`` output, which a station logs).
_IDX, _XT, _VT, _XG, _VG, _F = 0, slice(1, 8), slice(8, 14), slice(14, 21), slice(21, 27), slice(27, 33)
_CAPPED = 33
_TERMS = 34
_NO_WRENCH = (0.0,) * 13  # the wrench, capped, and the generalized forces with nothing held
TERMS_LAYOUT = {
    "held_body": _IDX, "pose_WT": _XT, "V_WT": _VT, "pose_WG": _XG, "V_WG": _VG, "F_Go_W": _F,
    "capped": _CAPPED,
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class _HotBody:
    """A graspable body's constants as plain floats, for the per-step calc."""

    q_start: int
    v_start: int
    mass: float
    p_BoBcm_B: tuple
    I_list: list  # I_Bcm_B row-major, kg·m²
    mg: tuple  # m g (N), zero without gravity compensation
    force_cap: float  # N, the spring-damper's (gravity compensation comes on top)
    torque_cap: float  # N·m


class GraspingCoupling:
    """What every rigid coupling (explicit :class:`GodObjectCoupling`, implicit
    :class:`~godobject_drake.systems.implicit.ImplicitCoupling`) knows of the bodies it may hold: which they
    are, their force caps, and which one a grasp name or the ``"*"`` button selects."""

    def _setup_bodies(
        self,
        plant,
        gains,
        gravity_compensation,
        carried,
        grasp_reach_m,
        max_stretch_m,
        max_twist_rad,
        graspable,
    ) -> None:
        for label, value in (("max_stretch_m", max_stretch_m), ("max_twist_rad", max_twist_rad)):
            if not value > 0.0:  # inf is allowed: no cap
                raise ValueError(f"{label}={value!r} must be > 0 (math.inf: no force cap)")
        self.max_stretch_m, self.max_twist_rad = float(max_stretch_m), float(max_twist_rad)
        if not (math.isfinite(grasp_reach_m) and grasp_reach_m > 0.0):
            raise ValueError(f"grasp_reach_m={grasp_reach_m!r} m must be > 0")
        self.grasp_reach_m = float(grasp_reach_m)
        self.gains = gains
        self.plant = plant
        self._free = graspable_bodies(plant)
        self._fixed = fixed_bodies(plant)
        self.bodies = self._free
        if graspable:
            chosen = {self.body_for_grasp(name).index for name in graspable}
            self.bodies = {k: v for k, v in self._free.items() if v.index in chosen}
        for name, M in (carried or {}).items():
            body = self.body_for_grasp(name)
            heavier = with_carried_inertia(body, M)
            self.bodies = {k: heavier if v is body else v for k, v in self.bodies.items()}
        self._by_index = {b.index: b for b in self.bodies.values()}
        g = np.asarray(plant.gravity_field().gravity_vector())
        self._g = g if gravity_compensation else np.zeros(3)
        self._wn2, self._2zwn = gains.omega_n**2, 2.0 * gains.zeta * gains.omega_n
        self._wr2, self._2zwr = gains.omega_r**2, 2.0 * gains.zeta_r * gains.omega_r

    def force_caps(self, body: GraspableBody) -> tuple[float, float]:
        """The spring-damper's force (N) and torque (N·m) caps on ``body``.

        ``|f| ≤ m ωn² · max_stretch_m`` and ``|τ| ≤ λmax(I) ωr² · max_twist_rad``: what the
        spring alone gives at that stretch and twist. Past them (a device teleport, a target
        deep in an obstacle) the wrench keeps its direction and is scaled down to the cap;
        gravity compensation comes on top. The ``terms`` output's last entry is 1 on a capped
        step, and the metrics count them (``coupling_capped_steps``).
        """
        lam = float(np.linalg.eigvalsh(body.I_Bcm_B)[-1])
        return (
            body.mass * self._wn2 * self.max_stretch_m,
            lam * self._wr2 * self.max_twist_rad,
        )

    def device_and_grasp(self, context) -> tuple[int, np.ndarray, float]:
        """``(held BodyIndex or −1, p_WD, |v_WD|)``: what is held (the coupling's state) and where
        the device point is and how fast it goes (its inputs), without computing the terms."""
        held = int(context.get_discrete_state(self._grasp_state).get_value()[0])
        p_WD = self._X_WD_port.Eval(context).translation()
        v_WD = self._V_WD_port.Eval(context)
        return held, p_WD, math.sqrt(v_WD[3] ** 2 + v_WD[4] ** 2 + v_WD[5] ** 2)

    # -- grasping -------------------------------------------------------------
    def body_for_grasp(self, name: str) -> GraspableBody | None:
        """The body a grasp name selects; None for ``""`` (and ``"*"``). Raises for unknown names."""
        if not name or name == GRASP_NEAREST:
            return None
        if name in self.bodies:
            return self.bodies[name]
        known = sorted(k for k in self.bodies if "::" not in k) or sorted(self.bodies)
        if name in self._fixed and name not in self._free:
            why = f"{name!r} names {self._fixed[name]}: only a free body can be a god-object"
        elif name in self._free:
            why = f"{name!r} is a free body, but not one of this coupling's graspable bodies"
        else:
            why = f"unknown body {name!r}"
        raise ValueError(f"grasp names {why}; graspable bodies are {known}. Fix the device path or log.")

    def validate_grasp_names(self, names) -> None:
        """Raise early if any of ``names`` is not a graspable body."""
        for name in names:
            self.body_for_grasp(name)

    def nearest_body(self, p_WD: np.ndarray, x: np.ndarray, taken=()) -> GraspableBody | None:
        """The free body whose centre of mass is nearest ``p_WD``, if within ``grasp_reach_m``, but
        those ``taken`` (BodyIndex values another tool holds)."""
        best, best_d = None, self.grasp_reach_m
        for body in self._by_index.values():
            if body.index in taken:
                continue
            d = float(np.linalg.norm(self._body_state(body, x)[1] - p_WD))
            if d <= best_d:
                best, best_d = body, d
        return best

    def _grasp_change(self, context, held: int) -> tuple[bool, "GraspableBody | None"]:
        """``(changed, body)``: whether the ``grasp`` input selects another body than ``held`` (a
        BodyIndex or −1), and which (None: release). ``"*"`` keeps what it took. A body another tool
        holds (the ``held_elsewhere`` input, in a scene of several tools) is not taken: ``"*"``
        passes it over, a grasp by name waits until it is let go (:attr:`refused_grasps` counts
        the samples that waited)."""
        name = self._grasp_port.Eval(context)
        taken = self._taken(context)
        if name == GRASP_NEAREST:
            if held >= 0:
                return False, None  # keep what "*" took
            body = self.nearest_body(
                pose_arrays(self._X_WD_port.Eval(context))[1], self._state_port.Eval(context), taken
            )
        else:
            body = self.body_for_grasp(name)
            if body is not None and body.index in taken and body.index != held:
                self.refused_grasps += 1
                return False, None
        return (body.index if body else -1) != held, body

    def _declare_held_elsewhere(self) -> None:
        """The optional input of what the scene's other tools hold (a tuple of BodyIndex values)."""
        self._elsewhere_port = self.DeclareAbstractInputPort("held_elsewhere", AbstractValue.Make(()))
        self.refused_grasps = 0

    def _taken(self, context) -> tuple:
        port = self._elsewhere_port
        return tuple(port.Eval(context)) if port.HasValue(context) else ()

    @staticmethod
    def _body_state(body: GraspableBody, x: np.ndarray):
        """``(q_WB, p_WG)``: the body's unit quaternion and its centre of mass in W."""
        q = x[body.q_start : body.q_start + 4]
        q = q / np.linalg.norm(q)  # the plant's quaternion drifts off unit norm (see _calc_terms)
        p_WG = x[body.q_start + 4 : body.q_start + 7] + quat_to_rotation(q) @ body.p_BoBcm_B
        return q, p_WG


class GodObjectCoupling(GraspingCoupling, LeafSystem):
    """PD coupling of a held free body to the device's target (paper Eq. 2).

    .. pydrake_system::

        name: GodObjectCoupling
        input_ports:
        - plant_state
        - X_WD
        - V_WD
        - grasp
        output_ports:
        - spatial_forces
        - F_Go_W
        - pose_WT
        - V_WT
        - pose_WG
        - V_WG
        - held_body
        - terms
        - generalized_force

    ``plant_state`` is the plant's ``[q; v]``; ``X_WD``/``V_WD``/``grasp``
    come from a :class:`~godobject_drake.devices.sources.DeviceSource`.
    ``spatial_forces`` goes to the plant's ``applied_spatial_force``, or
    ``generalized_force`` (the same wrench as generalized forces of the held
    body's floating joint, cheaper per step: add_god_object wires this one) to
    its ``applied_generalized_force``. ``terms`` is every per-step result
    in one vector, ``[held_body, pose_WT, V_WT, pose_WG, V_WG, F_Go_W, capped]``
    (:data:`TERMS_LAYOUT`), for logging with one port.
    ``F_Go_W`` is the coupling wrench ``[τ; f]`` (N·m, N) on G at Go in W,
    gravity compensation included. ``pose_WT``/``pose_WG`` are the target's and
    the god-object's poses ``[qw qx qy qz x y z]``, ``V_WT``/``V_WG`` their
    spatial velocities ``[w; v]``. ``held_body`` is the held BodyIndex, or −1.
    With nothing held, T and G both equal the device frame D and the wrench
    is zero.

    Admittance (paper Fig. 2: "the haptic interface handles the god-object
    directly"): if the optional input ``F_device_W`` (``[τ; f]``, N·m and N,
    at Go in W) is connected, it *is* the wrench on the held body, gravity
    compensation added; the PD spring is not used, and the device gets the
    god-object's pose from ``pose_WG`` (:class:`~godobject_drake.systems.haptic.AdmittanceDevice`).

    Grasping: when ``grasp`` changes, the coupling stores the pose of G in D
    at that instant (``X_DG``), so grasping does not move the target and
    the spring starts unstretched; ``""`` releases. ``"*"``
    (:data:`GRASP_NEAREST`, a live device's grasp button) takes the free
    body whose centre of mass is nearest the device point, if one is within
    ``grasp_reach_m``, and keeps it while ``"*"`` lasts. The check runs once
    per device period, half a plant step after the device samples.

    Parameters
    ----------
    plant : MultibodyPlant
        A finalized plant; every free body in it can be grasped.
    gains : CouplingGains
        Bandwidth and damping; checked against ``plant.time_step()``.
    device_period_s : float | None
        How often to look at ``grasp`` (s); None = every plant step.
    gravity_compensation : bool
        Add ``−m g`` so the held body hangs at its target instead of
        sagging by ``g/ωn²`` (6 mm at ωn = 40 rad/s).
    check_gains : bool
        Refuse gains past the explicit limit (:meth:`CouplingGains.check`).
        Only the stability analysis turns this off, to cross the limit on
        purpose (``godobject_drake.studies.validation``).
    carried : dict[str, SpatialInertia] | None
        Inertia (about Bo, in B) that a body carries without the plant
        attaching it rigidly, by body name: a deformable god-object's shell
        (:func:`with_carried_inertia`).
    grasp_reach_m : float
        How near (m) a body's centre of mass must be to the device point for
        ``"*"`` to take it.
    graspable : sequence of str | None
        The bodies this coupling may hold (names as a device gives them); None: every
        free body. A welded or unknown name is refused here, naming what it is.
    max_stretch_m, max_twist_rad : float
        Force and torque caps, as the stretch and twist whose spring force they equal
        (:meth:`force_caps`); ``math.inf`` turns a cap off.
    """

    def __init__(
        self,
        plant: MultibodyPlant,
        gains: CouplingGains,
        device_period_s: float | None = None,
        gravity_compensation: bool = True,
        check_gains: bool = True,
        carried: dict[str, SpatialInertia] | None = None,
        grasp_reach_m: float = 0.05,
        max_stretch_m: float = DEFAULT_MAX_STRETCH_M,
        max_twist_rad: float = DEFAULT_MAX_TWIST_RAD,
        graspable: Sequence[str] | None = None,
    ):
        super().__init__()
        h = plant.time_step()
        if check_gains:
            gains.check(h)
        self._setup_bodies(
            plant,
            gains,
            gravity_compensation,
            carried,
            grasp_reach_m,
            max_stretch_m,
            max_twist_rad,
            graspable,
        )
        self._force = ExternallyAppliedSpatialForce()
        self._fast = {i: self._hot_body(b) for i, b in self._by_index.items()}

        n = plant.num_multibody_states()
        self._state_port = self.DeclareVectorInputPort("plant_state", n)
        self._X_WD_port = self.DeclareAbstractInputPort("X_WD", AbstractValue.Make(RigidTransform()))
        self._V_WD_port = self.DeclareVectorInputPort("V_WD", 6)
        self._grasp_port = self.DeclareAbstractInputPort("grasp", AbstractValue.Make(""))
        self._declare_held_elsewhere()
        self._F_device_port = self.DeclareVectorInputPort("F_device_W", 6)

        # [held BodyIndex or −1, q_DG (4), p_DoGo_D (3)]
        self._grasp_state = self.DeclareDiscreteState(np.array([-1.0, 1, 0, 0, 0, 0, 0, 0]))
        period = device_period_s if device_period_s else (h if h > 0 else 1e-3)
        offset = 0.5 * h if h > 0 else 1e-6
        self.DeclarePeriodicDiscreteUpdateEvent(period, offset, self._update_grasp)
        # A body held from t = 0 is held from the start, not after the first plant step
        # (at h = 10 ms it would fall g h² = 1 mm first and keep that offset).
        self.DeclareInitializationDiscreteUpdateEvent(self._update_grasp)

        self._terms = self.DeclareCacheEntry(
            "coupling terms",
            # the terms, then the held body's six generalized forces (_calc_generalized_forces)
            ValueProducer(allocate=lambda: AbstractValue.Make(np.zeros(_TERMS + 6)), calc=self._calc_terms),
            {self.all_input_ports_ticket(), self.xd_ticket()},
        )
        self.DeclareAbstractOutputPort(
            "spatial_forces",
            lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
            self._calc_spatial_forces,
            {self._terms.ticket()},
        )
        for name, sl in (("F_Go_W", _F), ("pose_WT", _XT), ("V_WT", _VT), ("pose_WG", _XG), ("V_WG", _VG)):
            self.DeclareVectorOutputPort(
                name, sl.stop - sl.start, self._slice_calc(sl), {self._terms.ticket()}
            )
        self.DeclareVectorOutputPort("held_body", 1, self._slice_calc(slice(0, 1)), {self.xd_ticket()})
        self._nq = plant.num_positions()
        self.DeclareVectorOutputPort(
            "generalized_force", plant.num_velocities(), self._calc_generalized_forces, {self._terms.ticket()}
        )
        terms = self._slice_calc(slice(0, _TERMS))
        self.DeclareVectorOutputPort("terms", _TERMS, terms, {self._terms.ticket()})

    def _hot_body(self, body: GraspableBody) -> _HotBody:
        """A body's per-step constants, and its force caps (:meth:`force_caps`)."""
        f_cap, t_cap = self.force_caps(body)
        return _HotBody(
            q_start=body.q_start,
            v_start=body.v_start,
            mass=body.mass,
            p_BoBcm_B=tuple(body.p_BoBcm_B.tolist()),
            I_list=body.I_Bcm_B.ravel().tolist(),
            mg=tuple((body.mass * self._g).tolist()),
            force_cap=f_cap,
            torque_cap=t_cap,
        )

    def _update_grasp(self, context, discrete_state):
        held = int(context.get_discrete_state(self._grasp_state).get_value()[0])
        changed, body = self._grasp_change(context, held)
        if not changed:
            return
        new = np.array([-1.0, 1, 0, 0, 0, 0, 0, 0])
        if body is not None:
            q_WD, p_WD, R_WD = pose_arrays(self._X_WD_port.Eval(context))
            q_WG, p_WG = self._body_state(body, self._state_port.Eval(context))
            new[0] = body.index
            new[1:5] = quat_multiply(quat_conjugate(q_WD), q_WG)
            new[5:8] = R_WD.T @ (p_WG - p_WD)
        discrete_state.get_mutable_vector(self._grasp_state).SetFromVector(new)

    # -- the hot path -----------------------------------------------------------
    # Plain Python floats: on 3- and 4-vectors one numpy call costs about as
    # much as the whole float expression, so the per-step calc stays near
    # 20 µs (analysis/speed_vs_error.py measures it).
    def _calc_terms(self, context, value):
        out = value.get_mutable_value()
        s = context.get_discrete_state(self._grasp_state).get_value().tolist()
        M = self._X_WD_port.Eval(context).GetAsMatrix34().tolist()
        V = self._V_WD_port.Eval(context).tolist()
        R = (M[0][0], M[0][1], M[0][2], M[1][0], M[1][1], M[1][2], M[2][0], M[2][1], M[2][2])
        pD = (M[0][3], M[1][3], M[2][3])
        qD = quat_of_rotation_entries(R)
        held = int(s[0])
        if held < 0:
            pose = [*qD, *pD]
            out[:] = [held, *pose, *V, *pose, *V, *_NO_WRENCH]
            return
        b = self._fast[held]
        x = self._state_port.Eval(context)
        qG = x[b.q_start : b.q_start + 7].tolist()
        vG = x[b.v_start : b.v_start + 6].tolist()
        # Drake 1.51.1's discrete update does not keep a free body's quaternion at unit norm
        # (1.02 after the brick path; 12.6 after 24 s of fast twisting, when the rotation and
        # inertia below were built from it unnormalized: a torque ∝ |q|⁴). Normalize it.
        n = math.sqrt(qG[0] * qG[0] + qG[1] * qG[1] + qG[2] * qG[2] + qG[3] * qG[3])
        qG[0], qG[1], qG[2], qG[3] = qG[0] / n, qG[1] / n, qG[2] / n, qG[3] / n
        # G: the body's centre of mass (p_BoBcm rotated into W) and its velocity.
        RB = rotation_entries(qG[0], qG[1], qG[2], qG[3])
        c = b.p_BoBcm_B
        r0 = RB[0] * c[0] + RB[1] * c[1] + RB[2] * c[2]
        r1 = RB[3] * c[0] + RB[4] * c[1] + RB[5] * c[2]
        r2 = RB[6] * c[0] + RB[7] * c[1] + RB[8] * c[2]  # p_BoBcm_W
        w0, w1, w2 = vG[0], vG[1], vG[2]
        pG = (qG[4] + r0, qG[5] + r1, qG[6] + r2)
        vg = (vG[3] + w1 * r2 - w2 * r1, vG[4] + w2 * r0 - w0 * r2, vG[5] + w0 * r1 - w1 * r0)
        # T: the grasp offset X_DG carried by the device.
        d0, d1, d2 = s[5], s[6], s[7]
        e0 = R[0] * d0 + R[1] * d1 + R[2] * d2
        e1 = R[3] * d0 + R[4] * d1 + R[5] * d2
        e2 = R[6] * d0 + R[7] * d1 + R[8] * d2
        qT = quat_product(qD, (s[1], s[2], s[3], s[4]))
        pT = (pD[0] + e0, pD[1] + e1, pD[2] + e2)
        W0, W1, W2 = V[0], V[1], V[2]
        vT = (V[3] + W1 * e2 - W2 * e1, V[4] + W2 * e0 - W0 * e2, V[5] + W0 * e1 - W1 * e0)
        capped = 0.0
        if self._F_device_port.HasValue(context):  # admittance: the device's wrench drives G
            F = self._F_device_port.Eval(context).tolist()
            t0, t1, t2 = F[0], F[1], F[2]
            f0, f1, f2 = F[3] - b.mg[0], F[4] - b.mg[1], F[5] - b.mg[2]
        else:
            kp, kd, m = self._wn2, self._2zwn, b.mass
            a0 = kp * (pT[0] - pG[0]) + kd * (vT[0] - vg[0])
            a1 = kp * (pT[1] - pG[1]) + kd * (vT[1] - vg[1])
            a2 = kp * (pT[2] - pG[2]) + kd * (vT[2] - vg[2])
            n = m * math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            if n > b.force_cap:
                capped, m = 1.0, m * b.force_cap / n
            f0, f1, f2 = m * a0 - b.mg[0], m * a1 - b.mg[1], m * a2 - b.mg[2]
            e = rotation_vector_between(qT, qG)
            kr, dr = self._wr2, self._2zwr
            u0 = kr * e[0] + dr * (W0 - w0)
            u1 = kr * e[1] + dr * (W1 - w1)
            u2 = kr * e[2] + dr * (W2 - w2)
            # τ = I_W u = R_WB I_B R_WBᵀ u
            y0 = RB[0] * u0 + RB[3] * u1 + RB[6] * u2
            y1 = RB[1] * u0 + RB[4] * u1 + RB[7] * u2
            y2 = RB[2] * u0 + RB[5] * u1 + RB[8] * u2
            J = b.I_list
            z0 = J[0] * y0 + J[1] * y1 + J[2] * y2
            z1 = J[3] * y0 + J[4] * y1 + J[5] * y2
            z2 = J[6] * y0 + J[7] * y1 + J[8] * y2
            t0 = RB[0] * z0 + RB[1] * z1 + RB[2] * z2
            t1 = RB[3] * z0 + RB[4] * z1 + RB[5] * z2
            t2 = RB[6] * z0 + RB[7] * z1 + RB[8] * z2
            n = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
            if n > b.torque_cap:
                capped, k = 1.0, b.torque_cap / n
                t0, t1, t2 = t0 * k, t1 * k, t2 * k
        # The wrench as generalized forces of the floating joint, whose v = [w_WB; v_WBo]: the
        # torque about Bo, τ + p_BoBcm_W × f, and f (p_BoBcm_W = p_WG − p_WBo, as logged).
        r0, r1, r2 = pG[0] - qG[4], pG[1] - qG[5], pG[2] - qG[6]
        out[:] = [held, *qT, *pT, W0, W1, W2, *vT, *qG[:4], *pG, w0, w1, w2, *vg,
                  t0, t1, t2, f0, f1, f2, capped,
                  t0 + r1 * f2 - r2 * f1, t1 + r2 * f0 - r0 * f2, t2 + r0 * f1 - r1 * f0,
                  f0, f1, f2]  # fmt: skip

    def _calc_generalized_forces(self, context, output):
        """The coupling wrench as generalized forces of the held body's floating joint.

        Drake's quaternion floating joint has ``v = [w_WB; v_WBo]``, whose conjugate forces are
        the torque about Bo and the force, both in W: ``τ_Bo = τ + p_BoBcm_W × f``. One numpy
        vector is cheaper per step than the abstract ``spatial_forces`` list and gives the
        plant the same forces (tests/test_coupling.py checks against ``CalcGeneralizedForces``).
        Computed with the terms (their cache's last six entries), so that this port, read by the
        plant at every step, costs no second look at the plant's state.
        """
        t = self._terms.Eval(context)
        out = output.get_mutable_value()
        out[:] = 0.0
        held = int(t[_IDX])
        if held < 0:
            return
        vs = self._fast[held].v_start - self._nq
        out[vs : vs + 6] = t[_TERMS:]

    def _calc_spatial_forces(self, context, output):
        t = self._terms.Eval(context)
        held = int(t[_IDX])
        if held < 0:
            output.set_value([])
            return
        force = self._force
        force.body_index = BodyIndex(held)
        force.p_BoBq_B = self._by_index[held].p_BoBcm_B
        force.F_Bq_W = SpatialForce(t[_F][:3], t[_F][3:])
        output.set_value([force])

    def _slice_calc(self, sl: slice):
        def calc(context, output):
            output.SetFromVector(self._terms.Eval(context)[sl])

        return calc


class GraspLedger(LeafSystem):
    """What each rigid tool of a scene of several may not grasp: what the others hold.

    .. pydrake_system::

        name: GraspLedger
        input_ports:
        - held_body_0
        - ...
        output_ports:
        - held_elsewhere_0
        - ...

    Input ``held_body_i`` is tool i's coupling's ``held_body`` (−1: nothing); output
    ``held_elsewhere_i`` the BodyIndex values every other tool holds, for tool i's coupling's
    ``held_elsewhere`` (:meth:`GraspingCoupling._grasp_change`). The couplings' ``held_body`` is
    their state, so the ledger closes no algebraic loop.
    """

    def __init__(self, n: int):
        super().__init__()
        self._held = [self.DeclareVectorInputPort(f"held_body_{i}", 1) for i in range(n)]
        for i in range(n):
            self.DeclareAbstractOutputPort(
                f"held_elsewhere_{i}",
                lambda: AbstractValue.Make(()),
                lambda c, out, i=i: self._calc(c, out, i),
            )

    def _calc(self, context, output, i: int) -> None:
        held = (int(port.Eval(context)[0]) for j, port in enumerate(self._held) if j != i)
        output.set_value(tuple(index for index in held if index >= 0))
