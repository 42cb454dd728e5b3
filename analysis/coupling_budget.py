#!/usr/bin/env python3
"""The brick scene over its whole path: explicit and implicit coupling, and MuJoCo, at equal budgets.

    python analysis/coupling_budget.py --out reports/coupling_budget [--rounds 3] [--duration 8.5]

Issue 31's comparison, every figure a ratio of runs made in one process. Each round runs every
configuration once, in the same order, so a change of the machine's load reaches every row
alike; a row's cost is the median over the rounds of the simulation loop's CPU time per
simulated second (``godobject_drake.studies.benchmark.run_case``: the process's CPU time, which
a loaded machine inflates far less than the wall time). Rows:

- Drake, proxies and SAP, with the explicit and the implicit coupling at h = 1, 2, 4, 5 and
  10 ms, each with the shipped force cap (``max_stretch_m`` 0.2 m) and a 5 cm one (a lower cap
  presses the wall less: at equal caps the contact, not the coupling, sets the depth);
- the scale: 8 and 64 bricks on the path's first 3 s at h = 1 ms, sleeping on, each coupling;
- MuJoCo (the ``bench`` extra) with its best low-penetration settings of the speed report (a
  weld or the perturbation spring, contact time constant 2 h or its default, sleeping islands)
  at h = 0.5, 1 and 2 ms.

Penetration and tracking are measured the same way for both engines
(``benchmark.engine_neutral_errors``): the held brick's deepest overlap with any other true
shape, and its RMS distance from the device's target in free space. ``report.md`` gives each
row's cost as a ratio to the explicit coupling at h = 1 ms with the shipped cap (today's
default), the fastest row of each kind within 1 mm of penetration (and within 1 mm and 2 mm of
free-space tracking), and their speed ratios; ``results.json`` every number.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed_vs_error import contact, fmt, machine, variant

from godobject_drake.studies import benchmark as bm

HS = (1e-3, 2e-3, 4e-3, 5e-3, 10e-3)
CAPS_M = (0.2, 0.05)
MUJOCO_HS = (0.5e-3, 1e-3, 2e-3)
PENETRATION_BUDGET_M = 1e-3
TRACKING_BUDGET_M = 2e-3
BASELINE = ("explicit", 1e-3, 0.2)
SCALE_BRICKS = (8, 64)  # the scale rows: the path's first 3 s, h = 1 ms, sleeping on
SCALE_S = 3.0


def cases(duration: float, mujoco: bool) -> list[tuple[dict, bm.Case]]:
    """(what the row is, its case) for every configuration."""
    out = []
    for coupling in ("explicit", "implicit"):
        for h in HS:
            for cap in CAPS_M:
                s = variant("lego", duration, h, **contact("proxies", "sap"),
                            **{"god_object.coupling": coupling, "god_object.max_stretch_m": cap})  # fmt: skip
                label = f"{coupling} h={h * 1e3:g}ms cap={cap * 1e2:g}cm"
                out.append(({"engine": "drake", "coupling": coupling, "h": h, "cap_m": cap},
                            bm.make_case(s, label=label, repeats=1)))  # fmt: skip
    for coupling in ("explicit", "implicit"):
        for n in SCALE_BRICKS:
            s = variant("lego", SCALE_S, 1e-3, **contact("proxies", "sap"),
                        **{"god_object.coupling": coupling, "bricks": n, "sleep.enabled": True})  # fmt: skip
            label = f"{coupling} h=1ms {n} bricks ({SCALE_S:g} s)"
            out.append(({"engine": "drake", "coupling": coupling, "h": 1e-3, "bricks": n},
                        bm.make_case(s, label=label, repeats=1)))  # fmt: skip
    if mujoco:
        for h in MUJOCO_HS:
            for mode in ("weld", "perturb"):
                for tc in (None, 2 * h):
                    case = bm.make_case(variant("lego", duration, h), engine="mujoco", mujoco_mode=mode,
                                        mujoco_timeconst_s=tc, mujoco_sleep=True, repeats=1)  # fmt: skip
                    out.append(({"engine": "mujoco", "coupling": mode, "h": h, "timeconst_s": tc}, case))
    return out


def within(row: dict, track: float | None) -> bool:
    if row["refused"] or row["diverged"] or row.get("crossed_wall") or row["cost_median_s"] is None:
        return False
    if row.get("true_penetration_m") is None or row["true_penetration_m"] > PENETRATION_BUDGET_M:
        return False
    return track is None or (row.get("free_tracking_rms_m") or math.inf) <= track


def parse_args(argv):
    """The command line, checked: ``--rounds`` ≥ 1, 0 < ``--duration`` ≤ 8.5."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory (created)")
    parser.add_argument("--rounds", type=int, default=3, help="runs of each configuration (≥ 1; medians)")
    parser.add_argument("--duration", type=float, default=8.5, help="simulated seconds (the whole path: 8.5)")
    parser.add_argument("--no-mujoco", action="store_true", help="skip the MuJoCo rows")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error(f"--rounds {args.rounds}: give at least 1")
    if not 0 < args.duration <= 8.5:
        parser.error(f"--duration {args.duration}: the brick path is 8.5 s; give 0 < duration ≤ 8.5")
    return args


def with_mujoco(asked: bool) -> bool:
    """Whether the MuJoCo rows run: asked for, and MuJoCo importable (else say so on stderr)."""
    if not asked:
        return False
    try:
        import mujoco as _  # noqa: F401 (only whether it imports)
    except ImportError:
        print("MuJoCo not installed (pip install -e .[bench]): its rows are skipped", file=sys.stderr)
        return False
    return True


def run_rounds(todo: list, rounds: int, t0: float) -> tuple[list, list]:
    """Every case once per round, in the same order: (each case's first run, its CPU s per
    simulated s of every round). A refused or diverging case runs once only."""
    runs: list[dict | None] = [None] * len(todo)
    walls: list[list[float]] = [[] for _ in todo]  # CPU s per simulated s, one per round
    for k in range(rounds):
        for i, (_, case) in enumerate(todo):
            if runs[i] is not None and (runs[i]["refused"] or runs[i]["diverged"]):
                continue  # a refused or diverging configuration has no cost to measure
            r = bm.run_case(case)
            walls[i] += r["cpu_s_per_sim_s"]
            if runs[i] is None:
                runs[i] = r
        print(f"round {k + 1}/{rounds} done at {time.perf_counter() - t0:.0f} s", flush=True)
    return runs, walls


def table_rows(todo: list, runs: list, walls: list) -> tuple[list, list, dict]:
    """(the path's rows, each with its cost over the baseline's; the scale rows; the baseline row)."""
    rows = []
    for (what, _), r, w in zip(todo, runs, walls, strict=True):
        rows.append({
            **what, "label": r["label"], "refused": r["refused"], "diverged": r.get("diverged", False),
            "cpu_s_per_sim_s": w, **bm.summarize_cost(w),
            "true_penetration_m": r.get("true_penetration_m"),
            "free_tracking_rms_m": r.get("free_tracking_rms_m"),
            "crossed_wall": r.get("crossed_wall"),
        })  # fmt: skip
    scale = [r for r in rows if r.get("bricks")]
    rows = [r for r in rows if not r.get("bricks")]
    base = next(
        r for r in rows if (r["engine"], r["coupling"], r["h"], r.get("cap_m")) == ("drake", *BASELINE)
    )
    for r in rows:
        r["cost_over_baseline"] = (
            r["cost_median_s"] / base["cost_median_s"]
            if r["cost_median_s"] and base["cost_median_s"]
            else None
        )
    return rows, scale, base


def cost_lines(args, rows: list, base: dict) -> list[str]:
    """The report's head and its table of every row's cost over the baseline's."""
    md = [
        "# Explicit and implicit coupling, and MuJoCo, over the whole brick path",
        "",
        f"Generated by `python analysis/coupling_budget.py --out {args.out} --rounds {args.rounds}` "
        f"({args.duration:g} s of the path; {args.rounds} rounds, every configuration once per round). "
        f"Machine: {machine()}. Cost: the median CPU time per simulated second, shown as a ratio to "
        f"`{base['label']}` (today's default) measured in this run ({fmt(base['cost_median_s'])} s/s "
        "here, which carries to no other machine).",
        "",
        "| configuration | cost / default | true penetration | free-space tracking | note |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        note = "refused" if r["refused"] else "diverged" if r["diverged"] else (
            "crossed the wall" if r["crossed_wall"] else "")  # fmt: skip
        md.append(
            f"| `{r['label']}` | {fmt(r['cost_over_baseline'], digits=3)} | "
            f"{fmt(r['true_penetration_m'], ' mm', 1e3)} | "
            f"{fmt(r['free_tracking_rms_m'], ' mm', 1e3)} | {note} |"
        )
    return md


def budget_lines(rows: list, budgets: list) -> list[str]:
    """The fastest row of each kind within each budget, and their speed ratios; each budget's
    summary is appended to ``budgets``."""
    md = [
        "",
        "## The fastest within each budget",
        "",
        "| budget | explicit | implicit | MuJoCo | implicit speed / explicit | Drake speed / MuJoCo |",
        "|---|---|---|---|---|---|",
    ]
    for track in (None, TRACKING_BUDGET_M):
        best = {}
        for kind in ("explicit", "implicit", "mujoco"):
            ok = [r for r in rows if within(r, track)
                  and (r["engine"] == "mujoco" if kind == "mujoco" else r["coupling"] == kind)]  # fmt: skip
            best[kind] = min(ok, key=lambda r: r["cost_median_s"]) if ok else None
        e, i, m = best["explicit"], best["implicit"], best["mujoco"]
        drake = min((r for r in (e, i) if r), key=lambda r: r["cost_median_s"], default=None)
        speedup = e["cost_median_s"] / i["cost_median_s"] if (e and i) else None
        vs_mujoco = m["cost_median_s"] / drake["cost_median_s"] if (m and drake) else None
        budget = f"{PENETRATION_BUDGET_M * 1e3:g} mm" + (
            "" if track is None else f" + tracking {track * 1e3:g} mm"
        )
        md.append(
            f"| {budget} | "
            + " | ".join(f"`{r['label']}`" if r else "none within" for r in (e, i, m))
            + f" | {fmt(speedup, '×', digits=2)} | {fmt(vs_mujoco, digits=2)} |"
        )
        budgets.append({
            "penetration_budget_m": PENETRATION_BUDGET_M, "tracking_budget_m": track,
            "explicit": e and e["label"], "implicit": i and i["label"], "mujoco": m and m["label"],
            "implicit_speed_over_explicit": speedup, "drake_speed_over_mujoco": vs_mujoco,
        })  # fmt: skip
    return md


def scale_lines(scale: list, table: list) -> list[str]:
    """64 bricks against 8, each coupling; each coupling's summary is appended to ``table``."""
    md = [
        "",
        f"## Scale: 64 bricks against 8 (the path's first {SCALE_S:g} s, h = 1 ms, sleeping on)",
        "",
        "| coupling | 8 bricks CPU s/s | 64 bricks CPU s/s | 64 / 8 |",
        "|---|---|---|---|",
    ]
    for coupling in ("explicit", "implicit"):
        by_n = {r["bricks"]: r for r in scale if r["coupling"] == coupling}
        c8, c64 = (by_n[n]["cost_median_s"] if n in by_n else None for n in SCALE_BRICKS)
        ratio = c64 / c8 if (c8 and c64) else None
        md.append(f"| {coupling} | {fmt(c8)} | {fmt(c64)} | {fmt(ratio, '×', digits=3)} |")
        table.append({"coupling": coupling, "cost_8_s": c8, "cost_64_s": c64, "ratio_64_over_8": ratio})
    return md


def main(argv=None) -> int:
    args = parse_args(argv)
    mujoco = with_mujoco(not args.no_mujoco)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    todo = cases(args.duration, mujoco)
    runs, walls = run_rounds(todo, args.rounds, t0)
    rows, scale, base = table_rows(todo, runs, walls)
    md = cost_lines(args, rows, base)
    summary = {"machine": machine(), "duration_s": args.duration, "rounds": args.rounds,
               "baseline": base["label"], "rows": rows, "budgets": []}  # fmt: skip
    md += budget_lines(rows, summary["budgets"])
    summary["scale"] = []
    md += scale_lines(scale, summary["scale"])
    elapsed = time.perf_counter() - t0
    summary["elapsed_s"] = elapsed
    md += ["", f"Run time {elapsed:.0f} s on this machine.", ""]
    (args.out / "report.md").write_text("\n".join(md))
    (args.out / "results.json").write_text(json.dumps(summary, indent=1, default=_json))
    print("\n".join(md))
    return 0


def _json(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(type(o))


if __name__ == "__main__":
    sys.exit(main())
