"""Does a driver's memory stay bounded however long it runs? (The goal: a driver
left alone an hour keeps its memory within 5 MB.)

Runs ``godobject-driver run emulated`` (no ``--log``) for ``--minutes`` and samples its resident
memory (VmRSS, /proc/PID/status) every ``--every`` seconds; then fits a straight line to the
samples after the first ``--warmup`` seconds (least squares) and prints its slope, with the
memory at the start and the end and the spread about the line. Loopback only (127.0.0.1).

    python analysis/driver_memory.py                       # the driver alone (no scene): 10 min
    python analysis/driver_memory.py --scene               # a paired scene sends 1 N every ms
    python analysis/driver_memory.py --minutes 2 --every 5 --csv rss.csv

The link's key is a temporary one of this run (GODOBJECT_LINK_KEY), never the user's own. With
``--scene`` this process plays the scene's end of the link (godobject_drake.link.transport.UdpLcm):
it pairs with the driver and sends it a 1 N feedback wrench every millisecond, so the driver's
every period holds a force and a feedback gap. Linux only (/proc).
"""

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmRSS for process {pid}")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def play_scene(url: str, stop: threading.Event) -> dict:
    """The scene's end of the link: answer the driver, send 1 N along x every millisecond."""
    from drake import lcmt_force_torque

    from godobject_drake.link.messages import FEEDBACK_CHANNEL
    from godobject_drake.link.transport import UdpLcm

    link = UdpLcm.listen(url)
    message = lcmt_force_torque()
    message.fx = 1.0
    next_at = time.monotonic()
    try:
        while not stop.is_set():
            link.HandleSubscriptions(0)
            message.timestamp += 1000
            link.Publish(FEEDBACK_CHANNEL, message.encode())
            next_at += 0.001
            time.sleep(max(0.0, next_at - time.monotonic()))
    finally:
        link.close()
    return link.counts


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--minutes", type=float, default=10.0, help="how long the driver runs (default 10)")
    parser.add_argument("--every", type=float, default=10.0, help="seconds between samples (default 10)")
    parser.add_argument("--warmup", type=float, default=60.0, help="seconds left out of the fit (default 60)")
    parser.add_argument("--scene", action="store_true", help="pair a scene sending 1 N every ms")
    parser.add_argument("--csv", default="", help="write the samples (t_s, rss_mb) here")
    args = parser.parse_args(argv)
    if not (args.minutes * 60 > args.warmup + 3 * args.every):
        parser.error("--minutes must leave at least three samples after --warmup")

    work = Path(tempfile.mkdtemp(prefix="driver_memory_"))  # mode 0700: a key folder of this run
    os.environ["GODOBJECT_LINK_KEY"] = str(work / "link.key")
    url = f"udp://127.0.0.1:{free_port()}"
    stop, scene_counts = threading.Event(), {}
    if args.scene:
        scene = threading.Thread(target=lambda: scene_counts.update(play_scene(url, stop)), daemon=True)
        scene.start()
        time.sleep(0.5)
    duration = args.minutes * 60.0
    driver = subprocess.Popen(
        [sys.executable, "-m", "godobject_drake.driver.process", "run", "emulated", "--scene", url,
         "--duration", str(duration + 5.0), "--summary", str(work / "driver.json")],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    samples = []
    start = time.monotonic()
    try:
        while time.monotonic() - start < duration:
            samples.append((time.monotonic() - start, rss_mb(driver.pid)))
            print(f"  {samples[-1][0]:7.1f} s  {samples[-1][1]:8.2f} MB", file=sys.stderr, flush=True)
            time.sleep(args.every)
        driver.wait(timeout=120)
    finally:
        stop.set()
        driver.kill()
    t, rss = np.array(samples).T
    after = t >= args.warmup
    slope, intercept = np.polyfit(t[after], rss[after], 1)
    spread = np.max(np.abs(rss[after] - (slope * t[after] + intercept)))
    if args.csv:
        np.savetxt(args.csv, np.c_[t, rss], delimiter=",", header="t_s,rss_mb", comments="")
    print(f"driver ({'paired, 1 N every ms' if args.scene else 'alone, no scene'}), {args.minutes:g} min, "
          f"{len(t)} samples every {args.every:g} s")  # fmt: skip
    print(f"  RSS {rss[0]:.2f} MB at {t[0]:.0f} s, {rss[after][0]:.2f} MB at {t[after][0]:.0f} s, "
          f"{rss[-1]:.2f} MB at {t[-1]:.0f} s")  # fmt: skip
    print(f"  slope after {args.warmup:g} s: {slope * 3600:+.3f} MB/h ({slope * 1e3:+.4f} kB/s); "
          f"largest distance from the line {spread:.3f} MB")  # fmt: skip
    print(f"  an hour at this slope: {rss[after][0] + slope * 3600:.2f} MB "
          f"({slope * 3600:+.2f} MB over the first fitted sample)")  # fmt: skip
    if scene_counts:
        print(f"  scene's link: {scene_counts}")
    print(f"  driver's exit: {driver.stderr.read().strip().splitlines()[-1:]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
