"""What does pairing cost per message? (every datagram of a udp:// link is tagged and
checked, godobject_drake.link.transport.)

Times, per message, on this machine's CPU (no socket): sealing a driver's pose (~170 bytes with
its head and tag) and the scene's checks of it, and sealing a scene's feedback (~110 bytes) and
the driver's checks; against the same messages framed as LCM's short-message packet without any
check (the link before pairing: a header, the channel, the payload). Then the whole path over a
socket on 127.0.0.1 (UdpLcm.Publish, then HandleSubscriptions handing it on), for scale.

    python analysis/link_cost.py [--n 20000] [--repeat 7]

Each figure is the best of ``--repeat`` runs of ``--n`` messages (the least disturbed by other
load), in µs per message. The socket part uses a temporary key of this run, never the user's.
"""

import argparse
import struct
import sys
import tempfile
import timeit
from pathlib import Path

from drake import lcmt_force_torque

from godobject_drake.link.messages import FEEDBACK_CHANNEL, POSE_CHANNEL, pose_message
from godobject_drake.link.transport import DriverEnd, SceneEnd, UdpLcm

KEY = bytes(range(32))


def lc02(channel: str, payload: bytes, seqno: int) -> bytes:
    return struct.pack(">II", 0x4C433032, seqno & 0xFFFFFFFF) + channel.encode() + b"\0" + payload


def un_lc02(datagram: bytes):
    end = datagram.find(b"\0", 8)
    return datagram[8:end].decode(), datagram[end + 1 :]


def best(stmt, n: int, repeat: int) -> float:
    return min(timeit.repeat(stmt, number=n, repeat=repeat)) / n * 1e6


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n", type=int, default=20000, help="messages per run (default 20000)")
    parser.add_argument("--repeat", type=int, default=7, help="runs; the best is kept (default 7)")
    args = parser.parse_args(argv)

    scene, driver = SceneEnd(KEY), DriverEnd(KEY, ("127.0.0.1", 7667))
    _, welcome = scene.receive(driver.hello(0.0), ("127.0.0.1", 40000))
    scene.receive(driver.receive(welcome, ("127.0.0.1", 7667), 0.0)[1], ("127.0.0.1", 40000))
    pose = pose_message(1, [0.1, 0.2, 0.3], [1.0, 0.0, 0.0, 0.0], "*").encode()
    force = lcmt_force_torque()
    force.fx = 1.0
    force = force.encode()

    # each run seals fresh messages (their counters grow) and checks them at the other end
    def driver_to_scene():
        assert scene.receive(driver.seal(POSE_CHANNEL, pose), ("127.0.0.1", 40000))[0] is not None

    def scene_to_driver():
        assert driver.receive(scene.seal(FEEDBACK_CHANNEL, force), ("127.0.0.1", 7667), 0.0)[0] is not None

    seq = iter(range(1 << 62))
    n, r = args.n, args.repeat
    rows = [
        (
            "pose, LCM packet, no check (before)",
            best(lambda: un_lc02(lc02(POSE_CHANNEL, pose, next(seq))), n, r),
        ),
        ("pose, driver seals + scene checks", best(driver_to_scene, n, r)),
        (
            "feedback, LCM packet, no check (before)",
            best(lambda: un_lc02(lc02(FEEDBACK_CHANNEL, force, 1)), n, r),
        ),
        ("feedback, scene seals + driver checks", best(scene_to_driver, n, r)),
        ("seal alone (pose)", best(lambda: driver.seal(POSE_CHANNEL, pose), n, r)),
    ]
    print(f"per message, best of {r} runs of {n} (µs); datagram {len(driver.seal(POSE_CHANNEL, pose))} "
          f"bytes for a pose ({len(pose)}-byte LCM message), {len(scene.seal(FEEDBACK_CHANNEL, force))} "
          f"for a feedback ({len(force)})")  # fmt: skip
    for name, us in rows:
        print(f"  {name:42s} {us:7.2f}")

    key_file = Path(tempfile.mkdtemp(prefix="link_cost_")) / "link.key"  # this run's, not the user's
    listen = UdpLcm.listen("udp://127.0.0.1:0", key_file)
    connect = UdpLcm.connect(f"udp://127.0.0.1:{listen.port}", key_file)
    got = []
    listen.Subscribe(POSE_CHANNEL, got.append)
    while not (listen.paired and connect.paired):
        connect.HandleSubscriptions(1)
        listen.HandleSubscriptions(1)

    def over_socket():
        connect.Publish(POSE_CHANNEL, pose)
        while not listen.HandleSubscriptions(0):
            pass

    m = max(n // 10, 100)
    print(f"  {'pose over 127.0.0.1 (Publish + poll), paired':42s} {best(over_socket, m, r):7.2f}")
    listen.close(), connect.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
