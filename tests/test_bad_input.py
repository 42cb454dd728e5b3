"""Bad device input (issue 7): each case gets a clear error or a documented, counted safe behaviour.

docs/guide/devices.md#bad-device-input lists what happens in each case. The device outputs are read after
simulating the device alone, sample by sample; ``device_status`` counts what the guard did.
"""

import math

import numpy as np
import pytest
from conftest import add_free_boxes, lego_run, load_script, run_guarded
from pydrake.math import RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config.device_files import DEVICE_STATUS_KEYS, SampleGuard, Waypoint, read_increment_log
from godobject_drake.config.gains import CouplingGains
from godobject_drake.devices.sources import DeviceSource, ScriptedDevice
from godobject_drake.systems.coupling import GodObjectCoupling

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


def grasp_after(device, k: int) -> str:
    """The grasp name the device reports after sample k."""
    sim = Simulator(device)
    sim.AdvanceTo(k * T + 1e-6)
    return device.GetOutputPort("grasp").Eval(sim.get_context())


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
    # The far samples also grasp "b": held-back samples change no grasp, the relocation does.
    far = {k: (np.array([1.0 + 1e-3 * k, 0, 0]), Q, "b") for k in range(4, 20)}
    device = device_from(far, guard=SampleGuard(confirm_samples=3))
    p, _, status = run_device(device, 5)
    np.testing.assert_allclose(p, [3e-3, 0, 0], atol=1e-15)  # two samples held back so far
    assert grasp_after(device, 5) == ""
    p, V, status = run_device(device, 6)
    np.testing.assert_allclose(p, [1.006, 0, 0], atol=1e-12)
    assert np.all(V == 0.0)  # the relocation is reported at rest: no 100 m/s velocity
    assert status["device_rejected_jumps"] == 2 and status["device_relocations"] == 1
    assert grasp_after(device, 6) == "b"
    # The relocation ends the gap: the longest is the two held-back samples, 2 T, not 3 T.
    assert status["device_longest_gap_s"] == pytest.approx(2 * T, rel=1e-12)
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
        (HEADER + "0,0,0,0,0,0,0,2,\n", r"inc\.csv:2: clutch is 2; it must be 0 .* or 1"),
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


# -- the guard at its boundaries (each a case a mutation run showed untested) ------------------
T64 = 1.0 / 64.0  # binary fractions: a step of max_speed · T is exact, so "≤" is tested on the dot


def device_on(positions: dict[int, object], guard, default=lambda k: [0.0, 0.0, 0.0], **kwargs):
    """A 64 Hz device reporting ``positions[k]`` (a position, None for a dropout, or a whole sample)."""

    def sampler(t):
        k = round(t / T64)
        value = positions.get(k, default(k))
        if value is None or isinstance(value, tuple):
            return value
        return np.array(value, float), Q, ""

    return DeviceSource(sampler, period_s=T64, guard=guard, **kwargs)


def state_after(device, k):
    sim = Simulator(device)
    sim.AdvanceTo(k * T64 + 1e-9)
    c = sim.get_context()
    status = DeviceSource.status_dict(device.GetOutputPort("device_status").Eval(c))
    return device.GetOutputPort("X_WD").Eval(c).translation(), status


def test_a_move_of_exactly_max_speed_times_the_period_is_accepted():
    guard = SampleGuard(max_speed_m_s=1.0)  # step = 1/64 m
    p, status = state_after(device_on({1: [T64, 0, 0]}, guard, default=lambda k: [min(k, 1) * T64, 0, 0]), 1)
    assert p[0] == T64 and status["device_rejected_jumps"] == 0
    p, status = state_after(device_on({1: [T64 * 1.001, 0, 0]}, guard, default=lambda k: [0, 0, 0]), 1)
    assert p[0] == 0.0 and status["device_rejected_jumps"] == 1


def test_after_a_gap_the_allowed_move_grows_with_the_samples_missed():
    """Two dropouts, then a sample 3 steps away: allowed (max_speed over 3 periods), 3.5 is not."""
    guard = SampleGuard(max_speed_m_s=1.0)
    for distance, rejected in ((3.0, 0), (3.5, 1)):
        device = device_on({1: None, 2: None, 3: [distance * T64, 0, 0]}, guard)
        _, status = state_after(device, 3)
        assert status["device_rejected_jumps"] == rejected, distance
        assert (
            status["device_dropped_samples"] == 2 and status["device_longest_gap_s"] == (2 + rejected) * T64
        )


def test_counts_add_up():
    nan = (np.array([np.nan, 0, 0]), Q, "")
    far = [1.0, 0, 0]
    guard = SampleGuard(max_speed_m_s=1.0, confirm_samples=1)  # one far sample is a relocation
    device = device_on(
        {1: nan, 2: nan, 4: far, 6: [0, 0, 0]}, guard, default=lambda k: [1.0, 0, 0] if k > 4 else [0, 0, 0]
    )
    _, status = state_after(device, 6)
    assert status["device_invalid_samples"] == 2 and status["device_relocations"] == 2
    assert status["device_samples"] == 7 and status["device_rejected_jumps"] == 0


def test_samples_that_agree_at_exactly_max_speed_confirm_a_relocation():
    guard = SampleGuard(max_speed_m_s=1.0, confirm_samples=3)
    device = device_on({}, guard, default=lambda k: [0, 0, 0] if k < 2 else [1.0 + k * T64, 0, 0])
    p, status = state_after(device, 4)
    assert (
        p[0] == 1.0 + 4 * T64 and status["device_relocations"] == 1 and status["device_rejected_jumps"] == 2
    )


def test_a_glitch_does_not_count_toward_a_later_one():
    """Far, good, far: the good sample resets the count, so two far samples 2 apart are no relocation."""
    guard = SampleGuard(max_speed_m_s=1.0, confirm_samples=2)
    device = device_on({2: [1.0, 0, 0], 4: [1.0, 0, 0]}, guard)
    p, status = state_after(device, 4)
    assert p[0] == 0.0 and status["device_relocations"] == 0 and status["device_rejected_jumps"] == 2


def test_guard_settings_at_their_limits():
    SampleGuard(confirm_samples=1, quaternion_tolerance=0.999, max_speed_m_s=math.inf)  # all allowed
    for kwargs, message in (
        ({"confirm_samples": 1.5}, r"confirm_samples=1\.5 must be an integer ≥ 1"),
        ({"quaternion_tolerance": 0.0}, r"quaternion_tolerance=0\.0 must be in \(0, 1\)"),
        ({"quaternion_tolerance": 1.0}, r"quaternion_tolerance=1\.0 must be in \(0, 1\)"),
        ({"max_speed_m_s": math.nan}, r"max_speed_m_s=nan must be > 0 m/s \(inf: off\)"),
    ):
        with pytest.raises(ValueError, match=message):
            SampleGuard(**kwargs)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"period_s": 0.0}, r"^device period_s=0\.0 must be a positive number of seconds$"),
        ({"period_s": math.inf}, r"^device period_s=inf must be a positive number of seconds$"),
        ({"latency_s": -0.01}, r"^device latency_s=-0\.01 must be ≥ 0 s$"),
        ({"latency_s": math.inf}, r"^device latency_s=inf must be ≥ 0 s$"),
        ({"noise_m": math.inf}, r"^device noise_m=inf must be ≥ 0 m$"),
        ({"noise_m": -1e-3}, r"^device noise_m=-0\.001 must be ≥ 0 m$"),
        ({"interpolation": "cubic"}, r"^device interpolation='cubic'; choose one of \('hold', 'linear'\)$"),
    ],
)
def test_bad_device_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DeviceSource(lambda t: (np.zeros(3), Q, ""), **kwargs)


def test_a_quaternion_off_unit_by_exactly_the_tolerance_is_used():
    guard = SampleGuard(quaternion_tolerance=0.5)
    DeviceSource(lambda t: (np.zeros(3), np.array([1.5, 0, 0, 0]), ""), period_s=T64, guard=guard)
    wrong_sizes = (
        r"first sample \(t = 0\) is a sample of 2 positions and 4 quaternion values \(need 3 and 4\)"
    )
    with pytest.raises(ValueError, match=wrong_sizes + "; a device must start from a valid pose$"):
        DeviceSource(lambda t: (np.zeros(2), Q, ""), period_s=T64)
    with pytest.raises(ValueError, match=r"of 3 positions and 3 quaternion values"):
        DeviceSource(lambda t: (np.zeros(3), Q[:3], ""), period_s=T64)


def test_column_vectors_and_slightly_non_unit_quaternions_are_read_as_the_pose():
    """A sampler may hand (3, 1) and (4, 1) arrays and a quaternion 0.09 % off unit norm (inside the
    tolerance): the linear interpolation half-way between 0° and 90° about z is then exactly 45°."""
    s = 1.0009
    q90 = s * np.array([[np.cos(np.pi / 4)], [0], [0], [np.sin(np.pi / 4)]])
    device = DeviceSource(
        lambda t: (np.array([[t], [0.0], [0.0]]), s * Q.reshape(4, 1) if t < T64 / 2 else q90, ""),
        period_s=T64,
        interpolation="linear",
    )
    sim = Simulator(device)
    sim.AdvanceTo(1.5 * T64)
    X = device.GetOutputPort("X_WD").Eval(sim.get_context())
    np.testing.assert_allclose(
        X.rotation().matrix(), RotationMatrix.MakeZRotation(np.pi / 4).matrix(), atol=1e-12
    )
    np.testing.assert_allclose(X.translation(), [0.5 * T64, 0, 0], atol=1e-15)


def test_the_linear_output_follows_time_between_samples():
    """Within one period the sample does not change, but the interpolated pose does (it depends on t)."""
    device = DeviceSource(lambda t: (np.array([t, 0.0, 0.0]), Q, ""), period_s=T64, interpolation="linear")
    context = device.CreateDefaultContext()
    device.ExecuteInitializationEvents(context)
    sim = Simulator(device, context)
    sim.AdvanceTo(T64 + 1e-9)
    xs = []
    for fraction in (0.25, 0.75):
        context.SetTime(T64 + fraction * T64)
        xs.append(device.GetOutputPort("X_WD").Eval(context).translation()[0])
    np.testing.assert_allclose(xs, [0.25 * T64, 0.75 * T64], atol=1e-15)


def test_noise_of_sample_k_is_the_seeded_draw_k():
    """Sample k adds noise_m · N(0, 1)³ drawn from default_rng([seed, k]): the default seed is 0."""
    device = DeviceSource(lambda t: (np.array([t, 0.0, 0.0]), Q, ""), period_s=T64, noise_m=1e-3)
    for k, (_, (p, _, _)) in enumerate(device.samples(3 * T64)):
        expected = np.array([k * T64, 0, 0]) + 1e-3 * np.random.default_rng([0, k]).standard_normal(3)
        np.testing.assert_array_equal(p, expected)


def test_samples_and_grasp_names_cover_the_span_asked():
    names = {0: "a", 3: "b"}
    device = DeviceSource(
        lambda t: None if round(t / T64) == 2 else (np.array([t, 0, 0]), Q, names.get(round(t / T64), "")),
        period_s=T64,
    )
    samples = device.samples(4 * T64)
    assert [t for t, _ in samples] == [k * T64 for k in range(5)]
    assert samples[2][1] is None and samples[4][1][0][0] == 4 * T64
    assert device.grasp_names(4 * T64) == {"a", "b"}  # the dropout and the "" samples name nothing
    assert device.grasp_names() == {"a"}  # no end time: the first sample only
    path = [Waypoint(t=0.0), Waypoint(t=0.5, grasp="brick"), Waypoint(t=1.0, grasp="")]
    assert ScriptedDevice(path).grasp_names() == {"brick"}  # a path: to its end
