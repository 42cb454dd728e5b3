"""Does the loop keep up? The brick scene driven over LCM at 1 kHz, on the wall clock.

A driver thread publishes the brick path (the scripted device's samples, taken at 1 kHz) on
``memq://`` (in this process; nothing reaches the network) at their wall-clock times, as a
device's servo loop would; the scene runs at real time with ``--device lcm`` expecting 1 kHz,
and reports how late each plant step came (``realtime_lag_*``) and what the device received.

    python analysis/lcm_lag.py [--duration 10] [--rate 1000]
"""

import argparse
import sys
import threading
import time

import numpy as np

from godobject_drake.config import scenario as sc
from godobject_drake.link.messages import POSE_CHANNEL, pose_message
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.station.loop import make_device


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=10.0, help="simulated and wall time (s)")
    parser.add_argument("--rate", type=float, default=1000.0, help="the driver's rate (Hz)")
    parser.add_argument(
        "--switch-interval", type=float, default=1e-3,
        help="Python's thread switch interval (s); the default 5 ms starves the driver thread",
    )  # fmt: skip
    args = parser.parse_args(argv)
    sys.setswitchinterval(args.switch_interval)  # the driver and the simulation share one GIL
    base = sc.shipped_scenario("lego")
    path = make_device(sc.replace(base, **{"device.rate_hz": args.rate}).device)  # the brick path
    samples = path.samples(args.duration)
    s = sc.replace(base, **{"simulation.duration_s": args.duration})
    X0 = path.samples(0.0)[0][1]
    s.device = sc.Lcm(url="memq://", rate_hz=args.rate, start_xyz=X0[0].tolist(),
                      start_rpy_deg=[0.0, 0.0, 0.0])  # fmt: skip
    station = build_station(s)
    lcm = station.device.lcm
    stop = threading.Event()
    late = []

    def driver():
        start = time.perf_counter()
        for t, (p, q, grasp) in samples:
            if stop.is_set():
                return
            wait = start + t - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            late.append(max(-wait, 0.0))
            lcm.Publish(POSE_CHANNEL, pose_message(round(t * 1e6), p, q, grasp or "").encode())

    thread = threading.Thread(target=driver, daemon=True)
    thread.start()
    try:
        m = simulate(station, progress=False).metrics
    finally:
        stop.set()
        thread.join()
    print(
        f"{args.duration:g} s at real time; driver: a thread at {args.rate:g} Hz on memq://, wall-clock "
        f"paced; thread switch interval {args.switch_interval:g} s"
    )
    for key in ("realtime_lag_p50_s", "realtime_lag_p99_s", "realtime_lag_max_s", "realtime_late_steps",
                "realtime_late_threshold_s", "real_time_factor", "step_cost_us", "lcm_messages", "lcm_bursts",
                "lcm_silent_samples", "lcm_stale_messages", "lcm_bad_messages", "device_samples",
                "device_dropped_samples", "max_penetration_m", "diverged"):  # fmt: skip
        print(f"{key:28s} {m.get(key)}")
    print(f"{'driver_late_p99_s':28s} {np.quantile(late, 0.99):.3g} (how late the thread published)")
    return 1 if m["diverged"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
