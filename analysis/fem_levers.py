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

import numpy as np
import yaml

from godobject_drake.config import scenario as sc
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.studies.benchmark import cpu_model, machine

# The reference of each scene: its soft uterus at 8 even cells and h = 1 ms, the tissue's settings
# Drake's FEM organ has by default (organs: in docs/scenario.md), whatever the scene ships.
REFERENCE_ORGAN = {"model": "fem", "cells": 8, "grading": 1.0, "relaxation_time_s": 0.01,
                   "stiffness_damping_s": 0.01, "modulus_factor": 1.0, "glue_size_m": 0.012}  # fmt: skip
REFERENCE = {
    "laparoscopy": {
        "organs": REFERENCE_ORGAN,
        "plant": {"time_step": 0.001},
        "god_object": {"coupling": "cartesian"},
    },
    "laparoscopy_bimanual": {"organs": REFERENCE_ORGAN, "plant": {"time_step": 0.001}},
}
REFERENCE_LEVER = {"laparoscopy": "ref", "laparoscopy_bimanual": "bi_ref"}
SAP = {"god_object": {"coupling": "joint_pd_sap"}}
G15 = {"cells": 6, "grading": 1.5}
RT = {"cells": 6, "grading": 1.7, "relaxation_time_s": 0.2, "stiffness_damping_s": 0.03}
# the shipped real-time organ (diagrams/laparoscopy*.yaml): 4 even cells at h = 10 ms, the contact
# relaxed over 30 steps, the modulus calibrated against the reference (--calibrate)
RT4 = {"cells": 4, "relaxation_time_s": 0.3, "stiffness_damping_s": 0.03}
# name: (scene, overrides on top of the scene's reference; None: the scene as shipped, organ soft)
LEVERS = {
    "ref": ("laparoscopy", {}),
    "bi_ref": ("laparoscopy_bimanual", {}),
    "shipped": ("laparoscopy", None),
    "bi_shipped": ("laparoscopy_bimanual", None),
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
    "tau02_h10": ("laparoscopy", {"organs": {"relaxation_time_s": 0.2}, "plant": {"time_step": 0.01}}),
    "modulus04": ("laparoscopy", {"organs": {"modulus_factor": 0.4}}),
    # combinations, by --only
    "cells6_g15_h5_sap": (
        "laparoscopy",
        {"organs": {"cells": 6, "grading": 1.5}, "plant": {"time_step": 0.005}, **SAP},
    ),
    "cells6_g15_h10_sap": (
        "laparoscopy",
        {"organs": {"cells": 6, "grading": 1.5}, "plant": {"time_step": 0.01}, **SAP},
    ),
    # the graded 6-cell mesh at h = 10 to 20 ms, the tissue's contact relaxed over 20 h (a shorter
    # one chatters at these steps), its stiffness damping raised to ~2.5 h
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
    # the 4-cell organ at h = 10 ms, its contact relaxed over 20 steps: uncalibrated, and each
    # scene's shipped modulus factor
    "rt4_h10": ("laparoscopy", {"organs": RT4, "plant": {"time_step": 0.01}}),
    "rt4g2_h10": (
        "laparoscopy",
        {"organs": {**RT4, "grading": 2.0, "modulus_factor": 0.63}, "plant": {"time_step": 0.01}},
    ),
    "rt4g15_h10": (
        "laparoscopy",
        {"organs": {**RT4, "grading": 1.5, "modulus_factor": 0.6}, "plant": {"time_step": 0.01}},
    ),
    "rt4_h10_tau02": (
        "laparoscopy",
        {"organs": {**RT4, "relaxation_time_s": 0.2}, "plant": {"time_step": 0.01}},
    ),
    "bi_rt4_h10": ("laparoscopy_bimanual", {"organs": RT4, "plant": {"time_step": 0.01}}),
    # the bimanual's grasp site glued to the 4-cell mesh's vertex there and its 3 neighbours (the
    # 8-cell mesh's 12 mm cube holds 9 vertices, the 4-cell one's 1)
    "bi_rt4_h10_glue20": (
        "laparoscopy_bimanual",
        {"organs": {**RT4, "glue_size_m": 0.02, "modulus_factor": 0.69}, "plant": {"time_step": 0.01}},
    ),
    "bi_cells4_h2": ("laparoscopy_bimanual", {"organs": {"cells": 4}, "plant": {"time_step": 0.002}}),
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


SINGLE = ("ref", "cells6", "cells4", "h2", "h5", "h10", "sap", "h10_sap", "linear", "corotated", "threads2",
          "tau02_h10", "modulus04")  # fmt: skip


def overrides_of(name: str, duration: float | None, modulus_factor: float | None = None) -> tuple[str, str]:
    """The lever's scene and its overrides as one YAML flow mapping."""
    scene, lever = LEVERS[name]
    base = {"organs": {"model": "fem"}} if lever is None else merged(REFERENCE[scene], lever)
    parts = [base]
    if duration is not None:
        parts.append({"simulation": {"duration_s": duration}})
    if modulus_factor is not None:
        parts.append({"organs": {"modulus_factor": modulus_factor}})
    return scene, yaml.safe_dump(merged(*parts), default_flow_style=True).strip()


def tissue_metrics(m: dict) -> dict:
    """The run's tissue figures over its tools: the largest force, displacement, penetration and
    trocar offset, the steps any tool was inside, and the left grasper's lift where it grasps."""
    tools = list(m["tools"].values()) if m.get("tools") else [m]
    out = {
        "max_tissue_contact_force_N": max(t["max_tissue_contact_force_N"] for t in tools),
        "tissue_max_displacement_m": max(t["tissue_max_displacement_m"] for t in tools),
        "tool_tip_inside_tissue_steps": sum(t["tool_tip_inside_tissue_steps"] for t in tools),
        "max_penetration_m": max(t["max_penetration_m"] for t in tools),
        "max_trocar_offset_m": max(t["max_trocar_offset_m"] for t in tools),
        "tissue_vertices": tools[0]["tissue_vertices"],
        "diverged": m["diverged"],
    }
    rises = [t["grasped_max_rise_m"] for t in tools if t.get("grasped_max_rise_m") is not None]
    out["grasped_max_rise_m"] = max(rises) if rises else None
    return out


def run(name: str, duration: float | None, modulus_factor: float | None = None) -> dict:
    """One lever's run over the scene's whole path (or ``duration`` s of it)."""
    scene, text = overrides_of(name, duration, modulus_factor)
    station = build_station(sc.shipped_scenario(scene, text))
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    result = simulate(station, progress=False)
    total = time.perf_counter() - t0
    m = result.metrics
    sim = m["sim_time_s"]
    row = {"lever": name, "scene": scene, "overrides": text,
           "time_step_s": m["time_step_s"], "sim_s": sim, "wall_s_per_s": m["wall_time_s"] / sim,
           "cpu_s_per_s": m["cpu_time_s"] / sim, "run_s": total, "load": load,
           "modulus_factor": station.scenario.organs.modulus_factor}  # fmt: skip
    return {**row, **tissue_metrics(m), "displacement_mm": displacement_series(result, sim)}


SERIES_DT_S = 0.01  # the displacement's time series compared on this grid (s)


def displacement_series(result, sim: float) -> list[float]:
    """The tissue's largest surface displacement over time (mm; the largest of the tools'
    observers at each time), on a grid of :data:`SERIES_DT_S` from 0 to ``sim``."""
    logs = [np.asarray(v)[:, 0] for k, v in result.data.items() if k.split("/")[-1] == "tissue"]
    d = np.max(logs, axis=0)
    grid = np.arange(0.0, sim + 1e-9, SERIES_DT_S)
    return np.round(1e3 * np.interp(grid, np.asarray(result.times), d), 5).tolist()


def series_error(row: dict, ref: dict) -> float | None:
    """The RMS difference of the row's displacement series from the reference's over their common
    span, over the reference's largest displacement."""
    a, b = row.get("displacement_mm"), ref.get("displacement_mm")
    if not a or not b:
        return None
    n = min(len(a), len(b))
    a, b = np.asarray(a[:n]), np.asarray(b[:n])
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.max(b))


def against(row: dict, ref: dict) -> dict:
    """The row's errors against the reference: relative for the force and the displacement."""
    out = {}
    for key, label in (
        ("max_tissue_contact_force_N", "force_err"),
        ("tissue_max_displacement_m", "disp_err"),
    ):
        a, b = row.get(key), ref.get(key)
        out[label] = (a - b) / b if a is not None and b else None
    out["series_err"] = series_error(row, ref)
    return out


def lift(row: dict) -> str:
    """The grasped site's largest rise (mm), where a grasper holds one."""
    rise = row.get("grasped_max_rise_m")
    return "" if rise is None else f"{1e3 * rise:.3g}"


def table(rows: list[dict]) -> str:
    head = ("| lever | h (ms) | vertices | wall s / s | CPU s / s | force (N) | err | displacement (mm) "
            "| err | over time | steps inside | penetration (mm) | trocar (m) | lift (mm) |")  # fmt: skip
    lines = [head, "|" + "---|" * 14]
    for r in rows:
        e = r.get("errors", {})

        def pct(x):
            return "" if x is None else f"{100 * x:+.1f} %"

        def rms(x):
            return "" if x is None else f"{100 * x:.1f} %"

        lines.append(
            f"| {r['lever']} | {1e3 * r['time_step_s']:g} | {r['tissue_vertices']} | {r['wall_s_per_s']:.3g} "
            f"| {r['cpu_s_per_s']:.3g} | {r['max_tissue_contact_force_N']:.3g} | {pct(e.get('force_err'))} "
            f"| {1e3 * r['tissue_max_displacement_m']:.3g} | {pct(e.get('disp_err'))} "
            f"| {rms(e.get('series_err'))} "
            f"| {r['tool_tip_inside_tissue_steps']} | {1e3 * r['max_penetration_m']:.3g} "
            f"| {r['max_trocar_offset_m']:.2g} | {lift(r)} |"
        )
    return "\n".join(lines)


def calibrate(
    name: str, ref: dict, duration: float | None, tolerance: float = 0.01, rounds: int = 5
) -> list[dict]:
    """The lever's modulus factor whose displacement follows the reference's over the path (least
    squares): the displacement under the same press goes about as 1/E, so each round finds the
    scale ``c`` that best maps the run's displacement series onto the reference's and divides the
    factor by it, until ``c`` is within ``tolerance`` of 1. The rows of each round."""
    lever = LEVERS[name][1] or {}
    factor = lever.get("organs", {}).get("modulus_factor", 1.0)
    rows = []
    for _ in range(rounds):
        row = run(name, duration, factor)
        row["lever"] = f"{name} × {factor:.3g}"
        row["errors"] = against(row, ref)
        rows.append(row)
        show(row)
        n = min(len(row["displacement_mm"]), len(ref["displacement_mm"]))
        d, d_ref = np.asarray(row["displacement_mm"][:n]), np.asarray(ref["displacement_mm"][:n])
        c = float(d @ d_ref / (d @ d))
        if abs(c - 1.0) <= tolerance:
            break
        factor = min(1.0, factor / c)
    err = row["errors"]
    print(
        f"{name}: modulus_factor {row['modulus_factor']:.3g} (displacement over time "
        f"{100 * err['series_err']:.1f} %, largest {100 * err['disp_err']:+.1f} %, force "
        f"{100 * err['force_err']:+.1f} % against the reference)"
    )
    return rows


def show(row: dict) -> None:
    """The row on one line (its time series left out)."""
    print(json.dumps({k: v for k, v in row.items() if k != "displacement_mm"}), flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="folder for rows.json and table.md")
    parser.add_argument(
        "--only", nargs="+", choices=sorted(LEVERS), help="these levers (default: each alone)"
    )
    parser.add_argument("--reference", type=Path, help="an earlier rows.json whose reference rows to reuse")
    parser.add_argument("--duration", type=float, help="simulated seconds (default: the whole path)")
    parser.add_argument(
        "--calibrate",
        choices=sorted(LEVERS),
        help="find this lever's modulus_factor (its displacement the reference's)",
    )
    args = parser.parse_args(argv)
    print(f"{machine()}, load average {os.getloadavg()[0]:.2f}", flush=True)
    names = [args.calibrate] if args.calibrate else list(args.only or SINGLE)
    refs = {}
    if args.reference is not None:
        refs = {
            r["scene"]: r
            for r in json.loads(args.reference.read_text())["rows"]
            if r["lever"] in REFERENCE_LEVER.values()
        }
    needed = [REFERENCE_LEVER[LEVERS[n][0]] for n in names]
    names = [
        n
        for n in dict.fromkeys(needed + names)
        if not (n in REFERENCE_LEVER.values() and LEVERS[n][0] in refs)
    ]
    rows = list(refs.values())
    args.out.mkdir(parents=True, exist_ok=True)

    def save():
        meta = {"nproc": os.cpu_count(), "cpu": cpu_model(), "rows": rows}
        (args.out / "rows.json").write_text(json.dumps(meta, indent=1))  # after each run: none lost
        (args.out / "table.md").write_text(table(rows) + "\n")

    for name in names:
        if name == args.calibrate:
            rows += calibrate(name, refs[LEVERS[name][0]], args.duration)
            save()
            continue
        row = run(name, args.duration)
        if name in REFERENCE_LEVER.values():
            refs[row["scene"]] = row
        row["errors"] = against(row, refs[row["scene"]])
        rows.append(row)
        show(row)
        save()
    print(table(rows))
    print(f"load average after {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
