"""Issue 45's "Why" items 1 to 4, each as it was found (loopback only, the emulated device), and
what a stranger gets now: nothing.

A *stranger* is a process without the user's link key: another user's, or any process that read
the ports from ``/proc/net/udp``. It sends what it can: LCM's own short-message packets (the link's
format before pairing, ``LC02``), the paired format tagged with another key, truncated and
forged messages, from its own address or from the scene's while no scene holds it.

These tests use the transport only through what it had before pairing (``make_lcm``,
``driver_lcm``, ``Publish``, ``HandleSubscriptions``, ``LcmDevice``, ``Driver``), so they also run
on the code before it, where each fails on the behaviour it names (``docs/haptic_devices.md``,
"What is guarded"). The link's own counts are asserted after the behaviour."""

import hmac
import json
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from conftest import REPO
from drake import lcmt_force_torque
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from godobject_drake.devices.lcm import LcmDevice
from godobject_drake.driver.families import RATED, EmulatedDevice, HandPath
from godobject_drake.driver.process import Driver, read_log
from godobject_drake.link.keys import load_key
from godobject_drake.link.messages import (
    DRIVER_STATUS_CHANNEL,
    FEEDBACK_CHANNEL,
    POSE_CHANNEL,
    STOP_SUFFIX,
    pose_message,
    status_message,
)
from godobject_drake.link.transport import driver_lcm, make_lcm

T = 0.001  # the scene's device period (s)
Q = (1.0, 0.0, 0.0, 0.0)
START = np.array([0.1, 0.0, 0.05])
FAR = [10.1, 0.0, 0.05]  # 10 m from the start
STILL = HandPath(np.zeros(1), np.zeros((1, 3)), np.ones(1, bool), np.zeros(1, bool))  # grasp held
OTHER_KEY = b"\x5a" * 32


def above(dz: float) -> np.ndarray:
    return START + np.array([0.0, 0.0, dz])


def lc02(channel: str, payload: bytes, seqno: int = 1) -> bytes:
    """LCM's short-message packet: the link's format before pairing."""
    return struct.pack(">II", 0x4C433032, seqno) + channel.encode() + b"\0" + payload


def forged(kind: bytes, channel: str = "", payload: bytes = b"", counter: int = 1) -> bytes:
    """The paired format (docs/haptic_devices.md), tagged with a key that is not the user's:
    DATA (``D``, ``S``) with made-up nonces, or a handshake (``H``, ``W``, ``R``)."""
    body = bytes(48) if kind in b"WR" else bytes(32)
    if kind in b"DS":
        body = bytes(32) + struct.pack(">Q", counter) + channel.encode() + b"\0" + payload
    head = b"GOD1" + kind + body
    return head + hmac.digest(OTHER_KEY, head, "sha256")


def feedback(fx: float, t_us: int = 1000) -> bytes:
    m = lcmt_force_torque()
    m.timestamp, m.fx = t_us, fx
    return m.encode()


def udp_socket(port: int = 0) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    return s


def drain(s: socket.socket, wait_s: float = 0.05) -> list[bytes]:
    """Every datagram waiting on ``s`` (after ``wait_s``)."""
    time.sleep(wait_s)
    s.setblocking(False)
    out = []
    while True:
        try:
            out.append(s.recv(65535))
        except BlockingIOError:
            return out


class Scene:
    """An LCM device on ``url``, stepped one device period at a time (the target it reports)."""

    def __init__(self, url: str):
        self.lcm = make_lcm(url)
        self.device = LcmDevice(self.lcm, RigidTransform(START), period_s=T)
        self.sim = Simulator(self.device)
        self.k = 0

    def step(self) -> np.ndarray:
        self.k += 1
        self.sim.AdvanceTo(self.k * T + 1e-6)
        return self.device.GetOutputPort("X_WD").Eval(self.sim.get_context()).translation().copy()

    def close(self):
        self.lcm.close()


def deliver(scene: Scene, link, p, utime: int) -> int:
    """The real driver's pose ``p`` reaches the target (after the pairing, where there is one):
    published each period with the next utime until the scene reports it. Returns the next utime."""
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        link.Publish(POSE_CHANNEL, pose_message(utime, p, Q).encode())
        utime += 1
        link.HandleSubscriptions(1)
        if np.allclose(scene.step(), p, atol=1e-6):
            return utime
    raise AssertionError(f"the driver's pose {p} never reached the target: {scene.device.lcm_status()}")


def driver(link, seconds: float, watchdog_periods: int = 10, **options) -> tuple[Driver, threading.Thread]:
    """An emulated device (a still hand holding the grasp) on ``link`` in a thread, at 1 kHz."""
    d = Driver(EmulatedDevice(STILL, start_on_scene=False), link, RATED["emulated"], rate_hz=1000.0,
               watchdog_periods=watchdog_periods, max_force_n=12.0, grasp="always", **options)  # fmt: skip
    thread = threading.Thread(target=d.run, args=(seconds,))
    thread.start()
    return d, thread


def forces(d: Driver) -> np.ndarray:
    return np.array([r[7:10] for r in d.rows], float)


# -- Why 1: any local process could push the device at its rated force -------------------------------------


def test_a_stranger_cannot_push_the_device_with_no_scene_running():
    """No scene runs; the stranger holds the scene's own address (so its datagrams come from
    there), learns the driver's port from the driver's first datagram, and for 0.3 s sends 1e6 N
    of feedback at 1 kHz in both formats, answering each HELLO with a WELCOME of its own key.
    Before pairing this rendered exactly 12 N (the rated clamp) in ~1,700 periods and moved the
    handle 3.2 cm; now every period renders exactly 0 N and the handle does not move at all."""
    stranger = udp_socket()
    link = driver_lcm(f"udp://127.0.0.1:{stranger.getsockname()[1]}")
    d, thread = driver(link, 0.6)
    sent = 0
    try:
        stranger.settimeout(10.0)
        _, driver_at = stranger.recvfrom(65535)  # its first datagram: a HELLO now, a pose before
        stranger.setblocking(False)
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            push = feedback(1e6)
            for datagram in (
                lc02(FEEDBACK_CHANNEL, push),
                forged(b"S", FEEDBACK_CHANNEL, push),
                forged(b"W"),
            ):
                stranger.sendto(datagram, driver_at)
                sent += 1
            time.sleep(0.001)
    finally:
        thread.join()
        stranger.close()
    f = forces(d)
    print(f"stranger: {sent} datagrams; rendered |f| max {np.abs(f).max():.3g} N; link {link.counts}")
    assert len(f) > 10 and np.all(f == 0.0)
    np.testing.assert_array_equal(d.device.p, [0.0, 0.0, 0.0])  # the handle never moved
    assert d.counts["bad_feedback"] == 0 and not d.heard_scene
    rejected = link.counts["udp_malformed"] + link.counts["udp_unauthenticated"]
    assert rejected == link.counts["udp_received"] > 0 and link.counts["udp_pairings"] == 0
    assert link.counts["udp_taken"] == link.counts["udp_handshakes"] == 0


def test_a_stranger_cannot_change_the_force_a_paired_scene_asks():
    """The scene asks 1 N along x every millisecond; a stranger sends 1e6 N from its own port
    after each, both formats. Before pairing the device rendered 12 N whenever the stranger's
    message was the newest; now every period renders what the scene asked, ramped at the rated
    rate (1.2 N per period: 1 N at once) or zero while stale: within 0.01 N of the scene's force."""
    scene = make_lcm("udp://127.0.0.1:0")
    url = f"udp://127.0.0.1:{scene.port}"
    stranger = udp_socket()
    d, thread = driver(driver_lcm(url), 0.5)
    sent = 0
    try:
        while thread.is_alive():
            scene.HandleSubscriptions(1)
            scene.Publish(FEEDBACK_CHANNEL, feedback(1.0))
            driver_at = ("127.0.0.1", d.lcm.port)
            stranger.sendto(lc02(FEEDBACK_CHANNEL, feedback(1e6)), driver_at)
            stranger.sendto(forged(b"S", FEEDBACK_CHANNEL, feedback(1e6), counter=2**40), driver_at)
            sent += 2
    finally:
        thread.join()
        scene.close(), stranger.close()
    f = forces(d)
    states = np.array([r[11] for r in d.rows])
    asked = np.where((states == "ok")[:, None], [1.0, 0.0, 0.0], 0.0)
    print(f"paired: {np.sum(states == 'ok')} periods ok; link {d.lcm.counts}")
    assert np.sum(states == "ok") > 10
    assert np.max(np.abs(f - asked)) <= 0.01
    # the driver's socket is connected to the scene: the kernel drops the stranger's datagrams
    # before they are queued (before issue 55, each was read and counted here as foreign)
    assert sent > 0 and d.lcm.counts["udp_foreign"] == 0


# -- Why 2: forged poses took over the scene ---------------------------------------------------------------


def test_forged_poses_neither_move_the_target_nor_lock_the_driver_out():
    """The driver sends its poses; a stranger sends three poses 10 m away stamped utime 2^62 (the
    device's guard relocates after three samples that agree), in both formats. Before pairing the
    target went 10 m away and every later pose of the driver was dropped as stale; now the
    target stays on the driver's poses and none of them is stale."""
    scene = Scene("udp://127.0.0.1:0")
    stranger = udp_socket()
    link = driver_lcm(f"udp://127.0.0.1:{scene.lcm.port}")
    try:
        utime = deliver(scene, link, above(0.001), 1)
        for k in range(3):
            forged_pose = pose_message(2**62 + k, FAR, Q).encode()
            stranger.sendto(lc02(POSE_CHANNEL, forged_pose, k + 1), ("127.0.0.1", scene.lcm.port))
            stranger.sendto(forged(b"D", POSE_CHANNEL, forged_pose, 2**62), ("127.0.0.1", scene.lcm.port))
            time.sleep(0.002)
            assert np.linalg.norm(scene.step() - START) < 0.01, "a forged pose moved the target"
        utime = deliver(scene, link, above(0.002), utime)
        deliver(scene, link, above(0.003), utime)
        status = scene.device.lcm_status()
    finally:
        scene.close(), stranger.close(), link.close()
    assert status["lcm_stale_messages"] == 0
    assert status["lcm_udp_malformed"] == 3 and status["lcm_udp_unauthenticated"] == 3


def test_the_scene_answers_no_stranger_and_takes_no_forged_driver_counts():
    """A stranger sends junk, a forged HELLO and a forged driver status (driver_loops 1e9) to a
    scene with no driver. Before pairing the scene sent its feedback to whoever sent last (the
    stranger received it) and the metrics said driver_loops 1e9; now the stranger receives
    nothing and the metrics keep no driver count."""
    scene = Scene("udp://127.0.0.1:0")
    stranger = udp_socket()
    at = ("127.0.0.1", scene.lcm.port)
    try:
        forged_status = status_message(5, {"loops": 1e9, "watchdog_trips": 7}).encode()
        for datagram in (b"junk", lc02(DRIVER_STATUS_CHANNEL, forged_status), forged(b"H"),
                         forged(b"D", DRIVER_STATUS_CHANNEL, forged_status)):  # fmt: skip
            stranger.sendto(datagram, at)
        time.sleep(0.01)
        for _ in range(20):
            scene.step()
            scene.lcm.Publish(FEEDBACK_CHANNEL, feedback(3.0))
        scene.device.zero_feedback(0.02)
        heard = drain(stranger)
        status = scene.device.lcm_status()
    finally:
        scene.close(), stranger.close()
    assert heard == [], f"the stranger received {len(heard)} datagrams"
    assert status["driver_loops"] == 0 and status["driver_watchdog_trips"] == 0
    assert status["driver_status_messages"] == 0
    assert status["lcm_udp_received"] == 4 and status["lcm_udp_sent"] == 0


# -- Why 3: one truncated datagram killed either side ------------------------------------------------------


def test_truncated_datagrams_are_counted_and_the_scene_runs_on():
    """Truncated pose and driver-status messages, in LCM's packet and cut anywhere in the paired
    one: the scene polls on (before pairing, struct.error out of the device's poll), counts each,
    and then takes the driver's poses as before."""
    scene = Scene("udp://127.0.0.1:0")
    stranger = udp_socket()
    at = ("127.0.0.1", scene.lcm.port)
    link = driver_lcm(f"udp://127.0.0.1:{scene.lcm.port}")
    try:
        pose = pose_message(1, START, Q).encode()
        status = status_message(1, {"loops": 5}).encode()
        cut = [lc02(POSE_CHANNEL, pose[:20]), lc02(DRIVER_STATUS_CHANNEL, status[:30])]
        cut += [forged(b"D", POSE_CHANNEL, pose)[:n] for n in (3, 5, 40, 60, 100)]
        for datagram in cut:
            stranger.sendto(datagram, at)
        time.sleep(0.01)
        for _ in range(5):
            scene.step()
        deliver(scene, link, above(0.001), 1)
        counts = scene.device.lcm_status()
    finally:
        scene.close(), stranger.close(), link.close()
    assert counts["lcm_udp_malformed"] + counts["lcm_udp_unauthenticated"] == len(cut)
    assert counts["lcm_bad_messages"] == 0 and counts["driver_loops"] == 0


def test_a_scene_sent_truncated_datagrams_runs_to_its_end_and_writes_its_metrics_whole():
    """The brick scene with a driver's device on udp:// (no driver, so ``wait_s: 0``), sent
    truncated pose and status messages before and while it runs: before pairing struct.error
    ended the run (exit 1, no metrics at all); now it runs its 0.2 s and its metrics count each
    datagram."""
    from godobject_drake.config import scenario as sc
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    probe = udp_socket()
    port = probe.getsockname()[1]
    probe.close()  # a port free a moment ago, for the scene
    scenario = sc.load_scenario(REPO / "diagrams" / "lego.yaml",
                                f"device: !Lcm {{url: 'udp://127.0.0.1:{port}', rate_hz: 200.0, wait_s: 0}}\n"
                                "simulation: {duration_s: 0.2}")  # fmt: skip
    station = build_station(scenario)
    stranger = udp_socket()
    cut = [lc02(POSE_CHANNEL, pose_message(1, START, Q).encode()[:20]),
           lc02(DRIVER_STATUS_CHANNEL, status_message(1, {"loops": 9}).encode()[:30]),
           forged(b"D", POSE_CHANNEL, pose_message(1, START, Q).encode())[:60]]  # fmt: skip
    try:
        for datagram in cut:
            stranger.sendto(datagram, ("127.0.0.1", port))

        def more(metrics):
            for datagram in cut:
                stranger.sendto(datagram, ("127.0.0.1", port))

        m = simulate(station, progress=False, checkpoint=more, checkpoint_period_s=0.0).metrics
    finally:
        stranger.close()
        station.device.lcm.close()
    assert m["sim_time_s"] == pytest.approx(0.2) and not m["diverged"]
    assert m["lcm_bad_messages"] == 0 and m["driver_loops"] == 0
    assert m["lcm_udp_received"] >= 2 * len(cut) and m["lcm_udp_received"] % len(cut) == 0
    assert m["lcm_udp_malformed"] == m["lcm_udp_received"] and m["lcm_udp_pairings"] == 0


def test_a_truncated_message_of_the_paired_driver_is_dropped_and_counted():
    """The paired driver itself (a bug, a version mismatch) sends a truncated pose and a truncated
    status: before, struct.error out of the scene's poll; now lcm_bad_messages and
    driver_bad_status count them and the next good pose is taken."""
    scene = Scene("udp://127.0.0.1:0")
    link = driver_lcm(f"udp://127.0.0.1:{scene.lcm.port}")
    try:
        utime = deliver(scene, link, above(0.001), 1)
        link.Publish(POSE_CHANNEL, pose_message(utime, START, Q).encode()[:25])
        link.Publish(DRIVER_STATUS_CHANNEL, status_message(utime, {"loops": 3}).encode()[:30])
        time.sleep(0.01)
        scene.step()
        deliver(scene, link, above(0.002), utime + 1)
        counts = scene.device.lcm_status()
    finally:
        scene.close(), link.close()
    assert counts["lcm_bad_messages"] == 1 and counts["driver_bad_status"] == 1


def test_a_truncated_feedback_leaves_the_driver_process_running_and_its_summary_whole(tmp_path):
    """The driver is its own process; the test holds the scene's address and sends back, from
    there, truncated feedback in both formats. Before pairing the driver exited 1 with a
    traceback (struct.error); now it runs to its --duration, exits 0 and writes its summary."""
    scene_at = udp_socket()
    url = f"udp://127.0.0.1:{scene_at.getsockname()[1]}"
    command = [sys.executable, "-m", "godobject_drake.driver.process", "run", "emulated", "--scene", url,
               "--duration", "1.5", "--summary", str(tmp_path / "driver.json")]  # fmt: skip
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    try:
        scene_at.settimeout(30.0)
        _, driver_at = scene_at.recvfrom(65535)
        for n in (5, 20, 37, 50):
            scene_at.sendto(lc02(FEEDBACK_CHANNEL, feedback(1.0))[:n], driver_at)
            scene_at.sendto(forged(b"S", FEEDBACK_CHANNEL, feedback(1.0))[:n], driver_at)
        scene_at.sendto(lc02(FEEDBACK_CHANNEL, feedback(1.0)[:10]), driver_at)
        err = process.communicate(timeout=60)[1]
    finally:
        process.kill()
        scene_at.close()
    assert process.returncode == 0 and "Traceback" not in err, err[-3000:]
    summary = json.loads((tmp_path / "driver.json").read_text())
    assert summary["counts"]["loops"] > 100 and summary["counts"]["bad_feedback"] == 0
    assert summary["link"]["udp_malformed"] + summary["link"]["udp_unauthenticated"] == 9


def test_a_restarted_drivers_poses_move_the_scene_though_its_clock_starts_again(monkeypatch):
    """A driver's ``utime`` counts from its own start: a restarted one's first poses are far below
    the last of the driver it replaces. Before, the scene dropped each as stale (the tool frozen
    for as long as the first had run); now a new pairing starts the scene's utime check anew."""
    from godobject_drake.link import transport

    monkeypatch.setattr(transport, "DRIVER_SILENT_S", 0.3)  # 1 s by default; the test is quicker
    scene = Scene("udp://127.0.0.1:0")
    url = f"udp://127.0.0.1:{scene.lcm.port}"
    a = b = None
    try:
        a = driver_lcm(url)
        deliver(scene, a, START + np.array([0.01, 0.0, 0.0]), utime=10**9)  # A ran 1000 s
        a.close()  # and crashed
        b = driver_lcm(url)
        deliver(scene, b, START + np.array([0.0, 0.02, 0.0]), utime=1)  # B, restarted, from its first period
        assert scene.lcm.counts["udp_pairings"] == 2
    finally:
        for link in (a, b):
            if link is not None:
                link.close()
        scene.close()


# -- Why 4: a second driver was accepted silently ----------------------------------------------------------


def test_a_scene_takes_one_driver_and_a_second_renders_nothing(caplog):
    """Driver A pairs and feels the scene's 1.5 N; driver B (the same user's, the same key) starts
    while A runs. Before pairing B rendered the scene's 1.5 N too and the scene's driver_* counts
    mixed the two; now B renders nothing and is told why, the scene says it refused B (its log,
    lcm_udp_refused_drivers), and the counts in the metrics are A's alone.

    The scene and both drivers are threads of this process, sharing its GIL on a machine others
    load too: a driver's feedback is aged from its previous poll, so a driver thread held off the
    GIL for 10 ms (the default watchdog) rendered nothing. A's watchdog is 0.1 s here, and the scene
    steps at about its period (a real scene waits for the wall clock) rather than taking the GIL
    in a busy loop: what A renders is then the scene's force, which this test is about; the
    watchdog has its own tests (test_driver.py)."""
    scene = Scene("udp://127.0.0.1:0")
    url = f"udp://127.0.0.1:{scene.lcm.port}"
    a, thread_a = driver(driver_lcm(url), 30.0, watchdog_periods=100, exit_on_stop=True)
    b = thread_b = None
    try:
        with caplog.at_level("WARNING", logger="godobject_drake"):
            end = time.monotonic() + 1.0
            while time.monotonic() < end or b is None or thread_b.is_alive():  # the scene runs on
                scene.step()
                scene.lcm.Publish(FEEDBACK_CHANNEL, feedback(1.5))
                time.sleep(T)  # the scene's period: the drivers' threads get the GIL
                if b is None and a.heard_scene:
                    b, thread_b = driver(driver_lcm(url), 0.5)
            scene.device.zero_feedback(scene.k * T)  # the scene stops: A exits (--exit-on-stop)
            while thread_a.is_alive():
                scene.step()
            for _ in range(50):
                scene.step()  # A's last counts, sent as it exits
            status = scene.device.lcm_status()
    finally:
        thread_a.join()
        if thread_b is not None:
            thread_b.join()
        scene.close()
    f_a, f_b = forces(a), forces(b)
    asked_a, asked_b = (np.array([r[4:7] for r in d.rows], float) for d in (a, b))
    print(f"A asked 1.5 N in {np.sum(asked_a[:, 0] == 1.5)} periods, rendered it in "
          f"{np.sum(f_a[:, 0] == 1.5)} (the rest: watchdog, ramps); "
          f"B in {np.sum(f_b[:, 0] == 1.5)}")  # fmt: skip
    assert a.heard_scene and np.any(asked_a[:, 0] == 1.5) and np.max(f_a[:, 0]) > 0.0  # A feels the scene
    # most periods that asked it rendered it (99 % at a load of 10 on 2 cores; a busy-looping scene
    # with a 10 ms watchdog: 28-50 %, and once 0)
    assert np.sum(f_a[:, 0] == 1.5) >= 0.5 * np.sum(asked_a[:, 0] == 1.5)
    assert np.all(f_b == 0.0) and np.all(asked_b == 0.0) and not b.heard_scene
    assert a.counts["scene_stops"] == 1
    assert status["driver_loops"] == a.counts["loops"]  # A's last counts, sent as it stopped
    assert status["driver_status_messages"] == a.counts["loops"] // 100 + 1
    assert status["lcm_udp_refused_drivers"] == 1 and b.lcm.counts["udp_refused"] >= 1
    logged = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("refused a second driver") for m in logged), logged
    assert any("refused this driver" in m for m in logged), logged


def test_the_driver_renders_nothing_before_it_is_paired_with_a_key_of_its_own(tmp_path):
    """A scene with another key (another user's): the driver's HELLOs go unanswered, so it never
    pairs and renders nothing however long the scene sends its feedback."""
    theirs = tmp_path / "theirs" / "link.key"
    load_key(theirs, create=True)  # a named key file must exist: made here as its own end would
    scene = make_lcm("udp://127.0.0.1:0", theirs)
    d, thread = driver(driver_lcm(f"udp://127.0.0.1:{scene.port}"), 0.3)
    try:
        while thread.is_alive():
            scene.HandleSubscriptions(1)
            scene.Publish(FEEDBACK_CHANNEL, feedback(2.0))
    finally:
        thread.join()
        scene.close()
    assert np.all(forces(d) == 0.0) and not d.lcm.paired
    assert scene.counts["udp_unauthenticated"] >= 1 and scene.counts["udp_unpaired"] >= 1
    assert scene.counts["udp_sent"] == 0  # it answered no HELLO and sent no feedback


# -- issue 55, item 2: a flood on the driver's port starved its loop ----------------------------------------

FLOOD_S = 4.0  # as the issue measured
PUSH_N = 1.0  # the stand-in scene's feedback force (N, along x)
WATCHDOG_PERIODS = 50  # 50 ms (the default 10): the scene's thread is Python, in the test's process
FLOODERS = 2  # processes: one Python process sends ~150k datagrams a second on a loaded 2-core machine
FLOODER = """
import signal, socket, sys, time
port, seconds = int(sys.argv[1]), float(sys.argv[2])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
junk, to, sent = b"GOD1S" + bytes(100), ("127.0.0.1", port), 0
def done(*_):
    print(sent, start, time.monotonic(), flush=True)
    sys.exit(0)
signal.signal(signal.SIGTERM, done)
print("flooding", flush=True)
start = time.monotonic()
end = start + seconds
while time.monotonic() < end:
    for _ in range(1000):
        try:
            s.sendto(junk, to)
        except OSError:
            pass
    sent += 1000
done()
"""


class PushingScene:
    """A scene's end on a free port of 127.0.0.1 (a thread): once paired, its feedback wrench,
    ``PUSH_N`` along x, every millisecond; :meth:`stop` sends the scene's STOP once."""

    def __init__(self):
        self.link = make_lcm("udp://127.0.0.1:0")
        self.url = f"udp://127.0.0.1:{self.link.port}"
        self.running, self.stopping, self.stopped = True, False, False
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        k = 0
        while self.running:
            self.link.HandleSubscriptions(0)
            if self.stopping:  # the scene's last word, as a scene's at its end
                self.link.Publish(FEEDBACK_CHANNEL + STOP_SUFFIX, lcmt_force_torque().encode())
                self.stopping, self.stopped = False, True
            elif self.link.paired and not self.stopped:
                k += 1
                self.link.Publish(FEEDBACK_CHANNEL, feedback(PUSH_N, k * 1000))
            time.sleep(0.001)

    @property
    def driver_port(self) -> int:
        return self.link.end.peer[1]

    def stop(self):
        self.stopping = True

    def close(self):
        self.running = False
        self.thread.join(timeout=10)
        self.link.close()


def log_forces(path) -> np.ndarray:
    log = read_log(path) if path.exists() else None
    if log is None or not len(log["t"]):
        return np.zeros(0)
    return np.linalg.norm(np.c_[log["fx"], log["fy"], log["fz"]], axis=1)


@pytest.mark.slow
@pytest.mark.realtime
def test_a_flood_on_the_drivers_port_changes_nothing_it_renders_and_the_stop_arrives(tmp_path):
    """A real driver process (the emulated device) renders a scene's steady push (its feedback
    wrench, 1 N every millisecond, ``--no-local-model``, the watchdog 50 ms); two processes flood
    the driver's port (read, as any user can, from /proc/net/udp; here from the scene's pairing)
    from 127.0.0.1 as fast as they can for 4 s (180k to 310k datagrams a second here), then the
    scene sends its STOP once, the flood still running. Before (measured with this test), the
    driver read every datagram of the flood (``udp_foreign``, ~550k), its loop ran 28 % to 53 % of
    its periods, and at the default 10 ms watchdog the force fell to zero 8 times in 4 s (the
    issue's measurement also lost the STOP). Now: the loop runs, every period of the flood is
    ``ok`` and renders what the second before it rendered (1 N, its whole range), and the STOP
    ends the driver (``--exit-on-stop``) while the flood runs. Realtime: a machine that holds up
    the scene's thread 50 ms trips the watchdog with no flood at all."""
    scene = PushingScene()
    csv = tmp_path / "driver.csv"
    command = [sys.executable, "-m", "godobject_drake.driver.process", "run", "emulated", "--scene",
               scene.url, "--no-local-model", "--watchdog-periods", str(WATCHDOG_PERIODS),
               "--grasp", "always", "--exit-on-stop", "--duration", "120",
               "--log", str(csv), "--summary", str(tmp_path / "driver.json")]  # fmt: skip
    driver = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    flooders = []
    try:
        deadline = time.monotonic() + 60
        while np.sum(log_forces(csv) == PUSH_N) < 1500:  # pushing for 1.5 s
            assert driver.poll() is None, driver.stderr.read()[-3000:]
            assert time.monotonic() < deadline, f"the driver never rendered the push: {log_forces(csv)[-5:]}"
            time.sleep(0.5)  # the log read seldom: the scene's thread needs the GIL
        for _ in range(FLOODERS):
            flooders.append(subprocess.Popen([sys.executable, "-c", FLOODER, str(scene.driver_port), "60"],
                                             stdout=subprocess.PIPE, text=True))  # fmt: skip
        assert all(flooder.stdout.readline().strip() == "flooding" for flooder in flooders)
        time.sleep(FLOOD_S)
        t_stop = time.monotonic()
        scene.stop()
        try:
            driver.wait(timeout=10)
        finally:
            still_flooding = all(flooder.poll() is None for flooder in flooders)
            exited = time.monotonic()
            for flooder in flooders:
                flooder.terminate()
            said = [flooder.communicate(timeout=30)[0].split() for flooder in flooders]
            sent, starts, ends = np.array(said, float).T
        err = driver.communicate(timeout=30)[1]
    finally:
        driver.kill()
        for flooder in flooders:
            flooder.kill()
        scene.close()
    log = read_log(csv)
    summary = json.loads((tmp_path / "driver.json").read_text())
    f = log_forces(csv)
    sent, flood_start, flood_end = sent.sum(), starts.min(), ends.max()
    rate = sent / (flood_end - flood_start)
    before = (log["t"] >= flood_start - 1.0) & (log["t"] < flood_start)
    during = (log["t"] >= flood_start) & (log["t"] < t_stop)
    low, high = f[before].min(), f[before].max()
    print(f"flood: {sent:.0f} datagrams in {flood_end - flood_start:.2f} s ({rate:,.0f}/s); undisturbed "
          f"|f| {low:.6f} to {high:.6f} N over {before.sum()} periods; flooded {f[during].min():.6f} to "
          f"{f[during].max():.6f} N over {during.sum()} periods, states {set(log['state'][during])}; "
          f"the driver exited {exited - t_stop:.2f} s after the STOP; counts {summary['counts']}; "
          f"link {summary['link']}")  # fmt: skip
    assert driver.returncode == 0, err[-3000:]
    assert rate > 50_000  # the machine's own ceiling (module docstring of this test)
    # the loop not starved: 73 % to 95 % of its periods ran on a loaded 2-core machine, the two
    # flooders taking their share of the cores (before: 28 % to 53 %, reading the flood)
    assert before.sum() > 500 and during.sum() > 0.6 * (t_stop - flood_start) * 1000
    assert np.all(log["state"][during] == "ok")  # no watchdog trip (a loaded machine's start may have some)
    assert low == high == PUSH_N and np.all((f[during] >= low - 1e-9) & (f[during] <= high + 1e-9))
    assert summary["counts"]["scene_stops"] == 1 and still_flooding
    assert log["state"][-2] == "stopped" and f[-1] == 0.0
