"""What does a soft body (``deformables:``) cost a plant step, against its vertex count?

A box of soft tissue (8 x 8 x 3 cm, E = 50 kPa), hung from the world by its top face in the cube-and-
post scene (examples/cube_post.yaml) clear of everything, meshed finer and finer; each run is
``--seconds`` of simulated time at the scene's h = 1 ms, its CPU time per step (the metrics'
``cpu_time_s``: the process's, which other work on the machine moves less than the wall time)
against the same scene without the soft body, the best of ``--rounds``. The
cost includes the soft body's observer (its metrics and surface, per step). Prints a Markdown
table, nproc, the CPU and the load, and the fit ``cost ≈ a + b·n + c·n²`` that
``godobject_drake.systems.soft_body.estimated_step_cost_s`` uses to refuse a mesh too fine.

    python analysis/soft_body_cost.py [--seconds 0.3] [--rounds 2]
"""

import argparse
import os
import platform
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESOLUTIONS_M = (0.04, 0.027, 0.02, 0.0135, 0.01, 0.008)


def scene(resolution_m: float | None, seconds: float):
    from godobject_drake.config.scenario import load_scenario, replace

    overrides = None
    if resolution_m is not None:
        overrides = (
            "deformables:\n  pad:\n    shape: box\n    size_m: [0.08, 0.08, 0.03]\n"
            f"    resolution_m: {resolution_m}\n    xyz_m: [0.0, -0.12, 0.2]\n    max_slowdown: 1000\n"
            "    attach: [{to: world, lower_m: [-0.05, -0.17, 0.2145], upper_m: [0.05, -0.07, 0.2155]}]\n"
        )
    scenario = load_scenario(ROOT / "examples" / "cube_post.yaml", overrides)
    return replace(scenario, **{"simulation.duration_s": seconds})


def step_cost_us(resolution_m, seconds: float, rounds: int) -> tuple[float, int]:
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    best, vertices = np.inf, 0
    for _ in range(rounds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            station = build_station(scene(resolution_m, seconds))
        result = simulate(station, progress=False)
        steps = round(result.metrics["sim_time_s"] / result.metrics["time_step_s"])
        best = min(best, 1e6 * result.metrics["cpu_time_s"] / steps)
        vertices = sum(len(b.rest_W) for b in station_soft_bodies(station))
    return best, vertices


def station_soft_bodies(station):
    observers = [s for s in station.diagram.GetSystems() if s.get_name().endswith("_soft_body_observer")]
    return [o._body for o in observers]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=0.3)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args(argv)
    load = os.getloadavg()
    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")), platform.processor())  # fmt: skip
    print(f"nproc {os.cpu_count()}, CPU {cpu}, load {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (before)")
    base, _ = step_cost_us(None, args.seconds, args.rounds)
    print(f"\nscene without a soft body: {base:.0f} µs a step\n")
    print("| resolution (mm) | vertices | step, CPU (µs) | soft body's share (µs) | per vertex (µs) |")
    print("|---:|---:|---:|---:|---:|")
    ns, costs = [], []
    for r in RESOLUTIONS_M:
        cost, n = step_cost_us(r, args.seconds, args.rounds)
        ns.append(n)
        costs.append(cost - base)
        print(f"| {r * 1e3:g} | {n} | {cost:.0f} | {cost - base:.0f} | {(cost - base) / n:.1f} |", flush=True)
    c2, c1, c0 = np.polyfit(ns, costs, 2, w=1.0 / np.asarray(costs))  # relative error, each alike
    print(f"\nfit: cost ≈ {c0:.3g} µs + {c1:.3g} µs · n + {c2:.3g} µs · n²")
    load = os.getloadavg()
    print(f"load {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (after)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
