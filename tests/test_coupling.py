"""The PD coupling alone (hand computations), its gain checks, and in closed loop."""

import math
import warnings

import numpy as np
import pytest
from conftest import add_free_boxes
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import MultibodyForces, SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from godobject_drake.coupling import (
    CouplingGainError,
    CouplingGains,
    CouplingGainWarning,
    GodObjectCoupling,
    explicit_limit_omega_h,
)
from godobject_drake.devices import SampleGuard, ScriptedDevice, Waypoint

NO_JUMP_CHECK = SampleGuard(max_speed_m_s=float("inf"))

MASS, INERTIA = 0.5, (1e-3, 2e-3, 3e-3)
G = 9.81


def coupling_alone(gains, q_body, p_body, v_body=None, gravity_compensation=True):
    builder = DiagramBuilder()
    plant, (body,) = add_free_boxes(builder, 1e-3, (MASS,), INERTIA)
    coupling = GodObjectCoupling(plant, gains, gravity_compensation=gravity_compensation)
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
