"""Replay a device CSV onto LCM at its timestamps: a stand-in for a device driver.

``python -m godobject_drake.driver.replay LOG.csv --lcm-url URL [--key-file K] [--channel C] [--speed S]``

Each row ``t,x,y,z,qw,qx,qy,qz,grasp`` (docs/guide/devices.md#device-log-format-csv) is published at ``t / S``
seconds after the start as an ``lcmt_robot_state`` pose sample (``utime`` = t in µs; a grasp
column ``*`` becomes ``grasp=*``, an empty one ``grasp=``). A real driver does the same from
its servo loop with the device's pose, and listens on the feedback channel for the wrench to
render (docs/guide/lcm.md). On a ``udp://`` link it is a driver: it pairs with
the scene first (the key of ``--key-file``, :mod:`godobject_drake.link.keys`), then replays.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

from godobject_drake.config.device_files import DeviceLog, read_device_log
from godobject_drake.link.messages import POSE_CHANNEL, pose_message
from godobject_drake.link.transport import driver_lcm


def replay(
    log: DeviceLog,
    lcm,
    channel: str = POSE_CHANNEL,
    speed: float = 1.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> int:
    """Publish every row of ``log`` on ``channel`` at ``t / speed`` after the call; returns the count."""
    if not speed > 0:
        raise ValueError(f"speed={speed!r} must be > 0 (1: the log's own timing)")
    start = clock()
    for t, p, q, grasp in zip(log.t, log.p, log.q, log.grasp, strict=True):
        wait = start + t / speed - clock()
        if wait > 0:
            sleep(wait)
        lcm.HandleSubscriptions(0)  # a udp:// link hears its scene (and keeps its pairing) here
        lcm.Publish(channel, pose_message(round(t * 1e6), p, q, grasp).encode())
    return len(log.t)


def await_pairing(lcm, timeout_s: float, clock=time.monotonic, sleep=time.sleep) -> None:
    """Poll a ``udp://`` link until its scene has paired it; ``ValueError`` after ``timeout_s``."""
    end = clock() + timeout_s
    while not getattr(lcm, "paired", True):
        if clock() > end:
            raise ValueError(
                f"no scene at {lcm.get_lcm_url()} paired within {timeout_s:g} s: start the scene first, "
                f"with the same key file ({lcm.key_file})"
            )
        lcm.HandleSubscriptions(0)
        sleep(0.01)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m godobject_drake.driver.replay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("log", help="a device CSV (t,x,y,z,qw,qx,qy,qz,grasp)")
    parser.add_argument("--lcm-url", default="", help="Drake's LCM URL (default Drake's: UDP multicast)")
    parser.add_argument("--key-file", default="", help="udp://: the link's key (as godobject-driver's)")
    parser.add_argument("--channel", default=POSE_CHANNEL, help=f"default {POSE_CHANNEL}")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale (1: the log's own timing)")
    args = parser.parse_args(argv)
    try:
        log = read_device_log(args.log)
        lcm = driver_lcm(args.lcm_url, args.key_file)
        await_pairing(lcm, 30.0)
        n = replay(log, lcm, args.channel, args.speed)
    except (ValueError, OSError) as e:
        parser.error(str(e))
    print(f"published {n} samples on {args.channel}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
