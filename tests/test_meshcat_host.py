"""Every Meshcat the project starts listens on this machine only, unless asked otherwise, loudly.

The bound address is read from the kernel's socket tables (``/proc/net/tcp``, ``tcp6``), not
from what Meshcat prints: Drake's own default host is ``"*"`` (every interface), and the page
drives the device.
"""

import socket

import pytest
from conftest import scenario

from godobject_drake.station.build import make_meshcat
from godobject_drake.systems.drawing import start_meshcat


def listening_addresses(port: int) -> set[str]:
    """Local addresses of the listening TCP sockets on ``port``, IPv4 and IPv6."""
    found = set()
    for table, family in (("/proc/net/tcp", socket.AF_INET), ("/proc/net/tcp6", socket.AF_INET6)):
        try:
            lines = open(table).read().splitlines()[1:]
        except FileNotFoundError:
            continue
        for line in lines:
            local, state = line.split()[1], line.split()[3]
            address, port_hex = local.split(":")
            if state != "0A" or int(port_hex, 16) != port:  # 0A: LISTEN
                continue
            raw = bytes.fromhex(address)
            # The kernel prints each 32-bit word in host (little-endian) order.
            raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
            found.add(socket.inet_ntop(family, raw))
    return found


def test_a_recording_and_a_live_page_listen_on_loopback_only():
    recording = make_meshcat(scenario("lego", "--record", "unused.html"))
    assert listening_addresses(recording.port()) == {"127.0.0.1"}
    live = make_meshcat(scenario("lego", "--device", "meshcat"))
    assert listening_addresses(live.port()) == {"127.0.0.1"}
    assert live.web_url() == f"http://localhost:{live.port()}"  # what it prints is the truth
    served = make_meshcat(scenario("laparoscopy", "--meshcat"))
    assert listening_addresses(served.port()) == {"127.0.0.1"}


def test_another_host_is_deliberate_and_announced(capsys):
    meshcat = make_meshcat(scenario("lego", "--record", "unused.html", "--meshcat-host", "0.0.0.0"))
    assert listening_addresses(meshcat.port()) == {"0.0.0.0"}
    err = capsys.readouterr().err
    assert f"WARNING: Meshcat is listening on 0.0.0.0 port {meshcat.port()}, reachable from other" in err
    assert "anyone who can reach that address can open the page and drive the scene" in err
    assert f"ssh -N -L {meshcat.port()}:localhost:{meshcat.port()}" in err


def test_the_default_is_quiet(capsys):
    meshcat = start_meshcat(port=0)
    assert listening_addresses(meshcat.port()) == {"127.0.0.1"}
    assert "WARNING" not in capsys.readouterr().err


@pytest.mark.parametrize("host", ["", "   "])
def test_an_empty_host_is_refused(host):
    from godobject_drake.config.scenario import ScenarioError

    with pytest.raises(ScenarioError, match=r"visualization\.host: .* give localhost"):
        scenario("lego", "--meshcat-host", host)
