"""Bad device input, fuzzed (hypothesis): arbitrary CSV text, sample streams and LCM payloads.

Properties: a log is either read whole (finite values, increasing times, unit quaternions) or
refused with a ValueError naming the file (and the line, for a bad row); no non-finite value
or non-unit quaternion ever leaves a device for the coupling; every counter adds up to what
was sent. The number of cases: ``max_examples`` below (run with
``--hypothesis-show-statistics`` to see them).
"""

import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from drake import lcmt_robot_state
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydrake.lcm import DrakeLcm
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from godobject_drake.devices import (
    CSV_HEADER,
    RELATIVE_CSV_HEADER,
    DeviceSource,
    SampleGuard,
    read_device_log,
    read_increment_log,
    read_joint_log,
)
from godobject_drake.lcm_device import POSE_CHANNEL, POSE_NAMES, LcmDevice

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
