#!/usr/bin/env python3
"""The laparoscopy scene: a grasper through a trocar as an articulated god-object.

    python diagrams/laparoscopy.py --metrics m.json --record r.html

The grasper (models/laparoscopy/grasper.sdf) pivots about the insertion
point in the abdominal wall, slides and spins through the trocar and opens
its jaws; a 5-DoF laparoscopic interface gives ``yaw, pitch, insertion,
roll, jaw`` at 60 Hz: the scripted path models/laparoscopy/default_path.yaml
or a CSV log (``--device replay --device-log FILE.csv``, header
``t,yaw,pitch,insertion,roll,jaw``). ``--coupling`` picks the paper's
per-body Cartesian springs or joint-space PD (explicit, or implicit in SAP);
``--jaws imposed`` (the paper's choice) or ``simulated``.
"""

import argparse
import sys

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from godobject_drake.articulated import COUPLINGS, ArticulatedFeedback, add_articulated_god_object
from godobject_drake.coupling import CouplingGainError
from godobject_drake.devices import ReplayJointDevice, ScriptedJointDevice, load_joint_path
from godobject_drake.metrics import tool_metrics
from godobject_drake.recording import ToolGhostVisualizer, add_meshcat_visualization, save_recording
from godobject_drake.runner import (
    add_common_arguments,
    gains_from_args,
    is_live,
    make_meshcat,
    report,
    run_loop,
)
from godobject_drake.scenes import MODELS_DIR, add_scene_from_directives, exclude_self_collisions

SCENE = "laparoscopy"
DIRECTIVES = "package://godobject_models/laparoscopy/laparoscopy.dmd.yaml"
DEFAULT_PATH = MODELS_DIR / "laparoscopy" / "default_path.yaml"
CHANNELS = ("yaw", "pitch", "insertion", "roll", "jaw")
DEVICE_JOINTS = ("yaw", "pitch", "insertion", "roll", "jaw_upper", "jaw_lower")
JAWS = ("jaw_upper", "jaw_lower")
# Device joints from channels: the jaw opening turns each jaw by half.
MIX = np.array([[1, 0, 0, 0, 0], [0, 1, 0, 0, 0], [0, 0, 1, 0, 0], [0, 0, 0, 1, 0],
                [0, 0, 0, 0, 0.5], [0, 0, 0, 0, 0.5]], dtype=float)  # fmt: skip


# Live interface (--device meshcat): each channel's range (rad, m) and start.
LIVE_LIMITS = ((-0.6, 0.6), (-0.6, 0.6), (0.0, 0.15), (-3.1, 3.1), (0.0, 0.8))


def make_device(args, meshcat=None):
    kwargs = dict(mix=MIX, period_s=1.0 / args.device_rate, latency_s=args.device_latency)
    if args.device_noise:
        raise ValueError("--device-noise (m) is for pose devices; the laparoscopic interface has none")
    if args.haptic != "none" or args.kd or args.gamma_d or args.passivity_damping:
        raise ValueError(
            "--haptic/--kd/--gamma-d/--passivity-damping: the laparoscopic interface is a non-haptic "
            "joint-space device here; use them with the brick or deformable-probe scene"
        )
    if args.device_interpolation != "hold" or args.device == "relative":
        raise ValueError(
            f"--device {args.device} --device-interpolation {args.device_interpolation}: the "
            "laparoscopic interface is absolute and held; use --device scripted, replay or meshcat"
        )
    if args.device == "meshcat":
        from godobject_drake.live import MeshcatJointDevice

        q0 = ScriptedJointDevice(load_joint_path(DEFAULT_PATH)).channel_values(0.0)
        return MeshcatJointDevice(meshcat, CHANNELS, LIVE_LIMITS, q0, **kwargs)
    if args.device == "replay":
        if args.device_log is None:
            raise ValueError(
                "--device replay needs --device-log FILE.csv with header t," + ",".join(CHANNELS)
            )
        return ReplayJointDevice(args.device_log, CHANNELS, **kwargs)
    return ScriptedJointDevice(load_joint_path(DEFAULT_PATH), **kwargs)


def build(args):
    """Compose the diagram: interface → coupling → plant, coupling → feedback; ghost and logs."""
    builder = DiagramBuilder()
    scene = add_scene_from_directives(builder, DIRECTIVES, args.time_step)
    plant = scene.plant
    exclude_self_collisions(plant, scene.scene_graph, "grasper")
    meshcat = make_meshcat(args)
    device = builder.AddNamedSystem("device", make_device(args, meshcat))
    q_home = device.sample(0.0)
    gains = gains_from_args(args, rot_factor=1.0)  # rotation at the translational bandwidth here
    coupling = add_articulated_god_object(
        builder, plant, "grasper", DEVICE_JOINTS, coupling=args.coupling, gains=gains,
        device_period_s=device.period_s, q_reference=q_home,
        imposed_joints=JAWS if args.jaws == "imposed" else (),
        q_check=device.samples(args.duration)[::6], connect_forces=args.mode == "god_object",
    )  # fmt: skip
    tool = coupling.tool
    q = plant.GetDefaultPositions()
    q[tool.q_device] = q_home
    plant.SetDefaultPositions(q)  # the tool starts where the interface is
    feedback = builder.AddNamedSystem("feedback", ArticulatedFeedback(tool))  # non-haptic: zero gains
    for name in ("q_device", "v_device"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(device.GetOutputPort("q_device"), feedback.GetInputPort("q_device"))
    builder.Connect(coupling.GetOutputPort("targets"), feedback.GetInputPort("targets"))
    builder.Connect(plant.get_body_poses_output_port(), feedback.GetInputPort("body_poses"))
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), feedback.GetInputPort("body_spatial_velocities")
    )

    logs = {}
    for name, port in (
        ("state", plant.get_state_output_port()),
        ("q_device", device.GetOutputPort("q_device")),
    ):
        logs[name] = LogVectorOutput(port, builder, args.time_step)
        logs[name].set_name(f"{name}_log")
    if meshcat is not None:
        add_meshcat_visualization(builder, meshcat, scene.scene_graph)
        ghost = builder.AddNamedSystem(
            "device_tool_ghost", ToolGhostVisualizer(meshcat, tool, scene.scene_graph)
        )
        builder.Connect(device.GetOutputPort("q_device"), ghost.GetInputPort("q_device"))
    return builder.Build(), scene, coupling, logs, meshcat


def run(args):
    diagram, scene, coupling, logs, meshcat = build(args)
    plant = scene.plant
    device = diagram.GetSubsystemByName("device")
    everything = args.mode == "position"

    def prepare(simulator):
        coupling.lock_imposed(plant.GetMyMutableContextFromRoot(simulator.get_mutable_context()))

    def impose(plant_context, root_context):
        coupling.impose(plant_context, coupling.GetMyContextFromRoot(root_context), everything)

    loop = run_loop(
        diagram, plant, args.duration, impose=impose if (everything or coupling.tool.imposed) else None,
        prepare=prepare, meshcat=meshcat, record=args.record, realtime=args.meshcat or is_live(device),
        progress=not args.no_progress, live=is_live(device),
    )  # fmt: skip
    state = logs["state"].FindLog(loop.context)
    q_dev = logs["q_device"].FindLog(loop.context)
    n = min(state.num_samples(), q_dev.num_samples())
    states, q_device = state.data()[:, :n].T, q_dev.data()[:, :n].T
    finite = np.all(np.isfinite(states), axis=1)
    measured = tool_metrics(
        diagram, plant, scene.scene_graph, coupling.tool, states[finite], q_device[finite],
        tip_body="tube", pivot_body="port",
    )  # fmt: skip
    gains = gains_from_args(args, rot_factor=1.0)
    metrics = {
        "scene": SCENE, "mode": args.mode, "time_step_s": args.time_step, "sim_time_s": loop.sim_time_s,
        "wall_time_s": loop.wall_time_s,
        "real_time_factor": loop.sim_time_s / loop.wall_time_s if loop.wall_time_s > 0 else None,
        "max_penetration_m": measured["max_penetration_m"],
        "rms_tracking_error_m": measured["tip_tracking_rms_m"],
        "max_other_body_speed_mps": None,
        **measured,
        "diverged": loop.diagnosis is not None, "diagnosis": loop.diagnosis,
        "coupling": args.coupling, "jaws": args.jaws, "device": args.device,
        "device_rate_hz": args.device_rate, "omega_n_rad_s": gains.omega_n,
        "omega_n_rot_rad_s": gains.omega_r, "zeta": gains.zeta,
        "step_cost_us": 1e6 * loop.wall_time_s / max(round(loop.sim_time_s / args.time_step), 1),
    }  # fmt: skip
    if args.record and meshcat is not None:
        metrics["recording_bytes"] = save_recording(meshcat, args.record)
    return metrics, states, q_device


def make_parser():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_common_arguments(parser, default_duration=10.0)
    parser.set_defaults(omega_n=20.0)
    parser.add_argument("--coupling", choices=COUPLINGS, default="cartesian", help="coupling of the tool")
    parser.add_argument(
        "--jaws", choices=("imposed", "simulated"), default="imposed",
        help="imposed: the device sets the jaw opening (paper); simulated: jaws coupled like the rest",
    )  # fmt: skip
    return parser


def main(argv=None):
    parser = make_parser()
    args = parser.parse_args(argv)
    try:
        metrics, _, _ = run(args)
    except (CouplingGainError, ValueError, FileNotFoundError) as e:
        parser.error(str(e))
    report([metrics], args.metrics)
    if args.record:
        print(f"recording written to {args.record}")
    if (args.meshcat or args.device == "meshcat") and sys.stdin.isatty():
        input("Meshcat is still serving the scene; press Enter to exit.")
    return 1 if metrics["diverged"] else 0


if __name__ == "__main__":
    sys.exit(main())
