#!/usr/bin/env python3
"""Two sessions' task scores side by side, with their tips' paths and forces over time.

    python analysis/compare_runs.py SCENE_A SCENE_B [--set-a KEY=VALUE ...] [--set-b KEY=VALUE ...]
        [--names A B] [--duration S] [--out DIR]
    python analysis/compare_runs.py RUN_A.json RUN_B.json [--names A B]

A study compares conditions (haptic feedback, pseudo-haptics, none) on the same task. Given two
scenarios (a file or a shipped scene's name, each with its own ``--set`` overrides, as
``godobject run`` takes them), it runs both with their logs kept and prints, per tool, the motion,
force and safety scores (docs/task_metrics.md) of each run side by side. In ``--out`` (default
``compare_A_B``) it writes ``scores.json`` (both runs' whole metrics), ``tip_paths.png`` (each
tool's tip path, seen from above and from the side) and ``forces.png`` (each tool's net contact
force on other bodies over time).

Given two metrics JSON files (``godobject run SCENE --metrics RUN.json``), it prints their scores
side by side only: a metrics file holds no trajectory to plot.

Example, a clean session against a shaky one (2 mm of noise on each device sample)::

    python analysis/compare_runs.py lego lego --set-b device.noise_m=0.002 --names clean shaky
"""

import argparse
import json
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from godobject_drake.cli import load_with_sets, scenario_path
from godobject_drake.metrics import write_metrics
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station

# The scores compared, in the table's order (docs/task_metrics.md)
SCORES = (
    "task_time_s",
    "tip_path_m",
    "tip_economy_of_motion",
    "tip_log_dimensionless_jerk",
    "tip_idle_time_s",
    "tip_peak_speed_mps",
    "tip_out_of_view_s",
    "tool_max_force_N",
    "tool_mean_force_N",
    "tool_contact_time_s",
    "tool_collisions",
    "tool_collision_time_s",
)
SCENE_SCORES = ("instrument_collisions", "instrument_collision_time_s")


def per_tool(metrics: dict) -> dict[str, dict]:
    """Each tool's metrics by name (a scene of one tool: its one, named ``tool``)."""
    tools = metrics.get("tools")
    return tools if isinstance(tools, dict) else {"tool": metrics}


def side_by_side(runs: list[dict], names: list[str]) -> str:
    """The scores of ``runs`` as a plain-text table: one row per tool and score, one column per run."""

    def cell(v):
        if v is None:
            return "—"
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    rows = [["tool", "score", *names]]
    tools = list(dict.fromkeys(t for run in runs for t in per_tool(run)))
    for tool in tools:
        for key in SCORES:
            values = [per_tool(run).get(tool, {}).get(key) for run in runs]
            if any(v is not None for v in values) or any(key in per_tool(run).get(tool, {}) for run in runs):
                rows.append([tool, key, *(cell(v) for v in values)])
    for key in SCENE_SCORES:
        if any(key in run for run in runs):
            rows.append(["scene", key, *(cell(run.get(key)) for run in runs)])
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def run(path: Path, sets: list[str], duration: float | None):
    """One session: the scenario with its overrides, simulated with its logs (and traces) kept."""
    scenario = load_with_sets(path, sets)
    return simulate(build_station(scenario), duration_s=duration, progress=False)


def plot_paths(results, names, out: Path) -> None:
    """Each run's tool tips from above (x, y) and from the side (x, z), in mm."""
    fig, (top, side) = plt.subplots(1, 2, figsize=(11, 4.8))
    for result, name, style in zip(results, names, ("-", "--"), strict=True):
        for tool, trace in result.traces.items():
            label = f"{name}: {tool or 'tool'}"
            top.plot(1e3 * trace[:, 1], 1e3 * trace[:, 2], style, lw=1.2, label=label)
            side.plot(1e3 * trace[:, 1], 1e3 * trace[:, 3], style, lw=1.2, label=label)
    top.set(xlabel="x (mm)", ylabel="y (mm)", title="tip path from above")
    side.set(xlabel="x (mm)", ylabel="z (mm)", title="tip path from the side")
    for ax in (top, side):
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    top.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def plot_forces(results, names, out: Path) -> None:
    """Each run's tools' net contact force on other bodies over time."""
    fig, ax = plt.subplots(figsize=(9, 4))
    for result, name, style in zip(results, names, ("-", "--"), strict=True):
        for tool, trace in result.traces.items():
            ax.plot(trace[:, 0], trace[:, 4], style, lw=1.0, label=f"{name}: {tool or 'tool'}")
    ax.set(xlabel="t (s)", ylabel="contact force on other bodies (N)", title="tool force over time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("a", help="the first session: a scenario (file or shipped name), or a metrics JSON")
    parser.add_argument("b", help="the second session, of the same kind")
    parser.add_argument("--set-a", nargs="*", default=[], metavar="KEY=VALUE", help="the first's overrides")
    parser.add_argument("--set-b", nargs="*", default=[], metavar="KEY=VALUE", help="the second's overrides")
    parser.add_argument("--names", nargs=2, default=None, metavar=("A", "B"), help="the two columns' names")
    parser.add_argument("--duration", type=float, default=None, help="simulated time (s) of each run")
    parser.add_argument("--out", type=Path, default=None, help="the folder (default compare_A_B)")
    args = parser.parse_args(argv)
    names = args.names or [Path(args.a).stem, Path(args.b).stem]
    if names[0] == names[1]:
        names = [f"{names[0]} (a)", f"{names[1]} (b)"]
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        parser.error(f"--duration {args.duration!r} s must be finite and > 0: give e.g. 3")
    jsons = [str(p).endswith(".json") for p in (args.a, args.b)]
    if all(jsons):
        runs = [json.loads(Path(p).read_text()) for p in (args.a, args.b)]
        print(side_by_side(runs, names))
        return 0
    if any(jsons):
        parser.error(f"{args.a} and {args.b}: give two scenarios, or two metrics JSON files, not one of each")
    results = [
        run(scenario_path(args.a), args.set_a, args.duration),
        run(scenario_path(args.b), args.set_b, args.duration),
    ]
    print(side_by_side([r.metrics for r in results], names))
    out = args.out or Path(f"compare_{Path(args.a).stem}_{Path(args.b).stem}")
    out.mkdir(parents=True, exist_ok=True)
    write_metrics(out / "scores.json", {name: r.metrics for name, r in zip(names, results, strict=True)})
    plot_paths(results, names, out / "tip_paths.png")
    plot_forces(results, names, out / "forces.png")
    print(f"written: {out / 'scores.json'}, {out / 'tip_paths.png'}, {out / 'forces.png'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
