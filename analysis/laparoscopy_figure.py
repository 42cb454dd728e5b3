#!/usr/bin/env python3
"""Draw the laparoscopy scene's default run: tip paths and tissue indentation (docs/laparoscopy.png).

    python analysis/laparoscopy_figure.py --out docs/laparoscopy.png

Runs the default path with the god-object (Cartesian coupling) and the
position baseline and plots, in the plane y = 0, the uterus and bladder,
the insertion point P, the interface's tip and both tools' tips; and over
time, each tool's deepest overlap with the organs.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle, Ellipse

from godobject_drake.config.scenario import replace, shipped_scenario
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station


def tips(station, states, q_device):
    """God-object and interface tip positions (m) at every logged step."""
    plant, tool = station.plant, station.god_object.tool
    tip = plant.GetBodyByName("tube", tool.model)
    ctx = plant.CreateDefaultContext()
    god, dev = [], []
    for x, q in zip(states, q_device, strict=True):
        plant.SetPositions(ctx, x[: plant.num_positions()])
        god.append(plant.EvalBodyPoseInWorld(ctx, tip).translation())
        dev.append(plant.EvalBodyPoseInWorld(tool.set_device_state(q), tip).translation())
    return np.array(god), np.array(dev)


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=Path("docs/laparoscopy.png"))
    parser.add_argument(
        "--duration", type=float, default=10.0, help="simulated time (s); the path lasts 10 s"
    )
    args_cli = parser.parse_args(argv)
    fig, (ax, ax_pen) = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [1.1, 1]})
    ax.add_patch(Ellipse((0, 0), 0.09, 0.05, color=(0.85, 0.45, 0.5), alpha=0.5, label="uterus (E = 50 kPa)"))
    ax.add_patch(Circle((-0.075, -0.005), 0.025, color=(0.9, 0.8, 0.45), alpha=0.5, label="bladder"))
    ax.plot([0], [0.10], "k+", ms=12, mew=2, label="insertion point P")
    for mode, style in (("position", "--"), ("god_object", "-")):
        scenario = replace(
            shipped_scenario("laparoscopy"),
            **{"simulation.mode": mode, "simulation.duration_s": args_cli.duration},
        )
        result = simulate(build_station(scenario), progress=False)
        metrics, states, q_device = result.metrics, result.states, result.data["q_device"]
        god, dev = tips(result.station, states, q_device)
        t = result.times
        if mode == "god_object":
            ax.plot(dev[:, 0], dev[:, 2], color="tab:blue", lw=1, label="interface's tip (jaw hinge)")
        ax.plot(god[:, 0], god[:, 2], style, color="tab:red" if mode == "god_object" else "tab:gray", lw=1.5,
                label=f"{mode} tip (jaw hinge)")  # fmt: skip
        pen = penetration_series(result.station, states)
        ax_pen.plot(t, 1e3 * pen, style, color="tab:red" if mode == "god_object" else "tab:gray",
                    label=f"{mode}: max {1e3 * metrics['max_penetration_m']:.1f} mm")  # fmt: skip
    ax.set(xlabel="x (m)", ylabel="z (m)", aspect="equal", xlim=(-0.11, 0.08), ylim=(-0.04, 0.11),
           title="tips in the plane y = 0")  # fmt: skip
    ax.legend(fontsize=7, loc="upper left")
    ax_pen.axhline(5.0, color="k", lw=0.8, ls=":")
    ax_pen.set(xlabel="t (s)", ylabel="deepest overlap with the organs (mm)", title="tissue indentation")
    ax_pen.legend(fontsize=8)
    fig.tight_layout()
    args_cli.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args_cli.out, dpi=110)
    print(f"figure written to {args_cli.out}")


def penetration_series(station, states):
    """Deepest tool/organ overlap (m, ≥ 0) at every logged step, Drake's signed distance."""
    plant, inspector = station.plant, station.scene_graph.model_inspector()
    context = station.diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    tool_frames = {
        plant.GetBodyFrameIdOrThrow(b) for b in plant.GetBodyIndices(station.god_object.tool.model)
    }
    out = np.zeros(len(states))
    for k, x in enumerate(states):
        plant.SetPositions(plant_context, x[: plant.num_positions()])
        query = plant.get_geometry_query_input_port().Eval(plant_context)
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.0):
            if (inspector.GetFrameId(pair.id_A) in tool_frames) != (
                inspector.GetFrameId(pair.id_B) in tool_frames
            ):
                out[k] = max(out[k], -pair.distance)
    return out


if __name__ == "__main__":
    main()
