"""The articulated god-object: tool structure, feedback (Eq. 8, 9), explicit limit, tracking, generality."""

import math

import numpy as np
import pytest
from conftest import assert_refused
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex, JointIndex, MultibodyForces
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from godobject_drake.config.gains import CouplingGainError, CouplingGains, FeedbackGains
from godobject_drake.devices.sources import JointDevice
from godobject_drake.spatial import rotation_error
from godobject_drake.station.loop import add_joint_coupling
from godobject_drake.station.plant import add_scene_from_directives, exclude_self_collisions
from godobject_drake.studies.stability import bisect
from godobject_drake.systems.articulated import (
    ArticulatedFeedback,
    ArticulatedTool,
    joint_space_loop,
    propagate_to_parents,
)

LAPAROSCOPY = "package://godobject_models/laparoscopy/laparoscopy.dmd.yaml"
ARM = "package://godobject_models/arm/arm.dmd.yaml"
GRASPER_JOINTS = ("yaw", "pitch", "insertion", "roll", "jaw_upper", "jaw_lower")
HOME = np.array([0.0, 0.0, 0.03, 0.0, 0.15, 0.15])  # tip 70 mm above the organ


def grasper_plant(h=1e-3) -> MultibodyPlant:
    builder = DiagramBuilder()
    return add_scene_from_directives(builder, LAPAROSCOPY, h).plant


def test_coupled_bodies_follow_the_device_joints():
    tool = ArticulatedTool(
        grasper_plant(), "grasper", GRASPER_JOINTS, imposed_joints=("jaw_upper", "jaw_lower")
    )
    names = [b.name.split("::")[1] for b in tool.bodies]
    # The welded port does not move with the device; every moving body does.
    assert names == ["gimbal", "trocar", "sleeve", "tube", "upper_jaw", "lower_jaw"]
    parent = {names[k]: names[b.parent] if b.parent >= 0 else None for k, b in enumerate(tool.bodies)}
    assert parent == {"gimbal": None, "trocar": "gimbal", "sleeve": "trocar", "tube": "sleeve",
                      "upper_jaw": "tube", "lower_jaw": "tube"}  # fmt: skip
    assert [j.name for j in tool.imposed] == ["jaw_upper", "jaw_lower"]
    # Without the insertion joint, the tube and jaws are left to the simulation.
    partial = ArticulatedTool(tool.plant, "grasper", ("yaw", "pitch", "roll"))
    assert [b.name.split("::")[1] for b in partial.bodies] == ["gimbal", "trocar", "sleeve"]


def test_bad_joint_names_and_modes_are_refused():
    plant = grasper_plant()
    with pytest.raises(ValueError, match=r"not in model 'grasper'.*insertion"):
        ArticulatedTool(plant, "grasper", ("yaw", "pich"))
    with pytest.raises(ValueError, match="must also be device joints"):
        ArticulatedTool(plant, "grasper", ("yaw",), imposed_joints=("pitch",))


def random_feedback_inputs(tool, rng):
    """A device configuration, god-object poses/velocities and targets for one context."""
    plant = tool.plant
    q_dev = HOME + rng.uniform(-0.2, 0.2, HOME.size) * np.array([1, 1, 0.1, 1, 0.5, 0.5])
    targets = tool.body_targets(q_dev, rng.normal(size=HOME.size))
    ctx = plant.CreateDefaultContext()
    q = plant.GetPositions(ctx)
    q[tool.q_device] = q_dev + rng.normal(scale=0.02, size=HOME.size)
    plant.SetPositions(ctx, q)
    plant.SetVelocities(ctx, rng.normal(size=plant.num_velocities()))
    poses = plant.get_body_poses_output_port().Eval(ctx)
    vels = plant.get_body_spatial_velocities_output_port().Eval(ctx)
    return q_dev, targets, poses, vels


def test_feedback_generalized_forces_are_J_transpose_of_the_wrenches():
    """tau_device = Σ Jᵢᵀ Fᵢ, checked against Drake's CalcGeneralizedForces and against Eq. 9."""
    plant = grasper_plant()
    tool = ArticulatedTool(plant, "grasper", GRASPER_JOINTS)
    gains = FeedbackGains(kd=300.0, gamma_d=4.0, kd_rot=2.0, gamma_d_rot=0.05)
    feedback = ArticulatedFeedback(tool, gains)
    ctx = feedback.CreateDefaultContext()
    rng = np.random.default_rng(4)
    for _ in range(3):
        q_dev, targets, poses, vels = random_feedback_inputs(tool, rng)
        feedback.GetInputPort("body_poses").FixValue(ctx, poses)
        feedback.GetInputPort("body_spatial_velocities").FixValue(ctx, vels)
        feedback.GetInputPort("targets").FixValue(ctx, targets)
        feedback.GetInputPort("q_device").FixValue(ctx, q_dev)
        F = feedback.GetOutputPort("F_feedback_W").Eval(ctx).reshape(-1, 6)
        tau = feedback.GetOutputPort("tau_device").Eval(ctx)
        assert np.max(np.abs(F)) > 0.1  # a real load, not zeros

        # Eq. 8 by hand for the tube: f = kd (x − x_T) + γd (v − v_T).
        k = [b.name for b in tool.bodies].index("grasper::tube")
        b, t = tool.bodies[k], targets[13 * k : 13 * (k + 1)]
        X, V = poses[b.index], vels[b.index]
        p_cm = X.rotation().matrix() @ b.p_BoBcm_B
        v_cm = V.translational() + np.cross(V.rotational(), p_cm)
        f = gains.kd * (X.translation() + p_cm - t[4:7]) + gains.gamma_d * (v_cm - t[10:13])
        np.testing.assert_allclose(F[k, 3:], f, rtol=1e-12, atol=1e-12)

        # Second method: Drake applies the same wrenches on the device's configuration.
        dctx = tool.set_device_state(q_dev)
        forces = MultibodyForces(plant)
        for b, Fi in zip(tool.bodies, F, strict=True):
            body = plant.get_body(BodyIndex(b.index))
            p_BoBcm_W = plant.EvalBodyPoseInWorld(dctx, body).rotation().multiply(b.p_BoBcm_B)
            body.AddInForce(dctx, p_BoBcm_W, SpatialForce(Fi[:3], Fi[3:]), plant.world_frame(), forces)
        tau_drake = plant.CalcGeneralizedForces(dctx, forces)[tool.v_device]
        np.testing.assert_allclose(tau, tau_drake, rtol=0, atol=1e-9)

        # Third method: Eq. 9 subtree wrenches projected on each joint's axis.
        sub = propagate_to_parents(tool, F, targets)
        by_child = {b.index: k for k, b in enumerate(tool.bodies)}
        x_cm = targets.reshape(-1, 13)[:, 4:7]
        for i, j in enumerate(tool.joints):
            joint = plant.get_joint(JointIndex(j.index))
            c = by_child[int(joint.child_body().index())]
            X_WF = joint.frame_on_parent().CalcPoseInWorld(dctx)
            X_WM = joint.frame_on_child().CalcPoseInWorld(dctx)
            if j.type == "revolute":
                axis = X_WF.rotation().matrix() @ joint.revolute_axis()
                moment = sub[c, :3] + np.cross(x_cm[c] - X_WM.translation(), sub[c, 3:])
                expected = axis @ moment
            else:
                expected = (X_WF.rotation().matrix() @ joint.translation_axis()) @ sub[c, 3:]
            assert tau[i] == pytest.approx(expected, abs=1e-9)


def test_zero_feedback_gains_give_zero_at_no_cost():
    tool = ArticulatedTool(grasper_plant(), "grasper", GRASPER_JOINTS)
    feedback = ArticulatedFeedback(tool)
    ctx = feedback.CreateDefaultContext()
    assert not np.any(feedback.GetOutputPort("tau_device").Eval(ctx))


# -- a small diagram: device → coupling → grasper, no organ contact (free space) -------------
def run_grasper(coupling, omega_n, samples, duration, check_gains=True, h=1e-3):
    """Run the grasper in free space from HOME under a held-sample device ``samples(t)`` at 60 Hz.

    Returns ``(q, system)``: the positions of the device's joints, one row per plant step from
    t = 0, and the articulated god-object. A Drake error (a diverging run) is raised."""
    builder = DiagramBuilder()
    scene = add_scene_from_directives(builder, LAPAROSCOPY, h)
    plant = scene.plant
    exclude_self_collisions(plant, scene.scene_graph, "grasper")  # the jaws overlap at the hinge
    T = 1.0 / 60.0
    device = builder.AddNamedSystem("device", JointDevice(lambda t: samples(t), GRASPER_JOINTS, period_s=T))
    system = add_joint_coupling(
        builder, plant, "grasper", GRASPER_JOINTS, coupling=coupling,
        gains=CouplingGains(omega_n, 1.0, omega_n), device_period_s=T, q_reference=HOME,
        check_gains=check_gains,
    )  # fmt: skip
    for name in ("q_device", "v_device"):
        builder.Connect(device.GetOutputPort(name), system.GetInputPort(name))
    q = plant.GetDefaultPositions()
    q[system.tool.q_device] = HOME
    plant.SetDefaultPositions(q)
    log = LogVectorOutput(plant.get_state_output_port(), builder, h)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration)
    data = log.FindLog(simulator.get_context()).data().T
    return data[:, system.tool.q_device], system


def kicked(t):
    """HOME, then a 1 mm / 10 mrad step at t = 0.05 s."""
    return HOME + (t >= 0.05) * np.array([0.01, -0.01, 0.001, 0.01, 0.0, 0.0])


def test_explicit_joint_pd_is_refused_where_sap_pd_stays_stable():
    assert_refused(
        lambda: run_grasper("joint_pd", 2000.0, kicked, 0.01), CouplingGainError,
        value=r"omega_n=2000, omega_n_rot=2000 rad/s at time_step=0\.001 s",
        limit=r"spectral radius \d+\.\d+ ≥ 1 \(fastest mode .* ω·h = ",
        fix=r"Lower the bandwidths or time_step, or use coupling='joint_pd_sap' \(implicit\)",
    )  # fmt: skip
    q, _ = run_grasper("joint_pd_sap", 2000.0, kicked, 0.3)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(q[-1], kicked(1.0), atol=1e-6)  # settled on the target


def test_explicit_limit_predicted_by_the_joint_space_loop():
    """Bisect ωn on the linearized loop's spectral radius; Drake grows above it and not below."""
    tool = ArticulatedTool(grasper_plant(), "grasper", GRASPER_JOINTS)

    def stable(w):
        return joint_space_loop(tool, "joint_pd", CouplingGains(w, 1.0, w), HOME, 1e-3).radius < 1.0

    w_crit = bisect(stable, 100.0, 5000.0, rel_tol=1e-4)
    # By hand (docs/theory.md §1): K = ωn² diag(M) and D = 2ζωn diag(M), so the loop's modes are
    # scalar loops with ω_i = ωn √μ_i and ζ_i = ζ √μ_i, μ_i the eigenvalues of M⁻¹ diag(M); the
    # fastest (μ_max) breaks first, at ωn √μ h = 2(√(1 + ζ²μ) − ζ √μ).
    loop = joint_space_loop(tool, "joint_pd", CouplingGains(1.0, 1.0, 1.0), HOME, 1e-3)
    mu = float(np.max(np.linalg.eigvals(np.linalg.solve(loop.M, loop.K)).real))
    closed_form = 2.0 * (math.sqrt(1.0 + mu) - math.sqrt(mu)) / (math.sqrt(mu) * 1e-3)
    assert w_crit == pytest.approx(closed_form, rel=2e-4)  # the bisection's own tolerance
    assert mu > 1.0  # coupled joints: below the 828 rad/s of one free joint

    def grows(w):
        q, _ = run_grasper("joint_pd", w, kicked, 0.4, check_gains=False)
        err = np.abs(q - kicked(1.0))[:, :4].max(axis=1)
        return not np.all(np.isfinite(err)) or err[-50:].max() > err[60:110].max()

    assert not grows(0.97 * w_crit)
    assert grows(1.03 * w_crit)


def test_ball_jointed_arm_through_the_same_call():
    """A different tree (ball shoulder, elbow, passive wrist) follows its device; the wrist hangs."""
    h = 1e-3
    builder = DiagramBuilder()
    plant = add_scene_from_directives(builder, ARM, h).plant
    goal = np.array([0.3, -0.2, 0.4, 0.6])  # shoulder roll-pitch-yaw (rad), elbow (rad)

    def sample(t):
        return goal * min(t / 0.5, 1.0)

    device = builder.AddNamedSystem("device", JointDevice(sample, ("r", "p", "y", "elbow")))
    with pytest.raises(ValueError, match=r"ball_rpy.*cartesian"):
        add_joint_coupling(
            DiagramBuilder(), plant, "arm", ("shoulder", "elbow"), coupling="joint_pd",
            gains=CouplingGains(20.0, 1.0), device_period_s=device.period_s, q_reference=np.zeros(4),
        )  # fmt: skip
    coupling = add_joint_coupling(
        builder, plant, "arm", ("shoulder", "elbow"), coupling="cartesian",
        gains=CouplingGains(60.0, 1.0, 60.0), device_period_s=device.period_s, q_reference=np.zeros(4),
    )  # fmt: skip
    # The free hand's weight (0.2 kg) loads the coupling: it sags the arm 2.3 mm at 20 rad/s, 0.26 at 60.
    for name in ("q_device", "v_device"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    tool = coupling.tool
    assert [b.name for b in tool.bodies] == ["arm::upper_arm", "arm::forearm"]  # the hand is free
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(2.5)
    ctx = plant.GetMyContextFromRoot(simulator.get_context())
    targets = coupling.GetOutputPort("targets").Eval(coupling.GetMyContextFromRoot(simulator.get_context()))
    for k, b in enumerate(tool.bodies):
        X = plant.EvalBodyPoseInWorld(ctx, plant.GetBodyByName(b.name.split("::")[1]))
        t = targets[13 * k : 13 * (k + 1)]
        p_cm = X.translation() + X.rotation().matrix() @ b.p_BoBcm_B
        assert np.linalg.norm(p_cm - t[4:7]) < 1e-3  # the 0.26 mm sag above, with a 4× margin
        # The hand's load also twists the upper arm about its own axis, where its inertia (5e-4 kg·m²)
        # gives the least rotational stiffness: I ωr² = 1.8 N·m/rad, 6 mrad here.
        assert np.linalg.norm(rotation_error(t[:4], X.rotation().ToQuaternion().wxyz())) < 1e-2
    # The wrist is simulated: the hand hangs with its centre of mass under the wrist axis.
    wrist = plant.GetJointByName("wrist")
    X_WM = wrist.frame_on_child().CalcPoseInWorld(ctx)
    axis = X_WM.rotation().matrix() @ wrist.revolute_axis()
    hand = plant.GetBodyByName("hand")
    p_hand = plant.EvalBodyPoseInWorld(ctx, hand).multiply(hand.default_com())
    r = p_hand - X_WM.translation()
    r_perp = r - axis * (axis @ r)
    g = np.array([0.0, 0.0, -1.0])
    g_perp = g - axis * (axis @ g)
    angle = math.acos(np.clip(r_perp @ g_perp / np.linalg.norm(r_perp) / np.linalg.norm(g_perp), -1, 1))
    assert angle < 0.01  # rad
