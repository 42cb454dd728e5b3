"""Speed against error: run one scenario, measure its cost and its trajectory.

:func:`run_case` is the unit of work of ``analysis/speed_vs_error.py``: it
runs a scenario ``repeats`` times and returns the wall time of each run's
simulation loop and, from the first run, the god-object's pose and the
scene's mechanical energy every ``SAMPLE_DT_S``. A :class:`Case` carries its
scenario as YAML text, so it pickles for local worker processes and Dask.
:func:`compare` measures a run against a reference run of the same scene.
The MuJoCo peer of the brick scene (:mod:`godobject_drake.studies.mujoco_peer`,
optional extra) returns the same trajectory fields, so both engines are
measured the same way.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from godobject_drake.config.gains import CouplingGainError
from godobject_drake.config.scenario import Scenario, scenario_from_yaml, scenario_to_yaml, shipped_scenario
from godobject_drake.metrics import FREE_SPACE_MARGIN_M, TrueShapeMetrics, _cm_positions
from godobject_drake.simulation import simulate
from godobject_drake.sleeping import drake_version
from godobject_drake.spatial import quat_to_rotation
from godobject_drake.station.build import build_station
from godobject_drake.station.kinds import kind_for
from godobject_drake.station.loop import make_device
from godobject_drake.station.plant import add_plant
from godobject_drake.studies.kinds import StudyKind, study_kind
from godobject_drake.systems.coupling import GodObjectCoupling, graspable_bodies

SAMPLE_DT_S = 0.01  # trajectories are compared on this grid (s)
ENGINES = ("drake", "mujoco")


@dataclasses.dataclass(frozen=True)
class Case:
    """One point of a sweep.

    Attributes
    ----------
    label : str
        Short name for tables and figures.
    scenario_yaml : str
        The scenario (:func:`~godobject_drake.config.scenario.scenario_to_yaml`): YAML text pickles,
        Drake's config objects do not.
    repeats : int
        Runs; the cost is their median.
    engine : str
        ``drake``, or ``mujoco`` (the brick scene's peer, at the scenario's time step,
        duration, device rate and ``bricks``) with ``mujoco_mode`` ``weld`` or ``perturb``.
    mujoco_timeconst_s, mujoco_cone, mujoco_sleep :
        The peer's contact ``solref`` time constant (None: MuJoCo's 0.02 s), friction cone and
        sleeping islands (:func:`~godobject_drake.studies.mujoco_peer.scene_xml`).
    """

    label: str
    scenario_yaml: str
    repeats: int = 3
    engine: str = "drake"
    mujoco_mode: str = "weld"
    mujoco_timeconst_s: float | None = None
    mujoco_cone: str = "elliptic"
    mujoco_sleep: bool = False

    @property
    def scenario(self) -> Scenario:
        return scenario_from_yaml(self.scenario_yaml)


def make_case(scenario: Scenario, label: str | None = None, repeats: int = 3, engine: str = "drake",
              mujoco_mode: str = "weld", mujoco_timeconst_s: float | None = None,
              mujoco_cone: str = "elliptic", mujoco_sleep: bool = False) -> Case:  # fmt: skip
    """A :class:`Case` of ``scenario`` (label: :func:`describe`)."""
    if engine not in ENGINES:
        raise ValueError(f"engine={engine!r}; choose one of {ENGINES}")
    if label is None:
        if engine == "drake":
            label = describe(scenario)
        else:
            label = f"mujoco {describe(scenario, short=True)} {mujoco_mode}"
            if mujoco_timeconst_s is not None:
                label += f" tc={mujoco_timeconst_s * 1e3:g}ms"
            if mujoco_cone != "elliptic":
                label += f" {mujoco_cone}"
            if mujoco_sleep:
                label += " sleep"
    return Case(label, scenario_to_yaml(scenario), repeats, engine, mujoco_mode, mujoco_timeconst_s,
                mujoco_cone, mujoco_sleep)  # fmt: skip


def _study(scenario: Scenario) -> StudyKind:
    """What the studies ask of the scenario's tool kind (:mod:`godobject_drake.studies.kinds`)."""
    return study_kind(kind_for(scenario.god_object).kind)


def describe(scenario: Scenario, short: bool = False) -> str:
    """``h=1ms proxies sap``, ``h=1ms cartesian``, ``h=10ms fem``, with ``dev=250Hz`` off 60 Hz: the
    tool kind says what it varies (:attr:`~godobject_drake.studies.kinds.StudyKind.describe`)."""
    kind = _study(scenario)
    parts = [f"h={scenario.time_step * 1e3:g}ms"]
    if not short:
        parts += kind.describe(scenario)
    if scenario.device.rate_hz != 60.0:
        parts.append(f"dev={scenario.device.rate_hz:g}Hz")
    if scenario.bricks:
        parts.append(f"bricks={scenario.bricks}")
    return " ".join(parts + kind.describe_tail(scenario))


def case_config(scenario: Scenario, case: Case) -> dict:
    """What a case varies, as a flat dict for reports: scene, time_step, duration, device_rate,
    what the tool kind varies (:attr:`~godobject_drake.studies.kinds.StudyKind.study_config`:
    contact and approximation, coupling, shell, bricks, sleep; None where it does not apply),
    engine, repeats. A MuJoCo case (the brick scene's peer) has its mode as the coupling, its
    sleeping islands as sleep, and no Drake contact settings."""
    config = _study(scenario).study_config(scenario)
    mujoco = case.engine == "mujoco"
    if mujoco:
        config.update(contact=None, approximation=None, coupling=case.mujoco_mode, sleep=case.mujoco_sleep)
    return {
        "scene": scenario.name,
        "time_step": scenario.time_step,
        "duration": scenario.simulation.duration_s,
        "device_rate": scenario.device.rate_hz,
        **{k: config[k] for k in ("contact", "approximation", "coupling", "shell")},
        "engine": case.engine,
        "repeats": case.repeats,
        "bricks": config["bricks"],
        "sleep": config["sleep"],
        "mujoco_timeconst_s": case.mujoco_timeconst_s if mujoco else None,
        "mujoco_cone": case.mujoco_cone if mujoco else None,
    }


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; elsewhere ``platform.processor()``)."""
    import platform
    from pathlib import Path

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def machine() -> str:
    """``nproc`` and the CPU model, to print beside every absolute figure."""
    import os

    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{os.cpu_count()} cores ({usable} usable), {cpu_model()}"


def round_robin(scenarios: dict, rounds: int = 3) -> dict:
    """Each scenario's simulation-loop CPU time per simulated second (``simulate``'s
    ``cpu_time_s``), the scenarios run in turn in this process, ``rounds`` times over: the runs of
    a round share its load, so their ratios hold on a shared machine where single costs do not.

    Returns ``cpu_s_per_sim_s`` ({key: one value per round}), ``rounds``, ``drake`` (its
    version), ``machine`` (:func:`machine`) and ``load_1min`` (the 1-minute load average at the
    start of each round).
    """
    import os  # as machine() does

    if rounds < 1:
        raise ValueError(f"rounds={rounds}; give at least 1 (a ratio's spread needs 3)")
    cpu: dict = {key: [] for key in scenarios}
    loads = []
    for _ in range(rounds):
        loads.append(os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan)
        for key, scenario in scenarios.items():
            metrics = simulate(build_station(scenario), progress=False).metrics
            cpu[key].append(metrics["cpu_time_s"] / max(metrics["sim_time_s"], 1e-12))
    return {"cpu_s_per_sim_s": cpu, "rounds": rounds, "drake": drake_version(), "machine": machine(),
            "load_1min": loads}  # fmt: skip


def god_object_body(scenario: Scenario) -> str:
    """The body whose pose is "the god-object's pose" (the tool kind says which: the first body a
    rigid scene's device grasps, an articulated tool's tip body, a deformable probe's core)."""
    return _study(scenario).pose_body(scenario, make_device(scenario.device).grasp_names())


def run_case(case: Case) -> dict:
    """Run ``case`` ``repeats`` times; its cost, penetration and first-run trajectory.

    Returns a dict with ``config`` (:func:`case_config`), ``label``, ``wall_s_per_sim_s`` and
    ``cpu_s_per_sim_s`` (one per repeat), ``max_penetration_m``, ``diverged``/``diagnosis``,
    ``refused`` (the error text when the scene refuses the configuration, e.g. gains past the
    explicit limit at this h), and the trajectory ``times``, ``p_WG`` (N×3), ``q_WG`` (N×4, wxyz),
    ``energy_j`` (N).
    """

    if case.repeats < 1:
        raise ValueError(f"repeats={case.repeats}; give at least 1 (the report uses ≥ 3)")
    scenario = case.scenario
    out = {"config": case_config(scenario, case), "label": case.label, "refused": None}
    if case.engine == "mujoco":
        return {**out, **_run_mujoco(scenario, case)}
    walls, cpus = [], []
    for k in range(case.repeats):
        try:
            result = simulate(build_station(scenario), progress=False)
        except (CouplingGainError, ValueError) as e:
            return {
                **out,
                "refused": str(e),
                "wall_s_per_sim_s": [],
                "cpu_s_per_sim_s": [],
                "diverged": False,
            }
        metrics = result.metrics
        walls.append(metrics["wall_time_s"] / max(metrics["sim_time_s"], 1e-12))
        cpus.append(metrics["cpu_time_s"] / max(metrics["sim_time_s"], 1e-12))
        if k == 0:
            first = result
        if metrics["diverged"]:
            break  # a diverging run's cost means nothing; one is enough
    times, p, q, energy = trajectory(
        first.station.plant, first.states, scenario.time_step, god_object_body(scenario)
    )
    out.update(
        wall_s_per_sim_s=walls,
        cpu_s_per_sim_s=cpus,
        max_penetration_m=first.metrics["max_penetration_m"],
        diverged=bool(first.metrics["diverged"]),
        diagnosis=first.metrics["diagnosis"],
        times=times,
        p_WG=p,
        q_WG=q,
        energy_j=energy,
    )
    if _study(scenario).compares_engines:
        # Every stride-th step: at h = 4 ms that is every 8 ms, not every 10.
        stride = max(1, round(SAMPLE_DT_S / scenario.time_step))
        out.update(engine_neutral_errors(scenario, first.states[::stride], stride * scenario.time_step))
    return out


def trajectory(plant, states: np.ndarray, time_step: float, body_name: str):
    """The god-object body's pose and the plant's mechanical energy every ``SAMPLE_DT_S``.

    ``states`` holds one row ``[q; v]`` per plant step, the first at t = 0. Energy is
    Drake's ``CalcKineticEnergy + CalcPotentialEnergy`` (rigid bodies; a deformable shell's
    own energy is not included).
    """
    stride = max(1, round(SAMPLE_DT_S / time_step))
    rows = states[::stride]
    times = np.arange(len(rows)) * stride * time_step
    context = plant.CreateDefaultContext()
    from pydrake.multibody.tree import BodyIndex

    free = graspable_bodies(plant)  # "brick_0" names the body of model instance brick_0
    body = (
        plant.get_body(BodyIndex(free[body_name].index))
        if body_name in free
        else plant.GetBodyByName(body_name)
    )
    p, q, energy = [], [], []
    for x in rows:
        plant.SetPositionsAndVelocities(context, x)
        X = body.EvalPoseInWorld(context)
        p.append(X.translation())
        q.append(X.rotation().ToQuaternion().wxyz())
        energy.append(plant.CalcKineticEnergy(context) + plant.CalcPotentialEnergy(context))
    return times, np.array(p), np.array(q), np.array(energy)


def engine_neutral_errors(scenario: Scenario, states: np.ndarray, sample_dt_s: float = SAMPLE_DT_S) -> dict:
    """What both engines define the same way, from the free bodies' poses sampled every
    ``sample_dt_s`` (:data:`SAMPLE_DT_S`, or the nearest whole number of plant steps to it),
    measured by the same code whatever engine ran them:

    - ``true_penetration_m``: the held body's deepest overlap with any other true shape
      (:class:`~godobject_drake.metrics.TrueShapeMetrics`: boxes by separating axes);
    - ``free_tracking_rms_m``: RMS distance of its centre of mass from the device's target
      while it is held and in free space (≥ 2 mm from every other true shape); the target is
      the device's zero-order-held sample, with the grasp offset the first held sample gives;
    - ``crossed_wall``: the brick scene's held brick was ever beyond the wall (x > 0) below its
      top and within its ends: through it, where the penetration would read small again.

    ``states``: (N, nq + nv) rows of the scenario's plant's state (only the free bodies'
    positions are read).
    """
    from pydrake.systems.framework import DiagramBuilder

    parts = add_plant(DiagramBuilder(), scenario)
    name = god_object_body(scenario)
    body = graspable_bodies(parts.plant)[name]
    shapes = TrueShapeMetrics(parts.plant, parts.scene_graph)
    overlap = shapes.overlaps(body.index, states)  # (N, M)
    n = len(states)
    times = np.arange(n) * sample_dt_s
    device = make_device(scenario.device)
    samples = dict(device.samples(max(times[-1], 0.0) if n else 0.0))
    ticks = np.floor(times / device.period_s + 1e-9) * device.period_s
    keys = sorted(samples)
    held = np.zeros(n, bool)
    target = np.full((n, 3), np.nan)
    for i, t in enumerate(ticks):
        k = keys[min(int(np.searchsorted(keys, t + 1e-12, side="right")) - 1, len(keys) - 1)]
        p, _q, grasp = samples[k]
        held[i] = grasp == name or grasp.split("::")[0] == name
        target[i] = p
    cm = _cm_positions(body, states)
    if held.any():  # the grasp offset: where the body was from the device at its first held sample
        first = int(np.argmax(held))
        target = target + (cm[first] - target[first])
    free = held & np.all(overlap < -FREE_SPACE_MARGIN_M, axis=1)
    d2 = np.sum((cm - target) ** 2, axis=1)
    p_Bo = states[:, body.q_start + 4 : body.q_start + 7]
    crossed = bool(np.any((p_Bo[:, 0] > 0.0) & (np.abs(p_Bo[:, 1]) < 0.1) & (p_Bo[:, 2] < 0.048)))
    return {
        "true_penetration_m": float(max(0.0, np.max(overlap[held], initial=0.0))),
        "free_tracking_rms_m": float(np.sqrt(np.mean(d2[free]))) if free.any() else None,
        "free_samples": int(free.sum()),
        "crossed_wall": crossed,
    }


def rigid_energy(p, q, v, w, masses, inertias_B, g: float = 9.81) -> np.ndarray:
    """Kinetic + gravitational energy (J, zero at z = 0) of free rigid bodies, per sample.

    ``p, v, w``: (N, B, 3) centre positions, velocities and angular velocities in W;
    ``q``: (N, B, 4) wxyz; ``masses``: (B,); ``inertias_B``: (B, 3, 3) about the centre in
    the body frame. The formula both engines' trajectories are measured with
    (tests/test_benchmark.py checks it against Drake's own energy).
    """

    N, B = p.shape[:2]
    E = np.zeros(N)
    for n in range(N):
        for b in range(B):
            R = quat_to_rotation(q[n, b])
            Iw = R @ inertias_B[b] @ R.T
            E[n] += 0.5 * masses[b] * v[n, b] @ v[n, b] + 0.5 * w[n, b] @ Iw @ w[n, b]
            E[n] += masses[b] * g * p[n, b, 2]
    return E


def compare(run: dict, reference: dict) -> dict:
    """Errors of ``run`` against ``reference`` on their common time grid.

    ``pose_rms_m``: RMS distance between the god-object body's origins; ``angle_rms_rad``: RMS
    rotation angle between their orientations; ``energy_error_j``: largest
    ``|ΔE − ΔE_ref|``, where ``ΔE = E(t) − E(0)`` (a constant offset, such as a welded
    body's potential energy in one engine and not in the other, does not count).
    """
    n = min(len(run["times"]), len(reference["times"]))
    if n == 0:
        return {"pose_rms_m": math.nan, "angle_rms_rad": math.nan, "energy_error_j": math.nan}
    dp = np.asarray(run["p_WG"])[:n] - np.asarray(reference["p_WG"])[:n]
    dots = np.abs(np.sum(np.asarray(run["q_WG"])[:n] * np.asarray(reference["q_WG"])[:n], axis=1))
    angles = 2.0 * np.arccos(np.clip(dots, 0.0, 1.0))
    E, E_ref = np.asarray(run["energy_j"])[:n], np.asarray(reference["energy_j"])[:n]
    dE = (E - E[0]) - (E_ref - E_ref[0])
    return {
        "pose_rms_m": float(np.sqrt(np.mean(np.sum(dp * dp, axis=1)))),
        "angle_rms_rad": float(np.sqrt(np.mean(angles**2))),
        "energy_error_j": float(np.max(np.abs(dE))),
        "compared_samples": int(n),
    }


def summarize_cost(walls: list[float]) -> dict:
    """Median, min and max wall time per simulated second, and the real-time factor."""
    if not walls:
        return {"cost_median_s": None, "cost_min_s": None, "cost_max_s": None, "real_time_factor": None}
    med = float(np.median(walls))
    return {
        "cost_median_s": med,
        "cost_min_s": float(min(walls)),
        "cost_max_s": float(max(walls)),
        "real_time_factor": 1.0 / med if med > 0 else None,
    }


def _run_mujoco(scenario: Scenario, case: Case) -> dict:
    # MuJoCo is an optional extra (the bench extra): the peer loads only when a case asks for it.
    from godobject_drake.studies import mujoco_peer

    r = mujoco_peer.run_mujoco(
        duration_s=scenario.simulation.duration_s,
        time_step_s=scenario.time_step,
        mode=case.mujoco_mode,
        device_rate_hz=scenario.device.rate_hz,
        sample_dt_s=SAMPLE_DT_S,
        repeats=case.repeats,
        bricks=max(scenario.bricks, 8),
        contact_timeconst_s=case.mujoco_timeconst_s,
        cone=case.mujoco_cone,
        sleep=case.mujoco_sleep,
    )
    i = r["body_names"].index(god_object_body(scenario))
    bodies = _rigid_bodies(scenario)  # the same masses and inertias as the Drake scene's
    masses = [bodies[name].mass for name in r["body_names"]]
    inertias = [bodies[name].I_Bcm_B for name in r["body_names"]]
    energy = rigid_energy(r["p_WB"], r["q_WB"], r["v_WB"], r["w_WB"], masses, inertias)
    return {
        "wall_s_per_sim_s": list(r["wall_s_per_sim_s"]),
        "cpu_s_per_sim_s": list(r["cpu_s_per_sim_s"]),
        "max_penetration_m": r["max_penetration_m"],
        "diverged": bool(r["diverged"]),
        "diagnosis": r["diagnosis"],
        "times": r["times"],
        "p_WG": r["p_WB"][:, i],
        "q_WG": r["q_WB"][:, i],
        "energy_j": energy,
        "mujoco_version": r["mujoco_version"],
        "mean_awake_trees": r["mean_awake_trees"],
        **engine_neutral_errors(scenario, _drake_states(scenario, r)),
    }


def _drake_states(scenario: Scenario, r: dict) -> np.ndarray:
    """The MuJoCo samples as rows of the Drake plant's state (free bodies' poses, zero velocity)."""
    from pydrake.systems.framework import DiagramBuilder

    plant = add_plant(DiagramBuilder(), scenario).plant
    bodies = graspable_bodies(plant)
    x0 = plant.GetPositionsAndVelocities(plant.CreateDefaultContext())
    states = np.tile(x0, (len(r["times"]), 1))
    for j, name in enumerate(r["body_names"]):
        b = bodies[name]
        states[:, b.q_start : b.q_start + 4] = r["q_WB"][:, j]
        states[:, b.q_start + 4 : b.q_start + 7] = r["p_WB"][:, j]
    return states


def _rigid_bodies(scenario: Scenario):
    """The free bodies of the scenario's plant (the plant alone, no diagram around it)."""
    from pydrake.systems.framework import DiagramBuilder

    return graspable_bodies(add_plant(DiagramBuilder(), scenario).plant)


def coupling_overhead_us(samples: int = 2000, rounds: int = 5) -> dict:
    """Per-step cost (µs) of the brick scene's coupling (its plant and gains), measured alone.

    The coupling is evaluated the way the simulator does each step: a new plant state
    arrives (invalidating its cache), then the plant pulls ``generalized_force`` and the
    logger pulls ``terms``. The cost of setting the input is measured separately and
    subtracted. Median and min over ``rounds``.
    """
    from pydrake.common.value import AbstractValue
    from pydrake.math import RigidTransform
    from pydrake.systems.framework import DiagramBuilder

    lego = shipped_scenario("lego")
    plant = add_plant(DiagramBuilder(), lego).plant
    coupling = GodObjectCoupling(plant, lego.god_object.gains)
    context = coupling.CreateDefaultContext()
    x0 = plant.GetPositionsAndVelocities(plant.CreateDefaultContext())
    state = coupling.GetInputPort("plant_state")
    state.FixValue(context, x0)
    coupling.GetInputPort("X_WD").FixValue(context, RigidTransform([-0.1, 0.0, 0.01]))
    coupling.GetInputPort("V_WD").FixValue(context, np.zeros(6))
    coupling.GetInputPort("grasp").FixValue(context, AbstractValue.Make("brick_0"))
    coupling.ExecuteInitializationEvents(context)
    if coupling.GetOutputPort("held_body").Eval(context)[0] < 0:
        raise RuntimeError("the benchmark's coupling holds nothing; it would measure the idle path")
    rng = np.random.default_rng(0)
    xs = [x0 + 1e-4 * rng.standard_normal(x0.size) for _ in range(64)]
    outputs = [coupling.GetOutputPort(name) for name in ("generalized_force", "terms")]
    per_round = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for i in range(samples):
            state.FixValue(context, xs[i % 64])
        fix = time.perf_counter() - t0
        t0 = time.perf_counter()
        for i in range(samples):
            state.FixValue(context, xs[i % 64])
            for port in outputs:
                port.Eval(context)
        per_round.append((time.perf_counter() - t0 - fix) / samples * 1e6)
    return {"median_us": float(np.median(per_round)), "min_us": float(min(per_round)), "rounds": rounds}
