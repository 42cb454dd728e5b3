#!/usr/bin/env python3
"""The deformable-probe scene: a deformable god-object pressed on a block and around it.

    python diagrams/deformable_probe.py --shell fem --metrics m.json --record r.html

The probe is a rigid core (the god-object: coupled, simulated, not drawn,
not colliding) carrying a deformable shell (drawn, colliding), paper Fig. 4
and 8. ``--shell fem`` is Drake's FEM deformable body; ``--shell
mass_spring`` the paper's mass–spring net (godobject_drake.deformable). The
device path is models/deformable_probe/default_path.yaml, or a CSV log
(``--device replay --device-log FILE.csv``). ``--mode position`` imposes the
core's pose (the paper's first idea, which it rejects) and leaves only the
shell simulated.
"""

import argparse
import sys

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from godobject_drake.coupling import CouplingGainError, GodObjectCoupling
from godobject_drake.deformable import (
    SHELL_MODELS,
    ShellSpec,
    ShellSpecError,
    add_deformable_god_object,
    obstacle_geometries,
)
from godobject_drake.metrics import shell_metrics
from godobject_drake.recording import ShellVisualizer, add_meshcat_visualization, save_recording
from godobject_drake.runner import (
    add_common_arguments,
    connect_device,
    gains_from_args,
    impose_target,
    is_live,
    make_device,
    make_meshcat,
    report,
    run_loop,
)
from godobject_drake.scenes import MODELS_DIR, add_scene_from_directives
from godobject_drake.spatial import pose_from_array

SCENE = "deformable_probe"
PROBE = "probe"  # the god-object's (core's) name; a live device always holds it
# Where the live device may go (m): around and above the block.
LIVE_WORKSPACE = ([-0.15, -0.10, 0.0], [0.15, 0.10, 0.20])
DIRECTIVES = "package://godobject_models/deformable_probe/deformable_probe.dmd.yaml"
DEFAULT_PATH = MODELS_DIR / "deformable_probe" / "default_path.yaml"
# SAP's default near-rigid threshold (1.0) caps a contact's stiffness at what
# the contacting mass can follow within a step: a 2 g mass–spring node at
# h = 10 ms pressed a contact of nominal 5e3 N/m at ~110 N/m and sank 10 mm.
# 0.1 lifts that cap a hundredfold (README "Deformable probe").
NEAR_RIGID_THRESHOLD = 0.1


def spec_from_args(args) -> ShellSpec:
    return ShellSpec(
        youngs_modulus_pa=args.youngs_modulus, nodes=args.nodes, fem_resolution_m=args.fem_resolution
    )


def build(args):
    """Compose the diagram: device → coupling → core; shell observer, logs, drawing."""
    builder = DiagramBuilder()
    meshcat = make_meshcat(args)
    device = builder.AddNamedSystem(
        "device", make_device(args, DEFAULT_PATH, meshcat, LIVE_WORKSPACE, live_grasp=PROBE)
    )
    p0, q0, _ = device.samples(0.0)[0][1]
    X_WC = pose_from_array(np.concatenate([q0, p0]))  # the probe starts at the device
    spec = spec_from_args(args)
    spec.check()
    gains = gains_from_args(args, rot_factor=1.0)
    gains.check(args.time_step)  # before building anything heavy
    added = {}

    def add_probe(plant, scene_graph):
        added["probe"] = add_deformable_god_object(plant, scene_graph, args.shell, spec, X_WC, PROBE)

    scene = add_scene_from_directives(
        builder, DIRECTIVES, args.time_step, near_rigid_threshold=NEAR_RIGID_THRESHOLD,
        before_finalize=add_probe,
    )  # fmt: skip
    plant, probe = scene.plant, added["probe"]
    observer = probe.connect(builder, plant)
    coupling = builder.AddNamedSystem(
        "coupling",
        GodObjectCoupling(
            plant, gains, device_period_s=device.period_s, carried={probe.grasp_name: probe.shell_inertia()}
        ),
    )
    coupling.validate_grasp_names(device.grasp_names(args.duration))
    chain = connect_device(builder, args, device, plant, coupling)

    logs = {"state": plant.get_state_output_port(), "pose_WT": coupling.GetOutputPort("pose_WT")}
    for name in ("vertex_positions", "rest_positions", "pose_WC"):
        logs[name] = observer.GetOutputPort(name)
    logs = {name: LogVectorOutput(port, builder, args.time_step) for name, port in logs.items()}
    for name, log in logs.items():
        log.set_name(f"{name}_log")
    if meshcat is not None:
        add_meshcat_visualization(builder, meshcat, scene.scene_graph)
        drawing = builder.AddNamedSystem("shell_visualizer", ShellVisualizer(meshcat, probe))
        builder.Connect(observer.GetOutputPort("vertex_positions"), drawing.GetInputPort("vertex_positions"))
        builder.Connect(observer.GetOutputPort("pose_WC"), drawing.GetInputPort("pose_WC"))
        builder.Connect(coupling.GetOutputPort("pose_WT"), drawing.GetInputPort("pose_WT"))
    return builder.Build(), scene, probe, coupling, logs, meshcat, chain


def run(args, with_states: bool = False):
    """Build, run and measure; returns the metrics dict (and the plant's logged states, one row per
    step, if ``with_states``)."""
    diagram, scene, probe, coupling, logs, meshcat, chain = build(args)
    plant = scene.plant

    def impose(plant_context, root_context):
        coupling_context = coupling.GetMyContextFromRoot(root_context)
        probe.impose_core(
            plant, plant_context, lambda: impose_target(plant, plant_context, coupling, coupling_context)
        )

    loop = run_loop(
        diagram, plant, args.duration, impose=impose if args.mode == "position" else None,
        meshcat=meshcat, record=args.record, realtime=args.meshcat or is_live(chain.source),
        progress=not args.no_progress, live=is_live(chain.source),
    )  # fmt: skip
    data = {name: log.FindLog(loop.context).data().T for name, log in logs.items()}
    n = min(len(d) for d in data.values())
    data = {name: d[:n] for name, d in data.items()}
    finite = np.all(np.concatenate([np.isfinite(d) for d in data.values()], axis=1), axis=1)
    data = {name: d[finite] for name, d in data.items()}
    measured = shell_metrics(
        diagram, plant, probe, obstacle_geometries(scene.scene_graph, probe, plant), data["state"],
        data["vertex_positions"], data["rest_positions"], data["pose_WC"], data["pose_WT"],
    )  # fmt: skip
    gains = gains_from_args(args, rot_factor=1.0)
    steps = max(round(loop.sim_time_s / args.time_step), 1)
    metrics = {
        "scene": SCENE, "mode": args.mode, "time_step_s": args.time_step, "sim_time_s": loop.sim_time_s,
        "wall_time_s": loop.wall_time_s,
        "real_time_factor": loop.sim_time_s / loop.wall_time_s if loop.wall_time_s > 0 else None,
        "max_penetration_m": measured["max_penetration_m"],
        "rms_tracking_error_m": measured["rms_tracking_error_m"],
        "max_other_body_speed_mps": None,
        **measured,
        "diverged": loop.diagnosis is not None, "diagnosis": loop.diagnosis,
        "shell": probe.model, "shell_vertices": probe.vertex_count,
        "youngs_modulus_pa": probe.spec.youngs_modulus_pa, "device": args.device,
        "device_rate_hz": args.device_rate, "omega_n_rad_s": gains.omega_n,
        "omega_n_rot_rad_s": gains.omega_r, "zeta": gains.zeta,
        "step_cost_us": 1e6 * loop.wall_time_s / steps, "haptic": args.haptic,
        **chain.metrics(loop.context),
    }  # fmt: skip
    if args.record and meshcat is not None:
        metrics["recording_bytes"] = save_recording(meshcat, args.record)
    return (metrics, data["state"]) if with_states else metrics


def make_parser():
    """The scene's command line: the common flags and the shell's."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_common_arguments(parser, default_duration=6.5)
    parser.set_defaults(omega_n=30.0, time_step=1e-2)
    parser.add_argument("--shell", choices=SHELL_MODELS, default="fem", help="shell model")
    parser.add_argument("--youngs-modulus", type=float, default=5e4, help="shell's Young's modulus E (Pa)")
    parser.add_argument("--nodes", type=int, default=42, help="mass_spring: surface nodes")
    parser.add_argument(
        "--fem-resolution", type=float, default=0.02,
        help="fem: Drake's meshing hint (m); 0.03 / 0.02 / 0.01 give 25 / 129 / 833 vertices",
    )  # fmt: skip
    return parser


def main(argv=None):
    parser = make_parser()
    args = parser.parse_args(argv)
    try:
        metrics = run(args)
    except (CouplingGainError, ShellSpecError, ValueError, FileNotFoundError) as e:
        parser.error(str(e))
    report([metrics], args.metrics)
    if args.record:
        print(f"recording written to {args.record}")
    if (args.meshcat or args.device == "meshcat") and sys.stdin.isatty():
        input("Meshcat is still serving the scene; press Enter to exit.")
    return 1 if metrics["diverged"] else 0


if __name__ == "__main__":
    sys.exit(main())
