"""Hard numerical cases (docs/theory.md §4), each with a pass criterion a reader can check.

Every case drives one 2x4 brick (the brick scene's, 2.3 g, proxies on its corners) as the
god-object with the brick scene's default gains (ωn = 40 rad/s, ωr = 120 rad/s, ζ = 1,
h = 1 ms) on the brick scene's baseplate, plus what the case needs (a 2 mm wall, a heavy
block). Runs are a plain Simulator with the safeguards installed, which stop a blow-up with a
diagnosis.

The 10-minute random-motion case is marked ``slow``; CI runs it (the suite stays under
15 minutes), ``pytest -m "not slow"`` skips it.
"""

import dataclasses
import math

import numpy as np
import pytest
from conftest import assert_refused, run_guarded, run_scene
from pydrake.geometry import Box, ProximityProperties
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from godobject_drake.config.device_files import SampleGuard, Waypoint
from godobject_drake.config.gains import CouplingGainError, CouplingGains
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.station.plant import apply_contact_model, make_parser, set_relaxation_time
from godobject_drake.systems.coupling import TERMS_LAYOUT, GodObjectCoupling

H = 1e-3
GAINS = CouplingGains(omega_n=40.0, zeta=1.0, omega_n_rot=120.0)
G = 9.81
BRICK_MASS = 0.0023
HALF = (0.0159, 0.0079, 0.0048)  # brick half sizes (m)
REST_Z = 0.0048  # a brick's centre height resting on the baseplate (m)


FRICTION = CoulombFriction(0.5, 0.5)


def add_box(plant, name, size, mass, X_WB=None, k=2e4):
    """A box with point-contact properties like the brick scene's; welded if ``X_WB`` is given."""
    props = ProximityProperties()
    props.AddProperty("material", "point_contact_stiffness", k)
    props.AddProperty("material", "coulomb_friction", FRICTION)
    if X_WB is None:
        body = plant.AddRigidBody(
            name, plant.AddModelInstance(name), SpatialInertia.SolidBoxWithMass(mass, *size)
        )
        plant.RegisterCollisionGeometry(body, RigidTransform(), Box(*size), name, props)
        return body
    body = plant.world_body()
    plant.RegisterCollisionGeometry(body, X_WB, Box(*size), name, props)
    return body


def hard_scene(waypoints, *, extra=(), device_rate=1000.0, latency=0.0, guard=None, h=H, brick_xyz=None):
    """The brick on the brick scene's baseplate, held by a scripted device from t = 0.

    ``extra(plant)`` adds bodies before ``Finalize``. Returns (diagram, plant, logs, coupling).
    """
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=h, discrete_contact_approximation="sap"), builder
    )
    parser = make_parser(plant)
    (table,) = parser.AddModels(url="package://godobject_models/lego/table.sdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("baseplate", table))
    (brick,) = parser.AddModels(url="package://godobject_models/lego/brick_2x4.sdf")
    body = plant.GetBodyByName("brick", brick)
    for add in extra:
        add(plant)
    plant.Finalize()
    set_relaxation_time(plant, scene_graph, h)
    apply_contact_model(plant, scene_graph, "proxies")
    plant.SetDefaultFloatingBaseBodyPose(body, RigidTransform(brick_xyz or waypoints[0].xyz))
    device = builder.AddSystem(
        ScriptedDevice(waypoints, period_s=1.0 / device_rate, latency_s=latency, guard=guard)
    )
    coupling = builder.AddSystem(GodObjectCoupling(plant, GAINS, device_period_s=device.period_s))
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(
        coupling.GetOutputPort("generalized_force"), plant.get_applied_generalized_force_input_port()
    )
    logs = {
        "state": LogVectorOutput(plant.get_state_output_port(), builder, h),
        "terms": LogVectorOutput(coupling.GetOutputPort("terms"), builder, h),
    }
    return builder.Build(), plant, logs, coupling


@dataclasses.dataclass
class Run:
    loop: object  # conftest.Guarded
    t: np.ndarray  # sample times (s)
    x: np.ndarray  # plant states, one row per step
    terms: np.ndarray  # the coupling's terms (TERMS_LAYOUT), one row per step
    plant: object
    coupling: GodObjectCoupling


def run(waypoints, duration, **kw) -> Run:
    diagram, plant, logs, coupling = hard_scene(waypoints, **kw)
    loop = run_guarded(diagram, duration)
    x = logs["state"].FindLog(loop.context)
    terms = logs["terms"].FindLog(loop.context).data().T
    return Run(loop, x.sample_times(), x.data().T, terms, plant, coupling)


def brick_p(states):
    """The brick's centre (it is the first free body: q = [qw qx qy qz x y z])."""
    return states[:, 4:7]


def brick_v(states, plant):
    nq = plant.num_positions()
    return states[:, nq + 3 : nq + 6]


# -- 1. stiff coupling at and past the explicit limit -------------------------------------


@pytest.mark.parametrize("factor", [0.97, 1.03])
def test_stiff_coupling_near_the_explicit_limit(factor):
    """Pass: below the limit ωn h < 2(√(1+ζ²)−ζ) the brick settles on a 1 cm step; past it
    the coupling refuses with the limit and the fix in the message (docs/theory.md §1)."""
    limit = 2 * (math.sqrt(2) - 1) / H  # ζ = 1: 828.4 rad/s at h = 1 ms
    gains = CouplingGains(omega_n=factor * limit, zeta=1.0, omega_n_rot=factor * limit)
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=H), builder)
    plant.AddRigidBody("body", SpatialInertia.SolidBoxWithMass(BRICK_MASS, *HALF))
    plant.Finalize()
    if factor > 1:
        assert_refused(
            lambda: GodObjectCoupling(plant, gains), CouplingGainError,
            value=r"omega_n=853\.28 rad/s at time_step=0\.001 s gives ωn·h=0\.8533",
            limit=r"past the explicit \(symplectic Euler\) stability limit 2\(√\(1\+ζ²\)−ζ\)=0\.8284 for ζ=1",
            fix=r"omega_n_rot=853\.28 rad/s gives ωn·h=0\.8533, past .*\. Use omega_n < 828\.4 rad/s and "
                r"omega_n_rot < 828\.4 rad/s, or time_step < 0\.0009709 s",
        )  # fmt: skip
        return
    coupling = builder.AddSystem(GodObjectCoupling(plant, gains, max_stretch_m=math.inf))
    path = [
        Waypoint(t=0.0, grasp="body"),
        Waypoint(t=0.05, grasp="body"),
        Waypoint(t=0.0501, xyz=[0.01, 0, 0], grasp="body"),
        Waypoint(t=1.0, xyz=[0.01, 0, 0], grasp="body"),
    ]
    device = builder.AddSystem(ScriptedDevice(path, period_s=H, guard=SampleGuard(max_speed_m_s=math.inf)))
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(
        coupling.GetOutputPort("generalized_force"), plant.get_applied_generalized_force_input_port()
    )
    loop = run_guarded(builder.Build(), 0.3)
    assert loop.diagnosis is None
    x = plant.GetPositions(plant.GetMyContextFromRoot(loop.context))
    assert abs(x[4] - 0.01) < 1e-6  # settled on the step to a micrometre


def test_stiff_implicit_coupling_stays_stable_where_explicit_is_refused():
    """Pass: the grasper at ωn = 2000 rad/s (2.4 × the explicit limit at h = 1 ms): ``cartesian``
    is refused, ``joint_pd_sap`` (SAP's implicit PD) runs without diverging."""
    argv = ["--omega-n", "2000", "--duration", "0.5"]
    assert_refused(
        lambda: run_scene("laparoscopy", *argv, "--coupling", "cartesian"), CouplingGainError,
        value=r"coupling='cartesian' with omega_n=2000", limit=r"spectral radius \d+\.\d+ ≥ 1",
        fix=r"use coupling='joint_pd_sap' \(implicit\)",
    )  # fmt: skip
    result = run_scene("laparoscopy", *argv, "--coupling", "joint_pd_sap")
    metrics, states = result.metrics, result.states
    assert not metrics["diverged"], metrics["diagnosis"]
    assert np.all(np.isfinite(states))


# -- 2. a 1 m device teleport in one sample ---------------------------------------------------


@pytest.mark.parametrize("guarded", [False, True])
def test_one_metre_teleport_is_bounded_by_the_force_cap(guarded):
    """Pass: the wrench never exceeds the cap ``m ωn² · 0.2 m`` plus gravity compensation (the
    spring alone would give 5 × that, and the one-sample velocity 1 m/1 ms 100 × more), the run
    does not diverge, and the brick settles on the new target. With the device's jump guard on
    (the default) the jump is first held back as a glitch, then accepted as a relocation."""
    a, b = [-0.1, 0.0, 0.1], [-0.1, 0.9, 0.1]  # 1 m in y, in free air above the table
    path = [
        Waypoint(t=0.0, xyz=a, grasp="brick"),
        Waypoint(t=0.2, xyz=a, grasp="brick"),
        Waypoint(t=0.2005, xyz=b, grasp="brick"),
        Waypoint(t=5.0, xyz=b, grasp="brick"),
    ]
    guard = None if guarded else SampleGuard(max_speed_m_s=math.inf)
    r = run(path, 2.5, guard=guard)
    assert r.loop.diagnosis is None
    F = r.terms[:, TERMS_LAYOUT["F_Go_W"]]
    cap, _ = r.coupling.force_caps(r.coupling.bodies["brick"])
    assert cap == pytest.approx(BRICK_MASS * 40.0**2 * 0.2)
    assert np.max(np.linalg.norm(F[:, 3:], axis=1)) <= cap + BRICK_MASS * G + 1e-12
    assert np.sum(r.terms[:, TERMS_LAYOUT["capped"]] > 0.5) > 10  # the cap acted, and was counted
    assert np.linalg.norm(brick_p(r.x)[-1] - b) < 1e-3  # there 2.3 s after the jump


# -- 3. the target held 5 cm inside an obstacle for 10 s -----------------------------------------


@pytest.mark.slow
def test_target_held_5cm_inside_the_baseplate_for_10_s():
    """Pass: pressed by the target 5 cm below it for 10 s, the brick stays on the baseplate
    (centre within 0.1 mm of its resting height: no tunnelling), and comes to rest (speed
    below 1 mm/s for the last 9 s: the energy stays bounded)."""
    inside = [-0.1, 0.0, REST_Z - 0.05]
    path = [
        Waypoint(t=0.0, xyz=[-0.1, 0.0, REST_Z], grasp="brick"),
        Waypoint(t=0.05, xyz=inside, grasp="brick"),
        Waypoint(t=10.0, xyz=inside, grasp="brick"),
    ]
    r = run(path, 10.0)
    assert r.loop.diagnosis is None
    z = brick_p(r.x)[:, 2]
    assert np.all(np.abs(z - REST_Z) < 1e-4), f"centre height range {z.min():.5f}..{z.max():.5f} m"
    assert np.max(np.linalg.norm(brick_v(r.x, r.plant)[r.t > 1.0], axis=1)) < 1e-3


# -- 4. a 2 mm wall crossed by the device at 2 m/s ----------------------------------------------------


@pytest.mark.parametrize("h", [1e-3, 0.5e-3])
def test_thin_wall_crossed_at_2_m_s_does_not_pop_through(h):
    """Pass: the device sweeps through a 2 mm wall at 2 m/s and stays 20 cm past it. The brick
    (pulled to 2.3 m/s) never gets its leading face past the wall's far face, ends on the near
    side, and its deepest penetration is at most what it travels in one step, v h (point
    contact exists only once the shapes overlap: 2.3 mm at h = 1 ms, more than the wall's
    thickness, yet the contact catches it; measured 1.3 mm at 1 ms, 0.3 mm at 0.5 ms)."""
    wall_x, thickness = -0.05, 0.002  # clear of the scene's own wall at x = 0 (the path passes above it)

    def thin_wall(plant):
        add_box(plant, "thin_wall", (thickness, 0.2, 0.1), 0.0, RigidTransform([wall_x, 0.0, 0.05]))

    y, z = 0.0, 0.06  # the brick's bottom at 5.5 cm clears the scene's wall (4.8 cm)
    path = [
        Waypoint(t=0.0, xyz=[-0.15, y, z], grasp="brick"),
        Waypoint(t=0.1, xyz=[-0.15, y, z], grasp="brick"),
        Waypoint(t=0.25, xyz=[0.15, y, z], grasp="brick"),  # 0.3 m in 0.15 s: 2 m/s
        Waypoint(t=1.2, xyz=[0.15, y, z], grasp="brick"),
    ]
    r = run(path, 1.2, extra=[thin_wall], h=h)
    assert r.loop.diagnosis is None
    front = brick_p(r.x)[:, 0] + HALF[0]  # the brick's leading face (it stays level)
    near, far = wall_x - thickness / 2, wall_x + thickness / 2
    v_max = np.max(brick_v(r.x, r.plant)[:, 0])
    assert v_max > 2.0
    assert np.max(front) < far
    assert np.max(front) - near <= v_max * h
    assert abs(front[-1] - near) < 1e-4  # at rest against the near face


# -- 5. mass ratio 1000:1 ------------------------------------------------------------------------------


def test_light_god_object_against_a_1000_times_heavier_block():
    """Pass: the 2.3 g brick pushed by its device 5 cm into a 2.3 kg block resting on the
    table does not diverge, stops at the block's face (within 1 mm) and moves the block less
    than 1 mm: the coupling's force (at most its cap, 0.74 N) is below the block's friction,
    0.5 · 2.3 kg · g = 11 N."""
    block_x, face = -0.08, -0.10  # a 4 cm cube; its face toward the brick

    def heavy(plant):
        add_box(plant, "block", (0.04, 0.04, 0.04), 1000 * BRICK_MASS)

    end = [face + 0.05 - HALF[0], 0, 0.02]  # the brick's leading face 5 cm inside the block
    path = [
        Waypoint(t=0.0, xyz=[-0.16, 0, 0.02], grasp="brick"),
        Waypoint(t=0.5, xyz=end, grasp="brick"),
        Waypoint(t=2.0, xyz=end, grasp="brick"),
    ]
    diagram, plant, _, _ = hard_scene(path, extra=[heavy])
    block = plant.GetBodyByName("block")
    plant.SetDefaultFloatingBaseBodyPose(block, RigidTransform([block_x, 0, 0.02]))
    loop = run_guarded(diagram, 2.0)
    assert loop.diagnosis is None
    context = plant.GetMyContextFromRoot(loop.context)
    p_block = block.EvalPoseInWorld(context).translation()
    p_brick = plant.GetBodyByName("brick").EvalPoseInWorld(context).translation()
    assert abs(p_block[0] - block_x) < 1e-3
    assert abs(p_brick[0] + HALF[0] - face) < 1e-3


def test_heavy_god_object_pushes_a_1000_times_lighter_brick():
    """Pass: a 2.3 kg god-object (a 4 cm cube) pushes the 2.3 g brick 5 cm along the table
    without diverging; the brick moves with it (≥ 4 cm) and its centre stays within 1 mm of
    its resting height (neither sinking into the table nor thrown up)."""

    def heavy(plant):
        add_box(plant, "pusher", (0.04, 0.04, 0.04), 1000 * BRICK_MASS)

    start, end = [-0.15, 0.0, 0.02], [-0.10, 0.0, 0.02]
    path = [
        Waypoint(t=0.0, xyz=start, grasp="pusher"),
        Waypoint(t=0.3, xyz=start, grasp="pusher"),
        Waypoint(t=1.3, xyz=end, grasp="pusher"),
        Waypoint(t=2.0, xyz=end, grasp="pusher"),
    ]
    gap = 0.001  # between the pusher's face and the brick's back face at the start
    diagram, plant, logs, _ = hard_scene(path, extra=[heavy], brick_xyz=[-0.13 + HALF[0] + gap, 0.0, REST_Z])
    plant.SetDefaultFloatingBaseBodyPose(plant.GetBodyByName("pusher"), RigidTransform(start))
    loop = run_guarded(diagram, 2.0)
    assert loop.diagnosis is None
    p = brick_p(logs["state"].FindLog(loop.context).data().T)
    assert p[-1, 0] - p[0, 0] > 0.04
    assert np.all(np.abs(p[:, 2] - REST_Z) < 1e-3)


# -- 6. device at 30 Hz with 50 ms of delay --------------------------------------------------------------


def test_device_at_30_hz_with_50_ms_delay_lags_by_d_plus_half_a_period():
    """Pass: stable, and in steady motion at v = 0.1 m/s the brick lags the true path by
    v (d + T/2) = 0.1 (0.05 + 1/60) = 6.7 mm within 5 %: the delay plus the zero-order hold's
    half period. The coupling itself adds no lag on a ramp: its damping acts on v_T − v_G,
    and the device reports the path's velocity."""
    v, d, T = 0.1, 0.05, 1.0 / 30.0
    a, b = [-0.15, 0.05, 0.06], [0.05, 0.05, 0.06]  # z = 6 cm: clear of the 4.8 cm wall
    path = [Waypoint(t=0.0, xyz=a, grasp="brick"), Waypoint(t=2.0, xyz=b, grasp="brick")]
    r = run(path, 1.9, device_rate=30.0, latency=d)
    assert r.loop.diagnosis is None
    steady = (r.t > 1.0) & (r.t < 1.9)
    lag = (a[0] + v * r.t[steady]) - brick_p(r.x)[steady, 0]
    assert np.mean(lag) == pytest.approx(v * (d + T / 2), rel=0.05)


# -- 7. ten minutes of random device motion ---------------------------------------------------------


@pytest.mark.slow(seconds=340)  # on 2 cores of an AMD EPYC: under -n it starts first (conftest.py)
def test_ten_minutes_of_random_motion_stay_bounded():
    """Pass: 600 s of a random path (a new point every 0.25 s anywhere 7 cm or more inside the
    table's edges and clear of its wall, from 3 cm below the surface to 8 cm above it, so the
    brick is pushed into the table and dragged over it again and again, up to 0.6 m/s, turned
    by up to 90° each time): no divergence, no NaN, the brick never tunnels below the table
    (centre ≥ 4.3 mm), its kinetic energy stays below that of twice the device's top speed
    (½ m (2 v_max)²), and its quaternion stays unit (the safeguards renormalize it every 50 ms)."""
    rng = np.random.default_rng(7)
    pts = np.column_stack(
        [
            rng.uniform(-0.13, -0.05, 2401),
            rng.uniform(-0.07, 0.07, 2401),
            rng.uniform(REST_Z - 0.03, 0.08, 2401),
        ]
    )
    path = [
        Waypoint(t=0.25 * i, xyz=p.tolist(), rpy_deg=[0, 0, float(rng.uniform(-90, 90))], grasp="brick")
        for i, p in enumerate(pts)
    ]
    v_max = float(np.max(np.linalg.norm(np.diff(pts, axis=0), axis=1)) / 0.25)
    r = run(path, 600.0, brick_xyz=[-0.1, 0.0, REST_Z])
    assert r.loop.diagnosis is None and r.loop.sim_time_s == pytest.approx(600.0)
    assert np.all(np.isfinite(r.x))
    assert np.min(brick_p(r.x)[:, 2]) > REST_Z - 0.5e-3
    assert np.max(np.abs(np.linalg.norm(r.x[:, :4], axis=1) - 1.0)) < 1e-2
    kinetic = 0.5 * BRICK_MASS * np.sum(brick_v(r.x, r.plant) ** 2, axis=1)
    assert np.max(kinetic) < 0.5 * BRICK_MASS * (2 * v_max) ** 2
