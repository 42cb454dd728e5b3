#!/usr/bin/env python3
"""CENIC (error-controlled convex integration of a continuous plant) against SAP on the brick scene.

    python analysis/cenic_trial.py [--duration 8.5] [--out results.json] [--repeats 1] [--no-baseline]
    python analysis/cenic_trial.py --table results.json   # an earlier run's table again
        [--accuracies 1e-1 1e-2 3e-3 1e-3] [--sap-steps 1e-3 2e-3] [--sanity radau3] [--sanity-duration 0.5]

Issue 31, part 3: is Drake's ``cenic`` integration scheme (a ``time_step = 0`` plant advanced
by ``Simulator`` with ``SimulatorConfig(integration_scheme="cenic", accuracy=...)``) faster than
discrete SAP at equal penetration and tracking on ``diagrams/lego.yaml``'s path?

Every configuration is the same diagram the scene builds (device, coupling, loggers), only the
plant's time step and the integrator differ: SAP runs are ``build_station`` of the shipped
scenario at ``plant.time_step = h``; continuous runs build the same parts on a ``time_step = 0``
plant (contact: the models' point stiffness, the proxies' filters). The configurations run
interleaved in one process (round-robin over ``--repeats``), so their cost ratios share the
machine's state. None of these runs has sleeping bodies (the project's sleep manager and
safeguards live in :func:`~godobject_drake.simulation.simulate`, which needs a discrete plant);
the first row (``--no-baseline`` leaves it out) is the project's own ``simulate()`` at SAP
h = 1 ms with them, the figure ``godobject run lego`` gives. For each run:

- ``cpu_s_per_sim_s``: ``time.process_time()`` around ``Simulator.AdvanceTo`` alone, per
  simulated second (the median over repeats);
- ``max_penetration_m``: the scene's own metric (:class:`~godobject_drake.metrics.RigidMetrics`:
  the held brick's deepest true-shape overlap) over every logged state: every plant step (SAP),
  every integrator step (continuous; the logger publishes per step, so it forces no step
  boundary);
- ``rms_tracking_error_m``: the same class's RMS distance of the held brick from its target in
  free space, sampled like for like at the end of each device period (just before the next
  sample; both kinds step there anyway): per-step samples would weigh a variable-step run
  towards the instants after each target jump, where it steps densely;
- ``steps``, ``rejected`` (step shrinkages from error control), ``largest_step_s``;
- ``diverged``/``error``: what Drake raised, if it did.

``--sanity`` adds a general-purpose implicit integrator of the same continuous plant (e.g.
``radau3``, ``implicit_euler``) run for ``--sanity-duration`` s only and stopped after
``--sanity-cpu-cap`` CPU s: its cost is per simulated second of what it ran, labelled so.

Prints a markdown table (with ``nproc`` and the CPU model) and writes every figure to ``--out``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from godobject_drake.studies.benchmark import cpu_model


def build(scenario, h: float):
    """The brick scene's diagram at plant step ``h`` (s; 0: a continuous plant):
    ``(diagram, plant, scene_graph, loggers)``.

    The same parts either way: the scenario's device, plant (directives, proxies' collision
    filters), rigid god-object and its coupling. ``h > 0`` is the project's own
    :func:`~godobject_drake.station.build.add_plant` (SAP, relaxation time h). ``h = 0`` is
    ``AddMultibodyPlant`` at ``time_step = 0`` with the same models and filters (contact: the
    models' point stiffness; relaxation time is SAP's, not used). Loggers: ``state``/``terms``
    at every plant step (h > 0) or every integrator step (h = 0: a per-step publish forces no
    step boundary), and ``state_dev``/``terms_dev`` at the device period, just before each
    device sample (both kinds stop there anyway), where tracking is compared like for like.
    """
    from pydrake.multibody.parsing import ModelDirectives, ProcessModelDirectives
    from pydrake.multibody.plant import AddMultibodyPlant
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput

    from godobject_drake.config import scenario as sc
    from godobject_drake.station.build import make_device
    from godobject_drake.station.plant import add_plant, apply_contact_model, make_parser
    from godobject_drake.station.rigid_tool import add_god_object, coupling_options

    builder = DiagramBuilder()
    device = builder.AddNamedSystem(
        "device",
        make_device(scenario.device, seed=scenario.random_seed, workspace=scenario.workspace,
                    duration_s=scenario.simulation.duration_s),
    )  # fmt: skip
    if h > 0:
        scene = add_plant(builder, sc.replace(scenario, **{"plant.time_step": h}))
        plant, scene_graph = scene.plant, scene.scene_graph
    else:
        config = copy.deepcopy(scenario.plant)
        config.time_step = 0.0
        plant, scene_graph = AddMultibodyPlant(config, builder)
        directives = ModelDirectives(directives=list(scenario.directives))
        ProcessModelDirectives(directives, plant, make_parser(plant))
        plant.Finalize()
        apply_contact_model(plant, scene_graph, scenario.contact.geometry)
    god = add_god_object(
        builder, plant, device, scenario.god_object.gains, scenario.feedback, haptic=scenario.haptic,
        **coupling_options(scenario.god_object),
    )  # fmt: skip
    ports = {"state": plant.get_state_output_port(), "terms": god.coupling.GetOutputPort("terms")}
    loggers = {name: LogVectorOutput(port, builder, h) for name, port in ports.items()}
    for name, port in ports.items():
        loggers[f"{name}_dev"] = LogVectorOutput(port, builder, device.period_s)
    return builder.Build(), plant, scene_graph, loggers


def fold(plant, scene_graph, diagram, states, terms) -> dict:
    """The scene's rigid metrics (:class:`~godobject_drake.metrics.RigidMetrics`) of logged rows."""
    from godobject_drake.metrics import RigidMetrics, TrueShapeMetrics
    from godobject_drake.systems.coupling import TERMS_LAYOUT

    n = min(len(states), len(terms))
    states, terms = states[:n], terms[:n]
    finite = np.all(np.isfinite(states), axis=1) & np.all(np.isfinite(terms), axis=1)
    acc = RigidMetrics(TrueShapeMetrics(plant, scene_graph, diagram))
    held = terms[finite][:, TERMS_LAYOUT["held_body"]].round().astype(int)
    acc.update(states[finite], held, terms[finite][:, TERMS_LAYOUT["pose_WT"]][:, 4:])
    return {**acc.result(), "rows": int(n), "finite": bool(finite.all())}


def run(config: dict, scenario, duration: float) -> dict:
    """One run of ``config`` (``kind`` sap or an integration scheme) for ``duration`` s."""
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
    from pydrake.systems.framework import EventStatus

    if config["kind"] == "simulate":
        return run_simulate(config, scenario, duration)
    sap = config["kind"] == "sap"
    diagram, plant, scene_graph, loggers = build(scenario, config["h"] if sap else 0.0)
    simulator = Simulator(diagram)
    if not sap:
        ApplySimulatorConfig(
            SimulatorConfig(
                integration_scheme=config["kind"],
                accuracy=config["accuracy"],
                max_step_size=config.get("max_step_size", 0.1),
                use_error_control=True,
            ),
            simulator,
        )
    cap = config.get("cpu_cap_s")
    start = [None]
    if cap is not None:

        def monitor(context):
            if start[0] is not None and time.process_time() - start[0] > cap:
                return EventStatus.ReachedTermination(diagram, f"CPU cap {cap:g} s reached")
            return EventStatus.DidNothing()

        simulator.set_monitor(monitor)
    simulator.Initialize()
    context = simulator.get_context()
    error = None
    t0 = start[0] = time.process_time()
    try:
        simulator.AdvanceTo(duration)
    except Exception as e:  # Drake's refusal or failure is a result: recorded, never hidden
        error = f"{type(e).__name__}: {' '.join(str(e).split())[:400]}"
    cpu = time.process_time() - t0
    t_end = context.get_time()

    def rows(name):
        return loggers[name].FindLog(context).data().T

    every = fold(plant, scene_graph, diagram, rows("state"), rows("terms"))
    at_device = fold(plant, scene_graph, diagram, rows("state_dev"), rows("terms_dev"))
    integrator = simulator.get_integrator()
    out = {
        "sim_time_s": t_end,
        "cpu_s": cpu,
        "cpu_s_per_sim_s": cpu / t_end if t_end > 0 else None,
        "max_penetration_m": every["max_penetration_m"],
        "rms_tracking_error_m": at_device["rms_tracking_error_m"],
        "max_penetration_at_device_samples_m": at_device["max_penetration_m"],
        "rms_tracking_error_every_step_m": every["rms_tracking_error_m"],
        "free_space_samples": at_device["free_space_samples"],
        "logged_rows": every["rows"],
        "diverged": bool(error is not None or not every["finite"]),
        "error": error,
        "stopped_early": t_end < duration - 1e-9,
    }
    if sap:
        out.update(steps=round(t_end / config["h"]), rejected=0, largest_step_s=config["h"])
    else:
        out.update(
            steps=int(integrator.get_num_steps_taken()),
            rejected=int(integrator.get_num_step_shrinkages_from_error_control()),
            largest_step_s=float(integrator.get_largest_step_size_taken()),
        )
    return out


def run_simulate(config: dict, scenario, duration: float) -> dict:
    """The project's own run (``godobject run lego``: :func:`~godobject_drake.simulation.simulate`
    with its safeguards and sleeping bodies) at SAP step ``h``: the baseline the goal quotes."""
    from godobject_drake.config import scenario as sc
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    station = build_station(sc.replace(scenario, **{"plant.time_step": config["h"]}))
    t0 = time.process_time()
    result = simulate(station, duration_s=duration, progress=False, keep_logs=False)
    cpu = time.process_time() - t0
    m = result.metrics
    return {
        "sim_time_s": m["sim_time_s"],
        "cpu_s": cpu,
        "cpu_s_per_sim_s": cpu / m["sim_time_s"] if m["sim_time_s"] > 0 else None,
        "max_penetration_m": m["max_penetration_m"],
        "rms_tracking_error_m": None,  # simulate's is per plant step, not at the device samples
        "rms_tracking_error_every_step_m": m["rms_tracking_error_m"],
        "diverged": bool(m["diverged"]),
        "error": m["diagnosis"],
        "stopped_early": bool(m["partial"]),
        "steps": round(m["sim_time_s"] / config["h"]),
        "rejected": 0,
        "largest_step_s": config["h"],
    }


def label(config: dict) -> str:
    if config["kind"] == "simulate":
        return f"SAP h={config['h'] * 1e3:g} ms, simulate() (sleep on, safeguards)"
    if config["kind"] == "sap":
        return f"SAP h={config['h'] * 1e3:g} ms"
    text = f"{config['kind']} accuracy={config['accuracy']:g}"
    if config.get("max_step_size", 0.1) != 0.1:
        text += f" max_step={config['max_step_size'] * 1e3:g} ms"
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=None, help="simulated s (default: the scene's 8.5)")
    parser.add_argument("--out", default="results.json", help="JSON file for every figure")
    parser.add_argument("--repeats", type=int, default=1, help="round-robin repeats; cost is their median")
    parser.add_argument("--sap-steps", type=float, nargs="*", default=[1e-3, 2e-3], help="SAP steps h (s)")
    parser.add_argument(
        "--no-baseline",
        dest="baseline",
        action="store_false",
        help="leave out the project's own simulate() at SAP 1 ms (sleeping bodies on)",
    )
    parser.add_argument("--accuracies", type=float, nargs="*", default=[1e-1, 1e-2, 3e-3, 1e-3])
    parser.add_argument("--max-step", type=float, default=0.1, help="cenic's max_step_size (s)")
    parser.add_argument("--sanity", nargs="*", default=["radau3"], help="other schemes, run briefly")
    parser.add_argument("--sanity-accuracy", type=float, default=1e-3)
    parser.add_argument("--sanity-duration", type=float, default=0.5)
    parser.add_argument("--sanity-cpu-cap", type=float, default=120.0, help="CPU s before a sanity run stops")
    parser.add_argument("--table", metavar="RESULTS_JSON", help="print an earlier run's table; run nothing")
    args = parser.parse_args(argv)
    if args.table:
        report = json.loads(Path(args.table).read_text())
        report["rows"] = summarize([(row["config"], row["runs"]) for row in report["rows"]])
        print_table(report)
        return 0

    from importlib.metadata import version

    from pydrake.systems.analysis import GetIntegrationSchemes

    from godobject_drake.config.scenario import shipped_scenario

    scenario = shipped_scenario("lego")
    duration = scenario.simulation.duration_s if args.duration is None else args.duration
    if not duration > 0:
        parser.error(f"--duration {duration!r}: give simulated seconds > 0")
    if args.repeats < 1:
        parser.error(f"--repeats {args.repeats}: give at least 1")
    schemes = GetIntegrationSchemes()
    for scheme in ["cenic", *args.sanity] if args.accuracies else args.sanity:
        if scheme not in schemes:
            parser.error(
                f"integration scheme {scheme!r} is not in this Drake ({version('drake')}): it has "
                f"{', '.join(schemes)}. Both of the project's Drake pins have cenic (1.51.1 for Python 3.11, "
                "1.58.0 for ≥ 3.12): pip install -e . installs the one for your Python"
            )
    configs = [{"kind": "simulate", "h": 1e-3}] if args.baseline else []
    configs += [{"kind": "sap", "h": h} for h in args.sap_steps]
    configs += [{"kind": "cenic", "accuracy": a, "max_step_size": args.max_step} for a in args.accuracies]
    sanity = [
        {"kind": s, "accuracy": args.sanity_accuracy, "cpu_cap_s": args.sanity_cpu_cap} for s in args.sanity
    ]

    machine = {
        "nproc": os.cpu_count(),
        "cpu": cpu_model(),
        "drake": version("drake"),
        "python": sys.version.split()[0],
        "loadavg_1min_at_start": os.getloadavg()[0],
        "command": " ".join([Path(sys.argv[0]).name, *(sys.argv[1:] if argv is None else argv)]),
    }
    runs = {label(c): [] for c in configs + sanity}
    for r in range(args.repeats):
        for c in configs:
            result = run(c, scenario, duration)
            runs[label(c)].append(result)
            print(f"[{r + 1}/{args.repeats}] {label(c)}: {result['cpu_s_per_sim_s']:.3f} CPU s/s, "
                  f"pen {result['max_penetration_m'] * 1e3:.3f} mm", file=sys.stderr, flush=True)  # fmt: skip
    for c in sanity:  # once: they are the slow general-purpose points
        result = run(c, scenario, min(duration, args.sanity_duration))
        runs[label(c)].append(result)

    rows = summarize([(c, runs[label(c)]) for c in configs + sanity])
    report = {"machine": machine, "duration_s": duration, "rows": rows}
    print_table(report)
    Path(args.out).write_text(json.dumps(report, indent=1))
    print(f"\nwrote {args.out}")
    return 0


def summarize(runs: list[tuple[dict, list[dict]]]) -> list[dict]:
    """One row per configuration: its first run's figures, the median cost of its repeats, and
    ``speedup_vs_sap_1ms``: SAP 1 ms's cost over its own, the median of the repeats' own ratios
    (each repeat ran every configuration back to back, so a ratio shares its machine's load),
    or the ratio of the medians for a configuration run once."""
    sap1 = next(([x["cpu_s_per_sim_s"] for x in rs] for c, rs in runs if label(c) == "SAP h=1 ms"), [])
    rows = []
    for c, rs in runs:
        costs = [x["cpu_s_per_sim_s"] for x in rs]
        speedup = None
        if sap1 and None not in costs and None not in sap1:
            if len(rs) == len(sap1):
                speedup = statistics.median(b / x for b, x in zip(sap1, costs, strict=True))
            else:
                speedup = statistics.median(sap1) / statistics.median(costs)
        first = rs[0]
        rows.append({
            "label": label(c), "config": c, "runs": rs,
            "cpu_s_per_sim_s": statistics.median(x for x in costs if x is not None) if any(costs) else None,
            "speedup_vs_sap_1ms": speedup,
            **{k: first[k] for k in ("sim_time_s", "max_penetration_m", "rms_tracking_error_m", "steps",
                                     "rejected", "largest_step_s", "diverged", "error", "stopped_early")},
        })  # fmt: skip
    return rows


def print_table(report: dict) -> None:
    """The report as a markdown table, with the machine and the command above it."""
    machine = report["machine"]
    load = machine.get("loadavg_1min_at_start")
    load = "" if load is None else f", load average at start {load:.2f}"
    print(f"\nBrick scene, {report['duration_s']:g} s path. nproc {machine['nproc']}, {machine['cpu']}, "
          f"Drake {machine['drake']}, Python {machine['python']}"
          f"{load}. `{machine['command']}`\n")  # fmt: skip
    print(
        "| configuration | simulated s | max penetration (mm) | RMS tracking (mm) | CPU s / sim s "
        "| speed-up vs SAP 1 ms | steps | rejected | largest step (ms) | diverged / error |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in report["rows"]:
        cost = row["cpu_s_per_sim_s"]
        track, speed = row["rms_tracking_error_m"], row["speedup_vs_sap_1ms"]
        print(
            f"| {row['label']} | {row['sim_time_s']:.3g}{' (stopped early)' if row['stopped_early'] else ''} "
            f"| {row['max_penetration_m'] * 1e3:.3f} | {'—' if track is None else f'{track * 1e3:.2f}'} "
            f"| {'—' if cost is None else f'{cost:.3f}'} "
            f"| {'—' if speed is None else f'{speed:.2f}×'} "
            f"| {row['steps']} | {row['rejected']} "
            f"| {row['largest_step_s'] * 1e3:.3g} | {row['error'] or ('yes' if row['diverged'] else 'no')} |"
        )


if __name__ == "__main__":
    sys.exit(main())
