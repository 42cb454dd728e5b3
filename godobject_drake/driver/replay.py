"""Replay a device CSV onto LCM at its timestamps: a stand-in for a device driver.

``python -m godobject_drake.driver.replay LOG.csv --lcm-url URL [--channel C] [--speed S]``

Each row ``t,x,y,z,qw,qx,qy,qz,grasp`` (README "Device log format") is published at ``t / S``
seconds after the start as an ``lcmt_robot_state`` pose sample (``utime`` = t in µs; a grasp
column ``*`` becomes ``grasp=*``, an empty one ``grasp=``). A real driver does the same from
its servo loop with the device's pose, and listens on the feedback channel for the wrench to
render (README "Real devices over LCM").
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

from godobject_drake.config.device_files import DeviceLog, read_device_log
from godobject_drake.protocol import POSE_CHANNEL, make_lcm, pose_message


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
        lcm.Publish(channel, pose_message(round(t * 1e6), p, q, grasp).encode())
    return len(log.t)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m godobject_drake.driver.replay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("log", help="a device CSV (t,x,y,z,qw,qx,qy,qz,grasp)")
    parser.add_argument("--lcm-url", default="", help="Drake's LCM URL (default Drake's: UDP multicast)")
    parser.add_argument("--channel", default=POSE_CHANNEL, help=f"default {POSE_CHANNEL}")
    parser.add_argument("--speed", type=float, default=1.0, help="time scale (1: the log's own timing)")
    args = parser.parse_args(argv)
    try:
        log = read_device_log(args.log)
        n = replay(log, make_lcm(args.lcm_url), args.channel, args.speed)
    except (ValueError, OSError) as e:
        parser.error(str(e))
    print(f"published {n} samples on {args.channel}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
