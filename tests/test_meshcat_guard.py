"""A bad frame on Meshcat's websocket cannot lose a run (issue 55, item 3).

Drake's Meshcat (1.51.1 and 1.58) catches only msgpack's type errors in a websocket message: one
byte msgpack never uses (0xc1), from any local process or a web page, ends its server thread. Every
later Meshcat call then raises, the recording's HTML cannot be made, and a process that exits
before that thread has logged its end aborts (std::terminate: exit 134): a haptic scene recording
its run lost its metrics and its recording. What is measured here: the run ends at its next drawn
frame, its metrics (partial) are written and say why, the recording says why it is not made, and
the process exits 1, not by an abort. The client here is a plain socket speaking RFC 6455, as any
process on the machine can.
"""

import base64
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO

from godobject_drake.systems.drawing import start_meshcat
from godobject_drake.systems.page import page_of, server_stopped

BAD_FRAME = b"\xc1"  # "never used" in the msgpack format: msgpack's parse error, not a type error


def websocket_send(port: int, payload: bytes, host: str = "127.0.0.1") -> None:
    """One binary websocket message to ``host:port``: the opening handshake, then one masked frame."""
    assert len(payload) < 126  # one length byte
    with socket.create_connection((host, port), timeout=10) as s:
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall(
            f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        reply = b""
        while b"\r\n\r\n" not in reply:
            chunk = s.recv(65536)
            assert chunk, f"the server closed before the handshake's end: {reply[:200]!r}"
            reply += chunk
        assert reply.startswith(b"HTTP/1.1 101"), reply[:200]
        mask = os.urandom(4)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        s.sendall(bytes([0x82, 0x80 | len(payload)]) + mask + masked)  # FIN, binary; masked, length
        time.sleep(0.2)


def listening_ports(pid: int) -> list[int]:
    """The TCP ports process ``pid`` listens on (its sockets' inodes in /proc/PID/net/tcp*)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    ports = []
    for table in ("tcp", "tcp6"):
        path = Path(f"/proc/{pid}/net/{table}")
        for line in path.read_text().splitlines()[1:] if path.exists() else []:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # LISTEN
                ports.append(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def test_a_bad_frame_stops_the_server_and_server_stopped_says_so_once_its_thread_has_ended():
    meshcat = start_meshcat(port=0)
    thread = Path(f"/proc/self/task/{page_of(meshcat).server_thread}")
    assert thread.exists()  # the one thread Meshcat's constructor started: its server
    assert server_stopped(meshcat) is None
    websocket_send(meshcat.port(), BAD_FRAME)
    start = time.monotonic()
    while (why := server_stopped(meshcat)) is None:
        assert time.monotonic() - start < 10, "one byte 0xc1 no longer stops Drake's Meshcat: see docs"
        time.sleep(0.05)
    assert "a frame it could not parse" in why and "exited unexpectedly" in why
    assert not thread.exists()  # ended: the process may exit without Drake's abort
    assert server_stopped(meshcat) is why  # said once, then the same


def test_a_process_whose_meshcat_a_client_stopped_exits_without_an_abort(tmp_path):
    """Nothing asks the stopped Meshcat anything: at exit the package lets its thread end (it
    aborted the process, exit 134, with Drake's ``terminate called ... parse error``)."""
    code = (
        "import sys, time\n"
        "sys.path.insert(0, sys.argv[1])\n"
        "from test_meshcat_guard import BAD_FRAME, websocket_send\n"
        "from godobject_drake.systems.drawing import start_meshcat\n"
        "meshcat = start_meshcat(port=0)\n"
        "websocket_send(meshcat.port(), BAD_FRAME)\n"
        "time.sleep(0.3)\n"
        "print('done', flush=True)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, str(REPO / "tests")], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-2000:])
    assert proc.stdout == "done\n" and "terminate called" not in proc.stderr


@pytest.mark.slow
def test_a_bad_frame_on_meshcats_websocket_ends_a_recording_haptic_run_with_its_metrics(tmp_path):
    """The brick scene with a simulated haptic device, recording (the recording-only server, on a
    random port, allowed without ``--trust-local-pages``): a byte on its websocket ended the process
    with exit 134 while it saved the recording, the final metrics lost."""
    scenario = (REPO / "diagrams" / "lego.yaml").read_text()
    assert "\nmetrics:\n" in scenario
    checkpointed = scenario.replace("\nmetrics:\n", "\nmetrics:\n  checkpoint_period_s: 0.2\n")
    (tmp_path / "lego.yaml").write_text(checkpointed)
    proc = subprocess.Popen(
        [sys.executable, "-m", "godobject_drake", "run", str(tmp_path / "lego.yaml"), "--no-progress",
         "--haptic", "impedance", "--duration", "60", "--metrics", "m.json", "--record", "r.html"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        start = time.monotonic()
        while not (tmp_path / "m.json").exists():  # the first checkpoint: written from inside the loop
            assert time.monotonic() - start < 60 and proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        (port,) = listening_ports(proc.pid)  # as any local user reads it from /proc/net/tcp
        websocket_send(port, BAD_FRAME)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 1, (proc.returncode, err[-3000:])
    assert "terminate called" not in err and "Traceback" not in err
    m = json.loads((tmp_path / "m.json").read_text())
    assert "meshcat_error" in m and "could not parse" in m["meshcat_error"]
    assert m["partial"] is True and not m["diverged"] and m["diagnosis"] is None
    assert 0.0 < m["sim_time_s"] < 60.0
    assert f"the run ended at t = {m['sim_time_s']:.4f} s" in m["meshcat_error"]
    assert m["max_penetration_m"] is not None and m["device_samples"] >= 1  # measured, not empty
    assert "r.html: not made" in m["recording_error"] and not (tmp_path / "r.html").exists()
    assert "recording not written" in err and "metrics written to" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lego.yaml", "m.json"]  # no .tmp or .lock


def test_at_exit_only_the_meshcats_made_on_the_exiting_thread_are_asked():
    """Drake's Meshcat answers only the thread that made it (another's call aborts: a
    DRAKE_DEMAND). A Meshcat made in a worker thread and alive at exit is left alone by the
    package's exit check (Drake's own destructor still aborts on it: not this package's to change)."""
    code = (
        "import threading\n"
        "from godobject_drake.systems.drawing import start_meshcat\n"
        "keep = []\n"
        "worker = threading.Thread(target=lambda: keep.append(start_meshcat(port=0)))\n"
        "worker.start(); worker.join()\n"
        "print('done', flush=True)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout == "done\n", proc.stderr[-2000:]
    assert "ThrowIfWebsocketThreadExited" not in proc.stderr, proc.stderr[-2000:]
