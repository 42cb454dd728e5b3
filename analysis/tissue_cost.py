#!/usr/bin/env python3
"""The FEM tissue's cost: the laparoscopy scene's real-time factor with FEM organs against the
rigid ones, measured in one process, the runs interleaved (rigid, FEM, rigid, FEM, ...) so a
change in the machine's load hits both alike.

    python analysis/tissue_cost.py --duration 3 --cells 4 6 8 --steps 0.001 --repeats 2

Prints nproc and the CPU model beside the absolute figures, and each run's metrics that say
what the tissue did (the real-time factor is simulated time over wall time).
"""

import argparse
import json
import os
import platform
import time

from godobject_drake.config import scenario as sc
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station


def cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def run(model: str, cells: int, step: float, duration: float) -> dict:
    text = f"organs: {{model: {model}, cells: {cells}}}\nsimulation: {{duration_s: {duration}}}\n"
    text += f"plant: {{time_step: {step}, discrete_contact_approximation: sap, contact_model: point}}\n"
    s = sc.shipped_scenario("laparoscopy", text)
    station = build_station(s)
    start = time.perf_counter()
    m = simulate(station, progress=False).metrics
    wall = time.perf_counter() - start
    keep = ("diverged", "max_penetration_m", "tissue_max_displacement_m", "max_tissue_contact_force_N",
            "tool_tip_inside_tissue_steps")  # fmt: skip
    row = {"model": model, "cells": cells if model == "fem" else None, "time_step_s": step}
    row.update(sim_s=duration, wall_s=wall, rtf=duration / wall)
    return {**row, **{k: m.get(k) for k in keep}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds a run (s)")
    parser.add_argument("--cells", type=int, nargs="+", default=[4, 8], help="FEM mesh cells a side")
    parser.add_argument("--steps", type=float, nargs="+", default=[0.001], help="plant time steps (s)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--json", help="write the rows here")
    args = parser.parse_args(argv)
    print(f"nproc {os.cpu_count()}, CPU {cpu_model()}, load average {os.getloadavg()[0]:.2f}")
    rows = []
    for _ in range(args.repeats):
        for step in args.steps:
            for cells in args.cells:
                for model in ("rigid", "fem"):
                    row = run(model, cells, step, args.duration)
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    print(f"load average after {os.getloadavg()[0]:.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"nproc": os.cpu_count(), "cpu": cpu_model(), "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
