"""Bad device input, fuzzed (hypothesis): arbitrary CSV text, sample streams, LCM payloads, both
ends of a driver's udp:// link through an adversary, and a driver's feedback payloads.

Properties: a log is either read whole (finite values, increasing times, unit quaternions) or
refused with a ValueError naming the file (and the line, for a bad row); no non-finite value
or non-unit quaternion ever leaves a device for the coupling; junk among valid LCM messages
changes nothing the valid ones do; each end of a link hands on exactly the intact, newer
messages of its paired end; a driver renders only the newest valid force, within its rated
limits; every counter adds up to what was sent. The number of cases: ``max_examples`` below
(run with ``--hypothesis-show-statistics`` to see them).
"""

import functools
import itertools
import json
import math
import re
import select
import socket
import tempfile
from pathlib import Path

import numpy as np
import pytest
from drake import lcmt_force_torque, lcmt_robot_state
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
from godobject_drake.link.messages import POSE_CHANNEL, POSE_NAMES
from godobject_drake.link.transport import LINK_CHANNEL, MAX_DATAGRAM

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
#
# Two LCM devices side by side: one is sent only valid pose messages (utime increasing, the pose
# names, a known grasp), the other the same messages with junk interleaved (garbage, truncated,
# another type, other names, an unknown body, a utime not above the last one). The junk must change
# nothing: both report the same target, velocity, grasp and sample counts at every sample, and the
# first follows every valid message it is sent (so a device that ignored its messages would fail).

value32 = st.one_of(
    st.floats(-0.25, 0.25, width=32), st.floats(width=32), st.sampled_from([math.nan, math.inf, -math.inf])
)
some_q = st.one_of(
    st.just((1.0, 0.0, 0.0, 0.0)),
    st.tuples(*[st.floats(-1, 1, width=32)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1),
)


def _valid(p, q, normalize, grasp):
    return "valid", p, tuple(np.divide(q, np.linalg.norm(q))) if normalize else q, grasp


valid = st.builds(_valid, st.tuples(value32, value32, value32), some_q, st.booleans(),
                  st.sampled_from([None, "*", "", "brick"]))  # fmt: skip


def _robot_state(utime, names, values) -> bytes:
    msg = lcmt_robot_state()
    msg.utime, msg.num_joints, msg.joint_name, msg.joint_position = utime, len(names), names, values
    return msg.encode()


junk = st.one_of(
    st.tuples(st.just("garbage"), st.binary(max_size=120)),
    st.tuples(st.just("truncated"), st.integers(0, 120)),  # a valid message, cut there
    st.tuples(st.just("other type"), st.just(b"")),
    st.tuples(
        st.just("other names"), st.lists(st.sampled_from([*POSE_NAMES, "w", "grasp=", ""]), max_size=9)
    ),
    st.tuples(st.just("many names"), st.integers(8, 400)),
    st.tuples(st.just("unknown body"), st.just(b"")),
    st.tuples(st.just("not newer"), st.integers(0, 3)),  # utime: the last valid one's, minus this
)


def junk_bytes(kind: str, arg, utime: int) -> bytes:
    """A junk message of ``kind``, ``utime`` being the last valid message's."""
    from godobject_drake.link.messages import pose_message

    q = (1.0, 0.0, 0.0, 0.0)
    if kind == "garbage":
        return arg
    if kind == "truncated":
        whole = pose_message(utime + 1, [0.1] * 3, q, "*").encode()
        return whole[: min(arg, len(whole) - 1)]
    if kind == "other type":
        return lcmt_force_torque().encode()
    if kind == "other names":
        return _robot_state(utime + 1, arg, [0.0] * len(arg))
    if kind == "many names":
        return _robot_state(utime + 1, [f"j{i}" for i in range(arg)], [0.0] * arg)
    if kind == "unknown body":
        return pose_message(utime + 1, [0.1] * 3, q, "nobody").encode()
    return pose_message(utime - arg, [0.1] * 3, q).encode()  # not newer


MEMQ = DrakeLcm("memq://")
EXAMPLES = itertools.count()


@FUZZ
@given(batches=st.lists(st.lists(st.one_of(valid, junk), max_size=5), min_size=1, max_size=12))
def test_junk_interleaved_with_valid_lcm_messages_changes_nothing_they_do(batches):
    from godobject_drake.link.messages import pose_message

    rigs = []
    for side in "ab":
        # One memq:// LCM for every example, a channel of its own for each device: an LcmDevice is
        # never freed (its Python callbacks live in its C++ system), and LCM aborts past 1024 fds.
        channel = f"{POSE_CHANNEL}_{side}_{next(EXAMPLES)}"
        device = LcmDevice(MEMQ, RigidTransform([0.0, 0.0, 0.05]), channel=channel, period_s=T,
                           guard=SampleGuard(max_speed_m_s=math.inf))  # fmt: skip  # no jump check
        device.known_grasps = {"brick"}
        rigs.append((functools.partial(MEMQ.Publish, channel), device, Simulator(device)))
    (publish_a, a, sim_a), (publish_b, b, sim_b) = rigs
    utime, n_valid, n_junk = 0, 0, 0
    for k, batch in enumerate(batches, start=1):
        newest = None
        for item in batch:
            if item[0] == "valid":
                utime += 1 + k
                raw = pose_message(utime, item[1], item[2], item[3]).encode()
                publish_a(raw)
                publish_b(raw)
                n_valid, newest = n_valid + 1, item
                continue
            kind, arg = item
            if kind in ("truncated", "not newer", "unknown body") and utime == 0:
                continue  # needs a valid message first (a utime not above one, a message to cut)
            raw = junk_bytes(kind, arg, utime)
            event(f"junk: {kind}")
            publish_b(raw)
            n_junk += 1
        outputs = []
        for sim, device in ((sim_a, a), (sim_b, b)):
            sim.AdvanceTo(k * T + 1e-6)
            c = sim.get_context()
            status = DeviceSource.status_dict(device.GetOutputPort("device_status").Eval(c))
            outputs.append((device.GetOutputPort("X_WD").Eval(c).GetAsMatrix4(),
                            device.GetOutputPort("V_WD").Eval(c), device.GetOutputPort("grasp").Eval(c),
                            status))  # fmt: skip
        (X_a, V_a, grasp_a, status_a), (X_b, V_b, grasp_b, status_b) = outputs
        np.testing.assert_array_equal(X_a, X_b)
        np.testing.assert_array_equal(V_a, V_b)
        assert grasp_a == grasp_b and status_a == status_b
        if newest is not None:
            p, q = np.float32(newest[1]).astype(float), np.float32(newest[2]).astype(float)
            if np.all(np.isfinite([*p, *q])) and abs(np.linalg.norm(q) - 1.0) <= 1e-3:
                np.testing.assert_array_equal(X_a[:3, 3], p)  # the newest valid message, exactly
    counts_a, counts_b = a.lcm_status(), b.lcm_status()
    assert counts_a["lcm_messages"] == n_valid and counts_b["lcm_messages"] == n_valid + n_junk
    assert counts_a["lcm_bad_messages"] == 0 and counts_a["lcm_stale_messages"] == 0
    assert counts_b["lcm_bad_messages"] + counts_b["lcm_stale_messages"] == n_junk
    for key in ("lcm_bursts", "lcm_silent_samples"):
        assert counts_a[key] == counts_b[key], key


# -- the link, both ends, through an adversary ------------------------------------------------------------
#
# A scene's end and a driver's end of a udp:// link (godobject_drake.link.transport) on 127.0.0.1, every
# datagram either way passing two sockets of the test's (the driver's peer is one; the scene sees
# the driver at the other). There each datagram is forwarded, dropped, sent twice, truncated,
# split in two, changed by a bit or held back and sent later; and between the ends' own messages
# come garbage, oversized datagrams, well-formed ones tagged with another key (with the session's
# own nonces), earlier datagrams again (replays), from the right address or another one, and
# floods. Properties: neither end raises; each datagram an end reads is counted exactly once;
# each end hands on exactly the messages the other published that reached it intact, each the
# first time and only if newer than the last (the driver: from its scene's address only; the
# scene: from wherever, moving to the newest's address): nothing forged, replayed, reordered or
# changed, and nothing intact lost.

FATES = st.sampled_from(["forward"] * 10 + ["drop", "duplicate", "truncate", "split", "flip", "hold"])
SIDE = st.sampled_from(["scene", "driver"])
WIRE_ACTIONS = st.one_of(
    st.tuples(st.just("driver publishes")),
    st.tuples(st.just("scene publishes")),
    st.tuples(st.just("driver publishes")),
    st.tuples(st.just("scene publishes")),
    st.tuples(st.just("tick"), st.sampled_from([0.01, 0.05, 0.1, 0.6])),  # the driver's clock (s)
    st.tuples(st.just("release"), st.integers(0, 50)),  # a held datagram goes on, late
    st.tuples(st.just("replay"), st.integers(0, 500), st.booleans()),  # an earlier one again; from elsewhere?
    st.tuples(st.just("garbage"), st.binary(max_size=200), SIDE),
    st.tuples(st.just("oversized"), st.integers(MAX_DATAGRAM + 1, 20000), SIDE),
    st.tuples(st.just("another key"), SIDE),
    st.tuples(st.just("flood"), st.integers(1, 600), SIDE),
)
OTHER_KEY = b"\x5a" * 32


class Wire:
    """The two ends and the adversary between them (above). ``arrived[side]``: every datagram
    sent to that end, in order, with where it came from (``wire`` or ``elsewhere``)."""

    def __init__(self, fates):
        from godobject_drake.link.transport import UdpLcm

        self.now = 0.0
        self.fates = iter(fates)
        self.sockets = {}
        for name in ("scene", "driver", "elsewhere"):  # the wire's socket facing each end; a stranger's
            self.sockets[name] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sockets[name].bind(("127.0.0.1", 0))
            self.sockets[name].settimeout(5.0)
        self.scene = UdpLcm.listen("udp://127.0.0.1:0")
        self.driver = UdpLcm.connect(f"udp://127.0.0.1:{self.sockets['driver'].getsockname()[1]}",
                                     clock=lambda: self.now)  # fmt: skip
        self.ends = {"scene": self.scene, "driver": self.driver}
        self.address = {"scene": ("127.0.0.1", self.scene.port), "driver": ("127.0.0.1", self.driver.port)}
        self.read = {"scene": 0, "driver": 0}  # datagrams the wire read from each end
        self.sent = {"scene": 0, "driver": 0}  # datagrams sent to each end
        self.unheard = 0  # sent to the driver from elsewhere: never queued on its socket
        self.captured: list[tuple[str, bytes]] = []  # (the end that sent it, the datagram)
        self.held: list[tuple[str, bytes]] = []
        self.answered_elsewhere: list[bytes] = []  # what the scene sent the stranger
        self.arrived: dict[str, list[tuple[bytes, str]]] = {"scene": [], "driver": []}
        self.handled: dict[str, list[tuple[str, bytes]]] = {"scene": [], "driver": []}
        self.taken_via: dict[str, list[str]] = {"scene": [], "driver": []}  # set by expected()
        for side, channels in (("scene", ("POSE", LINK_CHANNEL)), ("driver", ("FEEDBACK",))):
            for channel in channels:
                self.ends[side].Subscribe(channel, functools.partial(self._handled, side, channel))

    def _handled(self, side, channel, payload):
        self.handled[side].append((channel, payload))

    def close(self):
        for s in (*self.sockets.values(), self.scene, self.driver):
            s.close()

    def send(self, to: str, datagram: bytes, via: str = "wire") -> None:
        self.sockets[to if via == "wire" else via].sendto(datagram, self.address[to])
        if to == "driver" and via != "wire":  # the driver's socket is connected to the scene's
            self.unheard += 1  # address (the wire's): the kernel drops another sender's datagram
            return
        self.sent[to] += 1
        self.arrived[to].append((datagram, via))

    def fate(self, to: str, datagram: bytes) -> None:
        fate = next(self.fates, "forward")
        if fate in ("forward", "duplicate"):
            self.send(to, datagram)
        if fate == "duplicate":
            self.send(to, datagram)
        elif fate == "truncate":
            self.send(to, datagram[: len(datagram) // 2])
        elif fate == "split":
            self.send(to, datagram[:40])
            self.send(to, datagram[40:])
        elif fate == "flip":
            self.send(to, datagram[:-7] + bytes([datagram[-7] ^ 0x10]) + datagram[-6:])
        elif fate == "hold":
            self.held.append((to, datagram))

    def settle(self) -> None:
        """Until nothing moves: the wire reads what each end sent (its udp_sent says how much) and
        gives each its fate; each end reads everything sent to it."""
        for _ in range(10_000):
            moved = False
            for side, other in (("driver", "scene"), ("scene", "driver")):
                while self.read[side] < self.ends[side].counts["udp_sent"]:
                    # a scene answers a HELLO where it came from: the stranger's too (a replay)
                    facing = [self.sockets[side], *([self.sockets["elsewhere"]] if side == "scene" else [])]
                    ready, _, _ = select.select(facing, [], [], 5.0)
                    assert ready, f"{side} sent {self.ends[side].counts['udp_sent']}, {self.read[side]} came"
                    datagram = ready[0].recv(65535)
                    self.read[side] += 1
                    if ready[0] is self.sockets["elsewhere"]:
                        self.answered_elsewhere.append(datagram)
                        continue
                    self.captured.append((side, datagram))
                    self.fate(other, datagram)
                    moved = True
            for side, end in self.ends.items():
                while end.counts["udp_received"] < self.sent[side]:
                    end.HandleSubscriptions(5)
                    moved = True
            if not moved:
                return
        raise AssertionError("the link never settled")

    def act(self, action, published: dict) -> None:
        kind = action[0]
        if kind == "driver publishes":
            published["driver"] += 1
            self.driver.Publish("POSE", b"d%d" % published["driver"])
        elif kind == "scene publishes":
            published["scene"] += 1
            self.scene.Publish("FEEDBACK", b"s%d" % published["scene"])
        elif kind == "tick":
            self.now += action[1]
            self.driver.HandleSubscriptions(0)  # a HELLO when one is due
        elif kind == "release" and self.held:
            self.send(*self.held.pop(action[1] % len(self.held)))
        elif kind == "replay" and self.captured:
            side, datagram = self.captured[action[1] % len(self.captured)]
            to = "driver" if side == "scene" else "scene"
            self.send(to, datagram, "elsewhere" if action[2] else "wire")
        elif kind == "garbage":
            self.send(action[2], action[1])
        elif kind == "oversized":
            self.send(action[2], b"GOD1" + bytes(action[1] - 4))
        elif kind == "another key":
            self.send(action[1], self.forged(action[1]))
        elif kind == "flood":
            for i in range(action[1]):
                self.send(action[2], b"flood %d" % i)
        self.now += 0.02  # the driver's loop polls between any two actions (a HELLO when due)
        self.driver.HandleSubscriptions(0)
        self.settle()

    def forged(self, to: str) -> bytes:
        """A well-formed datagram for ``to``, with the session's nonces, tagged with another key."""
        from godobject_drake.link.transport import DriverEnd, SceneEnd

        scene_nonce, driver_nonce = self.scene.end.nonce, self.driver.end.nonce
        if to == "scene":
            forger = DriverEnd(OTHER_KEY, None, driver_nonce)
        else:
            forger = SceneEnd(OTHER_KEY, scene_nonce)
        forger._pair((scene_nonce, driver_nonce))
        forger._sent = 2**40
        return forger.seal("POSE" if to == "scene" else "FEEDBACK", b"forged")

    def expected(self, side: str) -> list[tuple[str, bytes]]:
        """What ``side`` should have handed on: the other end's DATA that arrived intact, in order,
        each the first time, newer than the last (the driver: from the scene's address only);
        where each came from in ``taken_via``."""
        from godobject_drake.link.transport import COUNTER, DATA_HEAD, TAG_BYTES, data_fields

        other = "driver" if side == "scene" else "scene"
        theirs = {d for s, d in self.captured if s == other and d[4:5] in (b"D", b"S")}
        out, last = [], 0
        for datagram, via in self.arrived[side]:
            if datagram not in theirs or (side == "driver" and via != "wire"):
                continue
            (counter,) = COUNTER.unpack_from(datagram, DATA_HEAD - COUNTER.size)
            if counter > last:  # the scene: from wherever the newest comes (it moves its peer there)
                last = counter
                out.append(data_fields(datagram)[2])
                self.taken_via[side].append(via)
        assert all(len(d) > TAG_BYTES for d in theirs)
        return out


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(actions=st.lists(WIRE_ACTIONS, min_size=1, max_size=60), fates=st.lists(FATES, max_size=80))
def test_each_end_hands_on_exactly_the_intact_newer_messages_of_its_paired_end(actions, fates):
    from godobject_drake.link.transport import LINK_REJECTED

    wire = Wire(fates)
    published = {"scene": 0, "driver": 0}
    try:
        wire.act(("tick", 0.0), published)  # the driver's first HELLO
        for action in actions:
            event(action[0])
            wire.act(action, published)
    finally:
        wire.close()
    for side, end in wire.ends.items():
        counts = end.counts
        outcomes = counts["udp_taken"] + counts["udp_handshakes"] + counts["udp_refused"]
        assert counts["udp_received"] == wire.sent[side] == outcomes + sum(counts[k] for k in LINK_REJECTED)
        expected = [m for m in wire.expected(side) if m[0] != LINK_CHANNEL or side == "scene"]
        assert wire.handled[side] == expected
        other = "driver" if side == "scene" else "scene"
        numbers = [int(p[1:]) for c, p in wire.handled[side] if c != LINK_CHANNEL]
        assert all(p[:1] == other[:1].encode() for c, p in wire.handled[side] if c != LINK_CHANNEL)
        assert numbers == sorted(set(numbers)) and all(n <= published[other] for n in numbers)
        if counts["udp_flooded"]:
            event("a poll stopped at MAX_PER_POLL")
    poses = len(wire.handled["scene"]) - 1  # the first is the driver's LINK_CHANNEL message
    event("not paired" if poses < 0 else f"poses handed on: {min(poses, 5)}{'+' * (poses > 5)}")
    if wire.handled["driver"]:
        event("feedback reached the driver")
    # The stranger hears WELCOMEs answering HELLOs it replayed (at most one per HELLO_ANSWER_S each)
    # and, if it replayed one of the driver's messages before the scene had it (the newest: only
    # whoever can capture and hold back datagrams can, docs/haptic_devices.md), the scene's own
    # messages until the driver's next one moves the scene back: a replay cannot hold the scene.
    moved = "elsewhere" in wire.taken_via["scene"]
    assert all(d[4:5] == b"W" or (moved and d[4:5] == b"S") for d in wire.answered_elsewhere)
    if moved:
        event("the scene moved to a replay from elsewhere")
        if wire.taken_via["scene"][-1] == "wire":
            event("the driver's next message moved it back")


# -- the driver's end: any feedback payload ----------------------------------------------------------------
#
# What the paired scene itself could send the driver (a bug, another version): forces of any
# size, NaN and infinite ones, truncated messages, another type, garbage. Properties: the force
# the driver asks of its safety is always the newest valid (finite) feedback; what it renders is
# finite, within the rated 12 N and changes by at most the rated 1.2 N a period except to zero;
# each payload that is not a valid force is counted in bad_feedback.

any_force = st.tuples(*[st.one_of(st.floats(-20, 20), st.floats(), st.sampled_from([1e300, -1e300]))] * 3)
feedback_payload = st.one_of(
    st.tuples(st.just("force"), any_force),
    st.tuples(st.just("garbage"), st.binary(max_size=70)),
    st.tuples(st.just("truncated"), st.integers(0, 63)),
    st.tuples(st.just("other type"), st.just(b"")),
)


class _Feed:
    """A stand-in for the socket: hands the driver one batch of feedback payloads at each poll."""

    def __init__(self, batches):
        self.batches, self.handlers, self.polls = batches, {}, 0

    def Subscribe(self, channel, handler):
        self.handlers[channel] = handler

    def Publish(self, channel, data):
        pass

    def HandleSubscriptions(self, timeout_millis=0):
        for raw in self.batches[self.polls] if self.polls < len(self.batches) else ():
            self.handlers["GODOBJECT_FEEDBACK"](raw)
        self.polls += 1
        return 0


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(batches=st.lists(st.lists(feedback_payload, max_size=4), min_size=1, max_size=25))
def test_any_feedback_payload_renders_the_newest_valid_force_within_the_rated_limits(batches):
    from godobject_drake.driver.families import RATED, EmulatedDevice, HandPath
    from godobject_drake.driver.process import Driver

    raw_batches, newest, expected_requests, bad = [], np.zeros(3), [], 0
    for batch in batches:
        raws = []
        for kind, arg in batch:
            message = lcmt_force_torque()
            if kind == "force":
                message.fx, message.fy, message.fz = arg
                raws.append(message.encode())
                if np.all(np.isfinite(arg)):
                    newest = np.array(arg, float)
                    continue
            elif kind == "garbage":
                raws.append(arg)
            elif kind == "truncated":
                raws.append(message.encode()[:arg])
            else:
                raws.append(lcmt_robot_state().encode())
            bad += 1
        raw_batches.append(raws)
        expected_requests.append(newest.copy())
    device = EmulatedDevice(HandPath.still(), start_on_scene=False)
    driver = Driver(device, _Feed(raw_batches), RATED["emulated"], rate_hz=1000.0, watchdog_periods=1000,
                    max_force_n=12.0, grasp="always")  # fmt: skip
    read = device.read

    def read_until_fed():  # the loop polls, then reads the handle: stop after one empty poll
        driver.stop_requested = driver.lcm.polls > len(raw_batches)
        return read()

    device.read = read_until_fed
    driver.run()
    rows = list(driver.rows)[:-2]  # the last: the exit row; the one before it polled nothing new
    requested = np.array([r[4:7] for r in rows], float)
    rendered = np.array([r[7:10] for r in rows], float)
    assert len(rows) == len(raw_batches)
    np.testing.assert_array_equal(requested, expected_requests)
    assert driver.counts["bad_feedback"] == bad
    assert np.all(np.isfinite(rendered)) and np.all(np.linalg.norm(rendered, axis=1) <= 12.0 + 1e-9)
    steps = np.linalg.norm(np.diff(np.vstack([np.zeros(3), rendered]), axis=0), axis=1)
    to_zero = np.all(rendered == 0.0, axis=1)
    assert np.all((steps <= 1.2 + 1e-9) | to_zero)
    np.testing.assert_array_equal(list(driver.rows)[-1][7:10], [0.0, 0.0, 0.0])  # the exit row


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


# aliases of aliases under a private root key (Drake's loader drops it): 9**6 nodes
ALIAS_BOMB = (
    "".join(f"_a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9 if i else ['1'] * 9)}]\n" for i in range(6))
    + "_b: [*a5, *a5]\n"
)
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
            st.sampled_from(
                [""] * 6
                + [
                    "unknown_section: 3\n",
                    "simulation:\n  nothing: 1\n",
                    "bricks: [\n",
                    "name: twice\n",
                    "_deep: " + "[" * 100 + "]" * 100 + "\n",
                    ALIAS_BOMB,
                ]
            )
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


# -- the local model (issue 44) ----------------------------------------------------------------------------


def _valid_model(p_G, planes):
    from godobject_drake.link.messages import LocalModel

    return LocalModel(1, 2, 0.001, 200.0, 0.0, 0.0, 0.0, tuple(p_G), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                      (0.0, 0.0, 0.0), tuple(p_G), planes=tuple(planes))  # fmt: skip


coordinate = st.floats(-1.0, 1.0)
unit = st.sampled_from([(1.0, 0.0, 0.0), (0.0, 0.0, -1.0)])
plane = st.tuples(st.tuples(coordinate, coordinate, coordinate), unit,
                  st.one_of(st.just(math.inf), st.floats(1.0, 1e7)))  # fmt: skip


@FUZZ
@given(
    p_G=st.tuples(coordinate, coordinate, coordinate),
    planes=st.lists(plane, max_size=8),
    edits=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=4),
    cut=st.one_of(st.none(), st.integers(0, 800)),
)
def test_any_changed_local_model_is_read_whole_and_checked_or_refused_naming_why(p_G, planes, edits, cut):
    """A local model payload changed anywhere (bytes overwritten, cut short) is either refused
    with a LocalModelError (never another exception), or read into a model every value of which
    is within its limits: finite, gains ≥ 0, unit normals and quaternion, stiffness > 0."""
    from godobject_drake.link.messages import LocalModelError, parse_local_model

    raw = bytearray(_valid_model(p_G, planes).encode())
    for at, value in edits:
        raw[at % len(raw)] = value
    if cut is not None:
        raw = raw[:cut]
    try:
        m = parse_local_model(bytes(raw))
    except LocalModelError as e:
        event(str(e).split(":")[1].split()[0] if ":" in str(e) else "refused")
        return
    values = [m.period_s, m.kd, m.gamma_d, m.kd_rot, m.gamma_d_rot, *m.p_G, *m.v_G, *m.q_G, *m.w_G, *m.p_T]
    assert all(math.isfinite(v) for v in values) and m.period_s > 0 and min(m.kd, m.gamma_d) >= 0
    assert abs(math.hypot(*m.q_G) - 1.0) <= 1e-6 and len(m.planes) <= 8
    for point, normal, stiffness in m.planes:
        assert all(math.isfinite(v) for v in point) and abs(math.hypot(*normal) - 1.0) <= 1e-6
        assert stiffness > 0 and not math.isnan(stiffness)


# -- YAML bounds (config.yaml_guard) -----------------------------------------------------------------------


@st.composite
def aliased_yaml(draw):
    """Top-level private keys, each anchoring a flow list of scalars, nested lists and aliases of the
    anchors before it (so a bomb is a few lines), sometimes a key twice or one nest very deep."""
    lines = []
    for n in range(draw(st.integers(1, 8))):

        def value(depth, n=n):
            items = []
            for _ in range(draw(st.integers(0, 6))):
                kind = draw(
                    st.sampled_from(["scalar", "alias", "list"] if depth < 3 else ["scalar", "alias"])
                )
                if kind == "alias" and n:
                    items.append(f"*a{draw(st.integers(0, n - 1))}")
                elif kind == "list":
                    items.append(value(depth + 1))
                else:
                    items.append(str(draw(st.integers(0, 9))))
            return "[" + ", ".join(items) + "]"

        lines.append(f"_k{n}: &a{n} {value(0)}")
    if draw(st.booleans()):
        deep = draw(st.integers(1, 2 * 64))
        lines.append("_deep: " + "[" * deep + "]" * deep)
    if draw(st.integers(0, 4)) == 0:
        lines.append(draw(st.sampled_from(lines)).split(":")[0] + ": 0")  # a key twice
    return "\n".join(lines) + "\n"


def _expanded_count(value, cap):
    """Nodes of the loaded (shared) value, each alias expanded, counted up to ``cap``; and its depth."""
    count, deepest, stack = 0, 0, [(value, 1)]
    while stack and count <= cap:
        v, depth = stack.pop()
        count += 1
        deepest = max(deepest, depth)
        if isinstance(v, list):
            stack.extend((c, depth + 1) for c in v)
        elif isinstance(v, dict):
            stack.extend(x for k, c in v.items() for x in ((k, depth + 1), (c, depth + 1)))
    return count, deepest


@FUZZ
@given(text=aliased_yaml())
def test_any_aliased_yaml_is_refused_exactly_when_it_is_past_a_bound(text):
    """check_yaml refuses a text (a YamlShapeError, never another exception) exactly when its
    expansion, counted by loading it, adds more than MAX_ALIAS_NODES nodes, nests deeper than
    MAX_YAML_DEPTH or gives a key twice; in well under a second however large the expansion."""
    import time

    import yaml

    from godobject_drake.config.yaml_guard import MAX_ALIAS_NODES, MAX_YAML_DEPTH, YamlShapeError, check_yaml

    keys = [line.split(":")[0] for line in text.splitlines()]
    twice = len(keys) != len(set(keys))
    start = time.perf_counter()
    try:
        check_yaml(text, "text")
        refused = None
    except YamlShapeError as e:
        refused = str(e)
    assert time.perf_counter() - start < 0.5
    event("refused" if refused else "accepted")
    if twice:
        assert refused and ("given twice" in refused or "deep" in refused or "alias" in refused)
        return
    nodes = yaml.compose(text)
    written = len({id(n) for n in _all_nodes(nodes)})
    count, deepest = _expanded_count(yaml.safe_load(text), written + MAX_ALIAS_NODES)
    past = count > written + MAX_ALIAS_NODES or deepest > MAX_YAML_DEPTH
    assert bool(refused) == past, (refused, count, written, deepest)


def _all_nodes(node):
    seen, stack = {}, [node]
    while stack:
        n = stack.pop()
        if id(n) not in seen:
            seen[id(n)] = n
            if isinstance(n.value, list):
                stack.extend(x for item in n.value for x in (item if isinstance(item, tuple) else (item,)))
    return seen.values()


# -- mesh files (config.meshes) ----------------------------------------------------------------------------

obj_index = st.one_of(st.integers(-6, 8).map(str), st.sampled_from(["", "x", "1.5", "99999999999"]))
obj_ref = st.tuples(obj_index, obj_index, obj_index).map(
    lambda r: st.sampled_from([r[0], f"{r[0]}/{r[1]}", f"{r[0]}//{r[2]}", f"{r[0]}/{r[1]}/{r[2]}"])
)
obj_line = st.one_of(
    st.sampled_from(["v 0 0 0", "vt 0 0", "vn 0 0 1", "# a comment", "", "o thing", "usemtl m"]),
    st.tuples(
        st.sampled_from(["f", "l", "p"]), st.lists(obj_ref.flatmap(lambda s: s), min_size=1, max_size=4)
    ).map(lambda t: " ".join([t[0], *t[1]])),
)


@FUZZ
@given(lines=st.lists(obj_line, max_size=30))
def test_any_obj_is_passed_only_when_every_index_names_what_the_file_has(lines):
    """check_mesh passes an OBJ exactly when each integer index of its faces, lines and points
    names a vertex, texture coordinate or normal the file has (positive: 1 to the count; negative:
    counting back from those written before it), and refuses it otherwise with a MeshFileError
    naming the line (never another exception)."""
    from godobject_drake.config.meshes import MeshFileError, check_mesh

    counts, seen, bad = {"v": 0, "vt": 0, "vn": 0}, [], None
    for number, line in enumerate(lines, start=1):
        words = line.split()
        if words and words[0] in counts:
            counts[words[0]] += 1
        elif words and words[0] in ("f", "l", "p"):
            for ref in words[1:]:
                for kind, text in zip(("v", "vt", "vn"), ref.split("/"), strict=False):
                    if text.lstrip("-").isdigit():
                        i = int(text)
                        if i > 0:
                            seen.append((kind, i, number))
                        elif (i == 0 or -i > counts[kind]) and bad is None:
                            bad = number
    late = [n for kind, i, n in seen if i > counts[kind]]
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.obj"
        path.write_text("\n".join(lines) + "\n")
        try:
            check_mesh(path, "m.obj")
            refused = None
        except MeshFileError as e:
            refused = str(e)
    event("refused" if refused else "passed")
    assert (refused is not None) == (bad is not None or bool(late)), (refused, lines)
    if refused:
        assert re.match(r"m\.obj: line \d+: a face names ", refused), refused


vtk_word = st.one_of(st.integers(-3, 7).map(str), st.sampled_from(["x", "1.5", "-"]))


@FUZZ
@given(
    points=st.integers(0, 5),
    cells=st.lists(st.lists(vtk_word, min_size=1, max_size=5), max_size=6),
    tail=st.lists(st.integers(-9, 99).map(str), max_size=4),
)
def test_any_legacy_vtk_is_passed_only_when_every_cell_names_a_point_it_has(points, cells, tail):
    """check_mesh passes an ASCII legacy VTK exactly when every integer of its CELLS section (each
    line's first number is the cell's size, not an index) is a point the file has, 0 to POINTS - 1,
    and refuses it otherwise with a MeshFileError naming the first such line (never another
    exception); the numbers of the sections after it are not indices."""
    from godobject_drake.config.meshes import MeshFileError, check_mesh

    words = sum(len(c) for c in cells)
    lines = [
        "# vtk DataFile Version 3.0",
        "t",
        "ASCII",
        "DATASET UNSTRUCTURED_GRID",
        f"POINTS {points} double",
    ]
    lines += ["0 0 0"] * points + [f"CELLS {len(cells)} {words}"] + [" ".join(c) for c in cells]
    lines += [f"CELL_TYPES {len(tail)}", *tail]
    first_bad = next(
        (7 + points + k for k, c in enumerate(cells)
         if any(w.lstrip("-").isdigit() and not 0 <= int(w) < points for w in c[1:])),
        None,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.vtk"
        path.write_text("\n".join(lines) + "\n")
        try:
            check_mesh(path, "m.vtk")
            refused = None
        except MeshFileError as e:
            refused = str(e)
    event("refused" if refused else "passed")
    assert (refused is None) == (first_bad is None), (refused, lines)
    if refused:
        assert refused.startswith(f"m.vtk: line {first_bad}: a cell names point "), (refused, lines)


HEX = "0123456789abcdefABCDEF"
key_like = st.tuples(
    st.sampled_from(["", " ", "\n", "\t "]),
    st.text(st.sampled_from(HEX), min_size=28, max_size=40),
    st.one_of(st.none(), st.tuples(st.integers(0, 40), st.sampled_from("gx/. \n"))),
    st.sampled_from(["", "\n", " \n"]),
).map(lambda t: t[0] + (t[1] if t[2] is None else t[1][: t[2][0]] + t[2][1] + t[1][t[2][0] :]) + t[3])


@FUZZ
@given(value=st.one_of(st.text(st.sampled_from(HEX + " \n\t/.kgx"), max_size=80), key_like))
def test_a_key_files_path_is_refused_exactly_when_it_is_a_key_itself(value):
    """key_path refuses a value (a given key file, or ``$GODOBJECT_LINK_KEY``) exactly when it is,
    spaces and line ends aside, 32 or more hex digits and nothing else: a key pasted where its
    file's path goes; any other value is a path (none is made here)."""
    from godobject_drake.link.keys import KeyFileError, key_path

    stripped = value.strip()
    is_key = len(stripped) >= 32 and all(c in HEX for c in stripped)
    if not value:
        return  # the default path: not this rule
    try:
        key_path(value)
        refused = False
    except KeyFileError as e:
        refused = True
        assert str(e).startswith(f"the key file holds {len(stripped)} hex digits, a key itself"), str(e)
    assert refused == is_key, value
