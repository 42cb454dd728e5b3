"""Bad device input, fuzzed (hypothesis): arbitrary CSV text, sample streams and LCM payloads.

Properties: a log is either read whole (finite values, increasing times, unit quaternions) or
refused with a ValueError naming the file (and the line, for a bad row); no non-finite value
or non-unit quaternion ever leaves a device for the coupling; every counter adds up to what
was sent. The number of cases: ``max_examples`` below (run with
``--hypothesis-show-statistics`` to see them).
"""

import json
import math
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from drake import lcmt_robot_state
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from pydrake.lcm import DrakeLcm
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from godobject_drake.config.device_files import (
    CSV_HEADER,
    RELATIVE_CSV_HEADER,
    SampleGuard,
    read_device_log,
    read_increment_log,
    read_joint_log,
)
from godobject_drake.devices.lcm import LcmDevice
from godobject_drake.devices.sources import DeviceSource
from godobject_drake.protocol import POSE_CHANNEL, POSE_NAMES

pytestmark = pytest.mark.slow  # hypothesis: seconds per property

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
T = 0.01

# -- CSV logs ---------------------------------------------------------------------------------------------

number = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**6), 10**6).map(str),
    st.sampled_from(["", " ", "nan", "inf", "-inf", "1e999", "0x10", "1,5", "--1", "\x00", "é"]),
)
cell = st.one_of(number, st.text(max_size=6))
row = st.lists(cell, min_size=0, max_size=11).map(",".join)


def csv_text(header):
    good = ",".join(header)
    return st.tuples(
        st.one_of(st.just(good), st.just(good + " "), st.text(max_size=20)),
        st.lists(row, max_size=8),
        st.booleans(),
    ).map(lambda h: "\n".join([h[0], *h[1]]) + ("\n" if h[2] else ""))


def refused_well(error: ValueError, path: Path) -> bool:
    """The message names the file, and a line unless it is about the whole file."""
    message = str(error)
    return message.startswith(f"{path}:") and (
        re.match(rf"{re.escape(str(path))}:\d+: ", message) or "no rows" in message or "text" in message
    )


def fuzz_file(text: str) -> Path:
    directory = Path(tempfile.mkdtemp())
    path = directory / "log.csv"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    return path


@FUZZ
@given(text=csv_text(CSV_HEADER))
def test_any_pose_log_is_read_whole_or_refused_naming_file_and_line(text):
    path = fuzz_file(text)
    try:
        log = read_device_log(path)
    except ValueError as e:
        assert refused_well(e, path), str(e)
        return
    assert np.all(np.isfinite(log.p)) and np.all(np.diff(log.t) > 0)
    np.testing.assert_allclose(np.linalg.norm(log.q, axis=1), 1.0, rtol=1e-12)


# Bytes that no UTF-8 text holds anywhere (0xC0, 0xC1 and 0xF5 to 0xFF: RFC 3629).
NOT_UTF8 = st.sampled_from([bytes([b]) for b in (0xC0, 0xC1, *range(0xF5, 0x100))])


@FUZZ
@given(before=st.binary(max_size=100), bad=NOT_UTF8, after=st.binary(max_size=100))
def test_any_bytes_that_are_not_utf8_text_as_a_pose_log_are_refused_naming_the_file(before, bad, after):
    """Not text at all (a byte no UTF-8 text has, anywhere among any others): refused as not text,
    naming the file; never read as a log, never a crash."""
    path = Path(tempfile.mkdtemp()) / "log.csv"
    path.write_bytes(b"t,x,y,z,qw,qx,qy,qz,grasp\n" + before + bad + after)
    with pytest.raises(ValueError) as refused:
        read_device_log(path)
    assert refused_well(refused.value, path), str(refused.value)
    assert str(refused.value).startswith(f"{path}: not a UTF-8 text CSV"), str(refused.value)


@FUZZ
@given(text=csv_text(RELATIVE_CSV_HEADER))
def test_any_increment_log_is_read_whole_or_refused_naming_file_and_line(text):
    path = fuzz_file(text)
    try:
        log = read_increment_log(path)
    except ValueError as e:
        assert refused_well(e, path), str(e)
        return
    assert np.all(np.isfinite(log.dp)) and np.all(np.isfinite(log.drot)) and np.all(np.diff(log.t) > 0)


@FUZZ
@given(text=csv_text(("t", "yaw", "jaw")))
def test_any_joint_log_is_read_whole_or_refused_naming_file_and_line(text):
    path = fuzz_file(text)
    try:
        t, u = read_joint_log(path, ["yaw", "jaw"])
    except ValueError as e:
        assert refused_well(e, path), str(e)
        return
    assert np.all(np.isfinite(u)) and u.shape == (len(t), 2) and np.all(np.diff(t) > 0)


# -- sample streams into the guard ------------------------------------------------------------------------

coordinate = st.one_of(
    st.floats(-0.2, 0.2), st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e300, -1e300])
)
quaternion = st.one_of(
    st.just((1.0, 0.0, 0.0, 0.0)),
    st.tuples(*[st.floats(-1, 1)] * 4),  # usually not unit, sometimes zero
    st.tuples(*[st.floats(allow_nan=True, allow_infinity=True)] * 4),
)
sample = st.one_of(st.none(), st.tuples(st.tuples(*[coordinate] * 3), quaternion, st.sampled_from(["", "*"])))


def expected_invalid(s, tolerance: float) -> bool:
    p, q, _ = s
    values = np.array([*p, *q], float)
    if not np.all(np.isfinite(values)):
        return True
    return abs(float(np.linalg.norm(q)) - 1.0) > tolerance


@FUZZ
@given(rest=st.lists(sample, max_size=40))
def test_no_bad_sample_reaches_the_coupling_and_the_counts_add_up(rest):
    # A device must start from a valid pose (DeviceSource refuses otherwise, naming the fix).
    stream = [((0.0, 0.0, 0.05), (1.0, 0.0, 0.0, 0.0), ""), *rest]
    guard = SampleGuard()
    device = DeviceSource(lambda t: stream[min(round(t / T), len(stream) - 1)], period_s=T, guard=guard)
    sim = Simulator(device)
    c = sim.get_context()
    for k in range(len(stream)):
        sim.AdvanceTo(k * T + 1e-6)
        X = device.GetOutputPort("X_WD").Eval(c)
        V = device.GetOutputPort("V_WD").Eval(c)
        assert np.all(np.isfinite(X.GetAsMatrix4())) and np.all(np.isfinite(V)), (k, stream[: k + 1])
        q = X.rotation().ToQuaternion().wxyz()
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    status = DeviceSource.status_dict(device.GetOutputPort("device_status").Eval(c))
    dropped = sum(s is None for s in stream)
    invalid = sum(s is not None and expected_invalid(s, guard.quaternion_tolerance) for s in stream)
    assert status["device_samples"] == len(stream)
    assert status["device_dropped_samples"] == dropped and status["device_invalid_samples"] == invalid
    rest = len(stream) - dropped - invalid
    assert status["device_rejected_jumps"] + status["device_relocations"] <= rest


# -- LCM payloads -----------------------------------------------------------------------------------------

names = st.one_of(
    st.just(list(POSE_NAMES)),
    st.just([*POSE_NAMES, "grasp=*"]),
    st.just([*POSE_NAMES, "grasp=nobody"]),
    st.lists(st.sampled_from([*POSE_NAMES, "grasp=", "w", ""]), max_size=9),
)
message = st.builds(
    lambda utime, n, values: (utime, n, values),
    st.integers(-(2**40), 2**40),
    names,
    st.lists(coordinate, min_size=0, max_size=9),
)
payload = st.one_of(message, st.binary(max_size=80))


@FUZZ
@given(batches=st.lists(st.lists(payload, max_size=4), min_size=1, max_size=12))
def test_any_lcm_payload_is_used_or_dropped_and_counted(batches):
    lcm = DrakeLcm("memq://")
    device = LcmDevice(lcm, RigidTransform([0.0, 0.0, 0.05]), period_s=T)
    device.known_grasps = {"brick"}
    sim = Simulator(device)
    c = sim.get_context()
    sent = 0
    for k, batch in enumerate(batches, start=1):
        for item in batch:
            if isinstance(item, bytes):
                raw = item
            else:
                utime, joint_names, values = item
                msg = lcmt_robot_state()
                msg.utime, msg.joint_name = utime, joint_names
                msg.joint_position = values
                msg.num_joints = len(joint_names) if len(joint_names) == len(values) else len(values)
                try:
                    raw = msg.encode()
                except (ValueError, OverflowError, TypeError, AssertionError, Exception):
                    continue  # lcm itself refuses to build it: nothing is sent
            lcm.Publish(POSE_CHANNEL, raw)
            sent += 1
        sim.AdvanceTo(k * T + 1e-6)
        X = device.GetOutputPort("X_WD").Eval(c)
        assert np.all(np.isfinite(X.GetAsMatrix4())) and np.all(
            np.isfinite(device.GetOutputPort("V_WD").Eval(c))
        )
    counts = device.lcm_status()
    assert counts["lcm_messages"] == sent
    assert counts["lcm_bad_messages"] + counts["lcm_stale_messages"] <= sent
    assert counts["lcm_silent_samples"] <= len(batches) + 1


# -- whole scenario files ---------------------------------------------------------------------------------
#
# The brick scene's file with each field either its own value or one a user might write by mistake
# (a sign, a zero, a NaN, a huge number, a word, a list, nothing) and each tag either a known one or
# not. Every file either runs (exit 0, or 1 when it diverged, with strict-JSON metrics) or is refused
# before simulating (exit 2, one message, no traceback); nothing else.


def yaml_value(v) -> str:
    if isinstance(v, float) and math.isnan(v):
        return ".nan"
    if isinstance(v, float) and math.isinf(v):
        return ".inf" if v > 0 else "-.inf"
    return json.dumps(v)


BAD = [-1.0, 0.0, math.nan, math.inf, -math.inf, 1e300, "fast", [], {}, None, True, [1.0, 2.0]]


SCENARIO_TEMPLATE = """\
name: fuzz
plant:
  time_step: {time_step}
  discrete_contact_approximation: {approximation}
directives:
- add_directives:
    file: package://godobject_models/lego/lego.dmd.yaml
{directive}contact:
  geometry: {geometry}
god_object: {god_tag}
  gains:
    omega_n: {omega_n}
    zeta: {zeta}
    omega_n_rot: {omega_n_rot}
  max_stretch_m: {max_stretch}
device: {device}
workspace:
  lower_m: {lower}
  upper_m: {upper}
feedback:
  kd: {kd}
  gamma_d: {gamma_d}
haptic:
  mode: {haptic}
bricks: {bricks}
simulation:
  duration_s: {duration}
  check_period_s: {check_period}
recording:
  frames_per_second: {fps}
visualization:
  publish_period_s: {publish_period}
metrics:
  penetration_budget_m: {budget}
{extra}"""

DEVICES = [
    "!Scripted\n  path: package://godobject_models/lego/default_path.yaml\n  rate_hz: {rate}",
    "!Relative\n  log: package://godobject_models/lego/push_and_return.csv\n  rate_hz: {rate}\n"
    "  tether_m: {tether}",
    "!Replay\n  log: package://godobject_models/lego/push_and_return.csv\n  rate_hz: {rate}",
    "!Lcm\n  url: memq://\n  grasp: brick_0\n  rate_hz: {rate}",
    "!ScriptedJoints\n  path: package://godobject_models/lego/default_path.yaml",
    "!Nope\n  rate_hz: {rate}",
    "{{}}",
]

FIELDS = {  # the brick scene's value first, then other sensible ones; any may also get a BAD one
    "time_step": (0.001, 0.002, 1e-12, 0.05),
    "approximation": ("sap", "lagged", "similar", "tamsi", "SAP"),
    "geometry": ("proxies", "hydroelastic", "boxes"),
    "omega_n": (40.0, 400.0, 1e4),
    "zeta": (1.0, 0.7, 3.0),
    "omega_n_rot": (120.0, 1e5),
    "max_stretch": (0.05, 1e-9, 10.0),
    "lower": ([-0.15, -0.10, 0.0], [0.1, 0.1, 0.1], [0.0, 0.0]),
    "upper": ([0.15, 0.10, 0.12], [-0.2, -0.2, -0.2], ["a", "b", "c"]),
    "kd": (0.0, 20.0, 1e6),
    "gamma_d": (0.0, 0.2, -5.0),
    "haptic": ("none", "impedance", "admittance", "both"),
    "bricks": (0, 2, 513, 2.5),
    "duration": (0.05, 0.02, 1e7),
    "check_period": (0.05, 1e-9, 10.0),
    "fps": (64.0, 1001.0, 1e-3),
    "publish_period": (1 / 64, 1e-9),
    "budget": (1e-3, 1e-9, 10.0),
    "rate": (60.0, 1e5, 1e9, 0.1),
    "tether": (math.inf, 0.002, 0.0),
}


DIRECTIVES = [  # Drake's own errors while building (a missing file, not a model, a name twice, a bad weld)
    "- add_model: {name: thing, file: /nonexistent/thing.sdf}\n",
    "- add_model: {name: thing, file: package://godobject_models/lego/default_path.yaml}\n",
    "- add_directives: {file: package://godobject_models/lego/lego.dmd.yaml}\n",
    "- add_weld: {parent: world, child: nothing::body}\n",
    "- add_model: {name: extra, file: package://godobject_models/lego/brick_2x4.sdf}\n",
]


@st.composite
def scenario_text(draw):
    """The brick scene with up to three fields changed, its tags and an extra line drawn too."""
    values = {k: v[0] for k, v in FIELDS.items()}
    for k in draw(st.lists(st.sampled_from(sorted(FIELDS)), max_size=3, unique=True)):
        values[k] = draw(st.sampled_from([*FIELDS[k][1:], *BAD]))
    text = {k: yaml_value(v) for k, v in values.items()}
    device = draw(st.sampled_from(DEVICES[:1] * 4 + DEVICES[1:]))
    return SCENARIO_TEMPLATE.format(
        **text,
        god_tag=draw(st.sampled_from(["!Rigid"] * 4 + ["!Articulated", "!Deformable", "!Brick", ""])),
        device=device.format(rate=text["rate"], tether=text["tether"]),
        directive=draw(st.sampled_from([""] * 6 + DIRECTIVES)),
        extra=draw(
            st.sampled_from([""] * 4 + ["unknown_section: 3\n", "simulation:\n  nothing: 1\n", "bricks: [\n"])
        ),
    )


@settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(text=scenario_text())
def test_any_scenario_file_runs_or_is_refused_with_a_message(text, capsys):
    from godobject_drake import cli

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "scene.yaml"
        path.write_text(text)
        metrics = Path(d) / "m.json"
        try:
            code = cli.main(["run", str(path), "--no-progress", "--metrics", str(metrics)])
        except SystemExit as e:
            code = e.code
        err = capsys.readouterr().err
        event(f"exit {code}")
        assert code in (0, 1, 2), (code, text, err[-2000:])
        assert "Traceback" not in err, (text, err[-2000:])
        if code == 2:
            assert "error:" in err and len(err.strip().splitlines()[-1]) > 20, (text, err[-2000:])
        else:
            m = json.loads(metrics.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in {text}"))
            assert m["diverged"] == (code == 1) or "metrics_error" in m, (code, m["diagnosis"], text)
