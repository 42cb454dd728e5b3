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
