"""Bad device input (issue 7): each case gets a clear error or a documented, counted safe behaviour.

README "Bad device input" lists what happens in each case. The device outputs are read after
simulating the device alone, sample by sample; ``device_status`` counts what the guard did.
"""

import math

import numpy as np
import pytest
from conftest import add_free_boxes, lego_run, load_script, run_guarded
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.coupling import CouplingGains, GodObjectCoupling
from godobject_drake.devices import (
    DEVICE_STATUS_KEYS,
    DeviceSource,
    SampleGuard,
    ScriptedDevice,
    Waypoint,
    read_increment_log,
)

T = 0.01  # device period (s)
Q = np.array([1.0, 0.0, 0.0, 0.0])


def device_from(samples: dict[int, object], guard=None) -> DeviceSource:
    """A device at 100 Hz reporting ``samples[k]`` at sample k (default: x = 1 mm · k, at rest in y, z)."""

    def sampler(t):
        k = round(t / T)
        return samples.get(k, (np.array([1e-3 * k, 0.0, 0.0]), Q, ""))

    return DeviceSource(sampler, period_s=T, guard=guard)


def run_device(device, k: int):
    """Outputs and status after sample k (simulate to just past k T)."""
    sim = Simulator(device)
    sim.AdvanceTo(k * T + 1e-6)
    c = sim.get_context()
    X = device.GetOutputPort("X_WD").Eval(c)
    status = DeviceSource.status_dict(device.GetOutputPort("device_status").Eval(c))
    return X.translation(), device.GetOutputPort("V_WD").Eval(c), status


@pytest.mark.parametrize(
    "bad",
    [
        (np.array([np.nan, 0, 0]), Q, ""),
        (np.array([np.inf, 0, 0]), Q, ""),
        (np.zeros(3), np.zeros(4), ""),  # zero quaternion
        (np.zeros(3), np.array([0.9, 0, 0, 0]), ""),  # norm 0.9: not a rotation
    ],
    ids=["nan", "inf", "zero-quaternion", "non-unit-quaternion"],
)
def test_invalid_sample_is_held_and_counted(bad):
    device = device_from({5: bad})
    p, V, status = run_device(device, 5)
    np.testing.assert_allclose(p, [4e-3, 0, 0], atol=1e-15)  # sample 4 held
    assert np.all(V == 0.0)  # held: at rest, no damping kick
    assert status["device_invalid_samples"] == 1 and status["device_samples"] == 6
    p, V, status = run_device(device, 6)  # the next good sample is taken (it is 2 mm from the held one)
    np.testing.assert_allclose(p, [6e-3, 0, 0], atol=1e-15)
    assert status["device_longest_gap_s"] == pytest.approx(T)


def test_dropout_holds_the_last_sample_and_reports_the_gap():
    # Samples 3..7 are missing (the tracker lost the marker for 50 ms).
    device = device_from(dict.fromkeys(range(3, 8)))
    p, V, status = run_device(device, 7)
    np.testing.assert_allclose(p, [2e-3, 0, 0], atol=1e-15)
    assert np.all(V == 0.0)
    assert status["device_dropped_samples"] == 5
    assert status["device_longest_gap_s"] == pytest.approx(5 * T)
    p, _, status = run_device(device, 8)  # back: 6 mm in one sample after 5 held ones is allowed
    np.testing.assert_allclose(p, [8e-3, 0, 0], atol=1e-15)
    assert status["device_rejected_jumps"] == 0


def test_single_absurd_jump_is_rejected_as_a_glitch():
    # 1 m in 10 ms is 100 m/s, past the 10 m/s guard: held back, then the path goes on.
    device = device_from({4: (np.array([1.0, 0, 0]), Q, "")})
    p, V, status = run_device(device, 4)
    np.testing.assert_allclose(p, [3e-3, 0, 0], atol=1e-15)
    assert status["device_rejected_jumps"] == 1 and np.all(V == 0.0)
    p, _, status = run_device(device, 5)
    np.testing.assert_allclose(p, [5e-3, 0, 0], atol=1e-15)
    assert status["device_relocations"] == 0


def test_confirmed_jump_is_a_relocation_at_rest():
    # The device really moved 1 m (a tracker re-acquired elsewhere): 3 agreeing samples confirm it.
    far = {k: (np.array([1.0 + 1e-3 * k, 0, 0]), Q, "") for k in range(4, 20)}
    device = device_from(far, guard=SampleGuard(confirm_samples=3))
    p, _, status = run_device(device, 5)
    np.testing.assert_allclose(p, [3e-3, 0, 0], atol=1e-15)  # two samples held back so far
    p, V, status = run_device(device, 6)
    np.testing.assert_allclose(p, [1.006, 0, 0], atol=1e-12)
    assert np.all(V == 0.0)  # the relocation is reported at rest: no 100 m/s velocity
    assert status["device_rejected_jumps"] == 2 and status["device_relocations"] == 1
    _, V, _ = run_device(device, 7)
    np.testing.assert_allclose(V[3:], [0.1, 0, 0], atol=1e-9)  # 1 mm per 10 ms afterwards


def test_status_keys_and_first_sample():
    assert DEVICE_STATUS_KEYS[0] == "device_samples"
    with pytest.raises(ValueError, match=r"first sample \(t = 0\) is missing"):
        DeviceSource(lambda t: None, period_s=T)
    with pytest.raises(ValueError, match=r"first sample .* non-finite"):
        DeviceSource(lambda t: (np.array([np.nan, 0, 0]), Q, ""), period_s=T)


@pytest.mark.parametrize(
    "waypoint",
    [
        Waypoint(t=1.0, xyz=[0, math.nan, 0]),
        Waypoint(t=1.0, xyz=[0, 0]),
        Waypoint(t=1.0, rpy_deg=[0, math.inf, 0]),
    ],
    ids=["nan-xyz", "two-xyz", "inf-rpy"],
)
def test_bad_waypoints_are_refused_naming_the_waypoint(waypoint):
    with pytest.raises(ValueError, match=r"waypoint 1 \(t=1\.0\) needs a finite t, 3 finite xyz"):
        ScriptedDevice([Waypoint(t=0.0), waypoint])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"max_speed_m_s": 0.0}, "max_speed_m_s=0.0 must be > 0"),
        ({"confirm_samples": 0}, "confirm_samples=0 must be an integer ≥ 1"),
        ({"quaternion_tolerance": 1.5}, r"quaternion_tolerance=1\.5 must be in \(0, 1\)"),
    ],
)
def test_bad_guard_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SampleGuard(**kwargs)


HEADER = "t,dx,dy,dz,drx,dry,drz,clutch,grasp\n"


@pytest.mark.parametrize(
    "text, message",
    [
        (HEADER + "0,0,0,0,0,0,0,2,\n", r"inc\.csv:2: clutch is '2'; it must be 0 .* or 1"),
        (HEADER + "0.1,0,0,0,0,0,0,0,\n0.1,0,0,0,0,0,0,0,\n", r"inc\.csv:3: time 0\.1 is not after"),
        (HEADER + "0.2,0,0,0,0,0,0,0,\n0.1,0,0,0,0,0,0,0,\n", r"inc\.csv:3: time 0\.1 is not after"),
        ("t,dx,dy,dz,clutch\n0,0,0,0,0\n", r"inc\.csv:1: header must be t,dx,dy,dz,drx,dry,drz,clutch,grasp"),
        (HEADER + "0,0,0,0,0,0\n", r"inc\.csv:2: expected 9 columns"),
        (HEADER + "0,0,nan,0,0,0,0,0,\n", r"inc\.csv:2: non-finite"),
    ],
    ids=["clutch-2", "duplicate", "out-of-order", "missing-columns", "short-row", "nan"],
)
def test_bad_increment_logs_name_file_and_line(tmp_path, text, message):
    path = tmp_path / "inc.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_increment_log(path)


def test_unknown_grasp_name_in_a_scene_is_a_clear_command_line_error(tmp_path, capsys):
    log = tmp_path / "log.csv"
    log.write_text("t,x,y,z,qw,qx,qy,qz,grasp\n0,-0.1,0,0.0048,1,0,0,0,hammer\n")
    lego = load_script("diagrams/lego.py")
    with pytest.raises(SystemExit):
        lego.main(["--device", "replay", "--device-log", str(log), "--duration", "0.1", "--no-progress"])
    assert "unknown body 'hammer'" in capsys.readouterr().err


def test_scene_metrics_report_the_guard():
    # A guard set below the path's speed (5 cm/s; the brick is carried at 13 cm/s from t = 0.5 s):
    # every fast sample is held back, the target waits, and the metrics say so.
    m = lego_run("--duration", "1.0", "--max-device-speed", "0.05").metrics
    assert m["device_samples"] == 60 and m["device_invalid_samples"] == 0
    assert m["device_rejected_jumps"] >= 25 and m["device_longest_gap_s"] >= 0.4
    assert not m["diverged"]


def test_diverging_run_stops_with_a_diagnosis_not_nans():
    # Gains 1.5 × past the explicit limit (check turned off on purpose): the body's error grows
    # by |z| > 1 per step until the speed check stops the run.
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-2, (1.0,), gravity=False)
    gains = CouplingGains(omega_n=1.5 * 0.8284 / 1e-2, zeta=1.0)
    path = [Waypoint(t=0.0, grasp="body_0"), Waypoint(t=1.0, xyz=[0.01, 0, 0], grasp="body_0")]
    device = builder.AddSystem(ScriptedDevice(path))
    # No force cap: with it the growth stops at a bounded limit cycle (tests/test_hard_cases.py).
    coupling = builder.AddSystem(GodObjectCoupling(plant, gains, check_gains=False, max_stretch_m=math.inf))
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(coupling.GetOutputPort("spatial_forces"), plant.get_applied_spatial_force_input_port())
    loop = run_guarded(builder.Build(), 20.0)
    assert loop.diagnosis is not None and "velocity" in loop.diagnosis and "> 1000" in loop.diagnosis
    assert loop.sim_time_s < 20.0
    x = plant.GetPositionsAndVelocities(plant.GetMyContextFromRoot(loop.context))
    assert np.all(np.isfinite(x))  # stopped before the state became NaN
