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

from godobject_drake.coupling import CouplingGains, GodObjectCoupling
from godobject_drake.devices import (
    DEFAULT_DEVICE_RATE_HZ,
    DeviceSource,
    ReplayDevice,
    ScriptedDevice,
    load_device_path,
)
from godobject_drake.metrics import TrueShapeMetrics, compute_metrics, format_table, write_metrics
from godobject_drake.recording import GodObjectVisualizer, add_meshcat_visualization, save_recording

MODES = ("god_object", "position")
DIVERGED_SPEED = 1000.0  # m/s or rad/s: any generalized velocity past this is a blow-up
CHECK_EVERY_S = 0.05


REPO_DIR = Path(__file__).resolve().parent.parent


def load_scene_script(relative: str):
    """Import a script of the clone (``diagrams/lego.py``, ...) by path, as ``python`` would run it.

    ``diagrams/`` and ``analysis/`` are not installed packages (DESIGN.md).
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
    parser.add_argument("--device", choices=("scripted", "replay"), default="scripted")
    parser.add_argument("--device-log", type=Path, help="CSV t,x,y,z,qw,qx,qy,qz,grasp for --device replay")
    parser.add_argument("--device-rate", type=float, default=DEFAULT_DEVICE_RATE_HZ, help="device rate (Hz)")
    parser.add_argument("--device-latency", type=float, default=0.0, help="device latency (s)")
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


def make_device(args: argparse.Namespace, default_path: Path) -> DeviceSource:
    """The device the flags ask for: the scene's scripted path, or a replayed log."""
    kwargs = dict(
        period_s=1.0 / args.device_rate,
        latency_s=args.device_latency,
        noise_m=args.device_noise,
        seed=args.seed,
    )
    if args.device == "replay":
        if args.device_log is None:
            raise SystemExit("--device replay needs --device-log FILE.csv (README 'Device log format')")
        return ReplayDevice(args.device_log, **kwargs)
    return ScriptedDevice(load_device_path(default_path).waypoints, **kwargs)


def gains_from_args(args: argparse.Namespace, rot_factor: float = 3.0) -> CouplingGains:
    """Coupling gains from the flags; rotation defaults to ``rot_factor`` × the translational bandwidth."""
    omega_r = rot_factor * args.omega_n if args.omega_n_rot is None else args.omega_n_rot
    return CouplingGains(args.omega_n, args.zeta, omega_r)


@dataclasses.dataclass
class Loggers:
    """Per-step logs: plant state, held body, target pose and coupling wrench."""

    state: VectorLogSink
    held: VectorLogSink
    X_WT: VectorLogSink
    F_Go_W: VectorLogSink


def add_loggers(builder: DiagramBuilder, plant: MultibodyPlant, coupling: GodObjectCoupling) -> Loggers:
    """Log what the metrics need once per plant step."""
    h = plant.time_step()
    ports = {
        "state": plant.get_state_output_port(),
        "held": coupling.GetOutputPort("held_body"),
        "X_WT": coupling.GetOutputPort("X_WT"),
        "F_Go_W": coupling.GetOutputPort("F_Go_W"),
    }
    loggers = {}
    for name, port in ports.items():
        loggers[name] = LogVectorOutput(port, builder, h)
        loggers[name].set_name(f"{name}_log")  # named, so GetGraphvizString reads well
    return Loggers(**loggers)


def add_visualization(
    builder: DiagramBuilder,
    args: argparse.Namespace,
    plant: MultibodyPlant,
    scene_graph: SceneGraph,
    coupling: GodObjectCoupling,
) -> Meshcat | None:
    """Meshcat drawing when ``--record`` or ``--meshcat`` asks for it."""
    if not (args.record or args.meshcat):
        return None
    meshcat = Meshcat() if args.meshcat else Meshcat(port=0)
    add_meshcat_visualization(builder, meshcat, scene_graph)
    ghost = builder.AddNamedSystem("god_object_visualizer", GodObjectVisualizer(meshcat, plant, scene_graph))
    for name in ("X_WT", "X_WG", "held_body"):
        builder.Connect(coupling.GetOutputPort(name), ghost.GetInputPort(name))
    return meshcat


@dataclasses.dataclass
class RunResult:
    """Metrics and the per-step logs of one run."""

    metrics: dict
    times: np.ndarray
    states: np.ndarray
    held: np.ndarray
    X_WT: np.ndarray
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
        forces_connected = plant.get_applied_spatial_force_input_port().HasValue(plant_context)
        if (mode == "god_object") != forces_connected:
            raise ValueError(
                f"mode={mode} but the coupling's spatial_forces are "
                f"{'' if forces_connected else 'not '}connected to the plant"
            )

    def impose(plant_context, root_context):
        impose_target(plant, plant_context, coupling, coupling_context_of(root_context))

    loop = run_loop(
        diagram, plant, duration, impose=impose if mode == "position" else None, prepare=check_wiring,
        meshcat=meshcat, record=record, realtime=realtime, progress=progress,
    )  # fmt: skip
    context, diagnosis, wall, sim_time = loop.context, loop.diagnosis, loop.wall_time_s, loop.sim_time_s
    h = plant.time_step()

    log = {name: getattr(loggers, name).FindLog(context) for name in ("state", "held", "X_WT", "F_Go_W")}
    n = min(log[name].num_samples() for name in log)
    times = log["state"].sample_times()[:n]
    states = log["state"].data()[:, :n].T
    held = log["held"].data()[0, :n].round().astype(int)
    X_WT = log["X_WT"].data()[:, :n].T
    F = log["F_Go_W"].data()[:, :n].T
    finite = np.all(np.isfinite(states), axis=1) & np.all(np.isfinite(X_WT), axis=1)
    measured = compute_metrics(
        TrueShapeMetrics(plant, scene_graph), states[finite], held[finite], X_WT[finite, 4:]
    )
    metrics = {
        "scene": scene,
        "mode": mode,
        "time_step_s": h,
        "sim_time_s": sim_time,
        "wall_time_s": wall,
        "real_time_factor": sim_time / wall if wall > 0 else None,
        **measured,
        "diverged": diagnosis is not None,
        "diagnosis": diagnosis,
        **(extra or {}),
    }
    if record and meshcat is not None:
        metrics["recording_bytes"] = save_recording(meshcat, record)
    return RunResult(metrics, times, states, held, X_WT, F)


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
) -> LoopResult:
    """Advance a scene diagram for ``duration`` s, checking for divergence every 50 ms.

    ``impose(plant_context, root_context)``, if given, is called before
    every plant step (the position baseline, imposed joints); the loop then
    steps one plant step at a time. ``prepare(simulator)`` runs before
    ``Initialize``. A Drake error, a non-finite state or a speed past
    ``DIVERGED_SPEED`` stops the run with a diagnosis instead of NaNs.
    """
    if not (duration > 0 and math.isfinite(duration)):
        raise ValueError(f"duration={duration!r} s must be > 0")
    h = plant.time_step()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    if prepare is not None:
        prepare(simulator)
    simulator.set_target_realtime_rate(1.0 if realtime else 0.0)
    simulator.Initialize()
    if record and meshcat is not None:
        meshcat.StartRecording(frames_per_second=64.0, set_visualizations_while_recording=False)

    diagnosis = None
    n_steps = round(duration / h)
    chunk = max(1, round(CHECK_EVERY_S / h))
    bar = _progress(n_steps, progress)
    wall0 = time.perf_counter()
    k = 0
    try:
        while k < n_steps:
            k_next = min(k + chunk, n_steps)
            if impose is not None:
                for j in range(k, k_next):
                    impose(plant_context, context)
                    simulator.AdvanceTo((j + 1) * h)
            else:
                simulator.AdvanceTo(k_next * h)
            bar.update(k_next - k)
            k = k_next
            diagnosis = _check_state(plant, plant_context)
            if diagnosis:
                break
    except RuntimeError as e:
        diagnosis = f"Drake stopped at t={context.get_time():.4f} s: {e}"
    wall = time.perf_counter() - wall0
    bar.close()
    return LoopResult(simulator, context, context.get_time(), wall, diagnosis)


def impose_target(plant, plant_context, coupling, coupling_context) -> None:
    """Position baseline: set the held body to the target's pose and velocity (paper Fig. 5)."""
    held = int(coupling.GetOutputPort("held_body").Eval(coupling_context)[0])
    if held < 0:
        return
    X_WT = coupling.GetOutputPort("X_WT").Eval(coupling_context)
    V_WT = coupling.GetOutputPort("V_WT").Eval(coupling_context)
    body = plant.get_body(BodyIndex(held))
    p_BoBcm_B = coupling.bodies[body.scoped_name().get_full()].p_BoBcm_B
    X_WG = RigidTransform(Quaternion(X_WT[:4] / np.linalg.norm(X_WT[:4])), X_WT[4:])
    X_WB = X_WG.multiply(RigidTransform(-p_BoBcm_B))
    p_GB_W = X_WB.translation() - X_WT[4:]
    plant.SetFreeBodyPose(plant_context, body, X_WB)
    plant.SetFreeBodySpatialVelocity(
        plant_context, body, SpatialVelocity(V_WT[:3], V_WT[3:] + np.cross(V_WT[:3], p_GB_W))
    )


def _check_state(plant: MultibodyPlant, plant_context) -> str | None:
    x = plant.GetPositionsAndVelocities(plant_context)
    t = plant_context.get_time()
    if not np.all(np.isfinite(x)):
        return f"non-finite plant state at t={t:.4f} s"
    v = plant.GetVelocities(plant_context)
    if v.size and np.max(np.abs(v)) > DIVERGED_SPEED:
        i = int(np.argmax(np.abs(v)))
        return f"velocity {i} reached {v[i]:.3g} (> {DIVERGED_SPEED:g} m/s or rad/s) at t={t:.4f} s"
    return None


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
