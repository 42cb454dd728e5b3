#!/usr/bin/env python3
"""What each lever of the FEM tissue costs and what it changes: the laparoscopy scenes with their
soft uterus, one lever moved at a time (the mesh's cells, the plant step, the coupling, Drake's
material and threads), each run against a reference on the same path.

    python analysis/fem_levers.py --out reports/fem_levers                   # the single levers
    python analysis/fem_levers.py --out reports/fem_levers --only cells4_h10_sap cells6_h5_sap
    python analysis/fem_levers.py --out reports/fem_levers --reference reports/fem_levers/rows.json

The reference is the scene with ``organs.cells 8`` at ``plant.time_step 0.001`` (the FEM organ as
the laparoscopy scene ships it: 729 vertices, 3 072 tetrahedra). Each row gives the run's CPU
and wall time per simulated second (a real-time run needs ≤ 1.0 s of wall time a simulated second)
and, against the reference, the largest tissue contact force and the tissue's largest
displacement (relative error), the steps the tool was inside the tissue, its deepest penetration
and the trocar's offset. ``--reference`` reuses the reference row of an earlier run's JSON (it
costs ~40 CPU seconds a simulated second). Runs one at a time in this process; prints ``nproc``,
the CPU model and the load beside the figures. Writes ``rows.json`` and ``table.md`` in ``--out``.
"""

import argparse
import json
import os
import time
from pathlib import Path

import yaml

from godobject_drake.config import scenario as sc
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.studies.benchmark import cpu_model, machine

# name: (scene, overrides on top of its soft uterus); "ref" is the reference
BASE = {"organs": {"model": "fem"}}
SAP = {"god_object": {"coupling": "joint_pd_sap"}}
G15 = {"cells": 6, "grading": 1.5}
RT = {"cells": 6, "grading": 1.7, "relaxation_time_s": 0.2, "stiffness_damping_s": 0.03}
LEVERS = {
    "ref": ("laparoscopy", {"organs": {"cells": 8}, "plant": {"time_step": 0.001}}),
    "cells6": ("laparoscopy", {"organs": {"cells": 6}}),
    "cells4": ("laparoscopy", {"organs": {"cells": 4}}),
    "h2": ("laparoscopy", {"plant": {"time_step": 0.002}}),
    "h5": ("laparoscopy", {"plant": {"time_step": 0.005}}),
    "h10": ("laparoscopy", {"plant": {"time_step": 0.01}}),
    "sap": ("laparoscopy", SAP),
    "h10_sap": ("laparoscopy", {"plant": {"time_step": 0.01}, **SAP}),
    "linear": ("laparoscopy", {"organs": {"material": "linear"}}),
    "corotated": ("laparoscopy", {"organs": {"material": "corotated"}}),
    "threads2": ("laparoscopy", {"organs": {"threads": 2}}),
    "cells6_g15": ("laparoscopy", {"organs": G15}),
    "cells4_g2": ("laparoscopy", {"organs": {"cells": 4, "grading": 2.0}}),
    "cells6_g17_sap": ("laparoscopy", {"organs": {"cells": 6, "grading": 1.7}, **SAP}),
    # combinations, by --only
    "cells6_g15_h5_sap": (
        "laparoscopy",
        {"organs": {"cells": 6, "grading": 1.5}, "plant": {"time_step": 0.005}, **SAP},
    ),
    "cells6_g15_h10_sap": (
        "laparoscopy",
        {"organs": {"cells": 6, "grading": 1.5}, "plant": {"time_step": 0.01}, **SAP},
    ),
    # the real-time candidates: a graded 6-cell mesh at h = 10 to 20 ms, the tissue's contact relaxed
    # over 20 h (a shorter one chatters at these steps), its stiffness damping raised to ~2.5 h
    "rt_h10": ("laparoscopy", {"organs": RT, "plant": {"time_step": 0.01}, **SAP}),
    "rt_h15": (
        "laparoscopy",
        {
            "organs": {**RT, "relaxation_time_s": 0.3, "stiffness_damping_s": 0.04},
            "plant": {"time_step": 0.015},
            **SAP,
        },
    ),
    "rt_h20": (
        "laparoscopy",
        {
            "organs": {**RT, "relaxation_time_s": 0.4, "stiffness_damping_s": 0.05},
            "plant": {"time_step": 0.02},
            **SAP,
        },
    ),
    "rt_h20_beta01": (
        "laparoscopy",
        {
            "organs": {**RT, "relaxation_time_s": 0.4, "stiffness_damping_s": 0.01},
            "plant": {"time_step": 0.02},
            **SAP,
        },
    ),
    "rt_h10_threads2": ("laparoscopy", {"organs": {**RT, "threads": 2}, "plant": {"time_step": 0.01}, **SAP}),
    "rt_h5": (
        "laparoscopy",
        {"organs": {**RT, "relaxation_time_s": 0.1}, "plant": {"time_step": 0.005}, **SAP},
    ),
    "rt_h10_tau01": (
        "laparoscopy",
        {"organs": {**RT, "relaxation_time_s": 0.01}, "plant": {"time_step": 0.01}, **SAP},
    ),
    "rt_h10_even": ("laparoscopy", {"organs": {**RT, "grading": 1.0}, "plant": {"time_step": 0.01}, **SAP}),
    "cells4_h10_sap": ("laparoscopy", {"organs": {"cells": 4}, "plant": {"time_step": 0.01}, **SAP}),
    "cells6_h5_sap": ("laparoscopy", {"organs": {"cells": 6}, "plant": {"time_step": 0.005}, **SAP}),
    "cells6_h10_sap": ("laparoscopy", {"organs": {"cells": 6}, "plant": {"time_step": 0.01}, **SAP}),
}


def merged(*parts: dict) -> dict:
    """The overrides of ``parts`` merged field by field (a later part's value wins)."""
    out: dict = {}
    for part in parts:
        for key, value in part.items():
            if isinstance(value, dict) and isinstance(out.get(key), dict):
                out[key] = merged(out[key], value)
            else:
                out[key] = value
    return out


SINGLE = ("ref", "cells6", "cells4", "h2", "h5", "h10", "sap", "h10_sap", "linear", "corotated", "threads2")
KEYS = ("max_tissue_contact_force_N", "tissue_max_displacement_m", "tool_tip_inside_tissue_steps",
        "max_penetration_m", "max_trocar_offset_m", "tissue_vertices", "diverged")  # fmt: skip


def run(name: str, duration: float | None) -> dict:
    """One lever's run over the scene's whole path (or ``duration`` s of it)."""
    scene, lever = LEVERS[name]
    overrides = merged(BASE, lever, {} if duration is None else {"simulation": {"duration_s": duration}})
    text = yaml.safe_dump(overrides, default_flow_style=True).strip()
    station = build_station(sc.shipped_scenario(scene, text))
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    m = simulate(station, progress=False, keep_logs=False).metrics
    total = time.perf_counter() - t0
    sim = m["sim_time_s"]
    row = {"lever": name, "scene": scene, "overrides": text,
           "time_step_s": m["time_step_s"], "sim_s": sim, "wall_s_per_s": m["wall_time_s"] / sim,
           "cpu_s_per_s": m["cpu_time_s"] / sim, "run_s": total, "load": load}  # fmt: skip
    return {**row, **{k: m.get(k) for k in KEYS}}


def against(row: dict, ref: dict) -> dict:
    """The row's errors against the reference: relative for the force and the displacement."""
    out = {}
    for key, label in (
        ("max_tissue_contact_force_N", "force_err"),
        ("tissue_max_displacement_m", "disp_err"),
    ):
        a, b = row.get(key), ref.get(key)
        out[label] = (a - b) / b if a is not None and b else None
    return out


def table(rows: list[dict]) -> str:
    head = ("| lever | h (ms) | vertices | wall s / s | CPU s / s | force (N) | err | displacement (mm) "
            "| err | steps inside | penetration (mm) | trocar offset (m) |")  # fmt: skip
    lines = [head, "|" + "---|" * 12]
    for r in rows:
        e = r.get("errors", {})

        def pct(x):
            return "" if x is None else f"{100 * x:+.1f} %"

        lines.append(
            f"| {r['lever']} | {1e3 * r['time_step_s']:g} | {r['tissue_vertices']} | {r['wall_s_per_s']:.3g} "
            f"| {r['cpu_s_per_s']:.3g} | {r['max_tissue_contact_force_N']:.3g} | {pct(e.get('force_err'))} "
            f"| {1e3 * r['tissue_max_displacement_m']:.3g} | {pct(e.get('disp_err'))} "
            f"| {r['tool_tip_inside_tissue_steps']} | {1e3 * r['max_penetration_m']:.3g} "
            f"| {r['max_trocar_offset_m']:.2g} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="folder for rows.json and table.md")
    parser.add_argument(
        "--only", nargs="+", choices=sorted(LEVERS), help="these levers (default: each alone)"
    )
    parser.add_argument("--reference", type=Path, help="an earlier rows.json whose reference row to reuse")
    parser.add_argument("--duration", type=float, help="simulated seconds (default: the whole path)")
    args = parser.parse_args(argv)
    print(f"{machine()}, load average {os.getloadavg()[0]:.2f}", flush=True)
    names = list(args.only or SINGLE)
    ref = None
    if args.reference is not None:
        ref = next(r for r in json.loads(args.reference.read_text())["rows"] if r["lever"] == "ref")
        names = [n for n in names if n != "ref"]
    elif "ref" not in names:
        names.insert(0, "ref")
    rows = [] if ref is None else [ref]
    args.out.mkdir(parents=True, exist_ok=True)
    for name in names:
        row = run(name, args.duration)
        if name == "ref":
            ref = row
        row["errors"] = against(row, ref)
        rows.append(row)
        print(json.dumps(row), flush=True)
        meta = {"nproc": os.cpu_count(), "cpu": cpu_model(), "rows": rows}
        (args.out / "rows.json").write_text(json.dumps(meta, indent=1))  # after each run: none lost
        (args.out / "table.md").write_text(table(rows) + "\n")
    print(table(rows))
    print(f"load average after {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
