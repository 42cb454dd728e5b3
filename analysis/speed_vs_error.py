#!/usr/bin/env python3
"""Speed against error for every scene: sweep, compare with a reference run, recommend.

    python analysis/speed_vs_error.py --out reports/speed [--quick] [--scene lego] \
        [--workers N | --scheduler tcp://host:8786] [--no-mujoco]

For each scene, runs a grid of configurations (time step h; contact model and
Drake's discrete contact approximation for the bricks; explicit or implicit
coupling for the grasper; shell model for the probe; device rate) on the
scene's own device path. Each configuration runs ``--repeats`` times (≥ 3);
its cost is the median wall time per simulated second (min–max shown), its
error is measured against the scene's reference run (finest h,
highest-fidelity contact; ``godobject_drake.studies.benchmark.compare``): RMS pose
error of the god-object, max penetration, energy error. The brick scene is
also rebuilt in MuJoCo (``godobject_drake.studies.mujoco_peer``, the ``bench`` extra)
on the same path.

Writes ``report.md`` (tables, recommended configuration per error budget,
where the time goes in the brick scene), one Pareto figure per scene and
``results.json`` into ``--out``. Runs go through
``godobject_drake.studies.sweep.run_tasks``: local processes (default one worker, so
timings do not share a core) or a Dask cluster (``--scheduler``).
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import json
import math
import pstats
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from godobject_drake.config.scenario import replace, shipped_scenario
from godobject_drake.studies import benchmark as bm
from godobject_drake.studies.sweep import run_tasks

SCENES = ("lego", "laparoscopy", "deformable_probe")
# Error budgets (m of RMS god-object pose error against the reference), spanning what each
# scene's configurations reach, and the penetration each scene tolerates (m): a brick may sink
# 1 mm into another, the grasper 5 mm into tissue (its issue), the probe 5 mm.
BUDGETS_M = {
    "lego": (0.01e-3, 0.05e-3, 0.1e-3, 0.5e-3, 10e-3),
    "laparoscopy": (0.005e-3, 0.01e-3, 0.02e-3, 0.1e-3),
    "deformable_probe": (0.1e-3, 0.5e-3, 1e-3, 5e-3),
}
PENETRATION_BUDGET_M = {"lego": 1e-3, "laparoscopy": 5e-3, "deformable_probe": 5e-3}
# Performance goals (real-time factor at the stated configuration): the bricks 4x, the grasper
# 2.5x, the probe 1x; 64 bricks at h = 1 ms in real time.
GOALS = {"lego": 4.0, "laparoscopy": 2.5, "deformable_probe": 1.0}
GOAL_64_BRICKS = 1.0
COUPLING_GOAL_US = 30.0


def variant(scene: str, duration: float, time_step: float, device_rate: float = 60.0, **changes):
    """The shipped scene with these fields changed (``changes``: ``"field.sub": value``)."""
    return replace(
        shipped_scenario(scene),
        **{"simulation.duration_s": duration, "plant.time_step": time_step, "device.rate_hz": device_rate},
        **changes,
    )


def contact(geometry: str, approximation: str) -> dict:
    """The brick scene's contact settings, as ``--contact`` and ``--contact-approximation`` set them."""
    model = "point" if geometry == "proxies" else "hydroelastic_with_fallback"
    return {
        "contact.geometry": geometry,
        "plant.contact_model": model,
        "plant.discrete_contact_approximation": approximation,
    }


def sweep_cases(scene: str, quick: bool, repeats: int) -> tuple[bm.Case, list[bm.Case]]:
    """(reference, configurations) of one scene. Quick: fewer steps, shorter runs."""

    def case(*args, repeats=repeats, **kw):
        return bm.make_case(variant(scene, *args, **kw), repeats=repeats)

    hs = (0.5e-3, 1e-3, 2e-3, 5e-3) if quick else (0.25e-3, 0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3)
    if scene == "lego":
        T = 3.0 if quick else 8.5  # quick: grasp, carry, stop at the wall, start climbing
        approx = ("sap", "lagged") if quick else ("sap", "lagged", "similar")
        ref = case(T, 0.25e-3, repeats=1, **contact("hydroelastic", "sap"))
        # Quick: hydroelastic contact with SAP only (lagged costs as much and was never picked).
        grid = [
            case(T, h, **contact(c, a))
            for h in hs
            for c in ("proxies", "hydroelastic")
            for a in (approx if c == "proxies" or not quick else ("sap",))
        ]
        if not quick:  # the device's rate changes the error little and costs the most at 1 kHz
            grid += [case(T, 1e-3, r, **contact("proxies", "sap")) for r in (250.0, 1000.0)]
        # The implicit coupling (SAP's springs) beside the explicit one at each h (quick:
        # from 1 ms), and at 10 ms, where the explicit coupling is refused.
        grid += [
            case(T, h, **contact("proxies", "sap"), **{"god_object.coupling": "implicit"})
            for h in (*hs, 10e-3)
            if not (quick and h < 1e-3)
        ]
        return ref, grid
    if scene == "laparoscopy":
        T = 3.0 if quick else 10.0
        ref = case(T, 0.25e-3, repeats=1, **{"god_object.coupling": "joint_pd_sap"})
        couplings = ("cartesian", "joint_pd", "joint_pd_sap")
        grid = [case(T, h, **{"god_object.coupling": c}) for h in hs for c in couplings]
        if not quick:
            grid += [case(T, 1e-3, r, **{"god_object.coupling": "cartesian"}) for r in (250.0, 1000.0)]
        return ref, grid
    if scene == "deformable_probe":
        T = 2.0 if quick else 6.5
        ref = case(T, 1e-3, repeats=1, **{"god_object.shell": "fem"})
        hs = (2e-3, 5e-3, 10e-3) if quick else (1e-3, 2e-3, 5e-3, 10e-3)
        grid = [case(T, h, **{"god_object.shell": s}) for h in hs for s in ("fem", "mass_spring")]
        return ref, grid
    raise ValueError(f"scene={scene!r}; choose from {SCENES}")


def mujoco_cases(quick: bool, repeats: int) -> list[bm.Case]:
    """MuJoCo on the brick path: both drag modes, its default contact and its stiffest (time
    constant 2 h, the ``refsafe`` floor), both friction cones, with its sleeping islands."""
    T = 3.0 if quick else 8.5
    hs = (0.5e-3, 1e-3, 2e-3, 5e-3) if quick else (0.25e-3, 0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3)
    return [
        bm.make_case(
            variant("lego", T, h),
            engine="mujoco",
            mujoco_mode=mode,
            mujoco_timeconst_s=tc,
            mujoco_cone=cone,
            mujoco_sleep=True,
            repeats=repeats,
        )
        for h in hs
        for mode in ("weld", "perturb")
        for tc in (None, 2 * h)
        for cone in ("elliptic", "pyramidal")
    ]


def mujoco_available() -> bool:
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return False
    return True


def evaluate(runs: list[dict], reference: dict, scene: str) -> list[dict]:
    """One row per run: configuration, cost summary, errors against the reference."""
    rows = []
    for r in runs:
        row = {
            "scene": scene,
            "label": r["label"],
            "config": r["config"],
            "refused": r["refused"],
            "diverged": r.get("diverged", False),
            "diagnosis": r.get("diagnosis"),
            "wall_s_per_sim_s": r["wall_s_per_sim_s"],
            **bm.summarize_cost(r["wall_s_per_sim_s"]),
            # CPU time: what the couplings' ratio uses, as a loaded machine inflates it far less
            # than the wall time (the costs, RTFs and recommendations stay on the wall).
            "cpu_median_s": float(np.median(r["cpu_s_per_sim_s"])) if r.get("cpu_s_per_sim_s") else None,
        }
        if not r["refused"]:
            row["max_penetration_m"] = r["max_penetration_m"]
            row.update(bm.compare(r, reference))
            if r.get("mujoco_version"):
                row["mujoco_version"] = r["mujoco_version"]
            for key in ("true_penetration_m", "free_tracking_rms_m", "free_samples", "crossed_wall",
                        "mean_awake_trees"):  # fmt: skip
                if key in r:
                    row[key] = r[key]
        rows.append(row)
    return rows


def feasible(row: dict, budget_m: float, penetration_m: float) -> bool:
    return (
        not row["refused"]
        and not row["diverged"]
        and row.get("cost_median_s") is not None
        and row["pose_rms_m"] <= budget_m
        and row["max_penetration_m"] <= penetration_m
    )


def recommend(rows: list[dict], budget_m: float, penetration_m: float) -> dict | None:
    """The cheapest run (median cost) within the pose and penetration budgets."""
    ok = [r for r in rows if feasible(r, budget_m, penetration_m)]
    return min(ok, key=lambda r: r["cost_median_s"]) if ok else None


def pareto(rows: list[dict]) -> list[dict]:
    """Runs no other run beats on both cost and pose error."""
    pts = sorted(
        (r for r in rows if not r["refused"] and not r["diverged"] and r.get("cost_median_s")),
        key=lambda r: (r["cost_median_s"], r["pose_rms_m"]),
    )
    front, best = [], math.inf
    for r in pts:
        if r["pose_rms_m"] < best:
            front.append(r)
            best = r["pose_rms_m"]
    return front


def figure(scene: str, rows: list[dict], peers: list[dict], out: Path) -> str:
    """Error against cost, one marker per configuration, min–max cost bars, the Pareto front."""
    fig, ax = plt.subplots(figsize=(8, 5.2))
    floor = 1e-7  # the reference's own error is 0; plot it at the floor
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r["refused"] or r["diverged"] or not r.get("cost_median_s"):
            continue
        c = r["config"]
        key = (
            " ".join(
                v for v in (c.get("contact"), c.get("approximation"), c.get("coupling"), c.get("shell")) if v
            )
            or "default"
        )
        if c["device_rate"] != 60.0:
            key += f" dev={c['device_rate']:g}Hz"
        groups.setdefault(key, []).append(r)
    if peers:
        for r in peers:
            if not r["refused"] and not r["diverged"] and r.get("cost_median_s"):
                groups.setdefault(f"MuJoCo {r['config']['coupling']}", []).append(r)
    markers = "osD^v<>ph*"
    for i, (key, group) in enumerate(sorted(groups.items())):
        x = np.array([g["cost_median_s"] for g in group])
        y = np.array([max(g["pose_rms_m"], floor) for g in group]) * 1e3
        lo = x - np.array([g["cost_min_s"] for g in group])
        hi = np.array([g["cost_max_s"] for g in group]) - x
        style = dict(marker=markers[i % len(markers)], ls="none", capsize=2, label=key)
        if key.startswith("MuJoCo"):
            style.update(mfc="none", mew=1.5)
        ax.errorbar(x, y, xerr=[lo, hi], **style)
        for g, xx, yy in zip(group, x, y, strict=True):
            ax.annotate(
                f"{g['config']['time_step'] * 1e3:g}",
                (xx, yy),
                textcoords="offset points",
                xytext=(4, 3),
                fontsize=7,
            )
    front = pareto(rows)
    if front:
        ax.step(
            [r["cost_median_s"] for r in front],
            [max(r["pose_rms_m"], floor) * 1e3 for r in front],
            where="post",
            color="k",
            lw=0.8,
            alpha=0.6,
            label="Drake Pareto front",
        )
    ax.axvline(1.0, color="grey", ls=":", lw=1)
    ax.text(1.0, 1.0, " real time", color="grey", fontsize=8, va="bottom")  # at 1 mm on the error axis
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time per simulated second (s), median of repeats, bars min–max")
    ax.set_ylabel("RMS god-object pose error vs reference (mm)")
    ax.set_title(f"{scene}: error against cost (numbers: h in ms)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    name = f"pareto_{scene}.png"
    fig.tight_layout()
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def fmt(v, unit: str = "", scale: float = 1.0, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v * scale:.{digits}g}{unit}"


def scene_section(
    scene: str, ref: dict, rows: list[dict], peers: list[dict], fig: str, budgets: tuple, pen: float
) -> tuple[list[str], dict]:
    ref_cost = bm.summarize_cost(ref["wall_s_per_sim_s"])["cost_median_s"]
    md = [
        f"## {scene}",
        "",
        f"Reference: `{ref['label']}` ({fmt(ref_cost, ' s')} per simulated second). Errors are "
        "against it; penetration is the run's own.",
        "",
        f"![{scene}]({fig})",
        "",
    ]
    md += [
        "| configuration | cost s/s (min–max) | RTF | pose RMS | angle RMS | max penetration "
        "| energy error | note |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows + peers, key=lambda r: (r["refused"] is not None, r.get("cost_median_s") or 0)):
        if r["refused"]:
            md.append(f"| {r['label']} | – | – | – | – | – | – | refused: {r['refused'].split('. ')[0]} |")
            continue
        note = "diverged: " + str(r["diagnosis"]) if r["diverged"] else ""
        md.append(
            f"| {r['label']} | {fmt(r['cost_median_s'])} ({fmt(r['cost_min_s'])}–{fmt(r['cost_max_s'])}) "
            f"| {fmt(r['real_time_factor'], digits=2)} | {fmt(r['pose_rms_m'], ' mm', 1e3)} "
            f"| {fmt(r['angle_rms_rad'], ' mrad', 1e3)} | {fmt(r['max_penetration_m'], ' mm', 1e3)} "
            f"| {fmt(r['energy_error_j'], ' mJ', 1e3)} | {note} |"
        )
    md += [
        "",
        f"**Recommended** (cheapest within the pose budget and max penetration ≤ {pen * 1e3:g} mm"
        + (
            "; Drake only: the pose error of another engine against Drake's reference mixes the two "
            "engines' physics, so MuJoCo is compared below on what both define the same way):"
            if peers
            else "):"
        ),
        "",
        "| pose budget | Drake configuration | cost s/s | RTF | pose RMS |",
        "|---|---|---|---|---|",
    ]
    recs = {}
    for b in budgets:
        r = recommend(rows, b, pen)
        line = f"| {b * 1e3:g} mm | "
        line += (
            (
                f"`{r['label']}` | {fmt(r['cost_median_s'])} | {fmt(r['real_time_factor'], digits=2)} | "
                f"{fmt(r['pose_rms_m'], ' mm', 1e3)} |"
            )
            if r
            else "none within budget | – | – | – |"
        )
        md.append(line)
        recs[f"{b:g}"] = {
            "budget_m": b,
            "drake": r["label"] if r else None,
            "drake_cost_s": r["cost_median_s"] if r else None,
        }
    md.append("")
    return md, recs


PEER_BUDGETS_M = (0.5e-3, 1e-3, 2e-3)  # penetration budgets of the equal-budget table (m)
TRACKING_BUDGET_M = 2e-3  # and, in its second half, free-space tracking within this (m)


def _fair_ok(r: dict, pen_m: float, track_m: float | None = None) -> bool:
    if r["refused"] or r["diverged"] or not r.get("cost_median_s") or r.get("crossed_wall"):
        return False
    if r.get("true_penetration_m") is None or r["true_penetration_m"] > pen_m:
        return False
    return track_m is None or (
        r.get("free_tracking_rms_m") is not None and r["free_tracking_rms_m"] <= track_m
    )


def equal_budget(drake: list[dict], mujoco: list[dict]) -> tuple[list[str], list[dict]]:
    """The fastest configuration of each engine within each penetration budget (and the same with
    free-space tracking within :data:`TRACKING_BUDGET_M`), and their speed ratio."""
    md = [
        "## Drake and MuJoCo at equal budgets (brick scene)",
        "",
        "Measured the same way for both engines, by the same code, on each run's free bodies "
        "sampled every 10 ms (`benchmark.engine_neutral_errors`): the held brick's deepest "
        "penetration into any other true shape (boxes by separating axes), and the RMS distance "
        "of its centre of mass from the device's target while it is in free space (≥ 2 mm from "
        "everything). A run whose brick went through the wall is out of every budget (its "
        "penetration would read small again). Pose error against Drake's reference is not used "
        "here: it mixes the two engines' physics. MuJoCo gets its best low-penetration settings "
        "(contact `solref` time constant at its floor 2 h, a weld or `simulate`'s perturbation "
        "spring, elliptic or pyramidal cones, sleeping islands).",
        "",
        "| penetration budget | tracking budget | Drake (fastest within) | cost s/s | tracking | "
        "MuJoCo (fastest within) | cost s/s | tracking | Drake speed / MuJoCo speed |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    out = []
    for track in (None, TRACKING_BUDGET_M):
        for b in PEER_BUDGETS_M:
            d = [r for r in drake if _fair_ok(r, b, track)]
            m = [r for r in mujoco if _fair_ok(r, b, track)]
            d = min(d, key=lambda r: r["cost_median_s"]) if d else None
            m = min(m, key=lambda r: r["cost_median_s"]) if m else None
            ratio = m["cost_median_s"] / d["cost_median_s"] if (d and m) else None
            cells = []
            for r in (d, m):
                cells += (
                    [f"`{r['label']}`", fmt(r["cost_median_s"]), fmt(r["free_tracking_rms_m"], " mm", 1e3)]
                    if r
                    else ["none within budget", "–", "–"]
                )
            md.append(
                f"| {b * 1e3:g} mm | {'–' if track is None else f'{track * 1e3:g} mm'} | "
                + " | ".join(cells)
                + f" | {fmt(ratio, digits=2)} |"
            )
            out.append({
                "penetration_budget_m": b, "tracking_budget_m": track,
                "drake": d["label"] if d else None, "drake_cost_s": d["cost_median_s"] if d else None,
                "mujoco": m["label"] if m else None, "mujoco_cost_s": m["cost_median_s"] if m else None,
                "drake_speed_over_mujoco": ratio,
            })  # fmt: skip
    md.append("")
    return md, out


def coupling_section(rows: list[dict], pen: float) -> tuple[list[str], dict]:
    """The brick scene's two rigid couplings side by side at each h (proxies, SAP, 60 Hz): cost
    ratio of the medians measured in this run, penetration and pose error; and the fastest of
    each within the penetration budget ``pen`` (the goal: the implicit one ≥ 2× faster)."""

    def pick(coupling: str) -> dict[float, dict]:
        return {
            r["config"]["time_step"]: r
            for r in rows
            if r["config"].get("coupling") == coupling
            and r["config"].get("contact") == "proxies"
            and r["config"].get("approximation") == "sap"
            and r["config"]["device_rate"] == 60.0
        }

    explicit, implicit = pick("explicit"), pick("implicit")
    seconds = max((r["config"]["duration"] for r in (*explicit.values(), *implicit.values())), default=0.0)
    md = [
        "## Explicit against implicit coupling (brick scene, proxies, SAP)",
        "",
        f"The first {seconds:g} s of the path (the whole path is 8.5 s: analysis/coupling_budget.py), "
        "the same contact; the explicit coupling computes the paper's spring in "
        "Python each step, the implicit one hands it to SAP as seven compliant constraints "
        '(docs/design.md "The implicit coupling"). Cost: the median CPU time of the loop per '
        "simulated second, and its ratio implicit over explicit, both measured in this run.",
        "",
        "| h | explicit CPU s/s | explicit penetration | explicit pose RMS | implicit CPU s/s "
        "| implicit penetration "
        "| implicit pose RMS | implicit / explicit cost |",
        "|---|---|---|---|---|---|---|---|",
    ]

    def cells(r):
        if r is None:
            return ["–", "–", "–"]
        if r["refused"]:
            return ["refused", "–", "–"]
        if r["diverged"]:
            return ["diverged", "–", "–"]
        return [
            fmt(r["cpu_median_s"]),
            fmt(r["max_penetration_m"], " mm", 1e3),
            fmt(r["pose_rms_m"], " mm", 1e3),
        ]

    table = []
    for h in sorted(set(explicit) | set(implicit)):
        e, i = explicit.get(h), implicit.get(h)
        ok = all(r and not r["refused"] and not r["diverged"] and r.get("cpu_median_s") for r in (e, i))
        ratio = i["cpu_median_s"] / e["cpu_median_s"] if ok else None
        md.append(f"| {h * 1e3:g} ms | " + " | ".join(cells(e) + cells(i)) + f" | {fmt(ratio, digits=2)} |")
        table.append({"time_step": h, "explicit": e and e["label"], "implicit": i and i["label"],
                      "implicit_over_explicit_cost": ratio})  # fmt: skip

    def fastest(by_h):
        ok = [r for r in by_h.values() if not r["refused"] and not r["diverged"] and r.get("cpu_median_s")
              and r["max_penetration_m"] <= pen]  # fmt: skip
        return min(ok, key=lambda r: r["cpu_median_s"]) if ok else None

    e, i = fastest(explicit), fastest(implicit)
    speedup = e["cpu_median_s"] / i["cpu_median_s"] if (e and i) else None
    md += [
        "",
        f"Within {pen * 1e3:g} mm of penetration, the fastest explicit configuration is "
        f"`{e['label'] if e else 'none'}` and the fastest implicit one `{i['label'] if i else 'none'}`: "
        f"the implicit coupling is **{fmt(speedup, '×', digits=2)}** as fast (the goal: ≥ 2×).",
        "",
    ]
    summary = {"rows": table, "fastest_explicit": e and e["label"], "fastest_implicit": i and i["label"],
               "implicit_speedup_within_budget": speedup}  # fmt: skip
    return md, summary


machine = bm.machine  # nproc and the CPU model (coupling_budget.py imports it from here)


SCALE_BRICKS = (8, 16, 32, 64, 128)


def scale_cases(quick: bool, repeats: int) -> list[bm.Case]:
    """Cost against brick count: Drake at h = 1 ms with sleeping on and off, MuJoCo (weld,
    contact time constant 2 h, h = 1 ms) with its sleeping islands on and off; the default
    path's first 3 s: grasp, lift, carry into the wall. (1.5 s runs read 64 bricks at 0.56 to
    1.06 s per simulated second in three reports on this machine: the first 30 ms, every brick
    awake, cost 4 ms a step, and a short run weighs them double.) Quick leaves out Drake's 128
    bricks all awake (about 20 s per simulated second: three minutes of the 10-minute budget)."""
    T = 3.0
    cases = []
    for n in SCALE_BRICKS:
        for sleep in (True, False) if not (quick and n > 64) else (True,):
            s = variant("lego", T, 1e-3, **{"bricks": n, "sleep.enabled": sleep})
            cases.append(bm.make_case(s, repeats=repeats))
            cases.append(
                bm.make_case(s, engine="mujoco", mujoco_timeconst_s=2e-3, mujoco_sleep=sleep, repeats=repeats)
            )
    return cases


GOAL_64_OVER_8 = 1.6  # Drake 1.58: 64 bricks against 8 per simulated second, interleaved


def scale_interleaved(rounds: int) -> dict:
    """64 bricks against 8 (h = 1 ms, sleep on, the path's first 3 s as ``scale_cases``), run in
    turn in this process, ``rounds`` times: ``benchmark.round_robin``'s CPU times, each round's
    ratio (``ratio_rounds``) and their median (``ratio_median``)."""
    return with_ratios(bm.round_robin({n: variant("lego", 3.0, 1e-3, bricks=n) for n in (8, 64)}, rounds))


def with_ratios(r: dict) -> dict:
    """``r`` (``round_robin``'s, keys 8 and 64) with each round's 64-over-8 ratio and their median."""
    r["ratio_rounds"] = [b / a for a, b in zip(*(r["cpu_s_per_sim_s"][n] for n in (8, 64)), strict=True)]
    r["ratio_median"] = float(np.median(r["ratio_rounds"]))
    return r


def interleaved_lines(r: dict) -> list[str]:
    """The report's sentence on :func:`scale_interleaved`, with the Drake and the machine beside it."""
    cpu = r["cpu_s_per_sim_s"]
    loads = [x for x in r["load_1min"] if math.isfinite(x)]
    return [
        f"**64 bricks against 8, interleaved in one process: {r['ratio_median']:.2f}×** per simulated "
        f"second (CPU time of the simulation loop, the path's first 3 s, sleep on, {r['rounds']} rounds of "
        f"8 then 64 bricks; rounds {min(r['ratio_rounds']):.2f}–{max(r['ratio_rounds']):.2f}×; medians "
        f"{np.median(cpu[8]):.3g} and {np.median(cpu[64]):.3g} s/s). Drake {r['drake']}; {r['machine']}"
        + (f"; load {min(loads):.1f}–{max(loads):.1f}" if loads else "")
        + f". Issue 47's goal on Drake 1.58: ≤ {GOAL_64_OVER_8:g}×.",
        "",
    ]


def scale_section(rows: list[dict], out: Path, interleaved: dict | None = None) -> tuple[list[str], dict]:
    """The scale figure and its table: wall time per simulated second against brick count;
    ``interleaved`` (:func:`scale_interleaved`): the 64-against-8 ratio measured in turn."""
    series: dict[str, dict[int, dict]] = {}
    for r in rows:
        c = r["config"]
        key = f"{'Drake' if c['engine'] == 'drake' else 'MuJoCo'}, sleep {'on' if c['sleep'] else 'off'}"
        series.setdefault(key, {})[c["bricks"]] = r
    fig, ax = plt.subplots(figsize=(7, 4.6))
    for key, by_n in sorted(series.items()):
        ns = sorted(n for n, r in by_n.items() if r.get("cost_median_s") and not r["diverged"])
        ax.errorbar(
            ns, [by_n[n]["cost_median_s"] for n in ns],
            yerr=[[by_n[n]["cost_median_s"] - by_n[n]["cost_min_s"] for n in ns],
                  [by_n[n]["cost_max_s"] - by_n[n]["cost_median_s"] for n in ns]],
            marker="o" if key.startswith("Drake") else "s", ls="-" if key.endswith("on") else "--",
            capsize=2, label=key, mfc="none" if key.startswith("MuJoCo") else None,
        )  # fmt: skip
    ax.axhline(1.0, color="grey", ls=":", lw=1)
    ax.text(SCALE_BRICKS[0], 1.05, "real time", color="grey", fontsize=8)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(SCALE_BRICKS, [str(n) for n in SCALE_BRICKS])
    ax.set_xlabel("bricks (the scene's 8, then a grid beside the path, in layers)")
    ax.set_ylabel("wall time per simulated second (s), h = 1 ms")
    ax.set_title("Cost against scene size: sleeping bodies")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "scale_bricks.png", dpi=110)
    plt.close(fig)
    keys = sorted(series)
    md = [
        "## Scale: cost against brick count (h = 1 ms)",
        "",
        "![scale](scale_bricks.png)",
        "",
        "| bricks | " + " | ".join(f"{k} (s/s)" for k in keys) + " |",
        "|---|" + "---|" * len(keys),
    ]
    table = {}
    for n in SCALE_BRICKS:
        cells = []
        for k in keys:
            r = series[k].get(n)
            cost = r.get("cost_median_s") if r and not r["diverged"] else None
            cells.append(fmt(cost))
            table.setdefault(k, {})[n] = cost
        md.append(f"| {n} | " + " | ".join(cells) + " |")
    md += [
        "",
        f"The cost of 64 bricks against 8 in this run's medians above (Drake {bm.drake_version()}; "
        f"{machine()}; the goal for Drake, sleep on: ≤ 2×):",
        "",
    ]
    for k in keys:
        c8, c64 = table[k].get(8), table[k].get(64)
        md.append(f"- {k}: {fmt(c64 / c8 if (c8 and c64) else None, '×', digits=2)}")
    md.append("")
    if interleaved is not None:
        md += interleaved_lines(interleaved)
    return md, table


def performance_goals(scene: str, rows: list[dict]) -> list[tuple]:
    """Rows of the goals table: (scene, at, configuration, RTF, goal).

    Bricks and grasper: the scene's default contact, solver and coupling at h = 1 ms and the
    fastest configuration at h = 1 ms (their goals are stated at h = 1 ms); the probe: its
    fastest configuration. The row says "default" only where the shipped scene's own step is
    1 ms (the laparoscopy ships h = 10 ms: its row is its defaults at the goal's step).
    """
    ok = [r for r in rows if not r["refused"] and not r["diverged"] and r["cost_median_s"]]
    out = []
    if scene in ("lego", "laparoscopy"):
        at_1ms = [r for r in ok if r["config"]["time_step"] == 1e-3 and r["config"]["device_rate"] == 60.0]
        default = [
            r
            for r in at_1ms
            if r["config"].get("contact") in (None, "proxies")
            and r["config"].get("approximation") in (None, "sap")
            and r["config"].get("coupling") in (None, "cartesian", "explicit")
        ]
        shipped_h = shipped_scenario(scene).plant.time_step
        what = (
            "default configuration, h = 1 ms"
            if shipped_h == 1e-3
            else f"default contact, solver and coupling at h = 1 ms (ships h = {1e3 * shipped_h:g} ms)"
        )
        picks = [(what, default)]
        picks.append(
            ("fastest at h = 1 ms", [min(at_1ms, key=lambda r: r["cost_median_s"])] if at_1ms else [])
        )
    else:
        picks = [("fastest configuration", [min(ok, key=lambda r: r["cost_median_s"])] if ok else [])]
    for what, at in picks:
        rtf = at[0]["real_time_factor"] if at else None
        out.append((scene, what, at[0]["label"] if at else "–", rtf, GOALS[scene]))
    return out


def brick_profile(seconds: float = 2.0) -> dict:
    """Where the time goes in the brick scene at h = 1 ms (the default configuration).

    Splits one run's wall time with cProfile into Drake's C++ (inside ``AdvanceTo`` but not
    in a Python callback) and the Python callbacks by module, and measures the parts of
    the C++ side separately: the plant alone with its 32 resting contacts, and its
    geometry query.
    """
    from pydrake.multibody.tree import JointIndex
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station
    from godobject_drake.station.plant import add_plant

    lego = replace(shipped_scenario("lego"), **{"simulation.duration_s": seconds})
    steps = round(seconds / 1e-3)

    def profiled(scenario) -> tuple:
        """One run under cProfile: (result, Drake's C++ µs per step, Python µs per step by module)."""
        station = build_station(scenario)
        prof = cProfile.Profile()
        prof.enable()
        result = simulate(station, progress=False)
        prof.disable()
        by_module: dict[str, float] = {}
        advance = 0.0
        for (file, _line, func), (_cc, _nc, tt, _ct, _callers) in pstats.Stats(prof).stats.items():
            if "AdvanceTo" in func:
                advance += tt
                continue
            stem = Path(file).stem
            key = stem if "godobject_drake" in file else ("pydrake bindings" if file == "~" else "other")
            by_module[key] = by_module.get(key, 0.0) + tt
        per_step = {
            k: v / steps * 1e6
            for k, v in sorted(by_module.items(), key=lambda kv: -kv[1])
            if v / steps > 1e-7
        }
        return result, advance / steps * 1e6, per_step

    result, advance_us, per_step = profiled(lego)
    # The implicit coupling's Python per step: what remains is the safeguards' monitor and the
    # springs' hook (docs/design.md "The implicit coupling").
    _, _, per_step_implicit = profiled(replace(lego, **{"god_object.coupling": "implicit"}))
    # The plant alone: the same scene, nothing grasped, 8 bricks resting (32 contacts).
    builder = DiagramBuilder()
    bare = add_plant(builder, lego)
    sim = Simulator(builder.Build())
    sim.Initialize()
    sim.AdvanceTo(0.1)
    t0 = time.perf_counter()
    sim.AdvanceTo(1.1)
    plant_us = (time.perf_counter() - t0) * 1e3
    query = bare.scene_graph.get_query_output_port().Eval(
        bare.scene_graph.GetMyContextFromRoot(sim.get_context())
    )
    contacts = len(query.ComputePointPairPenetration())
    t0 = time.perf_counter()
    for _ in range(1000):
        query.ComputePointPairPenetration()
    query_us = (time.perf_counter() - t0) * 1e3
    # The scene again without the profiler (its step cost), and the plant as the scene leaves it:
    # the held brick awake, the 7 others locked as they sleep. Both in this process, one after
    # the other.
    plain = simulate(build_station(lego), progress=False)
    plain_us = plain.metrics["wall_time_s"] / steps * 1e6
    implicit = simulate(build_station(replace(lego, **{"god_object.coupling": "implicit"})), progress=False)
    implicit_us = implicit.metrics["wall_time_s"] / steps * 1e6
    plant_ctx = bare.plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    for i in bare.plant.GetFloatingBaseBodies():
        body = bare.plant.get_body(i)
        if body.model_instance() != bare.plant.GetModelInstanceByName("brick_0"):
            for j in range(bare.plant.num_joints()):
                joint = bare.plant.get_joint(JointIndex(j))
                if joint.child_body().index() == i:
                    joint.Lock(plant_ctx)
    t0 = time.perf_counter()
    sim.AdvanceTo(2.1)
    asleep_us = (time.perf_counter() - t0) * 1e3
    return {
        "step_us": result.metrics["wall_time_s"] / steps * 1e6,
        "drake_cpp_us": advance_us,
        "python_us_by_module": per_step,
        "python_us_by_module_implicit": per_step_implicit,
        "plant_alone_us": plant_us,
        "resting_contacts": contacts,
        "geometry_query_us": query_us,
        "plant_asleep_us": asleep_us,
        "scene_unprofiled_us": plain_us,
        "non_plant_us": plain_us - asleep_us,
        "scene_implicit_us": implicit_us,
        "scene_over_floor": plain_us / asleep_us,
        "scene_implicit_over_floor": implicit_us / asleep_us,
        "sleep_mean_bodies": result.metrics.get("sleep_mean_bodies"),
    }


def parse_args(argv):
    """The command line, checked: ``--repeats`` ≥ 3."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory (created)")
    parser.add_argument("--quick", action="store_true", help="fewer steps and shorter runs (under 10 min)")
    parser.add_argument("--scene", choices=SCENES, action="append", help="only this scene (repeatable)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration (≥ 3 for the report)")
    parser.add_argument("--workers", type=int, default=1, help="local worker processes (timings: keep 1)")
    parser.add_argument("--scheduler", help="Dask distributed scheduler address (tcp://host:8786)")
    parser.add_argument("--no-mujoco", action="store_true", help="skip the MuJoCo peer")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if args.repeats < 3:
        parser.error(f"--repeats {args.repeats}: the report's medians need at least 3 runs per configuration")
    return args


def all_cases(scenes: list[str], args) -> tuple[list[bm.Case], list[tuple[str, str]]]:
    """Every case to run and, for each, its ``(scene, part)``: ``reference``, ``grid``,
    ``mujoco`` (the brick scene's peer, when MuJoCo is there and wanted) or ``scale``."""
    cases, owner = [], []
    for scene in scenes:
        ref, grid = sweep_cases(scene, args.quick, args.repeats)
        cases += [ref, *grid]
        owner += [(scene, "reference")] + [(scene, "grid")] * len(grid)
    use_mujoco = "lego" in scenes and not args.no_mujoco
    if use_mujoco and not mujoco_available():
        print(
            "MuJoCo not installed (pip install -e .[bench]); the peer comparison is skipped", file=sys.stderr
        )
        use_mujoco = False
    if use_mujoco:
        peer = mujoco_cases(args.quick, args.repeats)
        cases += peer
        owner += [("lego", "mujoco")] * len(peer)
    if "lego" in scenes:
        scale = [c for c in scale_cases(args.quick, args.repeats) if use_mujoco or c.engine == "drake"]
        cases += scale
        owner += [("lego", "scale")] * len(scale)
    return cases, owner


def profile_with_floor(quick: bool) -> dict:
    """:func:`brick_profile`, with the fair floor under ``fair_floor``: the scene's own plant
    replayed with what the scene did to it, no Python per step (analysis/step_floor.py),
    round-robin against the scene, both couplings."""
    profile = brick_profile()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import step_floor

    profile["fair_floor"] = step_floor.measure(3.0 if quick else None, 3)
    return profile


def head_lines(args) -> list[str]:
    """The report's title and what its columns mean."""
    return [
        "# Speed against error",
        "",
        f"Generated by `python analysis/speed_vs_error.py --out {args.out}{' --quick' * args.quick}` "
        f"({args.repeats} runs per configuration; cost = wall time of the simulation loop per simulated "
        "second, median, min–max in brackets; RTF = 1/median). Pose error: RMS distance between the "
        "god-object's frame in the run and in the reference, sampled every 10 ms; energy error: largest "
        "difference of the rigid bodies' kinetic + potential energy. `refused`: the explicit coupling's "
        "gains are past its stability limit at that h (docs/theory.md §1) and the scene refuses to run.",
        "",
        f"Machine: {machine()}. Absolute costs carry to no other machine; the ratios between rows "
        "measured in this run do.",
        "",
    ]


def scene_lines(scene: str, runs: dict, args, summary: dict, goals: list) -> list[str]:
    """One scene's section: its rows against its reference, its figure and recommendations
    (into ``summary["scenes"]``), its performance goals appended to ``goals``; the brick
    scene's parts after them (:func:`brick_lines`). ``runs``: the results by part."""
    ref = runs["reference"][0]
    rows = evaluate([ref, *runs["grid"]], ref, scene)
    peer_rows = evaluate(runs["mujoco"], ref, scene)
    fig = figure(scene, rows, peer_rows, args.out)
    section, recs = scene_section(
        scene, ref, rows, peer_rows, fig, BUDGETS_M[scene], PENETRATION_BUDGET_M[scene]
    )
    md = [*section]
    summary["scenes"][scene] = {
        "reference": ref["label"],
        "rows": rows,
        "mujoco": peer_rows,
        "recommended": recs,
        "figure": fig,
    }
    goals += performance_goals(scene, rows)
    if scene == "lego":
        md += brick_lines(ref, rows, peer_rows, runs["scale"], args, summary, goals)
    return md


def brick_lines(ref, rows, peer_rows, scale_runs, args, summary: dict, goals: list) -> list[str]:
    """The brick scene's own parts: Drake against MuJoCo at equal budgets, the scale (64 bricks'
    goal appended to ``goals``) and the two couplings; their tables into ``summary``."""
    scene, md = "lego", []
    if peer_rows:
        section, table = equal_budget([r for r in rows if r["label"] != ref["label"]], peer_rows)
        md += section
        summary["equal_budget"] = table
    scale_rows = evaluate(scale_runs, ref, scene)
    interleaved = scale_interleaved(args.repeats)
    section, table = scale_section(scale_rows, args.out, interleaved)
    md += section
    summary["scale"] = {k: {str(n): v for n, v in t.items()} for k, t in table.items()}
    summary["scale_interleaved"] = interleaved
    section, summary["couplings"] = coupling_section(rows, PENETRATION_BUDGET_M[scene])
    md += section
    cost64 = table.get("Drake, sleep on", {}).get(64)
    goals.append((scene, "64 bricks, h = 1 ms, sleep on", "bricks=64", 1 / cost64 if cost64 else None,
                  GOAL_64_BRICKS))  # fmt: skip
    return md


def goal_lines(goals: list, overhead: dict) -> list[str]:
    """The performance goals' table: each scene's, and the coupling's per-step overhead."""
    md = [
        "## Performance goals",
        "",
        "| scene | at | configuration | RTF | goal | met |",
        "|---|---|---|---|---|---|",
    ]
    for scene, what, label, rtf, goal in goals:
        md.append(
            f"| {scene} | {what} | `{label}` | {fmt(rtf, digits=3)} | ≥ {goal:g} | "
            f"{'yes' if rtf and rtf >= goal else 'no'} |"
        )
    md.append(
        f"| coupling LeafSystem | per step, alone | `coupling_overhead_us()` | "
        f"{overhead['median_us']:.1f} µs (min {overhead['min_us']:.1f}) | ≤ {COUPLING_GOAL_US:g} µs | "
        f"{'yes' if overhead['median_us'] <= COUPLING_GOAL_US else 'no'} |"
    )
    return md


def profile_lines(profile: dict) -> list[str]:
    """Where the time goes in the brick scene (:func:`brick_profile`), against both floors."""
    py = profile["python_us_by_module"]
    md = [
        "",
        "## Where the time goes: brick scene, h = 1 ms",
        "",
        f"One step costs {profile['step_us']:.0f} µs: {profile['drake_cpp_us']:.0f} µs in Drake's C++ "
        f"(plant, SAP, geometry, logging, inside `AdvanceTo`) and the rest in Python callbacks:",
        "",
        "| Python, by module | µs per step |",
        "|---|---|",
    ]
    md += [f"| {k} | {v:.1f} |" for k, v in py.items()]
    md += [
        "",
        f"The plant alone (no device, no coupling, {profile['resting_contacts']} resting contacts) "
        f"costs {profile['plant_alone_us']:.0f} µs per step, of which the geometry query is "
        f"{profile['geometry_query_us']:.0f} µs; the rest is SAP's contact solve and the dynamics. "
        f"With the 7 bricks the scene puts to sleep locked ({profile['sleep_mean_bodies']:.1f} sleep "
        f"on average in the scene), the plant costs {profile['plant_asleep_us']:.0f} µs and the "
        f"scene, unprofiled, {profile['scene_unprofiled_us']:.0f} µs: the scene's "
        f"**non-plant cost is {profile['non_plant_us']:.0f} µs per step** (device, coupling, "
        "loggers, safeguards and sleep checks, the simulator's own events), both measured in this run.",
        "",
        f"**Against that floor** (ratios of this run): the scene with the explicit coupling costs "
        f"{profile['scene_over_floor']:.2f}× the plant's step, with the implicit coupling "
        f"{profile['scene_implicit_over_floor']:.2f}× ({profile['scene_implicit_us']:.0f} µs; its floor "
        "includes SAP's seven coupling constraints, which this plant-alone step does not solve). "
        "Issue 31's goal: ≤ 1.15×.",
        "",
        "",
        *_fair_floor_lines(profile.get("fair_floor")),
        "",
        "Python with the implicit coupling (cProfile, the same 2 s), µs per plant step by module: "
        + ", ".join(f"{k} {v:.1f}" for k, v in profile["python_us_by_module_implicit"].items())
        + ". As above these are the whole run's Python divided by its steps: the work at device "
        "samples (the `implicit` module's grasp and target, sleep checks) and after the run (the "
        "logged terms, the metrics) counted in. Only the safeguards' monitor runs at every step; "
        "it also moves the springs' ends at the first step after each sample.",
    ]
    return md


def main(argv=None) -> int:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    scenes = args.scene or list(SCENES)
    t_start = time.perf_counter()
    cases, owner = all_cases(scenes, args)
    results = run_tasks(
        bm.run_case,
        cases,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.no_progress,
        desc="speed vs error",
    )
    overhead = bm.coupling_overhead_us()
    profile = profile_with_floor(args.quick) if "lego" in scenes else None
    summary = {
        "quick": args.quick,
        "repeats": args.repeats,
        "scenes": {},
        "coupling_overhead_us": overhead,
        "brick_profile": profile,
        "machine": machine(),
    }
    md = head_lines(args)
    goals = []
    for scene in scenes:
        runs = {part: [r for r, o in zip(results, owner, strict=True) if o == (scene, part)]
                for part in ("reference", "grid", "mujoco", "scale")}  # fmt: skip
        md += scene_lines(scene, runs, args, summary, goals)
    md += goal_lines(goals, overhead)
    summary["goals"] = [dict(zip(("scene", "at", "label", "rtf", "goal"), g, strict=True)) for g in goals]
    if profile:
        md += profile_lines(profile)
    elapsed = time.perf_counter() - t_start
    summary["elapsed_s"] = elapsed
    md += ["", f"Report time {elapsed:.0f} s on this machine.", ""]
    (args.out / "report.md").write_text("\n".join(md))
    (args.out / "results.json").write_text(json.dumps(summary, indent=1, default=_json_default))
    print(f"wrote {args.out / 'report.md'} and results.json in {elapsed:.0f} s")
    return 0


def _fair_floor_lines(floor: dict | None) -> list[str]:
    """The speed report's paragraph on analysis/step_floor.py's fair floor (its ``measure``)."""
    if not floor:
        return []
    med, r = floor["cpu_us_per_step_median"], floor["ratio_rounds_median"]
    path = "the whole path" if floor["seconds"] is None else f"the path's first {floor['seconds']:g} s"
    rounds = len(floor["ratio_rounds"]["explicit_over_replay"])
    same = floor["explicit_replay_bit_identical"] and floor["implicit_replay_bit_identical"]
    return [
        f"**Against a fair floor** (`analysis/step_floor.py`, {path}, {rounds} rounds round-robin, "
        "CPU time): "
        "the resting floor above has the held brick at rest, but in the scene it moves, slides and "
        "climbs the wall; the fair floor is the scene's own plant replaying what the scene did to it "
        "(the explicit coupling's forces from a C++ `TrajectorySource`, the implicit springs, locks "
        "and projections between `AdvanceTo` calls), "
        + ("its final state bit-identical to the scene's" if same else "**its final state NOT the scene's**")
        + f". Scene over replay, median of the rounds' ratios: **{r['explicit_over_replay']:.2f}×** "
        f"explicit ({med['scene_explicit']:.0f} against {med['floor_explicit']:.0f} µs per step), "
        f"**{r['implicit_over_replay']:.2f}×** implicit ({med['scene_implicit']:.0f} against "
        f"{med['floor_implicit']:.0f} µs; SAP's coupling springs make its plant "
        f"{med['floor_implicit'] / med['floor_explicit']:.2f}× the explicit one's). "
        "Issue 31's goal: ≤ 1.15×.",
    ]


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.bool_):
        return bool(o)
    if dataclasses.is_dataclass(o):
        return dataclasses.asdict(o)
    raise TypeError(type(o))


if __name__ == "__main__":
    sys.exit(main())
