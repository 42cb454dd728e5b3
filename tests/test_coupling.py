"""The PD coupling alone (hand computations), its gain checks, and in closed loop."""

import math
import os
import warnings

import numpy as np
import pytest
from conftest import add_free_boxes
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import (
    MultibodyForces,
    RevoluteJoint,
    RotationalInertia,
    SpatialInertia,
    UnitInertia,
)
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from godobject_drake.config.device_files import SampleGuard, Waypoint
from godobject_drake.config.gains import CouplingGainError, CouplingGains, CouplingGainWarning
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.limits import explicit_limit_omega_h
from godobject_drake.systems.coupling import (
    GodObjectCoupling,
    GraspableBody,
    fixed_bodies,
    graspable_bodies,
    with_carried_inertia,
)

NO_JUMP_CHECK = SampleGuard(max_speed_m_s=float("inf"))

MASS, INERTIA = 0.5, (1e-3, 2e-3, 3e-3)
G = 9.81


def coupling_alone(gains, q_body, p_body, v_body=None, gravity_compensation=True, **options):
    builder = DiagramBuilder()
    plant, (body,) = add_free_boxes(builder, 1e-3, (MASS,), INERTIA)
    coupling = GodObjectCoupling(plant, gains, gravity_compensation=gravity_compensation, **options)
    context = coupling.CreateDefaultContext()
    x = np.zeros(plant.num_multibody_states())
    x[0:4], x[4:7] = q_body, p_body
    if v_body is not None:
        x[7:13] = v_body
    coupling.GetInputPort("plant_state").FixValue(context, x)
    coupling.GetInputPort("X_WD").FixValue(context, RigidTransform())
    coupling.GetInputPort("V_WD").FixValue(context, np.zeros(6))
    coupling.GetInputPort("grasp").FixValue(context, "body_0")
    # Held body_0 with X_DG = identity: the target is the device frame itself.
    context.SetDiscreteState(np.array([float(body.index()), 1, 0, 0, 0, 0, 0, 0]))
    return coupling, context


def test_ninety_degree_error_gives_kr_pi_over_2_about_z():
    gains = CouplingGains(omega_n=10.0, zeta=1.0, omega_n_rot=20.0)
    a = np.radians(-90)  # body at −90° about z, target at identity: error +90° about z
    coupling, context = coupling_alone(gains, [np.cos(a / 2), 0, 0, np.sin(a / 2)], [0, 0, 0])
    F = coupling.GetOutputPort("F_Go_W").Eval(context)
    kr_z = INERTIA[2] * 20.0**2  # the body's z inertia is unchanged by a rotation about z
    np.testing.assert_allclose(F[:3], [0, 0, kr_z * np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(F[3:], [0, 0, MASS * G], atol=1e-9)  # only gravity compensation


def test_translation_spring_and_damper():
    gains = CouplingGains(omega_n=10.0, zeta=0.7)
    v_body = np.array([0, 0, 0, 0.2, 0, 0])
    coupling, context = coupling_alone(gains, [1, 0, 0, 0], [-0.05, 0, 0], v_body, gravity_compensation=False)
    F = coupling.GetOutputPort("F_Go_W").Eval(context)
    k, gamma = MASS * 100.0, 2 * 0.7 * MASS * 10.0
    np.testing.assert_allclose(F[3:], [k * 0.05 - gamma * 0.2, 0, 0], atol=1e-12)
    (force,) = coupling.GetOutputPort("spatial_forces").Eval(context)
    np.testing.assert_allclose(force.F_Bq_W.translational(), F[3:], atol=1e-12)


def test_nothing_held_gives_no_force():
    coupling, context = coupling_alone(CouplingGains(), [1, 0, 0, 0], [1, 2, 3])
    context.SetDiscreteState(np.array([-1.0, 1, 0, 0, 0, 0, 0, 0]))
    assert coupling.GetOutputPort("spatial_forces").Eval(context) == []
    assert np.all(coupling.GetOutputPort("F_Go_W").Eval(context) == 0)


@pytest.mark.parametrize("zeta, limit", [(0.7, 1.0413), (1.0, 0.8284)])
def test_explicit_limit_matches_theory(zeta, limit):
    assert explicit_limit_omega_h(zeta) == pytest.approx(limit, abs=1e-4)


def test_gains_past_the_explicit_limit_are_refused_with_the_fix():
    with pytest.raises(
        CouplingGainError,
        match=r"omega_n=900 rad/s .*=0\.8284 for ζ=1\. Use omega_n < 828\.4 rad/s or time_step < 0\.00092",
    ):
        CouplingGains(omega_n=900.0, zeta=1.0).check(1e-3)
    CouplingGains(omega_n=800.0, zeta=1.0).check(1e-3)  # just inside: accepted


def test_damping_outside_paper_range_warns():
    with pytest.warns(CouplingGainWarning, match="ζ=0.5"):
        CouplingGains(omega_n=10.0, zeta=0.5).check(1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        CouplingGains(omega_n=10.0, zeta=0.85).check(1e-3)


def test_unknown_grasp_name_lists_the_choices():
    coupling, _ = coupling_alone(CouplingGains(), [1, 0, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match=r"unknown body 'hammer'.*body_0"):
        coupling.validate_grasp_names(["hammer"])


STEP_GAINS = CouplingGains(omega_n=20.0, zeta=1.0)


def closed_loop(waypoints, masses, h=1e-3, gains=STEP_GAINS, rate=1000.0):
    """Free bodies in zero gravity held by a scripted device through the coupling."""
    builder = DiagramBuilder()
    plant, bodies = add_free_boxes(builder, h, masses, INERTIA, gravity=False)
    # A deliberate step input: the guard's jump check (10 m/s) would hold it back as a glitch.
    device = builder.AddSystem(ScriptedDevice(waypoints, period_s=1.0 / rate, guard=NO_JUMP_CHECK))
    # Eq. 3 is the uncapped law: the step's one-sample velocity impulse would hit the force cap.
    coupling = builder.AddSystem(
        GodObjectCoupling(plant, gains, device_period_s=device.period_s, max_stretch_m=math.inf)
    )
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(coupling.GetOutputPort("spatial_forces"), plant.get_applied_spatial_force_input_port())
    state_log = LogVectorOutput(plant.get_state_output_port(), builder, h)
    force_log = LogVectorOutput(coupling.GetOutputPort("F_Go_W"), builder, h)
    held_log = LogVectorOutput(coupling.GetOutputPort("held_body"), builder, h)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    for i, body in enumerate(bodies):
        plant.SetFreeBodyPose(
            plant.GetMyMutableContextFromRoot(context), body, RigidTransform([0.0, 0.3 * i, 0])
        )
    return simulator, [int(b.index()) for b in bodies], state_log, force_log, held_log


def test_free_space_step_response_matches_eq3():
    """A 2 cm device step; the held body follows paper Eq. 3 (ζ = 1, no gravity).

    Eq. 3 with target step Δ: X/Xt = (γ s + k)/(m s² + γ s + k); at ζ = 1 its step
    response is Δ (1 − e^{−ωn t} + ωn t e^{−ωn t}) (13.5 % overshoot at ωn t = 2).
    The device samples at 1 kHz, so its finite-difference velocity is the impulse
    Δ/T over one sample; the plant first feels the step one step after the device
    samples it (Drake's discrete update order), so t counts from t_s + h.
    """
    h, wn, step, t_s = 1e-3, 20.0, 0.02, 0.1
    waypoints = [
        Waypoint(t=0.0, xyz=[0, 0, 0], grasp="body_0"),
        Waypoint(t=t_s - 1e-6, xyz=[0, 0, 0], grasp="body_0"),
        Waypoint(t=t_s, xyz=[step, 0, 0], grasp="body_0"),
        Waypoint(t=2.0, xyz=[step, 0, 0], grasp="body_0"),
    ]
    simulator, _, state_log, _, _ = closed_loop(waypoints, (MASS,), h, CouplingGains(omega_n=wn, zeta=1.0))
    simulator.AdvanceTo(0.6)
    log = state_log.FindLog(simulator.get_context())
    t, x = log.sample_times(), log.data()[4]
    tau = np.clip(t - (t_s + h), 0.0, None)
    expected = step * (1 - np.exp(-wn * tau) + wn * tau * np.exp(-wn * tau))
    err = np.max(np.abs(x - expected))
    assert err <= 0.02 * step, f"max deviation {err:.3g} m > 2 % of the {step} m step"
    assert np.max(x) == pytest.approx(step * (1 + np.exp(-2)), rel=0.02)  # the Eq. 3 overshoot
    assert np.max(np.abs(log.data()[[5, 6]])) < 1e-12  # no crosstalk into y, z


def test_grasp_switch_release_do_not_jump():
    """Grasping keeps the relative pose, so the spring starts unstretched.

    The device waits 5 cm away from body_0, grasps it at 0.1 s, switches to
    body_1 (0.3 m away) at 0.3 s and releases at 0.5 s, all in zero gravity:
    neither body may move and the coupling force must stay exactly zero.
    """
    waypoints = [
        Waypoint(t=0.0, xyz=[0.05, 0, 0], rpy_deg=[0, 0, 30], grasp=""),
        Waypoint(t=0.1, xyz=[0.05, 0, 0], rpy_deg=[0, 0, 30], grasp="body_0"),
        Waypoint(t=0.3, xyz=[0.05, 0, 0], rpy_deg=[0, 0, 30], grasp="body_1"),
        Waypoint(t=0.5, xyz=[0.05, 0, 0], rpy_deg=[0, 0, 30], grasp=""),
        Waypoint(t=0.6, xyz=[0.05, 0, 0], rpy_deg=[0, 0, 30], grasp=""),
    ]
    simulator, (b0, b1), state_log, force_log, held_log = closed_loop(waypoints, (MASS, 2 * MASS))
    simulator.AdvanceTo(0.6)
    context = simulator.get_context()
    t, held = held_log.FindLog(context).sample_times(), held_log.FindLog(context).data()[0]
    # The grasp takes effect half a step after the device sample that asks for it.
    for t0, t1, body in ((0, 0.1, -1), (0.1, 0.3, b0), (0.3, 0.5, b1), (0.5, 0.6, -1)):
        assert np.all(held[(t > t0 + 1e-6) & (t <= t1)] == body), f"({t0}, {t1}] should hold {body}"
    F = force_log.FindLog(context).data()
    assert np.max(np.abs(F)) < 1e-9, f"force jumped to {np.max(np.abs(F)):.3g} N"
    x = state_log.FindLog(context).data()
    for q0 in (0, 7):  # positions of body_0 and body_1 never move
        assert np.max(np.abs(x[q0 + 4 : q0 + 7] - x[q0 + 4 : q0 + 7, :1])) < 1e-12


def test_generalized_force_is_the_spatial_force_on_the_floating_joint():
    """Two ways into the plant, one wrench: ``generalized_force`` equals Drake's own
    ``CalcGeneralizedForces`` of ``spatial_forces`` for a body whose centre of mass is
    off its origin (τ about Bo = τ + p_BoBcm × f), turned and moving."""
    plant = MultibodyPlant(1e-3)
    M = SpatialInertia.SolidBoxWithMass(0.3, 0.1, 0.05, 0.02).Shift([-0.03, 0.02, 0.01])  # about Bo
    body = plant.AddRigidBody("offset", M)
    plant.Finalize()
    coupling = GodObjectCoupling(plant, CouplingGains(omega_n=15.0, zeta=0.8, omega_n_rot=30.0))
    context = coupling.CreateDefaultContext()
    x = np.zeros(plant.num_multibody_states())
    x[0:4] = [np.cos(0.3), np.sin(0.3) * 0.6, 0.0, np.sin(0.3) * 0.8]
    x[4:7], x[7:13] = [0.1, -0.2, 0.3], [0.4, -0.1, 0.2, 0.05, 0.1, -0.2]
    coupling.GetInputPort("plant_state").FixValue(context, x)
    coupling.GetInputPort("X_WD").FixValue(context, RigidTransform([0.15, -0.1, 0.25]))
    coupling.GetInputPort("V_WD").FixValue(context, [0.1, 0, 0, 0, 0.2, 0])
    coupling.GetInputPort("grasp").FixValue(context, "offset")
    context.SetDiscreteState(np.array([float(body.index()), 1, 0, 0, 0, 0, 0, 0]))
    plant_context = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(plant_context, x)
    forces = MultibodyForces(plant)
    (F,) = coupling.GetOutputPort("spatial_forces").Eval(context)
    R_WB = plant.get_body(F.body_index).EvalPoseInWorld(plant_context).rotation()
    # AddInForce takes the point's offset expressed in the frame it is given (W), not in B.
    plant.get_body(F.body_index).AddInForce(
        plant_context, R_WB @ F.p_BoBq_B, F.F_Bq_W, plant.world_frame(), forces
    )
    expected = plant.CalcGeneralizedForces(plant_context, forces)
    actual = coupling.GetOutputPort("generalized_force").Eval(context)
    np.testing.assert_allclose(actual, expected, atol=1e-12)
    assert np.linalg.norm(expected) > 0.1


def test_force_cap_scales_the_wrench_down_keeping_its_direction():
    """A 1 m stretch (a device teleport) gets the force of the cap's 0.2 m, toward the target."""
    gains = CouplingGains(omega_n=10.0, zeta=1.0)
    coupling, context = coupling_alone(gains, [1, 0, 0, 0], [-1.0, 0.0, 0.0], gravity_compensation=False)
    F = coupling.GetOutputPort("F_Go_W").Eval(context)
    np.testing.assert_allclose(F[3:], [MASS * 10.0**2 * 0.2, 0, 0], rtol=1e-12)  # not k · 1 m
    assert coupling.GetOutputPort("terms").Eval(context)[-1] == 1.0  # counted, not silent
    coupling, context = coupling_alone(gains, [1, 0, 0, 0], [-0.1, 0.0, 0.0], gravity_compensation=False)
    np.testing.assert_allclose(coupling.GetOutputPort("F_Go_W").Eval(context)[3:], [MASS * 100.0 * 0.1, 0, 0])
    assert coupling.GetOutputPort("terms").Eval(context)[-1] == 0.0


def test_unnormalized_plant_quaternion_gives_the_same_wrench():
    """Drake's discrete update lets a free body's quaternion drift off unit norm; the coupling
    reads the rotation it stands for, not the raw numbers."""
    gains = CouplingGains(omega_n=10.0, zeta=1.0, omega_n_rot=20.0)
    a = np.radians(-40)
    q = np.array([np.cos(a / 2), 0.3 * np.sin(a / 2), 0, np.sqrt(0.91) * np.sin(a / 2)])
    v_body = np.array([0.5, -0.2, 0.1, 0.05, 0, 0])
    unit, c1 = coupling_alone(gains, q, [0.01, 0.02, 0.0], v_body)
    drifted, c2 = coupling_alone(gains, 3.0 * q, [0.01, 0.02, 0.0], v_body)
    F1, F2 = unit.GetOutputPort("F_Go_W").Eval(c1), drifted.GetOutputPort("F_Go_W").Eval(c2)
    assert np.linalg.norm(F1[:3]) > 1e-4
    np.testing.assert_allclose(F2, F1, rtol=1e-12, atol=1e-15)


# -- every term against Drake's own kinematics ---------------------------------------------
TERMS = {"held": 0, "qT": slice(1, 5), "pT": slice(5, 8), "wT": slice(8, 11), "vT": slice(11, 14),
         "qG": slice(14, 18), "pG": slice(18, 21), "wG": slice(21, 24), "vG": slice(24, 27),
         "tau": slice(27, 30), "f": slice(30, 33), "capped": 33}  # fmt: skip


def random_rotation(rng):
    q = rng.normal(size=4)
    return RotationMatrix(Quaternion(q / np.linalg.norm(q)))


def held_off_centre_body(gains, rng, gravity_compensation=True):
    """A free body with its centre of mass off its origin and a full (non-diagonal) inertia,
    held through a random grasp offset X_DG, in a random state with a drifted quaternion,
    while the device moves: a case where no term is zero by symmetry."""
    plant = MultibodyPlant(1e-3)
    plant.mutable_gravity_field().set_gravity_vector([0.7, -1.3, -9.6])  # tilted: every component counts
    R_BE = random_rotation(rng)  # principal axes E turned against B: off-diagonal I_B
    M_Bcm = SpatialInertia.SolidBoxWithMass(0.3, 0.1, 0.05, 0.02).ReExpress(R_BE)
    p_BoBcm = np.array([-0.03, 0.02, 0.01])
    body = plant.AddRigidBody("tool", M_Bcm.Shift(-p_BoBcm))  # given about Bo
    plant.Finalize()
    options = {"max_stretch_m": math.inf, "max_twist_rad": math.inf}  # caps: tested on their own
    if not gravity_compensation:  # (on by default)
        options["gravity_compensation"] = False
    coupling = GodObjectCoupling(plant, gains, **options)
    context = coupling.CreateDefaultContext()
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    x = np.concatenate([q, rng.uniform(-0.3, 0.3, 3), rng.normal(scale=0.5, size=6)])
    X_WD = RigidTransform(random_rotation(rng), rng.uniform(-0.3, 0.3, 3))
    V_WD = rng.normal(scale=0.5, size=6)
    q_DG = random_rotation(rng).ToQuaternion().wxyz()
    p_DG = rng.uniform(-0.05, 0.05, 3)
    x_drifted = x.copy()
    x_drifted[:4] *= 1.07  # what Drake's discrete update lets the plant's quaternion do
    coupling.GetInputPort("plant_state").FixValue(context, x_drifted)
    coupling.GetInputPort("X_WD").FixValue(context, X_WD)
    coupling.GetInputPort("V_WD").FixValue(context, V_WD)
    coupling.GetInputPort("grasp").FixValue(context, "tool")
    context.SetDiscreteState(np.concatenate([[float(body.index())], q_DG, p_DG]))
    plant_context = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(plant_context, x)
    return plant, body, coupling, context, plant_context, (X_WD, V_WD, q_DG, p_DG, M_Bcm, p_BoBcm)


def expected_terms(plant, body, plant_context, gains, case, gravity_compensation=True):
    """The coupling's terms from Drake's RigidTransform, SpatialVelocity, RotationalInertia
    and AngleAxis: a second computation sharing no code with the coupling's float path."""
    X_WD, V_WD, q_DG, p_DG, M_Bcm, p_BoBcm = case
    X_WB = body.EvalPoseInWorld(plant_context)
    p_WG = X_WB.multiply(p_BoBcm)
    V_WG = body.EvalSpatialVelocityInWorld(plant_context).Shift(X_WB.rotation().multiply(p_BoBcm))
    X_WT = X_WD.multiply(RigidTransform(Quaternion(q_DG), p_DG))
    V_WT = SpatialVelocity(V_WD[:3], V_WD[3:]).Shift(X_WD.rotation().multiply(p_DG))
    angle_axis = (X_WT.rotation().multiply(X_WB.rotation().inverse())).ToAngleAxis()
    e = angle_axis.angle() * angle_axis.axis()  # α u in W, α ∈ [0, π]
    m = M_Bcm.get_mass()
    I_W = M_Bcm.CalcRotationalInertia().ReExpress(X_WB.rotation()).CopyToFullMatrix3()
    wr, zr, wn, z = gains.omega_r, gains.zeta_r, gains.omega_n, gains.zeta
    tau = I_W @ (wr**2 * e + 2 * zr * wr * (V_WT.rotational() - V_WG.rotational()))
    g = plant.gravity_field().gravity_vector() if gravity_compensation else np.zeros(3)
    f = m * (wn**2 * (X_WT.translation() - p_WG) + 2 * z * wn * (V_WT.translational() - V_WG.translational()))
    qT, qG = X_WT.rotation().ToQuaternion().wxyz(), X_WB.rotation().ToQuaternion().wxyz()
    return {"held": float(body.index()), "qT": qT, "pT": X_WT.translation(),
            "wT": V_WT.rotational(), "vT": V_WT.translational(), "qG": qG,
            "pG": p_WG, "wG": V_WG.rotational(), "vG": V_WG.translational(), "tau": tau, "f": f - m * g,
            "capped": 0.0}  # fmt: skip


@pytest.mark.parametrize("seed", range(6))
def test_every_term_matches_drakes_kinematics(seed):
    """Translational and rotational gains differ (so a swapped gain shows), ζ ≠ 1, the grasp
    offset and the centre-of-mass offset are both non-zero, the inertia is full: each of
    the 34 terms is checked against :func:`expected_terms` to 1e-12 relative."""
    gains = CouplingGains(omega_n=12.0, zeta=0.8, omega_n_rot=31.0, zeta_rot=0.9)
    rng = np.random.default_rng(seed)
    plant, body, coupling, context, plant_context, case = held_off_centre_body(gains, rng)
    terms = coupling.GetOutputPort("terms").Eval(context)
    expected = expected_terms(plant, body, plant_context, gains, case)
    for key, value in expected.items():
        actual = terms[TERMS[key]]
        if key in ("qT", "qG"):  # a quaternion and its negative are one rotation
            value = value if np.dot(value, actual) >= 0 else -value
        np.testing.assert_allclose(actual, value, rtol=1e-12, atol=1e-12, err_msg=key)
    for port, key in (("pose_WT", ("qT", "pT")), ("V_WT", ("wT", "vT")), ("pose_WG", ("qG", "pG")),
                      ("V_WG", ("wG", "vG")), ("F_Go_W", ("tau", "f"))):  # fmt: skip
        whole = np.concatenate([terms[TERMS[k]] for k in key])
        np.testing.assert_array_equal(coupling.GetOutputPort(port).Eval(context), whole, err_msg=port)
    assert coupling.GetOutputPort("held_body").Eval(context)[0] == float(body.index())
    assert np.linalg.norm(expected["tau"]) > 1e-4 and np.linalg.norm(expected["f"]) > 0.1
    assert coupling.plant is plant and coupling.gains is gains  # what check_wiring and reports read


def test_without_gravity_compensation_only_the_spring_pulls():
    gains = CouplingGains(omega_n=12.0, zeta=0.8, omega_n_rot=31.0, zeta_rot=0.9)
    plant, body, coupling, context, plant_context, case = held_off_centre_body(
        gains, np.random.default_rng(7), gravity_compensation=False
    )
    expected = expected_terms(plant, body, plant_context, gains, case, gravity_compensation=False)
    F = coupling.GetOutputPort("F_Go_W").Eval(context)
    np.testing.assert_allclose(F[3:], expected["f"], rtol=1e-12, atol=1e-12)


def test_admittance_the_devices_wrench_drives_the_god_object():
    """With ``F_device_W`` connected the PD spring is off: the wrench on G is the device's,
    plus the gravity compensation −m g (checked under a tilted gravity, component by component)."""
    gains = CouplingGains(omega_n=12.0, zeta=0.8, omega_n_rot=31.0, zeta_rot=0.9)
    plant, _, coupling, context, _, case = held_off_centre_body(gains, np.random.default_rng(3))
    F_device = np.array([0.11, -0.22, 0.33, 1.5, -2.5, 3.5])
    coupling.GetInputPort("F_device_W").FixValue(context, F_device)
    m = case[4].get_mass()
    expected = F_device - np.concatenate([np.zeros(3), m * plant.gravity_field().gravity_vector()])
    np.testing.assert_allclose(coupling.GetOutputPort("F_Go_W").Eval(context), expected, rtol=1e-15)
    assert coupling.GetOutputPort("terms").Eval(context)[-1] == 0.0  # the device's wrench is never capped


def test_grasping_an_off_centre_body_with_a_drifted_quaternion():
    """X_DG stored at the grasp is X_WD⁻¹ X_WG, G at the centre of mass with B's axes, whatever
    |q| the plant holds: the spring then starts unstretched (T = G)."""
    gains = CouplingGains(omega_n=12.0, zeta=0.8)
    _, body, coupling, context, plant_context, case = held_off_centre_body(gains, np.random.default_rng(5))
    X_WD = case[0]
    grasp_update(coupling, context, X_WD, "")
    s = grasp_update(coupling, context, X_WD, "tool")
    X_WB = body.EvalPoseInWorld(plant_context)
    X_DG = X_WD.inverse() @ RigidTransform(X_WB.rotation(), X_WB.multiply(case[5]))
    q = X_DG.rotation().ToQuaternion().wxyz()
    np.testing.assert_allclose(s[1:5], q if np.dot(q, s[1:5]) >= 0 else -q, atol=1e-14)
    np.testing.assert_allclose(s[5:8], X_DG.translation(), atol=1e-14)
    terms = coupling.GetOutputPort("terms").Eval(context)
    np.testing.assert_allclose(terms[TERMS["pT"]], terms[TERMS["pG"]], atol=1e-14)


def test_nothing_held_puts_target_and_god_object_on_the_device():
    """With nothing held, T and G are the device frame, moving with the device, and no
    wrench is applied (no step counted as capped)."""
    coupling, context = coupling_alone(CouplingGains(), [1, 0, 0, 0], [1, 2, 3])
    context.SetDiscreteState(np.array([-1.0, 1, 0, 0, 0, 0, 0, 0]))
    X_WD = RigidTransform(RotationMatrix.MakeZRotation(0.4), [0.1, -0.2, 0.3])
    V_WD = np.array([0.1, 0.2, 0.3, -0.4, 0.5, -0.6])
    coupling.GetInputPort("X_WD").FixValue(context, X_WD)
    coupling.GetInputPort("V_WD").FixValue(context, V_WD)
    pose = np.concatenate([[np.cos(0.2), 0, 0, np.sin(0.2)], [0.1, -0.2, 0.3]])
    expected = np.concatenate([[-1.0], pose, V_WD, pose, V_WD, np.zeros(7)])
    np.testing.assert_allclose(coupling.GetOutputPort("terms").Eval(context), expected, atol=1e-15)
    assert coupling.GetOutputPort("held_body").Eval(context)[0] == -1.0
    assert np.all(coupling.GetOutputPort("generalized_force").Eval(context) == 0)


def test_torque_cap_uses_the_largest_principal_inertia():
    """A 170° twist about the body's x axis, on a body whose inertia is largest about z:
    the spring torque I_x ωr² α is past the cap λmax ωr² · 0.5 rad = I_z ωr² · 0.5 only
    because α = 2.97 rad > (I_z/I_x) 0.5 = 1.5 rad; it is scaled to the cap, about x."""
    gains = CouplingGains(omega_n=10.0, zeta=1.0, omega_n_rot=20.0)
    a = np.radians(-170)
    q = [np.cos(a / 2), np.sin(a / 2), 0, 0]
    coupling, context = coupling_alone(gains, q, [0, 0, 0], max_twist_rad=0.5)
    body = coupling.body_for_grasp("body_0")
    f_cap, t_cap = coupling.force_caps(body)
    assert f_cap == pytest.approx(MASS * 10.0**2 * coupling.max_stretch_m, rel=1e-15)
    assert t_cap == pytest.approx(INERTIA[2] * 20.0**2 * coupling.max_twist_rad, rel=1e-12)
    tau = coupling.GetOutputPort("F_Go_W").Eval(context)[:3]
    np.testing.assert_allclose(tau, [t_cap, 0, 0], rtol=1e-12, atol=1e-12)
    assert coupling.GetOutputPort("terms").Eval(context)[-1] == 1.0
    # About an oblique axis every component is non-zero: the capped torque is the uncapped one
    # scaled to the cap's norm, its direction kept (each component scaled by the same factor).
    axis = np.array([1.0, -2.0, 3.0]) / np.sqrt(14.0)
    q = [np.cos(a / 2), *(np.sin(a / 2) * axis)]
    free, free_context = coupling_alone(gains, q, [0, 0, 0], max_twist_rad=math.inf)
    uncapped = free.GetOutputPort("F_Go_W").Eval(free_context)[:3]
    assert np.linalg.norm(uncapped) > 2 * t_cap and np.all(np.abs(uncapped) > t_cap / 10)
    coupling, context = coupling_alone(gains, q, [0, 0, 0], max_twist_rad=0.5)
    tau = coupling.GetOutputPort("F_Go_W").Eval(context)[:3]
    np.testing.assert_allclose(tau, uncapped * t_cap / np.linalg.norm(uncapped), rtol=1e-12)
    # 20° is within the cap: the plain spring I_x ωr² α, not capped.
    a = np.radians(-20)
    q = [np.cos(a / 2), np.sin(a / 2), 0, 0]
    coupling, context = coupling_alone(gains, q, [0, 0, 0], max_twist_rad=0.5)
    tau = coupling.GetOutputPort("F_Go_W").Eval(context)[:3]
    np.testing.assert_allclose(tau, [INERTIA[0] * 20.0**2 * np.radians(20), 0, 0], rtol=1e-12, atol=1e-15)
    assert coupling.GetOutputPort("terms").Eval(context)[-1] == 0.0


def test_force_exactly_at_the_cap_is_not_counted_as_capped():
    """The cap is |f| ≤ m ωn² · max_stretch_m: a stretch of exactly max_stretch_m gives the
    cap and is not a capped step (binary fractions: 0.25 m and ωn = 8 are exact)."""
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3, (MASS,), INERTIA)
    gains = CouplingGains(omega_n=8.0, zeta=1.0)
    coupling = GodObjectCoupling(plant, gains, gravity_compensation=False, max_stretch_m=0.25)
    context = coupling.CreateDefaultContext()
    x = np.zeros(plant.num_multibody_states())
    x[0], x[4] = 1.0, -0.25
    coupling.GetInputPort("plant_state").FixValue(context, x)
    coupling.GetInputPort("X_WD").FixValue(context, RigidTransform())
    coupling.GetInputPort("V_WD").FixValue(context, np.zeros(6))
    coupling.GetInputPort("grasp").FixValue(context, "body_0")
    context.SetDiscreteState(np.array([float(plant.GetBodyByName("body_0").index()), 1, 0, 0, 0, 0, 0, 0]))
    terms = coupling.GetOutputPort("terms").Eval(context)
    assert terms[30] == MASS * 64.0 * 0.25 and terms[-1] == 0.0


@pytest.mark.parametrize("kwargs, message", [
    ({"max_stretch_m": 0.0}, r"max_stretch_m=0\.0 must be > 0 \(math\.inf: no force cap\)"),
    ({"max_twist_rad": -1.0}, r"max_twist_rad=-1\.0 must be > 0"),
    ({"max_stretch_m": math.nan}, r"max_stretch_m=nan must be > 0"),
    ({"grasp_reach_m": 0.0}, r"grasp_reach_m=0\.0 m must be > 0"),
    ({"grasp_reach_m": math.inf}, r"grasp_reach_m=inf m must be > 0"),
])  # fmt: skip
def test_bad_coupling_options_are_refused(kwargs, message):
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3)
    with pytest.raises(ValueError, match=message):
        GodObjectCoupling(plant, CouplingGains(), **kwargs)


def test_defaults_compensate_gravity_check_gains_and_reach_5_cm():
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3, (MASS,), INERTIA)
    with pytest.raises(CouplingGainError, match="omega_n=2000"):
        GodObjectCoupling(plant, CouplingGains(omega_n=2000.0))
    coupling = GodObjectCoupling(plant, CouplingGains())
    assert coupling.grasp_reach_m == 0.05
    context = coupling.CreateDefaultContext()
    x = np.zeros(plant.num_multibody_states())
    x[0] = 1.0
    coupling.GetInputPort("plant_state").FixValue(context, x)
    coupling.GetInputPort("V_WD").FixValue(context, np.zeros(6))
    coupling.GetInputPort("X_WD").FixValue(context, RigidTransform())
    assert coupling.GetOutputPort("held_body").Eval(context)[0] == -1.0  # nothing held before any update
    grasp_update(coupling, context, RigidTransform(), "body_0")
    np.testing.assert_allclose(coupling.GetOutputPort("F_Go_W").Eval(context), [0, 0, 0, 0, 0, MASS * G])


@pytest.mark.parametrize(
    "time_step, device_period_s, expected",
    [(1e-3, 0.01, (0.01, 0.5e-3)), (2e-3, None, (2e-3, 1e-3)), (0.0, None, (1e-3, 1e-6))],
)
def test_the_grasp_is_looked_at_once_per_device_period_half_a_step_late(time_step, device_period_s, expected):
    """Half a plant step after the device samples (so a grasp sample is seen on the next step);
    every step without a device period; every 1 ms, 1 µs late, on a continuous plant."""
    plant = MultibodyPlant(time_step)
    plant.AddRigidBody("b", SpatialInertia.SolidBoxWithMass(0.2, 0.05, 0.05, 0.05))
    plant.Finalize()
    coupling = GodObjectCoupling(plant, CouplingGains(), device_period_s=device_period_s)
    event = coupling.GetUniquePeriodicDiscreteUpdateAttribute()
    assert (event.period_sec(), event.offset_sec()) == expected


def test_a_carried_inertia_adds_to_the_mass_the_gains_and_the_compensation_use():
    """A deformable shell of 0.25 kg carried by body_0 (not by body_1): body_0's spring is
    (0.5 + 0.25) ωn² per metre and its compensation (0.5 + 0.25) g; body_1 keeps its own 0.5 kg."""
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3, (MASS, MASS), INERTIA)
    shell = SpatialInertia.SolidSphereWithMass(0.25, 0.03)
    coupling = GodObjectCoupling(plant, CouplingGains(omega_n=10.0), carried={"body_0": shell})
    assert coupling.body_for_grasp("body_0").mass == 0.75 and coupling.body_for_grasp("body_1").mass == MASS
    context = coupling.CreateDefaultContext()
    x = np.zeros(plant.num_multibody_states())
    x[[0, 7]] = 1.0
    x[4] = x[11] = -0.01  # both bodies 1 cm behind the device along x
    coupling.GetInputPort("plant_state").FixValue(context, x)
    coupling.GetInputPort("V_WD").FixValue(context, np.zeros(6))
    for name, m in (("body_0", 0.75), ("body_1", MASS)):
        grasp_update(coupling, context, RigidTransform(), "")
        grasp_update(coupling, context, RigidTransform(), name)
        context.get_mutable_discrete_state_vector().SetAtIndex(5, 0.0)  # X_DG = identity: T at Do
        F = coupling.GetOutputPort("F_Go_W").Eval(context)
        np.testing.assert_allclose(F[3:], [m * 100.0 * 0.01, 0, m * G], rtol=1e-12, err_msg=name)


def test_carried_inertia_equals_drakes_sum_of_spatial_inertias():
    """Second method: Drake adds two spatial inertias about Bo (``SpatialInertia.__iadd__``) and
    shifts the sum to its centre of mass; with off-centre coms and full inertia matrices, the
    composite mass, com and central inertia equal with_carried_inertia's to rounding."""
    I_body = np.array([[2e-3, 3e-4, -1e-4], [3e-4, 3e-3, 2e-4], [-1e-4, 2e-4, 4e-3]])
    p_body = np.array([0.01, -0.02, 0.005])
    body = GraspableBody("b", 1, 0.4, p_body, I_body, 0, 0)
    carried = SpatialInertia.MakeFromCentralInertia(
        0.15, [-0.03, 0.01, 0.04], RotationalInertia(1e-3, 2e-3, 1.5e-3, 1e-4, -2e-4, 3e-4)
    )
    both = with_carried_inertia(body, carried)
    I_rot = RotationalInertia(*np.diag(I_body), I_body[0, 1], I_body[0, 2], I_body[1, 2])
    total = SpatialInertia.MakeFromCentralInertia(0.4, p_body, I_rot)
    total += carried
    assert both.mass == pytest.approx(total.get_mass(), rel=1e-15)
    np.testing.assert_allclose(both.p_BoBcm_B, total.get_com(), rtol=1e-14)
    I_cm = total.Shift(total.get_com()).CalcRotationalInertia().CopyToFullMatrix3()
    np.testing.assert_allclose(both.I_Bcm_B, I_cm, rtol=1e-12, atol=1e-18)
    assert (both.name, both.index) == ("b", 1)
    # Carrying nothing changes nothing; a mass that is not finite and ≥ 0 is refused by name.
    none = with_carried_inertia(body, SpatialInertia.Zero())
    assert none.mass == 0.4 and np.allclose(none.I_Bcm_B, I_body, rtol=0, atol=1e-18)
    for bad in (-0.1, math.nan):
        shell = SpatialInertia(bad, [0, 0, 0], UnitInertia(1, 1, 1), skip_validity_check=True)
        with pytest.raises(ValueError, match=rf"carried mass {bad!r} kg must be finite and ≥ 0"):
            with_carried_inertia(body, shell)


def test_bodies_are_named_by_every_unambiguous_alias():
    """Two models 'a' and 'b' with a body 'link' each: 'link' is ambiguous (left out), 'a' and
    'b' name them; two models with two bodies each leave only the scoped names, listed as such."""
    plant = MultibodyPlant(1e-3)
    M = SpatialInertia.SolidBoxWithMass(0.2, 0.05, 0.05, 0.05)
    for model in ("a", "b"):
        plant.AddRigidBody("link", plant.AddModelInstance(model), M)
    plant.Finalize()
    bodies = graspable_bodies(plant)
    assert set(bodies) == {"a::link", "b::link", "a", "b"}
    assert bodies["a"].name == "a::link" and bodies["b"] is bodies["b::link"]
    plant = MultibodyPlant(1e-3)
    for model in ("a", "b"):
        instance = plant.AddModelInstance(model)
        for name in ("link1", "link2"):
            plant.AddRigidBody(name, instance, M)
    plant.Finalize()
    coupling = GodObjectCoupling(plant, CouplingGains())
    assert set(coupling.bodies) == {"a::link1", "a::link2", "b::link1", "b::link2"}
    with pytest.raises(
        ValueError, match=r"graspable bodies are \['a::link1', 'a::link2', 'b::link1', 'b::link2'\]"
    ):
        coupling.body_for_grasp("link1")


def test_a_plant_that_cannot_give_god_objects_is_refused():
    plant = MultibodyPlant(1e-3)
    with pytest.raises(
        RuntimeError, match=r"^graspable_bodies\(\) needs a finalized plant; call plant\.Finalize\(\) first$"
    ):
        graspable_bodies(plant)
    plant.AddRigidBody("ghost", SpatialInertia(0.0, np.zeros(3), UnitInertia(1.0, 1.0, 1.0)))
    plant.Finalize()
    with pytest.raises(
        ValueError, match=r"^free body DefaultModelInstance::ghost has mass 0\.0; a god-object needs m > 0$"
    ):
        graspable_bodies(plant)


def test_infinite_caps_turn_the_cap_off():
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3, (MASS,), INERTIA)
    coupling = GodObjectCoupling(plant, CouplingGains(), max_stretch_m=math.inf, max_twist_rad=math.inf)
    assert coupling.force_caps(coupling.body_for_grasp("body_0")) == (math.inf, math.inf)


# -- the gain check, at its boundaries -------------------------------------------------------
@pytest.mark.parametrize("gains, message", [
    (CouplingGains(omega_n=0.0), r"omega_n=0\.0 rad/s must be a positive number"),
    (CouplingGains(omega_n=-5.0), r"omega_n=-5\.0 rad/s must be a positive number"),
    (CouplingGains(omega_n=math.inf), r"omega_n=inf rad/s must be a positive number"),
    (CouplingGains(omega_n=math.nan), r"omega_n=nan rad/s must be a positive number"),
    (CouplingGains(omega_n_rot=0.0), r"omega_n_rot=0\.0 rad/s must be a positive number"),
    (CouplingGains(zeta=-0.1), r"damping ratio -0\.1 for omega_n must be ≥ 0"),
    (CouplingGains(zeta=math.inf), r"damping ratio inf for omega_n must be ≥ 0"),
    (CouplingGains(zeta_rot=math.nan), r"damping ratio nan for omega_n_rot must be ≥ 0"),
])  # fmt: skip
def test_gains_that_are_not_gains_are_refused(gains, message):
    with pytest.raises(CouplingGainError, match=message):
        gains.check(1e-3)


def test_the_explicit_limit_is_strict_and_named_for_the_axis_that_breaks_it():
    """ζ = 0.75 gives the limit 2(√1.5625 − 0.75) = 1 exactly; ωn = 2 rad/s at h = 0.5 s sits
    on it (refused: the limit is where the step stops being stable), 1.99 rad/s is inside."""
    assert explicit_limit_omega_h(0.75) == 1.0 and explicit_limit_omega_h(0.0) == 2.0
    fix = r"ωn·h=1, past .* limit 2\(√\(1\+ζ²\)−ζ\)=1 for ζ=0\.75\. Use {0} < 2 rad/s or time_step < 0\.5 s\."
    with pytest.raises(
        CouplingGainError, match=r"^omega_n=2 rad/s at time_step=0\.5 s gives " + fix.format("omega_n")
    ):
        CouplingGains(omega_n=2.0, zeta=0.75).check(0.5)
    with pytest.raises(CouplingGainError, match=r"^omega_n_rot=2 rad/s .*" + fix.format("omega_n_rot")):
        CouplingGains(omega_n=1.0, zeta=0.75, omega_n_rot=2.0).check(0.5)
    CouplingGains(omega_n=1.99, zeta=0.75).check(0.5)
    CouplingGains(omega_n=1e9).check(0.0)  # a continuous plant: no step, no limit


def test_the_paper_damping_range_is_closed_and_each_side_says_what_happens():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for zeta in (0.7, 1.0):  # the paper's 1.4 ≤ γ/√(mk) ≤ 2, ends included
            CouplingGains(omega_n=10.0, zeta=zeta, zeta_rot=zeta).check(1e-3)
    with pytest.warns(
        CouplingGainWarning, match=r"ζ=0 for omega_n .* the god-object will overshoot and ring$"
    ) as record:
        CouplingGains(omega_n=10.0, zeta=0.0, zeta_rot=0.8).check(1e-3)  # undamped: allowed
    assert len(record) == 1
    with pytest.warns(CouplingGainWarning, match=r"ζ=1\.2 for omega_n_rot .*\[0\.7, 1\.0\].* will lag$"):
        CouplingGains(omega_n=10.0, zeta=0.8, zeta_rot=1.2).check(1e-3)


def test_a_damping_warning_points_at_the_line_that_built_the_coupling():
    if "MUTANT_UNDER_TEST" in os.environ:
        pytest.skip("mutmut's trampolines add stack frames between this line and warnings.warn")
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3)
    with pytest.warns(CouplingGainWarning) as record:
        GodObjectCoupling(plant, CouplingGains(zeta=0.5))
    assert record[0].filename == __file__


def test_gains_scale_with_the_mass():
    """k = m ωn², γ = 2 ζ m ωn (paper Eq. 3 with ωn, ζ given)."""
    assert CouplingGains(omega_n=10.0, zeta=0.8).translational(0.5) == (50.0, 8.0)
    gains = CouplingGains(omega_n=10.0, zeta=0.8)
    assert (gains.omega_r, gains.zeta_r) == (10.0, 0.8)  # rotation defaults to translation's


# -- grasping, one discrete update at a time ---------------------------------------------------
def two_boxes_and_a_device(p_body_0, p_body_1, **options):
    builder = DiagramBuilder()
    plant, bodies = add_free_boxes(builder, 1e-3, (MASS, MASS), INERTIA)
    coupling = GodObjectCoupling(plant, CouplingGains(), **options)
    context = coupling.CreateDefaultContext()
    x = np.zeros(plant.num_multibody_states())
    x[[0, 7]] = 1.0
    x[4:7], x[11:14] = p_body_0, p_body_1
    coupling.GetInputPort("plant_state").FixValue(context, x)
    coupling.GetInputPort("V_WD").FixValue(context, np.zeros(6))
    return coupling, context, [float(b.index()) for b in bodies]


def grasp_update(coupling, context, X_WD, grasp):
    """Run the coupling's grasp update once (its initialization event is that update)."""
    coupling.GetInputPort("X_WD").FixValue(context, X_WD)
    coupling.GetInputPort("grasp").FixValue(context, grasp)
    coupling.ExecuteInitializationEvents(context)
    return context.get_discrete_state_vector().CopyToVector()


def test_grasping_stores_the_god_object_pose_in_the_device_frame():
    """X_DG = X_WD⁻¹ X_WG at the grasp: checked with Drake's RigidTransform."""
    coupling, context, (i0, _) = two_boxes_and_a_device([0.1, 0.2, 0.3], [1, 1, 1])
    X_WD = RigidTransform(
        RotationMatrix.MakeYRotation(0.7) @ RotationMatrix.MakeZRotation(0.3), [0.0, 0.25, 0.2]
    )
    s = grasp_update(coupling, context, X_WD, "body_0")
    X_DG = X_WD.inverse() @ RigidTransform([0.1, 0.2, 0.3])
    assert s[0] == i0
    q = X_DG.rotation().ToQuaternion().wxyz()
    np.testing.assert_allclose(s[1:5], q if q[0] * s[1] >= 0 else -q, atol=1e-15)
    np.testing.assert_allclose(s[5:8], X_DG.translation(), atol=1e-15)
    # The first body in the plant (BodyIndex 1) is released by "" like any other.
    assert grasp_update(coupling, context, X_WD, "")[0] == -1.0


def test_grasp_nearest_takes_the_nearest_body_within_reach_and_keeps_it():
    coupling, context, (i0, i1) = two_boxes_and_a_device([0, 0, 0], [0.03, 0, 0], grasp_reach_m=0.05)
    assert grasp_update(coupling, context, RigidTransform([0.2, 0, 0]), "*")[0] == -1.0  # out of reach
    assert grasp_update(coupling, context, RigidTransform([0.02, 0, 0]), "*")[0] == i1  # 1 cm vs 2 cm
    assert grasp_update(coupling, context, RigidTransform([0.0, 0, 0]), "*")[0] == i1  # kept while "*" lasts
    assert grasp_update(coupling, context, RigidTransform([0.0, 0, 0]), "")[0] == -1.0
    assert grasp_update(coupling, context, RigidTransform([0.0, 0, 0]), "*")[0] == i0
    coupling, context, (i0, _) = two_boxes_and_a_device([0, 0, 0], [1, 0, 0], grasp_reach_m=0.25)
    assert grasp_update(coupling, context, RigidTransform([-0.25, 0, 0]), "*")[0] == i0  # reach is inclusive


def mixed_plant():
    """BodyIndex 1: a box welded to the world (model 'wall'); 2: a free brick (model 'brick');
    3, 4: a hinged arm whose base is welded (model 'arm')."""
    plant = MultibodyPlant(1e-3)
    M = SpatialInertia.SolidBoxWithMass(0.2, 0.05, 0.05, 0.05)
    box = plant.AddRigidBody("box", plant.AddModelInstance("wall"), M)
    plant.WeldFrames(plant.world_frame(), box.body_frame())
    plant.AddRigidBody("brick", plant.AddModelInstance("brick"), M)
    arm = plant.AddModelInstance("arm")
    base, link = plant.AddRigidBody("base", arm, M), plant.AddRigidBody("link", arm, M)
    plant.WeldFrames(plant.world_frame(), base.body_frame())
    plant.AddJoint(RevoluteJoint("hinge", base.body_frame(), link.body_frame(), [0, 0, 1]))
    plant.Finalize()
    return plant


def test_bodies_that_cannot_be_grasped_say_why():
    plant = mixed_plant()
    welded = "is welded to the world (an obstacle)"
    linked = "is a link of an articulated model (use godobject_drake.station.loop.add_joint_coupling for it)"
    assert fixed_bodies(plant) == {
        "wall::box": f"wall::box {welded}",
        "box": f"wall::box {welded}",
        "wall": f"wall::box {welded}",
        "arm::base": f"arm::base {welded}",
        "base": f"arm::base {welded}",
        "arm::link": f"arm::link {linked}",
        "link": f"arm::link {linked}",
    }  # fmt: skip  (the world is no body a device names; 'arm' has two bodies: no alias)
    coupling = GodObjectCoupling(plant, CouplingGains())
    with pytest.raises(
        ValueError,
        match=r"^grasp names 'wall' names wall::box is welded to the world \(an obstacle\): "
        r"only a free body can be a god-object; graspable bodies are \['brick'\]\. Fix the device",
    ):
        coupling.body_for_grasp("wall")
    with pytest.raises(
        ValueError, match=r"'link' names arm::link is a link of an articulated model \(use godobject_drake"
    ):
        coupling.body_for_grasp("link")
    with pytest.raises(ValueError, match=r"unknown body 'world'; graspable bodies are \['brick'\]"):
        coupling.body_for_grasp("world")
    assert coupling.body_for_grasp("brick") is coupling.body_for_grasp("brick::brick")
    assert coupling.body_for_grasp("") is None and coupling.body_for_grasp("*") is None


def test_a_free_body_left_out_of_graspable_is_named_as_such():
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3, (MASS, MASS))
    coupling = GodObjectCoupling(plant, CouplingGains(), graspable=["body_1"])
    with pytest.raises(
        ValueError,
        match=r"'body_0' is a free body, but not one of this coupling's graspable bodies; "
        r"graspable bodies are \['body_1'\]",
    ):
        coupling.body_for_grasp("body_0")
