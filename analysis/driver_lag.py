"""How late is a real device's loop out of process? The brick scene and a 1 kHz driver as two
processes on loopback, idle and beside a CPU load.

The scene is the command line (``python -m godobject_drake run`` with ``device: !Lcm`` on
``udp://127.0.0.1:PORT``, expecting 1 kHz, at real time); the driver is ``godobject-driver run
emulated``, its simulated hand carrying brick_0 into the wall and pushing. Each phase runs the
pair for ``--duration`` simulated seconds, first alone, then beside ``--load`` processes that
spin the CPU (default: one per core). Reported per phase (p50, p99, max):

- ``driver loop``: how late each 1 ms period of the driver started (its own process, so the
  scene's work does not hold it, unlike the in-process thread of analysis/lcm_lag.py);
- ``feedback gap``: the time between two feedback messages arriving at the driver (1 ms when the
  scene keeps up at 1 kHz);
- ``scene step``: the scene's ``realtime_lag_*`` (how late each plant step came against the
  wall clock), with its real-time factor;
- the driver's watchdog trips (10 ms without feedback: force zeroed) and overruns.

    python analysis/driver_lag.py [--duration 10] [--load N] [--rt-priority P] [--idle-only] [--out lag.json]
        [--scenario diagrams/lego_haptic.yaml]

Not a test: figures depend on the machine. All traffic stays on 127.0.0.1.
"""

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HAND = {
    "waypoints": [
        {"t": 0.0, "xyz": [0.0, 0.05, -0.0152], "grasp": False},
        {"t": 0.3, "xyz": [0.0, 0.05, -0.0152], "grasp": True},
        {"t": 0.8, "xyz": [0.0, 0.05, 0.0], "grasp": True},
        {"t": 2.3, "xyz": [0.0, -0.06, 0.0], "grasp": True},
        {"t": 1e6, "xyz": [0.0, -0.06, 0.0], "grasp": True},
    ]
}
SPIN = "import time\nwhile True: pass"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def phase(work: Path, duration: float, load: int, rt_priority: int = 0, base: Path | None = None) -> dict:
    from godobject_drake.config import scenario as sc

    url = f"udp://127.0.0.1:{free_port()}"
    base = base or ROOT / "diagrams" / "lego.yaml"
    own = sc.load_scenario(base).device
    rate = own.rate_hz if type(own).__name__ == "Lcm" else 1000.0  # a recipe's own rate; else 1 kHz
    s = sc.load_scenario(
        base,
        f"""
device: !Lcm
  url: {url}
  rate_hz: {rate}
  start_xyz: [-0.10, 0.0, 0.0048]
  device_to_world: {{xyz: [-0.05, 0.0, 0.02], rpy_deg: [0, 0, 90]}}
feedback: {{kd: 50.0}}
simulation: {{duration_s: {duration}}}
""",
    )
    (work / "scene.yaml").write_text(sc.scenario_to_yaml(s))
    (work / "hand.json").write_text(json.dumps(HAND))
    spinners = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(load)]
    try:
        driver = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "godobject_drake.driver.process",
                "run",
                "emulated",
                "--scene",
                url,
                "--hand",
                str(work / "hand.json"),
                "--exit-on-stop",
                "--summary",
                str(work / "driver.json"),
                "--rt-priority",
                str(rt_priority),
            ],
            stderr=subprocess.DEVNULL,
        )
        start = time.monotonic()
        scene = subprocess.run(
            [
                sys.executable,
                "-m",
                "godobject_drake",
                "run",
                str(work / "scene.yaml"),
                "--no-progress",
                "--metrics",
                str(work / "metrics.json"),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        wall = time.monotonic() - start
        if scene.returncode not in (0, 1):
            raise RuntimeError(f"the scene failed: {scene.stderr[-2000:]}")
        driver.wait(timeout=60)
    finally:
        for p in spinners:
            p.kill()
        for p in spinners:
            p.wait()
    m = json.loads((work / "metrics.json").read_text())
    d = json.loads((work / "driver.json").read_text())
    return {
        "load_processes": load,
        "wall_s": wall,
        "loadavg_1min": os.getloadavg()[0],
        "scene": m,
        "driver": d,
    }


def row(name: str, p50, p99, mx) -> str:
    def ms(v):
        return "   n/a" if v is None or not math.isfinite(v) else f"{v * 1e3:6.2f}"

    return f"  {name:28s} {ms(p50)} {ms(p99)} {ms(mx)}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--duration", type=float, default=10.0, help="simulated seconds per phase (default 10)"
    )
    parser.add_argument(
        "--load", type=int, default=os.cpu_count() or 1, help="spinning processes (default: cores)"
    )
    parser.add_argument(
        "--rt-priority", type=int, default=0, help="the driver's SCHED_FIFO priority (0: none)"
    )
    parser.add_argument("--idle-only", action="store_true", help="skip the phase beside the load (CI)")
    parser.add_argument(
        "--scenario", type=Path, default=None,
        help="the scene's file (default diagrams/lego.yaml; its device is replaced by the driver's, "
        "at 1 kHz; e.g. diagrams/lego_haptic.yaml, the haptic recipe)",
    )  # fmt: skip
    parser.add_argument("--out", default="", help="write both phases' figures to FILE.json")
    args = parser.parse_args(argv)
    if not args.duration > 0 or args.load < 0:
        parser.error(f"--duration {args.duration} must be > 0 and --load {args.load} ≥ 0")
    cpu = next(
        (ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "?"
    )
    print(f"{os.cpu_count()} cores ({cpu}); loadavg before: {os.getloadavg()[0]:.2f}")
    results = {}
    phases = (("idle", 0),) if args.idle_only else (("idle", 0), ("loaded", args.load))
    for name, load in phases:
        with tempfile.TemporaryDirectory() as work:
            r = results[name] = phase(Path(work), args.duration, load, args.rt_priority, args.scenario)
        m, d = r["scene"], r["driver"]
        print(
            f"\n{name}: {load} spinning processes beside; {args.duration:g} s simulated "
            f"in {r['wall_s']:.1f} s "
            f"wall (scene real-time factor {m['real_time_factor']:.2f}); loadavg {r['loadavg_1min']:.2f}"
        )
        print(f"  {'(ms)':28s} {'p50':>6s} {'p99':>6s} {'max':>6s}")
        lo, gap = d["loop_lateness"], d["feedback_gap"]
        print(row("driver loop lateness", lo["p50_s"], lo["p99_s"], lo["max_s"]))
        print(row("feedback gap at the driver", gap["p50_s"], gap["p99_s"], gap["max_s"]))
        print(
            row(
                "scene step lag",
                m.get("realtime_lag_p50_s"),
                m.get("realtime_lag_p99_s"),
                m.get("realtime_lag_max_s"),
            )
        )
        print(
            f"  driver rt priority {d.get('rt_priority', 0)}; scene step cost {m['step_cost_us']:.0f} µs "
            f"(h = {m['time_step_s'] * 1e3:g} ms); scene ended "
            f"{m.get('realtime_lag_end_s', float('nan')):.3f} s behind; "
            f"warned: {m.get('realtime_warning') is not None}"
        )
        c = d["counts"]
        print(
            f"  driver: {c['loops']} periods, {c['overruns']} overruns, "
            f"{c['watchdog_trips']} watchdog trips, {c['rate_clamps']} rate clamps, "
            f"{c['buzz_events']} buzz events; scene: {m['lcm_messages']} poses, "
            f"{m['lcm_bursts']} bursts, {m['lcm_silent_samples']} silent samples"
        )
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
