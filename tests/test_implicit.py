"""The implicit coupling (godobject_drake.systems.implicit): the paper's spring as SAP springs.

Each test checks a number against theory or a second method: the layout's sums against
``k = m ωn²`` and ``I ωr²``; the step response against paper Eq. 3; the logged coupling wrench
against the body's own change of momentum; the weight carried against ``m g``.
"""

import math
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import SpatialInertia, UnitInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, EventStatus
from pydrake.systems.primitives import LogVectorOutput

from godobject_drake import cli
from godobject_drake.config import scenario as sc
from godobject_drake.config.device_files import SampleGuard, Waypoint
from godobject_drake.config.gains import CouplingGainError, CouplingGains
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.systems.coupling import GodObjectCoupling, GraspableBody, graspable_bodies
from godobject_drake.systems.implicit import (
    N_SPRINGS,
    ImplicitCoupling,
    SpringHook,
    add_springs,
    implicit_terms,
    spring_layout,
)

MASS, INERTIA = 0.5, (1e-3, 2e-3, 3e-3)
NO_JUMP_CHECK = SampleGuard(max_speed_m_s=math.inf)


def _spatial(L, values):
    """The springs' 6×6 stiffness (or damping) at the centre of mass, [rotation; translation]:
    Σ_j v_j w_j w_jᵀ with w_j = [a_j × e_j; e_j], each spring linear along its world axis e_j."""
    w = np.hstack([np.cross(L.offsets_B, L.axis_W), L.axis_W])
    return (w * np.asarray(values)[:, None]).T @ w


@pytest.mark.parametrize("zeta_rot", [0.8, None])
def test_spring_layout_sums_to_the_paper_gains(zeta_rot):
    """The springs' spatial stiffness is ``diag(I ωr², m ωn² 1)`` and their damping
    ``diag(2 ζr ωr I, 2 ζ m ωn 1)`` (no coupling between translation and rotation, the same in
    every direction), for a body whose principal axes are turned away from its frame's: with
    different gains in rotation (the centre's springs on) and with the same (off)."""
    R = RotationMatrix(RollPitchYaw(0.3, -0.2, 0.5)).matrix()
    I_B = R @ np.diag(INERTIA) @ R.T
    body = GraspableBody("b", 1, MASS, np.zeros(3), I_B, 0, 7)
    same = zeta_rot is None
    gains = CouplingGains(omega_n=40.0, zeta=1.0, omega_n_rot=40.0 if same else 120.0, zeta_rot=zeta_rot)
    wr, zr = (40.0, 1.0) if same else (120.0, 0.8)
    L = spring_layout(body, gains)
    assert len(L.stiffness) == N_SPRINGS and np.all(L.stiffness >= 0) and np.all(L.damping >= 0)
    assert np.all(L.stiffness[:3] == 0) == same  # the centre's springs: off only with the same gains
    K, D = _spatial(L, L.stiffness), _spatial(L, L.damping)
    k, g = MASS * 40.0**2, 2 * 1.0 * MASS * 40.0
    np.testing.assert_allclose(K[3:, 3:], k * np.eye(3), rtol=1e-12, atol=1e-12 * k)
    np.testing.assert_allclose(D[3:, 3:], g * np.eye(3), rtol=1e-12, atol=1e-12 * g)
    np.testing.assert_allclose(K[:3, 3:], 0.0, atol=1e-12 * k)
    np.testing.assert_allclose(D[:3, 3:], 0.0, atol=1e-12 * g)
    np.testing.assert_allclose(K[:3, :3], I_B * wr**2, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(D[:3, :3], I_B * 2 * zr * wr, rtol=1e-10, atol=1e-12)


def closed_loop(waypoints, h=1e-3, gains=None, gravity=False, rate=1000.0, **options):
    """One free box held through the implicit coupling by a scripted device (SAP plant)."""
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=h, discrete_contact_approximation="sap"), builder
    )
    if not gravity:
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    M = SpatialInertia(MASS, np.zeros(3), UnitInertia(*(np.array(INERTIA) / MASS)))
    plant.AddRigidBody("body_0", M)
    springs = add_springs(plant)
    plant.Finalize()
    device = builder.AddSystem(ScriptedDevice(waypoints, period_s=1.0 / rate, guard=NO_JUMP_CHECK))
    gains = gains or CouplingGains(omega_n=20.0, zeta=1.0)
    coupling = builder.AddSystem(ImplicitCoupling(plant, gains, springs, device.period_s, **options))
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    logs = {
        "state": LogVectorOutput(plant.get_state_output_port(), builder, h),
        "coupling": LogVectorOutput(coupling.GetOutputPort("coupling_state"), builder, h),
    }
    diagram = builder.Build()
    simulator = Simulator(diagram)
    root = simulator.get_mutable_context()
    plant_context = plant.GetMyMutableContextFromRoot(root)
    hook = SpringHook(plant, coupling)
    hook.deactivate(plant_context)

    def monitor(context):
        hook(plant_context, context)
        return EventStatus.DidNothing()

    simulator.set_monitor(monitor)
    return simulator, plant, coupling, logs


def run_logs(simulator, logs):
    context = simulator.get_context()
    return {k: log.FindLog(context).data().T for k, log in logs.items()}


STEP, T_STEP = 0.02, 0.1
STEP_PATH = [
    Waypoint(t=0.0, xyz=[0, 0, 0], grasp="body_0"),
    Waypoint(t=T_STEP - 1e-6, xyz=[0, 0, 0], grasp="body_0"),
    Waypoint(t=T_STEP, xyz=[STEP, 0, 0], grasp="body_0"),
    Waypoint(t=2.0, xyz=[STEP, 0, 0], grasp="body_0"),
]


def test_free_space_step_response_matches_eq3():
    """A 2 cm device step at ωn = 20 rad/s, ζ = 1, h = 1 ms: the held body follows paper Eq. 3,
    ``Δ (1 − e^{−ωn t} + ωn t e^{−ωn t})`` (13.5 % overshoot). The explicit coupling meets it within
    2 % of the step (tests/test_coupling.py); the implicit one within 2 % too (measured 0.79 %,
    0.16 mm: backward Euler's slower decay, ln(1 + ωn h)/(ωn h) = 0.99 of Eq. 3's rate, and the
    target sampled at 1 kHz). With the former seven vertical springs it was 11.3 %: across their
    lines they were soft and undamped."""
    h, wn = 1e-3, 20.0
    gains = CouplingGains(omega_n=wn, zeta=1.0)
    simulator, _plant, _coupling, logs = closed_loop(STEP_PATH, h, gains)
    simulator.AdvanceTo(0.6)
    x = run_logs(simulator, logs)["state"]
    t = np.arange(len(x)) * h
    tau = np.clip(t - (T_STEP + h), 0.0, None)
    expected = STEP * (1 - np.exp(-wn * tau) + wn * tau * np.exp(-wn * tau))
    err = np.max(np.abs(x[:, 4] - expected))
    assert err <= 0.02 * STEP, f"max deviation {err:.3g} m > 2 % of the {STEP} m step"
    assert np.max(x[:, 4]) == pytest.approx(STEP * (1 + np.exp(-2)), rel=0.05)
    assert np.max(np.abs(x[:, 5])) < 1e-6  # none into y (z: test_zero_gravity_hold_does_not_drift)
    assert np.max(np.abs(x[:, 1:4])) < 1e-12  # no turn


def test_zero_gravity_hold_does_not_drift():
    """In zero gravity, after the 2 cm step in x, the body stays at its target's height. The former
    seven springs, with a 0.1 mm rest length all along +z, were soft across it and let the body
    drift in z: 1.28 mm at 0.6 s and growing. Now the springs are linear along x, y and z: the
    step moves the body 0.14 µm in z (the long springs' |P − x|²/(2 LENGTH_M) while the target's
    lead is large, implicit.py) and it returns."""
    simulator, _plant, _coupling, logs = closed_loop(STEP_PATH, 1e-3, CouplingGains(omega_n=20.0))
    simulator.AdvanceTo(0.6)
    x = run_logs(simulator, logs)["state"]
    assert np.max(np.abs(x[:, 6])) < 1e-6


def test_logged_wrench_is_the_bodys_change_of_momentum():
    """SAP integrates implicitly: v_{k+1} = v_k + h F(x_{k+1}, v_{k+1}) / m. So the springs'
    force evaluated after the run at logged state k+1 (:func:`implicit_terms`) must equal
    m (v_{k+1} − v_k) / h, the body's change of momentum (zero gravity), to SAP's tolerance."""
    h = 1e-3
    simulator, plant, coupling, logs = closed_loop(STEP_PATH, h)
    simulator.AdvanceTo(0.4)
    data = run_logs(simulator, logs)
    terms = implicit_terms(coupling, data["state"], data["coupling"])
    nq = plant.num_positions()
    v = data["state"][:, nq + 3 : nq + 6]
    momentum = MASS * np.diff(v, axis=0) / h
    F = terms[1:, 30:33]
    scale = np.max(np.abs(F[:, 0]))
    assert scale > 0.1  # the step pulls hard: the check is not of zeros
    err = np.max(np.abs(F - momentum), axis=1)
    assert np.median(err) <= 1e-3 * scale and np.max(err) <= 0.05 * scale


def test_held_body_carries_its_weight_at_its_target():
    """Gravity on, the device still: the body hangs at its target (the springs' ends are raised
    by g/ωn², 6 mm here) and the springs carry m g."""
    h = 1e-3
    path = [Waypoint(t=0.0, xyz=[0, 0, 0], grasp="body_0"), Waypoint(t=2.0, xyz=[0, 0, 0], grasp="body_0")]
    simulator, _plant, coupling, logs = closed_loop(
        path, h, CouplingGains(omega_n=40.0), gravity=True, rate=60.0
    )
    simulator.AdvanceTo(1.0)
    data = run_logs(simulator, logs)
    terms = implicit_terms(coupling, data["state"], data["coupling"])
    assert abs(data["state"][-1, 6]) < 2e-5  # z within 20 µm of the target after 1 s
    assert terms[-1, 32] == pytest.approx(MASS * 9.81, rel=1e-3)


def test_stable_where_the_explicit_coupling_is_refused():
    """ωn = 120 rad/s at h = 20 ms (ωn h = 2.4): the explicit coupling refuses it (its limit is
    0.83); the implicit one settles on the step, within the 0.5 mm its rest offsets allow in zero
    gravity (measured 0.32 mm), without overshooting past Eq. 3's 13.5 %."""
    h, wn = 0.02, 120.0
    gains = CouplingGains(omega_n=wn, zeta=1.0)
    with pytest.raises(CouplingGainError, match="past the explicit"):
        gains.check(h)
    simulator, _plant, _coupling, logs = closed_loop(STEP_PATH, h, gains, rate=50.0)
    simulator.AdvanceTo(1.0)
    x = run_logs(simulator, logs)["state"][:, 4]
    assert np.all(np.isfinite(x)) and np.max(x) <= STEP * (1 + np.exp(-2)) + 1e-6
    assert x[-1] == pytest.approx(STEP, abs=5e-4)


def test_turns_past_ninety_degrees_about_every_axis():
    """The springs' ends carry the orientation (no angles): the device turns the body 170° about
    y (where a yaw-pitch-roll chain is singular at 90°), then about x; the body follows to within
    a degree of its target once the turn stops."""
    h = 2e-3
    path = [
        Waypoint(t=0.0, xyz=[0, 0, 0], grasp="body_0"),
        Waypoint(t=0.1, xyz=[0, 0, 0], grasp="body_0"),
        Waypoint(t=1.1, xyz=[0, 0, 0], rpy_deg=[0, 170, 0], grasp="body_0"),
        Waypoint(t=1.6, xyz=[0, 0, 0], rpy_deg=[0, 170, 0], grasp="body_0"),
        Waypoint(t=2.6, xyz=[0, 0, 0], rpy_deg=[170, 170, 0], grasp="body_0"),
        Waypoint(t=3.5, xyz=[0, 0, 0], rpy_deg=[170, 170, 0], grasp="body_0"),
    ]
    gains = CouplingGains(omega_n=20.0, omega_n_rot=40.0)
    simulator, _plant, _coupling, logs = closed_loop(path, h, gains, rate=60.0)
    for t_end in (1.6, 3.5):
        simulator.AdvanceTo(t_end)
        data = run_logs(simulator, logs)
        q_body, q_target = data["state"][-1, :4], data["coupling"][-1, 8:12]
        angle = 2 * math.degrees(math.acos(min(1.0, abs(float(q_body @ q_target)))))
        assert angle < 1.0, f"at t = {t_end}: {angle:.2f}° from the target"


def test_drake_crashes_on_a_distance_constraint_to_the_world_body():
    """Why the springs start on a welded anchor body (add_springs): in Drake 1.51.1 and 1.58.0 an
    active distance constraint whose body A is the world ends the process in the first SAP step
    (SIGSEGV). If a Drake release fixes it, this fails, and the anchor body can go."""
    code = textwrap.dedent(
        """
        from pydrake.all import *
        b = DiagramBuilder()
        config = MultibodyPlantConfig(time_step=1e-3, discrete_contact_approximation="sap")
        plant, _ = AddMultibodyPlant(config, b)
        box = plant.AddRigidBody("box", SpatialInertia.SolidBoxWithMass(0.01, .03, .02, .01))
        plant.AddDistanceConstraint(plant.world_body(), [1e-4, 0, 0], box, [0, 0, 0], 1e-4, 16.0, 0.8)
        plant.Finalize()
        Simulator(b.Build()).AdvanceTo(0.01)
        """
    )
    # undefined behaviour, not a check that fails: 12 of 12 runs here ended with SIGSEGV, and one
    # in a fresh CI venv ran through; a fix is told by every one of five tries running through
    codes = []
    for _ in range(5):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
        codes.append(done.returncode)
        if done.returncode == -11:
            break
    assert codes[-1] == -11, (codes, done.stderr[-500:])


@pytest.mark.slow
def test_implicit_lego_run_grasps_and_releases():
    """The brick scene on the implicit coupling at h = 5 ms: the brick is carried, released, and
    the logs' terms and metrics are there as with the explicit coupling."""
    s = sc.shipped_scenario("lego")
    s.god_object.coupling = "implicit"
    s.plant.time_step = 0.005
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = simulate(build_station(s), progress=False)
    m = result.metrics
    assert not m["diverged"] and m["coupling"] == "implicit"
    held = result.held
    assert held[0] >= 0 and held[-1] == -1  # grasped from the start, released at the end
    assert m["max_penetration_m"] < 0.01 and m["rms_tracking_error_m"] < 0.03
    # the released brick rests: its speed at the end is ~0
    body = graspable_bodies(result.station.plant)["brick_0"]
    assert np.linalg.norm(result.states[-1, body.v_start + 3 : body.v_start + 6]) < 1e-3


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--haptic", "admittance"], "haptic.mode admittance"),
        (["--mode", "position"], "simulation.mode position"),
    ],
)
def test_implicit_refuses_what_it_cannot_drive(flags, message, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["run", "lego", "--coupling", "implicit", "--duration", "0.1", *flags])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "god_object.coupling: explicit" in err and "Traceback" not in err


def test_explicit_coupling_class_is_unchanged_by_the_shared_base():
    """The explicit coupling still refuses what it refused (the grasp logic moved to a shared base)."""
    with pytest.raises(ValueError, match="max_stretch_m"):
        builder = DiagramBuilder()
        plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=1e-3), builder)
        plant.AddRigidBody("b", SpatialInertia.SolidBoxWithMass(0.1, 0.1, 0.1, 0.1))
        plant.Finalize()
        GodObjectCoupling(plant, CouplingGains(), max_stretch_m=0.0)


def test_implicit_rate_is_backward_euler_by_hand():
    """``analyze``'s accuracy row for the implicit coupling: at ζ = 1 backward Euler puts a double
    pole at 1/(1 + ω h), so the step response decays at ln(1 + ω h)/h, a fraction
    ln(1 + ω h)/(ω h) of Eq. 3's ωn (0.98 at the brick scene's 40 rad/s and 1 ms; 0.51 at
    ωn h = 2.4, the settling test above)."""
    from godobject_drake.studies.analyze import implicit_rate

    for w, h in ((40.0, 1e-3), (120.0, 20e-3), (120.0, 1e-3)):
        assert implicit_rate(w, 1.0, h) == pytest.approx(math.log1p(w * h) / (w * h), rel=1e-6)


def _implicit_lego_analysis():
    from godobject_drake.studies.analyze import analyze

    return analyze(sc.replace(sc.shipped_scenario("lego"), **{"god_object.coupling": "implicit"}),
                   quick=True, verify=True)  # fmt: skip


def test_analyze_reports_what_limits_the_implicit_coupling_and_checks_it_in_drake():
    """No explicit limit for the implicit coupling (no row bisects one), its accuracy and SAP's
    near-rigid rows instead, and the one-body backward-Euler model against Drake's own step
    response: a 3 cm target jump up, along the springs' lines, from Drake's state one device
    sample later."""
    out = _implicit_lego_analysis()
    names = [c["name"] for c in out["checks"]]
    assert not [n for n in names if n.startswith("explicit limit,")], names
    assert "verify_explicit_limit" not in out
    rate = next(c for c in out["checks"] if c["name"].startswith("implicit step response, translation"))
    assert rate["value"] == pytest.approx(math.log1p(40.0e-3) / 40.0e-3, rel=1e-6)  # ωn = 40, h = 1 ms
    near = next(c for c in out["checks"] if c["name"].startswith("SAP near-rigid regime, translation"))
    assert near["value"] == pytest.approx(0.04**2 + 2 * 0.04, rel=1e-6) and near["verdict"] == "ok"
    v = out["verify_implicit_rate"]["along"]
    assert abs(v["start_error_m"]) > 5e-3  # a real transient left to compare, not the settled body
    assert v["relative_error"] <= 0.1 and v["predicted_t10_s"] > 0
    # Along the springs' lines SAP's step is the model's linear one (measured 3e-10 of the start
    # error: the springs are linear along their axes up to |error|/LENGTH_M, 1e-7 here).
    assert v["worst_gap_over_start"] < 1e-5


def test_implicit_step_across_the_springs_lines_matches_the_model():
    """The same step, the brick lifted 3 cm and its target jumped 3 cm sideways, across the
    gravity raise (the vertical): Drake's response is the model's as along it. The former seven
    vertical springs did not damp across their lines: t10 20 % early, curves 127 % apart. Now the
    springs lie along x, y and z, linear up to |error|/LENGTH_M (1.1e-7 for the 1.06 cm error at
    the start, implicit.py); measured 1.4e-8 of the start error, so 1e-5 leaves room for SAP's
    convergence tolerance and still fails on any damping missing across."""
    v = _implicit_lego_analysis()["verify_implicit_rate"]["across"]
    assert abs(v["start_error_m"]) > 5e-3
    assert v["relative_error"] <= 0.1 and v["worst_gap_over_start"] < 1e-5


@pytest.mark.slow(seconds=25)
def test_implicit_coupling_closes_the_haptic_impedance_loop_passively():
    """The simulated impedance device on the implicit coupling, as tests/test_device_modes.py runs
    it on the explicit one (a hand pushing the handle along the brick path, proportional feedback
    gains, the passivity controller): the device never gives the user energy, and the feedback
    takes from the handle at least the energy its spring holds at the end, ½ kd s², with s the
    target's distance past the brick the wall stopped."""
    from conftest import shared_run

    result = shared_run("lego", "--coupling", "implicit", "--duration", "2.0", "--haptic", "impedance",
                        "--kd", "20", "--gamma-d", "0.2", "--passivity-damping", "100")  # fmt: skip
    m = result.metrics
    assert not m["diverged"] and m["coupling"] == "implicit"
    s = np.linalg.norm(result.coupling_terms("pose_WT")[-1, 4:] - result.coupling_terms("pose_WG")[-1, 4:])
    spring = 0.5 * 20 * s**2
    assert s > 0.1 and -1.05 * spring < m["haptic_feedback_work_j"] < -spring
    assert m["haptic_energy_to_user_j"] <= 1e-9
    assert m["passivity_observed_energy_j"] >= -1e-6
