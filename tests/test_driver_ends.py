"""Every way the driver process ends, or is stopped, while it pushes: the device is commanded zero
first; its outputs (``--log``, ``--summary``, ``calibrate --out``) checked before the device is
opened and a failed write ending it cleanly; the device's own watchdog armed where the SDK has one;
and the scene's side of a closed terminal (the table of what is guarded in docs/haptic_devices.md).

A real driver process (the emulated device, ``--no-local-model``: the scene's newest wrench, held)
paired with a scene end of this test's own that sends 6 N of feedback every millisecond, so the
driver is rendering 6 N when the signal comes. Before, SIGHUP and SIGQUIT ended it with its log's
last row ``ok`` at the force and no exit row, and SIGTSTP held the force for the whole stop.

The checks are logical (which rows the log holds, in which order), not timings, so they hold on a
loaded machine; each waits on the clock only for the driver to reach a state, generously."""

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque

import numpy as np
import pytest
from drake import lcmt_force_torque
from test_link import scene_link

from godobject_drake.driver import process as drv
from godobject_drake.driver.families import RATED
from godobject_drake.link.messages import FEEDBACK_CHANNEL

PUSH_N = 6.0  # five rated-rate steps (12 N / 10 ms at 1 kHz: 1.2 N a period) from zero
STEP_N = RATED["emulated"].max_force_n / 10


class PushingScene:
    """A scene's end on a free port of 127.0.0.1 that, once paired, sends ``PUSH_N`` along x every
    millisecond (a thread), until :meth:`close`."""

    def __init__(self):
        self.link = scene_link()
        self.url = f"udp://127.0.0.1:{self.link.port}"
        self.running = True
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        k = 0
        while self.running:
            self.link.HandleSubscriptions(0)
            if self.link.paired:
                k += 1
                m = lcmt_force_torque()
                m.timestamp, m.fx = k * 1000, PUSH_N
                self.link.Publish(FEEDBACK_CHANNEL, m.encode())
            time.sleep(0.001)

    def close(self):
        self.running = False
        self.thread.join(timeout=10)
        self.link.close()


def start(tmp_path, url, *extra):
    command = [sys.executable, "-m", "godobject_drake.driver.process", "run", "emulated", "--scene", url,
               "--no-local-model", "--grasp", "always", "--log", str(tmp_path / "driver.csv"),
               "--summary", str(tmp_path / "driver.json"), *extra]  # fmt: skip
    return subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True)


def forces(log) -> np.ndarray:
    return np.linalg.norm(np.c_[log["fx"], log["fy"], log["fz"]], axis=1)


def wait_until(what: str, done, timeout_s: float = 60.0):
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, f"not within {timeout_s} s: {what}"
        time.sleep(0.05)


def log_of(tmp_path):
    path = tmp_path / "driver.csv"
    return drv.read_log(path) if path.exists() else None


def pushing(tmp_path, n: int = 300) -> bool:
    """The log (flushed every 100 periods) holds ``n`` periods rendering the whole push."""
    log = log_of(tmp_path)
    return log is not None and np.sum(np.isclose(forces(log), PUSH_N)) >= n


def process_state(pid: int) -> str:
    """The process's state letter in /proc (``T``: stopped)."""
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0]


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGQUIT, signal.SIGTERM, signal.SIGINT],
                         ids=lambda s: signal.Signals(s).name)  # fmt: skip
def test_every_ending_signal_zeroes_the_device_and_writes_the_exit_row(tmp_path, signum):
    """SIGHUP (a closed terminal, a dropped SSH session) and SIGQUIT (Ctrl-\\\\) as SIGTERM and
    Ctrl-C: the driver, rendering 6 N, renders zero, writes its exit row and its summary (naming
    the signal) and exits 0."""
    scene = PushingScene()
    driver = start(tmp_path, scene.url)
    try:
        wait_until("the driver renders the push", lambda: pushing(tmp_path))
        driver.send_signal(signum)
        err = driver.communicate(timeout=60)[1]
    finally:
        driver.kill()
        scene.close()
    assert driver.returncode == 0, err[-3000:]
    log = log_of(tmp_path)
    assert log["state"][-1] == "exit" and forces(log)[-1] == 0.0
    summary = json.loads((tmp_path / "driver.json").read_text())
    assert summary["ended_by"] == signal.Signals(signum).name
    assert f"ended by {signal.Signals(signum).name}: zero force commanded" in err


@pytest.mark.slow
def test_ctrl_z_zeroes_the_device_before_the_process_stops_and_it_ramps_from_zero_after(tmp_path):
    """SIGTSTP (Ctrl-Z) while 6 N is rendered: the log's last row before the stop is ``paused`` at
    zero, and the process is stopped (it held 6 N for the whole stop). On SIGCONT the force comes
    back from zero by at most the rated step a period, never a step to the held 6 N; SIGTERM then
    ends it as usual."""
    scene = PushingScene()
    driver = start(tmp_path, scene.url)
    try:
        wait_until("the driver renders the push", lambda: pushing(tmp_path))
        driver.send_signal(signal.SIGTSTP)
        wait_until("the driver stops", lambda: process_state(driver.pid) == "T")
        stopped = log_of(tmp_path)
        time.sleep(0.3)  # stopped while the scene keeps sending
        driver.send_signal(signal.SIGCONT)
        wait_until("the driver pushes again", lambda: pushing(tmp_path, n=len(stopped["t"]) + 200))
        driver.send_signal(signal.SIGTERM)
        err = driver.communicate(timeout=60)[1]
    finally:
        driver.kill()
        scene.close()
    assert stopped["state"][-1] == "paused" and forces(stopped)[-1] == 0.0, stopped["state"][-5:]
    assert driver.returncode == 0, err[-3000:]
    log = log_of(tmp_path)
    f = forces(log)
    (paused,) = np.flatnonzero(log["state"] == "paused")
    after = f[paused:]
    assert np.all(np.diff(after) <= STEP_N + 1e-9), np.diff(after).max()
    assert np.any(np.isclose(after, PUSH_N)) and log["state"][-1] == "exit"
    assert json.loads((tmp_path / "driver.json").read_text())["pauses"] == 1


@pytest.mark.slow
def test_a_crash_of_the_driver_leaves_its_traceback(tmp_path):
    """A crash (here SIGSEGV, as a vendor library's fault gives) cannot command zero from inside the
    process: what covers it is the scene-side watchdog and the device's own, where armed. The
    driver leaves at least the traceback of where it crashed (``faulthandler``), not a bare
    'Segmentation fault'."""
    scene = PushingScene()
    driver = start(tmp_path, scene.url)
    try:
        wait_until("the driver renders the push", lambda: pushing(tmp_path, n=100))
        driver.send_signal(signal.SIGSEGV)
        err = driver.communicate(timeout=60)[1]
    finally:
        driver.kill()
        scene.close()
    assert driver.returncode == -signal.SIGSEGV
    assert "Fatal Python error: Segmentation fault" in err and "godobject_drake/driver/process.py" in err


# -- the driver's outputs, guarded before the device is opened --------------------------------------------


def run_driver(tmp_path, *extra, timeout_s: float = 30.0, **popen):
    """The driver with no scene (``--duration 20``); its exit code and stderr, or a failure if it
    has not ended within ``timeout_s`` (it hung)."""
    command = [sys.executable, "-m", "godobject_drake.driver.process", "run", "emulated", "--scene",
               "udp://127.0.0.1:9", "--duration", "20", *extra]  # fmt: skip
    process = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True, **popen)
    try:
        err = process.communicate(timeout=timeout_s)[1]
    except subprocess.TimeoutExpired:
        process.terminate()
        try:
            process.communicate(timeout=5)
            ended = f"ended by SIGTERM, rc {process.returncode}"
        except subprocess.TimeoutExpired:
            ended = "deaf to SIGTERM"
        process.kill()
        process.communicate()
        pytest.fail(f"the driver had not ended after {timeout_s} s ({ended})")
    return process.returncode, err


@pytest.mark.slow
def test_a_log_naming_a_fifo_nobody_reads_is_refused_at_once(tmp_path):
    """It hung before the loop (opening the FIFO for writing waits for a reader), deaf to SIGTERM."""
    fifo = tmp_path / "log.csv"
    os.mkfifo(fifo)
    rc, err = run_driver(tmp_path, "--log", str(fifo), timeout_s=20)
    assert rc == 2, err
    assert f"--log {fifo} is not a regular file" in err and "give a file, e.g. driver.csv" in err
    assert "godobject-driver emulated:" not in err  # refused before the device was opened


@pytest.mark.slow
def test_a_log_on_a_character_device_is_refused_at_once(tmp_path):
    """``/dev/full`` (every write fails with ENOSPC) was opened, and the driver died at its first
    flush with a traceback; a device is no log the loop may write to every period."""
    rc, err = run_driver(tmp_path, "--log", "/dev/full", timeout_s=20)
    assert rc == 2 and "--log /dev/full is not a regular file" in err and "Traceback" not in err, err


@pytest.mark.slow
@pytest.mark.parametrize("where", ["folder", "missing folder"])
def test_a_summary_naming_a_folder_or_a_missing_folder_is_refused_at_once(tmp_path, where):
    """It failed only at the end of the run (IsADirectoryError, a traceback), the run's summary lost."""
    target = tmp_path if where == "folder" else tmp_path / "no_such" / "driver.json"
    rc, err = run_driver(tmp_path, "--summary", str(target), timeout_s=20)
    assert rc == 2 and "Traceback" not in err, err
    assert f"--summary: {target}" in err
    assert ("give a file name, e.g." if where == "folder" else "create it or write elsewhere") in err
    assert "godobject-driver emulated:" not in err


@pytest.mark.slow
def test_a_write_error_on_the_log_stops_the_driver_with_zero_and_says_why(tmp_path):
    """A log that cannot grow (a file-size limit here, ``RLIMIT_FSIZE``: EFBIG as a full disk gives
    ENOSPC, both a real write error at a flush) while the driver renders 6 N. It died at the flush
    with a traceback; now it stops before its next period (zero, the device closed), says why,
    writes its summary (naming the error) and exits 1."""
    import resource

    scene = PushingScene()
    limit = 200_000  # ~1600 rows: past the first pushes

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    log = tmp_path / "driver.csv"
    try:
        rc, err = run_driver(tmp_path, "--scene", scene.url, "--no-local-model", "--grasp", "always",
                             "--log", str(log), "--summary", str(tmp_path / "driver.json"),
                             timeout_s=40, preexec_fn=small_files)  # fmt: skip
    finally:
        scene.close()
    assert rc == 1 and "Traceback" not in err, err[-3000:]
    assert f"--log {log}: could not write (File too large); the force was zeroed" in err
    summary = json.loads((tmp_path / "driver.json").read_text())
    assert "File too large" in summary["output_error"] and summary["counts"]["loops"] < 5000
    assert np.any(np.isclose(forces(drv.read_log(log)), PUSH_N))  # it was pushing when the log filled


def test_a_log_cut_short_is_read_to_its_last_whole_line(tmp_path):
    """A log cut by a full disk or a file-size limit (or read while the driver writes it) ends in
    a partial line; cut after a comma it has every field, the last one empty, and reading it
    raised ``could not convert string to float: ''`` (the test above, at one cut in some).
    Its whole lines are read, at every cut of the last one."""
    header = drv.Driver.LOG_HEADER
    row = "1.5,0,0,0,0,0,6,0,0,6,0.25,ok,0,1,1,0,0"
    assert len(row.split(",")) == len(header.split(","))
    whole = f"{header}\n{row}\n"
    for cut in range(len(row) + 1):
        path = tmp_path / f"cut_{cut}.csv"
        path.write_text(whole + row[:cut])
        log = drv.read_log(path)
        assert log["fz"].tolist() == [6.0] and log["state"].tolist() == ["ok"], cut
    path.write_text(whole)
    assert drv.read_log(path)["t"].tolist() == [1.5]
    path.write_text(header[:20])  # the header itself cut short: no rows
    assert drv.read_log(path)["t"].tolist() == []


# -- the device's own watchdog, where the vendor's SDK has one ----------------------------------------------


@pytest.fixture
def dhd(monkeypatch):
    """Force Dimension's wrapper, the stand-in (tests/stand_ins/README.md)."""
    import importlib

    from test_driver import STAND_INS

    monkeypatch.syspath_prepend(str(STAND_INS))
    for name in [n for n in sys.modules if n.split(".")[0] == "forcedimension_core"]:
        monkeypatch.delitem(sys.modules, name)
    return importlib.import_module("forcedimension_core.dhd")


def test_the_force_dimension_watchdog_is_armed_at_the_start(dhd):
    """Its SDK's expert ``setWatchdog`` (125 µs units): 25 ms without a command and the firmware turns
    the forces off, which covers what the driver cannot (SIGKILL, a crash). It was never armed."""
    device = drv.FAMILIES["forcedimension"]()
    try:
        assert dhd.state["watchdog"] == 200 and not dhd.state["expert"]  # expert mode left as found
        assert device.watchdog == "device watchdog armed: forces off 25 ms after the last command"
    finally:
        device.close()


def test_a_force_dimension_model_without_a_watchdog_says_so_and_runs(dhd, monkeypatch):
    monkeypatch.setitem(dhd.state, "has_watchdog", False)
    device = drv.FAMILIES["forcedimension"]()
    try:
        assert device.watchdog.startswith("device watchdog NOT armed (no error (stand-in))")
    finally:
        device.close()


@pytest.mark.parametrize("family", ["emulated", "haply", "openhaptics"])
def test_the_families_without_a_device_watchdog_say_so(family):
    assert drv.FAMILIES[family].watchdog.startswith("no device watchdog")


def test_calibrate_refuses_an_out_folder_before_the_sweep(tmp_path, capsys, monkeypatch):
    """``calibrate --out`` naming a folder: nothing looked at it before the whole sweep had run (its
    --seconds; here a still hand, so it then complained of the handle, never of the folder; a hand
    that moved would have met ``Path.write_text``'s IsADirectoryError, which nothing caught). Now
    exit 2 before the device is opened, naming the value and the fix."""
    from test_driver import LEGO_DRIVER

    opened = []
    monkeypatch.setattr(drv, "open_device", lambda *a: opened.append(a) or pytest.fail("device opened"))
    rc = drv.main(["calibrate", "emulated", "--scenario", str(LEGO_DRIVER), "--out", str(tmp_path),
                   "--seconds", "3"])  # fmt: skip
    assert rc == 2 and not opened
    assert f"--out: {tmp_path} is a folder; give a file name, e.g. {tmp_path / 'calibrated.yaml'}" in (
        capsys.readouterr().err
    )


# -- the scene's side: a closed terminal ends the run as SIGTERM does --------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGQUIT], ids=lambda s: signal.Signals(s).name)
def test_sighup_to_the_scene_stops_the_device_and_writes_the_metrics(tmp_path, signum):
    """The scene (``godobject run``, the quick start's !Lcm scene) and a real driver
    (``--exit-on-stop``) as processes; once the run is under way the scene gets SIGHUP (its
    terminal closed) or SIGQUIT (Ctrl-\\). Before, it died by the signal (SIGQUIT: a core dump):
    no metrics, no STOP (the driver ran on with the last model until its fade). Now it ends as for
    SIGTERM: the device's STOP (the driver counts it, renders zero and exits 0), the metrics
    written marked interrupted, exit 128 + N (129, 131)."""
    from test_driver import free_port, lcm_scenario, start_driver

    from godobject_drake.config import scenario as sc

    url = f"udp://127.0.0.1:{free_port()}"
    scenario = tmp_path / "scene.yaml"
    s = sc.replace(lcm_scenario(url, 120.0), **{"metrics.checkpoint_period_s": 0.3})
    scenario.write_text(sc.scenario_to_yaml(s))
    scene = subprocess.Popen([sys.executable, "-m", "godobject_drake", "run", str(scenario), "--no-progress",
                              "--metrics", str(tmp_path / "m.json")], cwd=tmp_path,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    driver = start_driver(tmp_path, url, "--exit-on-stop", "--duration", "600")
    try:
        wait_until("the run is under way", lambda: (tmp_path / "m.json").exists(), timeout_s=240)
        scene.send_signal(signum)
        scene_err = scene.communicate(timeout=120)[1]
        driver_rc = driver.wait(timeout=60)
    finally:
        scene.kill(), driver.kill()
    assert scene.returncode == 128 + signum, scene_err[-3000:]
    assert f"interrupted ({signal.Signals(signum).name}) at t = " in scene_err
    assert "metrics written to" in scene_err
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["interrupted"] is True and m["partial"] is True
    assert driver_rc == 0
    summary = json.loads((tmp_path / "driver.json").read_text())
    log = drv.read_log(tmp_path / "driver.csv")
    assert summary["counts"]["scene_stops"] == 1 and log["state"][-2] == "stopped"
    assert np.all(forces(log)[np.flatnonzero(log["state"] == "stopped")[0] :] == 0.0)


@pytest.mark.slow
def test_a_driver_started_under_nohup_keeps_running_through_sighup(tmp_path):
    """``nohup`` starts a process with SIGHUP ignored, asking it to outlive its terminal: the driver
    keeps it ignored (renders on), and SIGTERM still ends it with zero."""
    scene = PushingScene()
    command = [sys.executable, "-m", "godobject_drake.driver.process", "run", "emulated", "--scene",
               scene.url, "--no-local-model", "--grasp", "always", "--log", str(tmp_path / "driver.csv"),
               "--summary", str(tmp_path / "driver.json")]  # fmt: skip
    driver = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True,
                              preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))  # fmt: skip
    try:
        wait_until("the driver renders the push", lambda: pushing(tmp_path))
        driver.send_signal(signal.SIGHUP)
        rows = len(log_of(tmp_path)["t"])
        wait_until("the driver renders on", lambda: pushing(tmp_path, n=rows + 300))
        assert driver.poll() is None
        driver.send_signal(signal.SIGTERM)
        err = driver.communicate(timeout=60)[1]
    finally:
        driver.kill()
        scene.close()
    assert driver.returncode == 0, err[-3000:]
    assert json.loads((tmp_path / "driver.json").read_text())["ended_by"] == "SIGTERM"
    assert log_of(tmp_path)["state"][-1] == "exit"


# -- a driver killed and started again while its scene runs -------------------------------------------------


class Relay:
    """A UDP relay on 127.0.0.1 between a driver and a scene's end: each datagram forwarded, and
    the driver's kept (:attr:`sent`) to be replayed later, as a process that captured them would."""

    def __init__(self, scene_port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port, self.scene = self.sock.getsockname()[1], ("127.0.0.1", scene_port)
        self.driver, self.sent, self.running = None, deque(maxlen=500), True
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        while self.running:
            try:
                datagram, sender = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            if sender == self.scene:
                if self.driver is not None:
                    self.sock.sendto(datagram, self.driver)
            else:
                self.driver = sender
                self.sent.append(datagram)
                self.sock.sendto(datagram, self.scene)

    def close(self):
        self.running = False
        self.thread.join(timeout=10)
        self.sock.close()


@pytest.mark.slow
def test_a_killed_driver_started_again_renders_its_scene_and_its_old_sessions_datagrams_are_refused(tmp_path):
    """Driver A (a process, through a relay that keeps what it sends) renders the scene's push;
    it is killed (SIGKILL: no goodbye); driver B, started again with the same key, pairs once A has
    been silent ``DRIVER_SILENT_S`` (1 s) and renders the push; A's datagrams replayed then (its
    data, of its old session) are refused and counted, and B renders on. Before, B was refused
    until the scene ended, the tool frozen."""
    from godobject_drake.link import transport

    scene = PushingScene()
    relay = Relay(scene.link.port)
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    a = start(tmp_path / "a", f"udp://127.0.0.1:{relay.port}", "--duration", "600")
    b = None
    try:
        wait_until("A renders the push", lambda: pushing(tmp_path / "a"))
        a.kill()
        a.wait(timeout=30)
        killed = time.monotonic()
        b = start(tmp_path / "b", scene.url, "--duration", "600")
        wait_until("B renders the push", lambda: pushing(tmp_path / "b"))
        assert time.monotonic() - killed > transport.DRIVER_SILENT_S  # not before A was silent
        assert scene.link.counts["udp_pairings"] == 2
        old = [d for d in relay.sent if d[len(transport.MAGIC) : transport.HEAD] == transport.DRIVER_DATA]
        assert len(old) >= 100  # A's pose messages, sealed in its session
        refused = scene.link.counts["udp_refused"]
        for datagram in old:
            relay.sock.sendto(datagram, relay.scene)
        wait_until("the replay refused", lambda: scene.link.counts["udp_refused"] >= refused + len(old), 10)
        rows = len(log_of(tmp_path / "b")["t"])
        wait_until("B renders on", lambda: pushing(tmp_path / "b", n=rows + 300))
        assert scene.link.counts["udp_pairings"] == 2  # no third: the replay paired nothing
        b.send_signal(signal.SIGTERM)
        assert b.wait(timeout=30) == 0
    finally:
        for proc in (a, b):
            if proc is not None:
                proc.kill()
        relay.close()
        scene.close()
