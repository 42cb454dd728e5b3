"""The articulated tool's local model (issue 53 item 3; docs/local_model.md "An articulated
tool"): the trocar's lever mapping the feedback's stiffness to the device, checked against a
finite difference of the feedback itself (Drake's poses of the tool's bodies, paper Eq. 8, the
joints' forces mapped by the trocar: a second method), and the model a scene publishes."""

import numpy as np
import pytest
from pydrake.multibody.tree import BodyIndex
from test_pose_to_joints import pose_scene

from godobject_drake.station.articulated_model import lever_matrices
from godobject_drake.station.build import build_station
from godobject_drake.systems.articulated import generalized_forces


@pytest.fixture(scope="module")
def grasper():
    s = pose_scene([{"t": 0.0, "xyz": [0.0, 0.0, 0.06]}, {"t": 1.0, "xyz": [0.0, 0.0, 0.06]}], kd=21.07)
    s.feedback.gamma_d, s.feedback.kd_rot = 0.3, 0.02
    station = build_station(s)
    mapped = station.diagram.GetSubsystemByName("pose_to_joints")
    return station, mapped


def _device_force(station, mapped, q_target, q_actual):
    """The force the device is sent with the tool's joints at ``q_actual`` and their targets at
    ``q_target`` (device joints' order), at rest: Eq. 8 on Drake's poses of the tool's bodies, the
    joints' forces, the trocar's ``Jᵀ f = τ``."""
    tool, plant = station.coupling.tool, station.plant
    feedback = station.god_object.feedback
    targets = tool.body_targets(q_target)
    ctx = plant.CreateDefaultContext()
    q = plant.GetPositions(ctx).copy()
    q[tool.q_device] = q_actual
    plant.SetPositions(ctx, q)
    poses = [plant.EvalBodyPoseInWorld(ctx, plant.get_body(BodyIndex(i))) for i in range(plant.num_bodies())]
    vels = [
        plant.EvalBodySpatialVelocityInWorld(ctx, plant.get_body(BodyIndex(i)))
        for i in range(plant.num_bodies())
    ]
    tau = generalized_forces(tool, feedback.wrenches(poses, vels, targets), q_target)
    q4, tau4 = q_target[mapped._index], tau[mapped._index]
    return mapped.trocar.device_wrench(q4, tau4)[3:]


@pytest.mark.parametrize("tip", [[0.0, 0.0, 0.04], [0.012, -0.008, 0.03]])
def test_the_levers_stiffness_is_the_feedbacks_force_differenced_at_the_device(grasper, tip):
    """``K = J⁻ᵀ Kq J⁻¹`` against the central difference of the device's force as the tool's
    tip is displaced 1 µm along each axis from its target (the joints by the trocar's inverse, the
    roll and jaws kept): equal to 1e-6 of its largest entry. Stiffer along the tube than across
    it (by hand: 3 kd along it)."""
    station, mapped = grasper
    trocar = mapped.trocar
    p_T = trocar.p_WP + np.asarray(tip)
    q_target = np.zeros(len(mapped.device_joints))
    q_target[mapped._index] = trocar.inverse(p_T, np.eye(3))
    q4 = q_target[mapped._index]
    _, R_T = trocar.forward(q4)
    tool = station.coupling.tool
    v_trocar = [list(tool.v_device)[i] for i in mapped._index[:3]]
    K, D = lever_matrices(tool, trocar, q_target, q4, v_trocar, station.god_object.feedback.gains)
    step, K_fd = 1e-6, np.zeros((3, 3))
    for j in range(3):
        forces = []
        for sign in (1.0, -1.0):
            q_actual = q_target.copy()
            moved = trocar.inverse(p_T + sign * step * np.eye(3)[j], R_T)
            moved[3] = q4[3]  # the handle's twist is its own: the roll kept
            q_actual[mapped._index] = moved
            forces.append(_device_force(station, mapped, q_target, q_actual))
        K_fd[:, j] = (forces[0] - forces[1]) / (2 * step)
    np.testing.assert_allclose(K, K_fd, rtol=0, atol=1e-6 * np.max(np.abs(K)))
    axis = R_T[:, 2]
    along, across = axis @ K @ axis, np.linalg.eigvalsh(K)[-1]
    print(f"tip {tip}: K along the tube {along:.4g} N/m, stiffest across {across:.4g} N/m")
    # by hand: the insertion moves the tube and both jaws with the tip, so along the tube K is
    # 3 kd and D 3 γd (the rotational gains see no rotation); across, the tube's centre of mass
    # (the handle's, far above the pivot) moves several times the tip's motion
    assert along == pytest.approx(3 * 21.07, rel=1e-9) and axis @ D @ axis == pytest.approx(0.9, rel=1e-9)
    assert across > 10 * along


def test_the_lever_is_no_spring_closer_to_the_pivot_than_the_trocars_least_insertion(grasper):
    """At 9 mm below the pivot (the trocar's least insertion: 10 mm) the device's wrench is zero
    (``device_wrench``), and so is the model's spring: no 1/d² stiffness near the pivot; at
    11 mm, ``K`` is the lever's (63.2 N/m along the tube)."""
    station, mapped = grasper
    trocar, tool = mapped.trocar, station.coupling.tool
    v_trocar = [list(tool.v_device)[i] for i in mapped._index[:3]]
    for depth, along in ((0.009, 0.0), (0.011, 3 * 21.07)):
        q = np.zeros(len(mapped.device_joints))
        q[mapped._index] = trocar.inverse(trocar.p_WP + np.array([0.0, 0.0, -depth]), np.eye(3))
        K, D = lever_matrices(tool, trocar, q, q[mapped._index], v_trocar, station.god_object.feedback.gains)
        assert K[2, 2] == pytest.approx(along, rel=1e-9) and (along > 0 or not np.any(D))


# -- a driver process pressing the FEM uterus through the trocar ----------------------------------------


def fem_press_realtime(duration_s: float):
    """:func:`test_pose_to_joints.fem_press` on the shipped real-time organ (``organs.model=fem``
    and the scene's own ``organs:`` fields: 4 cells, h = 10 ms), the feedback spring matched to
    the coupling's at the tip; and ``analyze``'s tissue stiffness there."""
    import dataclasses

    from conftest import scenario
    from test_pose_to_joints import DOWN

    from godobject_drake.config import devices as dk
    from godobject_drake.config.device_files import Waypoint
    from godobject_drake.studies.analyze import analyze

    s = scenario("laparoscopy", "--duration", str(duration_s))
    s.organs = dataclasses.replace(s.organs, model="fem")
    s.device = dk.Scripted(waypoints=[
        Waypoint(t=0.0, xyz=[0.0, 0.0, 0.06], grasp="*"), Waypoint(t=0.1, xyz=DOWN, grasp="*"),
        Waypoint(t=max(duration_s, 0.2), xyz=DOWN, grasp="*"),
    ], rate_hz=60.0)  # fmt: skip
    tissue = analyze(s, quick=True, verify=False)["tissue"]
    station = build_station(s)
    plant, tool = station.plant, station.coupling.tool
    v = plant.GetJointByName("insertion", plant.GetModelInstanceByName("grasper")).velocity_start()
    q_end = station.device.samples(max(duration_s, 0.2))[-1]
    per_kd = sum(float(J[3:, v] @ J[3:, v]) for J in tool.com_jacobians(q_end))
    s.feedback.kd = tissue["tool_stiffness_n_m"] / per_kd
    return s, tissue["stiffness_n_m"]


HOLD_HAND = {"waypoints": [{"t": 0.0, "xyz": [0.0, 0.0, 0.01], "grasp": True},
                           {"t": 1.0, "xyz": [0.0, 0.0, -0.02], "grasp": True},
                           {"t": 600.0, "xyz": [0.0, 0.0, -0.02], "grasp": True}]}  # fmt: skip


def driver_press(tmp_path, s, hold_s: float, *flags):
    """The emulated hand (a ``godobject-driver`` process, 0.1 kg handle on 400 N/m and 8 N·s/m)
    takes the handle 3 cm down in 1 s of wall time and holds; the scene (``s``, its device an
    ``!Lcm`` on loopback 5 cm below the world's frame) runs its duration. Returns the run, the
    driver's log and summary, and what was measured at the hold (the last ``hold_s`` of scene
    time): the trips while the scene ran, the force's ripple (peak to peak of its norm), the
    work the device did on the handle over the run (J), the force rendered up (median) and the
    tissue's indentation (the scene's, over its last 50 ms)."""
    import json

    from test_driver import free_port, rendered, start_driver, trips_and_work
    from test_pose_to_joints import pressed

    from godobject_drake.config import devices as dk
    from godobject_drake.driver import process as drv
    from godobject_drake.simulation import simulate

    url = f"udp://127.0.0.1:{free_port()}"
    s.device = dk.Lcm(url=url, start_xyz=[0.0, 0.0, 0.06], rate_hz=1000.0,
                      device_to_world=dk.DeviceToWorld(xyz=[0.0, 0.0, 0.05]))  # fmt: skip
    driver = start_driver(tmp_path, url, "--exit-on-stop", "--duration", "600", *flags, hand=HOLD_HAND)
    try:
        result = simulate(build_station(s), progress=False)
        assert driver.wait(timeout=120) == 0, driver.stderr.read()
    finally:
        driver.kill()
    log = drv.read_log(tmp_path / "driver.csv")
    summary = json.loads((tmp_path / "driver.json").read_text())
    f = rendered(log)
    trips, work = trips_and_work(log)
    hold = (log["state"] != "stopped") & (log["t_scene"] >= s.simulation.duration_s - hold_s)
    norm = np.linalg.norm(f, axis=1)
    F, u = pressed(result)
    out = {
        "trips": trips, "ripple_N": float(np.ptp(norm[hold])) if hold.any() else np.nan, "work_J": work,
        "force_N": float(np.median(f[hold, 2])) if hold.any() else np.nan, "u_m": u,
        "hold_rows": int(hold.sum()), "scene_force_N": float(F[5]),
        "models": summary["local_model"]["models"], "heartbeats": summary["local_model"]["heartbeats"],
        "rtf": result.metrics.get("realtime_factor"),
    }  # fmt: skip
    return result, log, out


def _check_press(result, out, k):
    print(f"from the driver: {out}; analyze {k:.4g} N/m, felt {out['force_N'] / out['u_m']:.4g}")
    m = result.metrics
    assert not m["diverged"] and m["tool_tip_inside_tissue_steps"] == 0
    assert out["models"] > 0 and out["hold_rows"] > 100
    assert out["trips"] == 0 and out["ripple_N"] <= 0.05 and out["work_J"] <= 0.5e-3
    assert 0.5e-3 < out["u_m"] < 2e-3
    assert out["force_N"] / out["u_m"] == pytest.approx(k, rel=0.15)


@pytest.mark.realtime  # no trip, no ripple: the scene's and the driver's loops kept on time
@pytest.mark.slow(seconds=60)
def test_a_driver_process_presses_the_realtime_fem_uterus_through_the_trocar_on_the_local_model(tmp_path):
    """The shipped real-time organ (4 cells, h = 10 ms) pressed through the trocar from the
    emulated driver process for 3 s of scene time (:func:`driver_press`), held over its last
    second: the driver renders the grasper's local model (the lever's matrix, the tissue's plane
    and stiffness): no watchdog trip while the scene runs, a ripple ≤ 0.05 N at the hold,
    ≤ +0.5 mJ of work on the handle, the force rendered over the tissue's indentation within
    15 % of ``analyze``'s stiffness. Measured: docs/results.md "The grasper's local model"."""
    s, k = fem_press_realtime(3.0)
    result, _, out = driver_press(tmp_path, s, 1.0)
    _check_press(result, out, k)


@pytest.mark.realtime  # no trip, no ripple: the scene's and the driver's loops kept on time
@pytest.mark.slow(seconds=150)
def test_a_driver_process_presses_the_reference_fem_uterus_through_the_trocar_on_the_local_model(tmp_path):
    """The same on the reference organ (8 cells, h = 1 ms, about 0.01 of real time here: a
    model every 0.3 to 1.3 s of wall time, the heartbeat between them), 0.4 s of scene time held
    over its last 0.1 s."""
    from test_pose_to_joints import fem_press

    s, k = fem_press(0.4)
    result, _, out = driver_press(tmp_path, s, 0.1)
    _check_press(result, out, k)


def test_a_scene_whose_models_come_slowly_is_vouched_for_six_of_its_intervals_at_most_five_seconds():
    """The FEM uterus at h = 1 ms sends a model every 0.3 to 0.6 s of wall time: the heartbeat
    vouches for each for 6 times the median of the last 16 intervals (2.4 s at 0.4 s), not the
    0.5 s of a fast scene (a model every 10 ms: 0.5 s still), at most 5 s (models 2 s apart);
    one long interval does not move the median; a run again starts over."""
    from godobject_drake.link.scene_model import BEAT_S, SceneHeartbeat

    beat = SceneHeartbeat(lambda raw: None, clock=lambda: 0.0)
    beat._thread = "not started"  # the decisions alone: no thread
    for k in range(10):
        beat.model_sent(k, now=0.01 * k)
    assert beat.limit() == 0.5
    t = 0.0
    for k in range(10, 20):
        t += 0.4
        beat.model_sent(k, now=t)
    assert beat.limit() == pytest.approx(2.4)  # the median of 6 intervals of 10 ms, 10 of 0.4 s
    assert beat.tick(t + 2.4 - 1e-9) and not beat.tick(t + 2.4 + 1e-9)
    beat.model_sent(20, now=t + 3.0)  # one long interval: the median stays
    assert beat.limit() == pytest.approx(2.4)
    for k in range(21, 40):
        beat.model_sent(k, now=t + 3.0 + 2.0 * (k - 20))
    assert beat.limit() == 5.0
    beat.stop()
    beat.model_sent(40, now=1000.0)
    assert beat.limit() == 0.5 and beat.tick(1000.0 + 2 * BEAT_S)
    beat.stop()


def test_the_factorised_compliance_is_analyzes_contact_stiffness():
    """:class:`OrganCompliance` (the organ's matrix factorised once, what the scene asks at its
    rate) against ``analyze``'s :func:`contact_stiffness` (a sparse solve each) on the shipped
    real-time organ: the same stiffness to 1e-9 at five points of its top, straight down and
    slanted."""
    import dataclasses

    from conftest import scenario

    from godobject_drake.systems.tissue_stiffness import OrganCompliance, contact_stiffness, ray_surface_hit

    s = scenario("laparoscopy")
    s.organs = dataclasses.replace(s.organs, model="fem")
    organ = build_station(s).god_object.tissue
    compliance = OrganCompliance(organ)
    for x, y, slant in (
        (0.0, 0.0, 0.0),
        (0.01, 0.0, 0.0),
        (-0.012, 0.008, 0.0),
        (0.0, 0.0, 0.3),
        (0.005, -0.01, -0.2),
    ):
        origin, d = np.array([x, y, 0.1]), np.array([np.sin(slant), 0.0, -np.cos(slant)])
        _, tri, w, _ = ray_surface_hit(organ.rest_W, organ.triangles, origin, d)
        k = contact_stiffness(organ, origin, d)["stiffness_n_m"]
        assert compliance.stiffness(tri, w, d) == pytest.approx(k, rel=1e-9)
        assert 100.0 < k < 5000.0
