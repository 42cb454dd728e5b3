"""Device sources: sampling, hold, latency, velocity, CSV replay and its errors."""

import numpy as np
import pytest
from pydrake.math import RigidTransform

from godobject_drake.config.device_files import (
    IncrementLog,
    Waypoint,
    read_device_log,
    write_device_log,
    write_increment_log,
)
from godobject_drake.devices.sources import DeviceSource, RelativeDevice, ReplayDevice, ScriptedDevice

PATH = [
    Waypoint(t=0.0, xyz=[0.0, 0.0, 0.0], grasp=""),
    Waypoint(t=1.0, xyz=[0.6, 0.0, 0.0], rpy_deg=[0, 0, 90], grasp="brick_0"),
    Waypoint(t=2.0, xyz=[0.6, 0.3, 0.0], rpy_deg=[0, 0, 90], grasp=""),
]


def outputs_at(device, t):
    """Device outputs after simulating it alone to time t."""
    from pydrake.systems.analysis import Simulator

    simulator = Simulator(device)
    simulator.AdvanceTo(t)
    context = simulator.get_context()
    X = device.GetOutputPort("X_WD").Eval(context)
    return X, device.GetOutputPort("V_WD").Eval(context), device.GetOutputPort("grasp").Eval(context)


def test_scripted_device_samples_and_holds():
    device = ScriptedDevice(PATH, period_s=0.1)
    # Between samples the output holds the sample of t = 0.5 (0.3 m, 45°): zero-order hold.
    X, V, grasp = outputs_at(device, 0.55)
    np.testing.assert_allclose(X.translation(), [0.3, 0, 0], atol=1e-12)
    assert X.rotation().ToRollPitchYaw().yaw_angle() == pytest.approx(np.pi / 4)
    # Backward difference of the last two samples: 0.06 m and 9° per 0.1 s.
    np.testing.assert_allclose(V, [0, 0, np.radians(90) / 10 / 0.1, 0.6, 0, 0], atol=1e-9)
    assert grasp == ""
    assert outputs_at(device, 1.05)[2] == "brick_0"


def test_latency_delays_the_samples():
    X, _, _ = outputs_at(ScriptedDevice(PATH, period_s=0.1, latency_s=0.2), 0.55)
    np.testing.assert_allclose(X.translation(), [0.18, 0, 0], atol=1e-12)  # the path at t = 0.3


def test_noise_is_seeded():
    a = ScriptedDevice(PATH, noise_m=1e-3, seed=3).samples(0.5)
    b = ScriptedDevice(PATH, noise_m=1e-3, seed=3).samples(0.5)
    c = ScriptedDevice(PATH, noise_m=1e-3, seed=4).samples(0.5)
    clean = ScriptedDevice(PATH).samples(0.5)
    pa, pb, pc, p0 = (np.array([s[1][0] for s in x]) for x in (a, b, c, clean))
    assert np.array_equal(pa, pb) and not np.allclose(pa, pc)
    # 31 samples (0.5 s at 60 Hz) of x: the sample std of σ = 1 mm is within ±13 % (1/√(2·30)) at one
    # standard error; the bounds are about 4 of them.
    assert 0.5e-3 < np.std(pa - p0) < 2e-3


def test_csv_round_trip_replays_exactly(tmp_path):
    scripted = ScriptedDevice(PATH, period_s=1 / 60)
    log = tmp_path / "path.csv"
    write_device_log(log, scripted.samples(2.0))
    replay = ReplayDevice(log, period_s=1 / 60)
    for (t, (p, q, g)), (_, (p2, q2, g2)) in zip(scripted.samples(2.0), replay.samples(2.0), strict=True):
        assert np.array_equal(p, p2) and np.allclose(q, q2, atol=1e-15) and g == g2, t


def write(tmp_path, text):
    path = tmp_path / "log.csv"
    path.write_text(text)
    return path


HEADER = "t,x,y,z,qw,qx,qy,qz,grasp\n"


@pytest.mark.parametrize(
    "text, message",
    [
        ("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n", r"log\.csv:1: header must be t,x,y,z,qw,qx,qy,qz,grasp"),
        (HEADER + "0,0,0,0,1,0,0,0,\n0,0,0,0,1,0,0,0,\n", r"log\.csv:3: time 0\.0 is not after"),
        (HEADER + "0,0,0,0,0.5,0,0,0,\n", r"log\.csv:2: quaternion .* norm 0\.5"),
        (HEADER + "0,nan,0,0,1,0,0,0,\n", r"log\.csv:2: non-finite"),
        (HEADER + "0,0,0\n", r"log\.csv:2: expected 9 columns"),
    ],
    ids=["missing-column", "duplicate-time", "non-unit-quaternion", "nan", "short-row"],
)
def test_bad_logs_name_file_and_line(tmp_path, text, message):
    with pytest.raises(ValueError, match=message):
        read_device_log(write(tmp_path, text))


def test_unsorted_waypoints_are_refused():
    with pytest.raises(ValueError, match="increase strictly"):
        ScriptedDevice([PATH[1], PATH[0]])


def test_linear_interpolation_is_one_period_late_and_smooth():
    device = ScriptedDevice(PATH, period_s=0.1, interpolation="linear")
    # At t = 0.55 the last two samples are t = 0.4 (0.24 m) and 0.5 (0.3 m): halfway between them.
    X, V, _ = outputs_at(device, 0.55)
    np.testing.assert_allclose(X.translation(), [0.27, 0, 0], atol=1e-12)
    assert X.rotation().ToRollPitchYaw().yaw_angle() == pytest.approx(np.radians(40.5))
    np.testing.assert_allclose(V[3:], [0.6, 0, 0], atol=1e-9)  # the slope it moves at


def test_multi_rate_30_hz_with_50_ms_latency():
    # Sample k = 16 at t = 16/30 s reports the path at 16/30 − 0.05 s: x = 0.6 m/s × 0.4833 s.
    X, _, _ = outputs_at(ScriptedDevice(PATH, period_s=1 / 30, latency_s=0.05), 0.55)
    np.testing.assert_allclose(X.translation(), [0.6 * (16 / 30 - 0.05), 0, 0], atol=1e-12)


def increments(rows):
    """An IncrementLog from rows (t, dp, drot, clutch, grasp)."""
    return IncrementLog(
        np.array([r[0] for r in rows], float),
        np.array([r[1] for r in rows], float),
        np.array([r[2] for r in rows], float),
        np.array([r[3] for r in rows], bool),
        [r[4] for r in rows],
    )


def test_relative_device_with_clutch_reproduces_a_known_path(tmp_path):
    dx, back = [0.025, 0, 0], [-0.025, 0, 0]
    rows = [(0.1 * k, dx, [0, 0, 0], False, "") for k in (1, 2, 3, 4)]  # 4 strokes: +0.1 m
    rows += [(0.1 * k, back, [0, 0, 0], True, "") for k in (5, 6, 7, 8)]  # clutch: mouse brought back
    rows += [(0.1 * k, dx, [0, 0, 0], False, "") for k in (9, 10, 11, 12)]  # +0.1 m again
    rows += [(1.3, [0, 0, 0], [0, 0, np.pi / 2], False, ""), (1.4, [0, 0.05, 0], [0, 0, 0], False, "brick_0")]
    log = tmp_path / "increments.csv"
    write_increment_log(log, increments(rows))
    device = RelativeDevice(log, RigidTransform([0, 0, 0.1]), period_s=1 / 60)
    expected = {0.05: [0, 0, 0.1], 0.45: [0.1, 0, 0.1], 0.85: [0.1, 0, 0.1], 1.25: [0.2, 0, 0.1],
                1.45: [0.2, 0.05, 0.1]}  # fmt: skip
    for t, p in expected.items():
        X, _, grasp = outputs_at(device, t)
        np.testing.assert_allclose(X.translation(), p, atol=1e-12, err_msg=f"t={t}")
    assert X.rotation().ToRollPitchYaw().yaw_angle() == pytest.approx(np.pi / 2)
    assert grasp == "brick_0"
    assert outputs_at(device, 1.25)[0].rotation().ToRollPitchYaw().yaw_angle() == pytest.approx(0.0)


class _Named(DeviceSource):
    """A device of one's own without a path of rows: its grasp names come from sampling it."""

    def __init__(self, end_time_s=None):
        if end_time_s is not None:
            self.end_time_s = end_time_s
        super().__init__(lambda t: (np.zeros(3), np.array([1.0, 0, 0, 0]), f"b{round(10 * t)}"), period_s=0.1)


def test_a_device_of_ones_own_names_what_it_reports_to_its_end():
    """Sampled at 10 Hz: to its end_time_s (0.3 s: b0..b3), or its first sample without one; a
    duration given is the span sampled."""
    assert _Named(0.3).grasp_names() == {"b0", "b1", "b2", "b3"}
    assert _Named().grasp_names() == {"b0"}
    assert _Named().grasp_names(0.2) == {"b0", "b1", "b2"}


def test_a_device_that_renders_no_feedback_adds_and_sends_nothing():
    """Only a device that renders the feedback itself (LCM) wires it and is sent a zero wrench."""
    device = _Named()
    assert device.zero_feedback(1.0) is False
    assert device.connect_feedback(None, None, {"b0"}) is None
    assert device.reversals(0.002) is None


def test_a_recorded_pose_device_replays_the_same_run_bit_for_bit(tmp_path):
    """The brick scene's scripted device with 1 mm of seeded noise and linear interpolation,
    recorded (``--record-devices``: every tick's sample, noise and latency applied: 8.5 s at 60 Hz
    is 510 rows, t = 0 to 8.5 s less a period: Drake's simulator stops before the events of the
    run's last instant) and replayed (``--replay-devices``: a Replay at 60 Hz with no latency or noise):
    the plant's state at every step is the same, bit for bit, and so is every metric but the
    device's kind."""
    from godobject_drake.config.scenario import replace, replaying_devices, shipped_scenario
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    log = tmp_path / "session.csv"
    changes = {"device.noise_m": 0.001, "device.interpolation": "linear", "device.latency_s": 0.02}
    s = replace(shipped_scenario("lego"), **changes, **{"recording.device_log": str(log)})
    first = simulate(build_station(s), progress=False)
    rows = log.read_text().splitlines()
    assert rows[0] == "t,x,y,z,qw,qx,qy,qz,grasp" and len(rows) == 1 + 510
    assert float(rows[-1].split(",")[0]) == pytest.approx(8.5 - 1 / 60)
    assert first.metrics["device_log_rows"] == 510 and first.metrics["device_logs"] == str(log)
    replay = replaying_devices(replace(s, **{"recording.device_log": ""}), log)
    assert (replay.device.noise_m, replay.device.latency_s, replay.device.interpolation) == (
        0.0,
        0.0,
        "linear",
    )
    again = simulate(build_station(replay), progress=False)
    assert np.array_equal(first.data["state"], again.data["state"])
    machine = {"wall_time_s", "cpu_time_s", "real_time_factor", "step_cost_us", "build_time_s",
               "metrics_time_s", "device", "device_logs", "device_log_rows"}  # fmt: skip
    assert {k: v for k, v in first.metrics.items() if k not in machine} == {
        k: v for k, v in again.metrics.items() if k not in machine
    }


def test_recording_a_device_is_refused_where_it_cannot_be_written_or_replayed(tmp_path):
    """A log in a folder that does not exist exits 2 naming it; a relative device's tether moves
    its target off the samples a replay would report, so it is refused; --replay-devices and
    --device together are refused."""
    import subprocess
    import sys

    def run(*args):
        command = [
            sys.executable,
            "-m",
            "godobject_drake",
            "run",
            "lego",
            "--no-progress",
            "--duration",
            "0.05",
        ]
        return subprocess.run([*command, *args], capture_output=True, text=True, timeout=300)

    done = run("--record-devices", str(tmp_path / "nowhere" / "log.csv"))
    assert done.returncode == 2 and "recording.device_log" in done.stderr and "nowhere" in done.stderr
    assert "Traceback" not in done.stderr
    done = run("--device", "relative", "--device-log", "models/lego/push_and_return.csv", "--tether", "0.002",
               "--record-devices", str(tmp_path / "log.csv"))  # fmt: skip
    assert done.returncode == 2 and "tether or control/display ratio" in done.stderr, done.stderr[-600:]
    done = run("--replay-devices", str(tmp_path / "log.csv"), "--device", "scripted")
    assert done.returncode == 2 and "--replay-devices sets every tool's device" in done.stderr
