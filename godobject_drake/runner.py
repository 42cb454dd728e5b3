"""Running a god-object scene: common flags, logging, the simulation loop, metrics.

Every scene script in ``diagrams/`` takes the same flags
(:func:`add_common_arguments`), builds its Diagram, and hands it to
:func:`simulate`, which runs it headless (or live in Meshcat), detects
divergence, and returns the metrics of README "Metrics JSON".
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import math
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Meshcat, SceneGraph
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, VectorLogSink

from godobject_drake.coupling import TERMS_LAYOUT, CouplingGains, GodObjectCoupling
from godobject_drake.devices import (
    DEFAULT_DEVICE_RATE_HZ,
    INTERPOLATIONS,
    DeviceSource,
    RelativeDevice,
    ReplayDevice,
    SampleGuard,
    ScriptedDevice,
    load_device_path,
)
from godobject_drake.feedback import FeedbackGains, FeedbackPort
from godobject_drake.haptic import (
    AdmittanceDevice,
    HandImpedance,
    HapticDevice,
    PassivityController,
    SimulatedHand,
)
from godobject_drake.live import MeshcatDevice, MeshcatJointDevice, stop_requested
from godobject_drake.metrics import TrueShapeMetrics, compute_metrics, format_table, write_metrics
from godobject_drake.recording import GodObjectVisualizer, add_meshcat_visualization, save_recording
from godobject_drake.safeguards import DIVERGED_SPEED, DivergenceError, Safeguards

MODES = ("god_object", "position")
DEVICES = ("scripted", "replay", "relative", "meshcat")
HAPTIC_MODES = ("none", "impedance", "admittance")
# The simulated impedance device of --haptic impedance (the stability report's device) and the
# hand that holds it: a 0.1 kg handle with 2 N·s/m of friction, pulled toward the device path at
# ~10 Hz, critically damped (k = m (2π·10)², b = 2 m 2π·10).
HAPTIC_DEVICE_MASS_KG = 0.1
HAPTIC_DEVICE_DAMPING = 2.0
HAND_ON_HANDLE = HandImpedance(
    k=HAPTIC_DEVICE_MASS_KG * (2 * math.pi * 10) ** 2, b=2 * HAPTIC_DEVICE_MASS_KG * 2 * math.pi * 10
)
CHECK_EVERY_S = 0.05


REPO_DIR = Path(__file__).resolve().parent.parent


def load_scene_script(relative: str):
    """Import a script of the clone (``diagrams/lego.py``, ...) by path, as ``python`` would run it.

    ``diagrams/`` and ``analysis/`` are not installed packages (docs/design.md).
    """
    path = REPO_DIR / relative
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def add_common_arguments(parser: argparse.ArgumentParser, default_duration: float) -> None:
    """The flags every scene script takes."""
    parser.add_argument(
        "--mode",
        choices=MODES,
        default="god_object",
        help="god_object: PD coupling (default); position: impose the device pose (baseline)",
    )
    parser.add_argument("--duration", type=float, default=default_duration, help="simulated time (s)")
    parser.add_argument("--time-step", type=float, default=1e-3, help="plant step h (s)")
    parser.add_argument(
        "--device",
        choices=DEVICES,
        default="scripted",
        help="scripted: the scene's path; replay: a CSV log; relative: a CSV of increments with a "
        "clutch (the paper's mouse); meshcat: live from the browser (README 'Driving a scene live')",
    )
    parser.add_argument(
        "--device-log",
        type=Path,
        help="CSV for --device replay (t,x,y,z,qw,qx,qy,qz,grasp) or relative "
        "(t,dx,dy,dz,drx,dry,drz,clutch,grasp)",
    )
    parser.add_argument("--device-rate", type=float, default=DEFAULT_DEVICE_RATE_HZ, help="device rate (Hz)")
    parser.add_argument("--device-latency", type=float, default=0.0, help="device latency (s)")
    parser.add_argument(
        "--device-interpolation",
        choices=INTERPOLATIONS,
        default="hold",
        help="between device samples: hold (default) or linear (smooth, one period late)",
    )
    parser.add_argument(
        "--max-device-speed",
        type=float,
        default=SampleGuard.max_speed_m_s,
        help="a sample farther than this speed (m/s) could go is held back as a glitch (inf: off)",
    )
    parser.add_argument(
        "--haptic",
        choices=HAPTIC_MODES,
        default="none",
        help="none: the device's pose drives the target; impedance: a simulated 3-axis haptic device "
        "(pose out, force in) held by a simulated hand; admittance: a simulated admittance device "
        "(the hand's force drives the god-object, the handle follows it)",
    )
    parser.add_argument("--haptic-rate", type=float, default=1000.0, help="haptic servo rate (Hz)")
    parser.add_argument("--kd", type=float, default=0.0, help="feedback stiffness kd (N/m); 0 = non-haptic")
    parser.add_argument("--gamma-d", type=float, default=0.0, help="feedback damping γd (N·s/m)")
    parser.add_argument(
        "--passivity-damping",
        type=float,
        default=0.0,
        help="passivity observer/controller on the feedback path, damping capped at this (N·s/m); 0 = off",
    )
    parser.add_argument(
        "--device-noise",
        type=float,
        default=0.0,
        help="std. dev. of Gaussian noise on each device position sample (m), seeded by --seed",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw (device noise)")
    parser.add_argument("--omega-n", type=float, default=40.0, help="coupling bandwidth ωn (rad/s)")
    parser.add_argument("--zeta", type=float, default=1.0, help="coupling damping ratio ζ")
    parser.add_argument(
        "--omega-n-rot",
        type=float,
        default=None,
        help="rotational coupling bandwidth (rad/s); default 3 × --omega-n",
    )
    parser.add_argument("--record", type=Path, help="write a self-contained Meshcat HTML recording")
    parser.add_argument(
        "--meshcat", action="store_true", help="serve the run live in Meshcat (real-time rate)"
    )
    parser.add_argument("--metrics", type=Path, help="write the metrics JSON here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def make_meshcat(args: argparse.Namespace) -> Meshcat | None:
    """The scene's Meshcat: served on a port for ``--meshcat`` and ``--device meshcat``, any free
    port for a ``--record``ing only, None otherwise."""
    if args.meshcat or args.device == "meshcat":
        return Meshcat()
    return Meshcat(port=0) if args.record else None


def make_device(
    args: argparse.Namespace,
    default_path: Path,
    meshcat: Meshcat | None = None,
    workspace: tuple | None = None,
    live_grasp: str | None = None,
) -> DeviceSource:
    """The device the flags ask for: the scene's path, a replayed log, increments, or live.

    ``relative`` and ``meshcat`` start where the scene's path starts;
    ``meshcat`` needs the scene's ``meshcat`` and ``workspace`` (box corners, m),
    and ``live_grasp`` (a fixed body name, or None for the grasp button).
    """
    if not (args.device_rate > 0 and math.isfinite(args.device_rate)):
        raise ValueError(f"--device-rate {args.device_rate!r} Hz must be > 0")
    kwargs = dict(
        period_s=1.0 / args.device_rate,
        latency_s=args.device_latency,
        interpolation=args.device_interpolation,
        guard=SampleGuard(max_speed_m_s=args.max_device_speed),
    )
    path = ScriptedDevice(load_device_path(default_path).waypoints, noise_m=args.device_noise, seed=args.seed,
                          **kwargs)  # fmt: skip
    p0, q0, _ = path.path_sample(0.0)  # where the path starts, without the tracker noise
    X0 = RigidTransform(Quaternion(q0), p0)
    if args.device in ("replay", "relative"):
        if args.device_log is None:
            raise ValueError(
                f"--device {args.device} needs --device-log FILE.csv (README 'Device log format' and "
                "'Relative device')"
            )
        noisy = dict(noise_m=args.device_noise, seed=args.seed, **kwargs)
        if args.device == "replay":
            return ReplayDevice(args.device_log, **noisy)
        return RelativeDevice(args.device_log, X0, **noisy)
    if args.device == "meshcat":
        if meshcat is None or workspace is None:
            raise ValueError("--device meshcat needs the scene's Meshcat and workspace")
        return MeshcatDevice(meshcat, X0, workspace, grasp=live_grasp, **kwargs)
    return path


def gains_from_args(args: argparse.Namespace, rot_factor: float = 3.0) -> CouplingGains:
    """Coupling gains from the flags; rotation defaults to ``rot_factor`` × the translational bandwidth."""
    omega_r = rot_factor * args.omega_n if args.omega_n_rot is None else args.omega_n_rot
    return CouplingGains(args.omega_n, args.zeta, omega_r)


@dataclasses.dataclass
class Loggers:
    """Per-step logs: plant state, and the coupling's ``terms`` (held body, target, god-object, wrench)."""

    state: VectorLogSink
    terms: VectorLogSink


def add_loggers(builder: DiagramBuilder, plant: MultibodyPlant, coupling: GodObjectCoupling) -> Loggers:
    """Log what the metrics need once per plant step (two ports: each logged port costs a call)."""
    h = plant.time_step()
    ports = {"state": plant.get_state_output_port(), "terms": coupling.GetOutputPort("terms")}
    loggers = {}
    for name, port in ports.items():
        loggers[name] = LogVectorOutput(port, builder, h)
        loggers[name].set_name(f"{name}_log")  # named, so GetGraphvizString reads well
    return Loggers(**loggers)


@dataclasses.dataclass
class DeviceChain:
    """What :func:`connect_device` built between the user's device and the coupling."""

    source: DeviceSource  # what the user means: a path, a log, increments, the browser
    device: object  # what the coupling reads X_WD, V_WD, grasp from: source, HapticDevice or AdmittanceDevice
    feedback: FeedbackPort
    haptic: HapticDevice | AdmittanceDevice | None = None
    passivity: PassivityController | None = None

    def metrics(self, root_context) -> dict:
        """Device status counts, and the haptic loop's energies (J) at the end of a run."""
        out = {}
        if isinstance(self.source, DeviceSource):
            status = self.source.GetOutputPort("device_status").Eval(
                self.source.GetMyContextFromRoot(root_context)
            )
            out.update(DeviceSource.status_dict(status))
        if isinstance(self.haptic, HapticDevice):
            work = self.haptic.GetOutputPort("work").Eval(self.haptic.GetMyContextFromRoot(root_context))
            out["haptic_energy_to_user_j"] = float(-work[0])
            out["haptic_feedback_work_j"] = float(work[1])
        if self.passivity is not None:
            e = self.passivity.GetOutputPort("energy").Eval(self.passivity.GetMyContextFromRoot(root_context))
            out["passivity_observed_energy_j"] = float(e[0] + e[1])
            out["passivity_dissipated_j"] = float(e[2] + e[3])
        return out


def connect_device(
    builder: DiagramBuilder,
    args: argparse.Namespace,
    source: DeviceSource,
    plant: MultibodyPlant,
    coupling: GodObjectCoupling,
) -> DeviceChain:
    """Wire the user's device to the coupling for ``--haptic``, the feedback path, and the plant.

    - ``none``: the device's pose is the target (paper Fig. 2, non-haptic).
    - ``impedance``: a simulated hand (:data:`HAND_ON_HANDLE`) pushes a 3-axis
      :class:`HapticDevice` along the device's path; the haptic device's pose is the target, and
      the feedback port's force (``--kd``, ``--gamma-d``; optionally through a
      :class:`PassivityController`, ``--passivity-damping``) comes back to its handle.
    - ``admittance``: the hand pulls an :class:`AdmittanceDevice`'s handle toward the path with
      the coupling's own stiffness and damping (:meth:`HandImpedance.matching`, for the first body
      the path grasps); the sensed wrench drives the god-object, the handle follows it.
    """
    if args.haptic not in HAPTIC_MODES:
        raise ValueError(f"--haptic {args.haptic!r}; choose one of {HAPTIC_MODES}")
    if not (args.haptic_rate > 0 and math.isfinite(args.haptic_rate)):
        raise ValueError(f"--haptic-rate {args.haptic_rate!r} Hz must be > 0")
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    feedback = builder.AddNamedSystem(
        "feedback", FeedbackPort(FeedbackGains(kd=args.kd, gamma_d=args.gamma_d))
    )
    chain = DeviceChain(source=source, device=source, feedback=feedback)
    period = 1.0 / args.haptic_rate
    p0, q0, _ = source.samples(0.0)[0][1]
    if args.haptic != "impedance" and (args.kd or args.gamma_d or args.passivity_damping):
        raise ValueError(
            f"--kd/--gamma-d/--passivity-damping act on a haptic device's handle; with --haptic "
            f"{args.haptic} there is none. Add --haptic impedance."
        )
    if args.haptic == "impedance":
        haptic = builder.AddNamedSystem(
            "haptic_device",
            HapticDevice(HAPTIC_DEVICE_MASS_KG, HAPTIC_DEVICE_DAMPING, period, axes="xyz",
                         X_WD_home=RigidTransform(p0)),
        )  # fmt: skip
        hand = builder.AddNamedSystem("hand", SimulatedHand(HAND_ON_HANDLE, p0))
        builder.Connect(source.GetOutputPort("X_WD"), hand.GetInputPort("X_WH"))
        builder.Connect(source.GetOutputPort("V_WD"), hand.GetInputPort("V_WH"))
        builder.Connect(haptic.GetOutputPort("device_state"), hand.GetInputPort("device_state"))
        builder.Connect(hand.GetOutputPort("human_force"), haptic.GetInputPort("human_force"))
        builder.Connect(hand.GetOutputPort("q_WD"), haptic.GetInputPort("q_WD"))
        builder.Connect(source.GetOutputPort("grasp"), haptic.GetInputPort("grasp_in"))
        force = feedback.GetOutputPort("F_Do_W")
        if args.passivity_damping > 0.0:
            pc = builder.AddNamedSystem("passivity", PassivityController(period, args.passivity_damping))
            builder.Connect(force, pc.GetInputPort("F_in"))
            builder.Connect(haptic.GetOutputPort("X_WD"), pc.GetInputPort("X_WD"))
            force = pc.GetOutputPort("F_out")
            chain.passivity = pc
        builder.Connect(force, haptic.GetInputPort("F_Do_W"))
        chain.haptic = chain.device = haptic
    elif args.haptic == "admittance":
        names = sorted(source.grasp_names(args.duration))
        if not names:
            raise ValueError(
                "--haptic admittance sizes the hand on the first body the device grasps; it grasps none"
            )
        body = coupling.body_for_grasp(names[0])
        hand = HandImpedance.matching(coupling.gains, body.mass, float(np.trace(body.I_Bcm_B)) / 3.0)
        adm = builder.AddNamedSystem(
            "admittance_device", AdmittanceDevice(hand, period, RigidTransform(Quaternion(q0), p0))
        )
        builder.Connect(source.GetOutputPort("X_WD"), adm.GetInputPort("X_WH"))
        builder.Connect(source.GetOutputPort("V_WD"), adm.GetInputPort("V_WH"))
        builder.Connect(source.GetOutputPort("grasp"), adm.GetInputPort("grasp_in"))
        for name in ("pose_WG", "V_WG"):
            builder.Connect(coupling.GetOutputPort(name), adm.GetInputPort(name))
        builder.Connect(adm.GetOutputPort("F_device_W"), coupling.GetInputPort("F_device_W"))
        chain.haptic = chain.device = adm
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(chain.device.GetOutputPort(name), coupling.GetInputPort(name))
    if args.mode == "god_object":
        builder.Connect(
            coupling.GetOutputPort("generalized_force"), plant.get_applied_generalized_force_input_port()
        )
    builder.Connect(chain.device.GetOutputPort("X_WD"), feedback.GetInputPort("X_WD"))
    for name in ("pose_WT", "V_WT", "pose_WG", "V_WG"):
        builder.Connect(coupling.GetOutputPort(name), feedback.GetInputPort(name))
    return chain


def add_visualization(
    builder: DiagramBuilder,
    args: argparse.Namespace,
    plant: MultibodyPlant,
    scene_graph: SceneGraph,
    coupling: GodObjectCoupling,
    meshcat: Meshcat | None = None,
) -> Meshcat | None:
    """Meshcat drawing when ``--record``, ``--meshcat`` or ``--device meshcat`` asks for it."""
    meshcat = meshcat or make_meshcat(args)
    if meshcat is None:
        return None
    add_meshcat_visualization(builder, meshcat, scene_graph)
    ghost = builder.AddNamedSystem("god_object_visualizer", GodObjectVisualizer(meshcat, plant, scene_graph))
    for name in ("pose_WT", "pose_WG", "held_body"):
        builder.Connect(coupling.GetOutputPort(name), ghost.GetInputPort(name))
    return meshcat


@dataclasses.dataclass
class RunResult:
    """Metrics and the per-step logs of one run."""

    metrics: dict
    times: np.ndarray
    states: np.ndarray
    held: np.ndarray
    pose_WT: np.ndarray
    F_Go_W: np.ndarray


def simulate(
    diagram: Diagram,
    plant: MultibodyPlant,
    scene_graph: SceneGraph,
    coupling: GodObjectCoupling,
    loggers: Loggers,
    *,
    scene: str,
    mode: str,
    duration: float,
    meshcat: Meshcat | None = None,
    record: Path | None = None,
    realtime: bool = False,
    progress: bool = True,
    extra: dict | None = None,
    chain: DeviceChain | None = None,
) -> RunResult:
    """Run a built scene diagram and measure it.

    In ``god_object`` mode the coupling's forces must be connected to the
    plant; in ``position`` mode they must not be, and before every step the
    held body is set to the target pose and velocity (paper Fig. 5).
    A run that raises in Drake, produces a non-finite state or moves any
    body faster than ``DIVERGED_SPEED`` stops and is reported as
    ``diverged`` with a diagnosis.
    """
    if mode not in MODES:
        raise ValueError(f"mode={mode!r}; choose one of {MODES}")
    if not (duration > 0 and math.isfinite(duration)):
        raise ValueError(f"duration={duration!r} s must be > 0")
    coupling_context_of = coupling.GetMyContextFromRoot

    def check_wiring(simulator):
        plant_context = plant.GetMyContextFromRoot(simulator.get_context())
        inputs = (
            plant.get_applied_spatial_force_input_port(),
            plant.get_applied_generalized_force_input_port(),
        )
        forces_connected = any(port.HasValue(plant_context) for port in inputs)
        if (mode == "god_object") != forces_connected:
            raise ValueError(
                f"mode={mode} but the coupling's forces are "
                f"{'' if forces_connected else 'not '}connected to the plant"
            )

    def impose(plant_context, root_context):
        impose_target(plant, plant_context, coupling, coupling_context_of(root_context))

    loop = run_loop(
        diagram, plant, duration, impose=impose if mode == "position" else None, prepare=check_wiring,
        meshcat=meshcat, record=record, realtime=realtime, progress=progress,
        live=chain is not None and is_live(chain.source),
    )  # fmt: skip
    context, diagnosis, wall, sim_time = loop.context, loop.diagnosis, loop.wall_time_s, loop.sim_time_s
    h = plant.time_step()

    log = {name: getattr(loggers, name).FindLog(context) for name in ("state", "terms")}
    n = min(log[name].num_samples() for name in log)
    times = log["state"].sample_times()[:n]
    states = log["state"].data()[:, :n].T
    terms = log["terms"].data()[:, :n].T
    held = terms[:, TERMS_LAYOUT["held_body"]].round().astype(int)
    pose_WT = terms[:, TERMS_LAYOUT["pose_WT"]]
    F = terms[:, TERMS_LAYOUT["F_Go_W"]]
    capped = terms[:, TERMS_LAYOUT["capped"]]
    finite = np.all(np.isfinite(states), axis=1) & np.all(np.isfinite(pose_WT), axis=1)
    measured = compute_metrics(
        TrueShapeMetrics(plant, scene_graph), states[finite], held[finite], pose_WT[finite, 4:]
    )
    metrics = {
        "scene": scene,
        "mode": mode,
        "time_step_s": h,
        "sim_time_s": sim_time,
        "wall_time_s": wall,
        "real_time_factor": sim_time / wall if wall > 0 else None,
        **measured,
        "coupling_capped_steps": int(np.sum(capped > 0.5)),
        "diverged": diagnosis is not None,
        "diagnosis": diagnosis,
        **(chain.metrics(context) if chain else {}),
        **(extra or {}),
    }
    if record and meshcat is not None:
        metrics["recording_bytes"] = save_recording(meshcat, record)
    return RunResult(metrics, times, states, held, pose_WT, F)


@dataclasses.dataclass
class LoopResult:
    """What :func:`run_loop` returns: the simulator, where it stopped and why."""

    simulator: Simulator
    context: object
    sim_time_s: float
    wall_time_s: float
    diagnosis: str | None


def run_loop(
    diagram: Diagram,
    plant: MultibodyPlant,
    duration: float,
    *,
    impose=None,
    prepare=None,
    meshcat: Meshcat | None = None,
    record: Path | None = None,
    realtime: bool = False,
    progress: bool = True,
    live: bool = False,
) -> LoopResult:
    """Advance a scene diagram for ``duration`` s, checking for divergence every 50 ms.

    ``impose(plant_context, root_context)``, if given, is called before
    every plant step (the position baseline, imposed joints); the loop then
    steps one plant step at a time. ``prepare(simulator)`` runs before
    ``Initialize``. A Drake error, a non-finite state or a speed past
    ``DIVERGED_SPEED`` stops the run with a diagnosis instead of NaNs.
    ``live`` (a browser device): the run also ends when the page's Stop
    button (Escape) is pressed.
    """
    if not (duration > 0 and math.isfinite(duration)):
        raise ValueError(f"duration={duration!r} s must be > 0")
    simulator = Simulator(diagram)
    if prepare is not None:
        prepare(simulator)
    simulator.set_target_realtime_rate(1.0 if realtime else 0.0)
    stop = (lambda: stop_requested(meshcat)) if live and meshcat is not None else None
    guard = Safeguards(plant, check_period_s=CHECK_EVERY_S, max_speed=DIVERGED_SPEED, stop=stop,
                       before_step=impose).install(simulator)  # fmt: skip
    context = simulator.get_context()
    simulator.Initialize()
    if record and meshcat is not None:
        meshcat.StartRecording(frames_per_second=64.0, set_visualizations_while_recording=False)

    diagnosis = None
    h = plant.time_step()
    n_steps = round(duration / h)
    chunk = max(1, round(CHECK_EVERY_S / h))
    bar = _progress(n_steps, progress)
    wall0 = time.perf_counter()
    k = 0
    try:
        while k < n_steps and not guard.stopped:
            k_next = min(k + chunk, n_steps)
            simulator.AdvanceTo(k_next * h)
            bar.update(k_next - k)
            k = k_next
        guard.check()
    except DivergenceError:
        diagnosis = guard.diagnosis
    except RuntimeError as e:
        diagnosis = f"Drake stopped at t={context.get_time():.4f} s: {e}"
    wall = time.perf_counter() - wall0
    bar.close()
    return LoopResult(simulator, context, context.get_time(), wall, diagnosis)


def is_live(device) -> bool:
    """Whether a device is driven from the browser."""
    return isinstance(device, MeshcatDevice | MeshcatJointDevice)


def impose_target(plant, plant_context, coupling, coupling_context) -> None:
    """Position baseline: set the held body to the target's pose and velocity (paper Fig. 5)."""
    held = int(coupling.GetOutputPort("held_body").Eval(coupling_context)[0])
    if held < 0:
        return
    pose_WT = coupling.GetOutputPort("pose_WT").Eval(coupling_context)
    V_WT = coupling.GetOutputPort("V_WT").Eval(coupling_context)
    body = plant.get_body(BodyIndex(held))
    p_BoBcm_B = coupling.bodies[body.scoped_name().get_full()].p_BoBcm_B
    X_WG = RigidTransform(Quaternion(pose_WT[:4] / np.linalg.norm(pose_WT[:4])), pose_WT[4:])
    X_WB = X_WG.multiply(RigidTransform(-p_BoBcm_B))
    p_GB_W = X_WB.translation() - pose_WT[4:]
    plant.SetFreeBodyPose(plant_context, body, X_WB)
    plant.SetFreeBodySpatialVelocity(
        plant_context, body, SpatialVelocity(V_WT[:3], V_WT[3:] + np.cross(V_WT[:3], p_GB_W))
    )


class _NoBar:
    def update(self, n):
        pass

    def close(self):
        pass


def _progress(total: int, enabled: bool):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, unit="step", file=sys.stderr, leave=False, mininterval=0.5)


def report(results: list[dict], metrics_path: Path | None) -> None:
    """Print the metrics table; write the JSON (one run: an object; several: a list)."""
    print(format_table(results))
    if metrics_path:
        write_metrics(metrics_path, results[0] if len(results) == 1 else results)
        print(f"metrics written to {metrics_path}")
