"""Live devices (``--device meshcat``): what the browser sends reaches the target.

The browser is replaced by the messages it would send over Meshcat's websocket (button
clicks, gamepad state; msgpack as in Drake's own tests) and by setting slider values.
"""

import msgpack
import numpy as np
import pytest
from conftest import build_scene
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator

from godobject_drake.config.gains import GRASP_NEAREST
from godobject_drake.devices.live import GRASP_BUTTON, STOP_BUTTON, MeshcatDevice, MeshcatJointDevice
from godobject_drake.simulation import simulate
from godobject_drake.systems.coupling import graspable_bodies
from godobject_drake.systems.drawing import start_meshcat

WORKSPACE = ([-0.2, -0.2, 0.0], [0.2, 0.2, 0.2])


@pytest.fixture(scope="module")
def meshcat():
    return start_meshcat(port=0)


def click(meshcat, name):
    meshcat._InjectWebsocketMessage(msgpack.packb({"type": "button", "name": name}))


def gamepad(meshcat, axes, buttons=(0.0,)):
    msg = {
        "type": "gamepad",
        "name": "",
        "gamepad": {"index": 0, "button_values": list(buttons), "axes": axes},
    }
    meshcat._InjectWebsocketMessage(msgpack.packb(msg))


def advance(device, simulator, t):
    simulator.AdvanceTo(t)
    c = simulator.get_context()
    return device.GetOutputPort("X_WD").Eval(c), device.GetOutputPort("grasp").Eval(c)


def test_sliders_keys_and_grasp_button_drive_the_target(meshcat):
    meshcat.Delete()
    meshcat.DeleteAddedControls()
    device = MeshcatDevice(meshcat, RigidTransform([0, 0, 0.05]), WORKSPACE, period_s=0.01)
    sim = Simulator(device)
    X, grasp = advance(device, sim, 0.005)
    np.testing.assert_allclose(X.translation(), [0, 0, 0.05], atol=1e-12)
    assert grasp == ""
    # The sliders (what the keys step) moved to x = 4 cm, yaw 0.3 rad: the next sample has them.
    device.sliders.SetPose(RigidTransform(RollPitchYaw(0, 0, 0.3), [0.04, 0, 0.05]))
    X, _ = advance(device, sim, 0.015)
    np.testing.assert_allclose(X.translation(), [0.04, 0, 0.05], atol=1e-9)
    assert RollPitchYaw(X.rotation()).yaw_angle() == pytest.approx(0.3, abs=1e-9)
    click(meshcat, GRASP_BUTTON)
    assert advance(device, sim, 0.025)[1] == GRASP_NEAREST
    click(meshcat, GRASP_BUTTON)
    assert advance(device, sim, 0.035)[1] == ""


def test_gamepad_stick_moves_the_target_at_its_speed(meshcat):
    meshcat.Delete()
    meshcat.DeleteAddedControls()
    device = MeshcatDevice(meshcat, RigidTransform([0, 0, 0.05]), WORKSPACE, period_s=0.01)
    sim = Simulator(device)
    advance(device, sim, 0.005)
    gamepad(meshcat, [1.0, 0.0, 0.0, -0.5])  # right at full speed, up at half
    X, _ = advance(device, sim, 0.505)
    # 0.1 m/s × 0.5 s in x, 0.05 m/s × 0.5 s in z (one sample's read lags by a period).
    np.testing.assert_allclose(X.translation(), [0.05, 0, 0.075], atol=0.1 * 0.011)
    gamepad(meshcat, [0.0, 0.0, 0.0, 0.0], buttons=(1.0,))  # sticks released, button 0 pressed
    X2, grasp = advance(device, sim, 0.6)
    np.testing.assert_allclose(X2.translation(), X.translation(), atol=0.1 * 0.011)
    assert grasp == GRASP_NEAREST


def test_live_brick_scene_grasps_the_nearest_brick_and_stops_on_the_button():
    station = build_scene("lego", "--device", "meshcat", "--duration", "30")
    click(station.meshcat, GRASP_BUTTON)  # the device starts on brick_0 (the scene path's start)
    click(station.meshcat, STOP_BUTTON)  # ... and the user stops at once
    result = simulate(station, progress=False)
    assert result.metrics["sim_time_s"] == pytest.approx(0.05)  # one 50 ms check, then Stop
    brick = graspable_bodies(station.plant)["brick_0"]
    assert result.held[-1] == brick.index
    assert not result.metrics["diverged"]


def test_live_joint_device_reads_its_sliders(meshcat):
    meshcat.Delete()
    meshcat.DeleteAddedControls()
    limits = [(-0.6, 0.6), (0.0, 0.15)]
    device = MeshcatJointDevice(meshcat, ["yaw", "insertion"], limits, [0.0, 0.05], period_s=0.01)
    sim = Simulator(device)
    sim.AdvanceTo(0.005)
    meshcat.SetSliderValue("device insertion", 0.09)
    sim.AdvanceTo(0.015)
    np.testing.assert_allclose(device.GetOutputPort("q_device").Eval(sim.get_context()), [0.0, 0.09])
    with pytest.raises(ValueError, match=r"channel yaw starts at 0\.9, outside its range \[-0\.6, 0\.6\]"):
        MeshcatJointDevice(meshcat, ["yaw"], [(-0.6, 0.6)], [0.9])


def slide(meshcat, name, value):
    """What any page on this machine can send: a slider value, unbounded (Meshcat keeps it as sent)."""
    meshcat._InjectWebsocketMessage(msgpack.packb({"type": "slider", "name": name, "value": value}))


def test_a_slider_value_past_the_workspace_is_held_to_it_on_the_server(meshcat):
    """A page sent x = 1000 m (it moved the target 1 km away before): the device holds it to the
    workspace's 0.2 m, counts it, and puts the slider back where the target is."""
    meshcat.Delete()
    meshcat.DeleteAddedControls()
    # 0.1 s between samples, so the sample guard's 10 m/s lets the held move (0.21 m) through
    device = MeshcatDevice(meshcat, RigidTransform([0, 0, 0.05]), WORKSPACE, period_s=0.1)
    sim = Simulator(device)
    advance(device, sim, 0.05)
    slide(meshcat, "x", 1000.0)
    slide(meshcat, "z", -3.0)
    assert meshcat.GetSliderValue("x") == 1000.0  # Meshcat itself does not bound it
    X, _ = advance(device, sim, 0.15)
    np.testing.assert_array_equal(X.translation(), [0.2, 0.0, 0.0])  # the workspace's corner
    assert meshcat.GetSliderValue("x") == 0.2 and meshcat.GetSliderValue("z") == 0.0
    assert device.status(device.GetMyContextFromRoot(sim.get_context()))["device_clamped_samples"] == 1
    advance(device, sim, 0.25)  # held: nothing more to count
    assert device.clamped == 1


def test_a_joint_slider_value_past_its_range_is_held_to_it(meshcat):
    meshcat.Delete()
    meshcat.DeleteAddedControls()
    device = MeshcatJointDevice(meshcat, ["yaw", "insertion"], [(-0.6, 0.6), (0.0, 0.15)], [0.0, 0.05])
    slide(meshcat, "device insertion", 1e6)
    slide(meshcat, "device yaw", float("nan"))
    np.testing.assert_array_equal(device.channel_values(0.0), [-0.6, 0.15])
    assert device.clamped == 2 and meshcat.GetSliderValue("device insertion") == 0.15


def test_live_workspace_must_contain_the_start(meshcat):
    with pytest.raises(ValueError, match=r"workspace .* must be a box containing the start point \[0\.5"):
        MeshcatDevice(meshcat, RigidTransform([0.5, 0, 0]), WORKSPACE)


def test_two_live_tools_each_have_their_own_sliders_and_only_theirs_move_them():
    """lego_two_hands with both hands on live sliders (each holding its brick from the start):
    each tool's controls carry its name (left_x, right_x, ...; the keys on the first only), and
    moving left_z up 2 cm lifts brick_2 (left's) by about that while brick_1 (right's) stays
    within 0.1 mm; then right_z lifts brick_1 and brick_2 stays put."""
    from godobject_drake.config import scenario as sc
    from godobject_drake.station.build import build_station

    live = (
        "{{device: !MeshcatSliders {{grasp: {b}, start_xyz: [-0.06, {y}, 0.0048], rate_hz: 60.0}}, "
        "workspace: {{lower_m: [-0.15, -0.10, 0.0], upper_m: [0.15, 0.10, 0.12]}}}}"
    )
    s = sc.shipped_scenario(
        "lego_two_hands",
        f"tools:\n  left: {live.format(b='brick_2', y=-0.05)}\n  right: {live.format(b='brick_1', y=0.05)}\n"
        "sleep: {enabled: false}",
    )
    meshcat = start_meshcat(port=0)
    station = build_station(s, meshcat)
    names = meshcat.GetSliderNames()
    for tool in ("left", "right"):
        assert {f"{tool}_{a}" for a in ("roll", "pitch", "yaw", "x", "y", "z")} <= set(names), names
    assert not {"x", "y", "z"} & set(names)  # no slider of the same name for two tools
    assert station.tools["left"].source.keys and not station.tools["right"].source.keys
    plant = station.plant
    simulator = Simulator(station.diagram)
    simulator.Initialize()
    context = plant.GetMyContextFromRoot(simulator.get_context())

    model = plant.GetModelInstanceByName
    bricks = {b: plant.GetBodyByName("brick", model(b)) for b in ("brick_1", "brick_2")}

    def heights():
        return {b: plant.EvalBodyPoseInWorld(context, body).translation()[2] for b, body in bricks.items()}

    simulator.AdvanceTo(0.3)
    z0 = heights()
    meshcat.SetSliderValue("left_z", 0.0048 + 0.02)
    simulator.AdvanceTo(1.0)
    z1 = heights()
    assert z1["brick_2"] - z0["brick_2"] == pytest.approx(0.02, abs=0.002), (z0, z1)
    assert abs(z1["brick_1"] - z0["brick_1"]) < 1e-4, (z0, z1)
    meshcat.SetSliderValue("right_z", 0.0048 + 0.03)
    simulator.AdvanceTo(1.7)
    z2 = heights()
    assert z2["brick_1"] - z1["brick_1"] == pytest.approx(0.03, abs=0.002), (z1, z2)
    assert abs(z2["brick_2"] - z1["brick_2"]) < 1e-4, (z1, z2)
