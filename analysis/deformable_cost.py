#!/usr/bin/env python3
"""Cost and accuracy of the two shell models of the deformable probe, at h = 1 ms and 10 ms.

    python analysis/deformable_cost.py [--repeats 3] [--out deformable_cost.md]

Runs the probe scene's (diagrams/deformable_probe.yaml) default path for each shell model and
time step (the interactive sizes: 129 FEM vertices, 42 mass–spring nodes)
and prints ms per step (median of ``--repeats`` runs, in this process, one
after the other) with the deformation and penetration metrics; then the
cost of the next mesh size of each model over a short run (``--big``).
"""

import argparse
import statistics
import sys
from pathlib import Path

from godobject_drake.config.scenario import replace, shipped_scenario
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station

INTERACTIVE = {
    "fem": {"god_object.spec.fem_resolution_m": 0.02},
    "mass_spring": {"god_object.spec.nodes": 42},
}
BIG = {"fem": {"god_object.spec.fem_resolution_m": 0.01}, "mass_spring": {"god_object.spec.nodes": 162}}


def measure(shell, size, time_step, duration, repeats):
    scenario = replace(shipped_scenario("deformable_probe"), **size,
                       **{"god_object.shell": shell, "plant.time_step": time_step})  # fmt: skip
    if duration is not None:
        scenario = replace(scenario, **{"simulation.duration_s": duration})
    runs = [simulate(build_station(scenario), progress=False).metrics for _ in range(repeats)]
    m = runs[0]
    m["ms_per_step"] = statistics.median(r["step_cost_us"] for r in runs) / 1e3
    return m


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=3, help="runs per row; the median is reported")
    parser.add_argument(
        "--big", action="store_true", help="also time 833 FEM vertices / 162 nodes (0.1 s runs)"
    )
    parser.add_argument("--out", type=Path, help="also write the table here (Markdown)")
    args = parser.parse_args(argv)
    lines = [
        "| shell | vertices | h (ms) | ms/step | real-time factor | max deformation (mm) "
        "| final deformation (mm) | max shell penetration (mm) | max core penetration (mm) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for shell, size in INTERACTIVE.items():
        for h in (0.001, 0.01):
            m = measure(shell, size, h, None, args.repeats)
            lines.append(
                f"| {shell} | {m['shell_vertices']} | {h * 1e3:g} | {m['ms_per_step']:.2f} "
                f"| {h * 1e3 / m['ms_per_step']:.2f} | {m['max_shell_deformation_m'] * 1e3:.2f} "
                f"| {m['final_shell_deformation_m'] * 1e3:.3f} | {m['max_penetration_m'] * 1e3:.2f} "
                f"| {m['max_core_penetration_m'] * 1e3:.2f} |"
            )
            print(lines[-1], file=sys.stderr)
    if args.big:
        for shell, size in BIG.items():
            m = measure(shell, size, 0.01, 0.1, 1)
            lines.append(
                f"| {shell} | {m['shell_vertices']} | 10 | {m['ms_per_step']:.1f} "
                f"| {10 / m['ms_per_step']:.2f} | (0.1 s run: cost only) | | | |"
            )
    table = "\n".join(lines)
    print(table)
    if args.out:
        args.out.write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
