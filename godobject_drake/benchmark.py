"""Speed against error: run one scene configuration, measure its cost and its trajectory.

:func:`run_config` is the unit of work of ``analysis/speed_vs_error.py``: it
runs a scene (``diagrams/*.py``) ``repeats`` times with the flags a
:class:`Config` gives, and returns the wall time of each run's simulation
loop and, from the first run, the god-object's pose and the scene's
mechanical energy every ``SAMPLE_DT_S``. :func:`compare` measures a run
against a reference run of the same scene. The MuJoCo peer of the brick
scene (``analysis/mujoco_bricks.py``, optional extra) returns the same
trajectory fields, so both engines are measured the same way.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from godobject_drake.coupling import CouplingGainError
from godobject_drake.runner import load_scene_script

SAMPLE_DT_S = 0.01  # trajectories are compared on this grid (s)
SCRIPTS = {
    "lego": "diagrams/lego.py",
    "laparoscopy": "diagrams/laparoscopy.py",
    "deformable": "diagrams/deformable_probe.py",
}
# The body whose pose is "the god-object's pose" in each scene: the brick the path holds, the
# grasper's tube, the deformable probe's rigid core.
GOD_OBJECT_BODY = {"lego": "brick_0", "laparoscopy": "tube", "deformable": "probe"}


@dataclasses.dataclass(frozen=True)
class Config:
    """One point of the sweep. ``None`` keeps the scene script's default."""

    scene: str
    time_step: float
    duration: float
    device_rate: float = 60.0
    contact: str | None = None  # lego: proxies | hydroelastic
    approximation: str | None = None  # lego: sap | lagged | similar
    coupling: str | None = None  # laparoscopy: cartesian | joint_pd | joint_pd_sap
    shell: str | None = None  # deformable: fem | mass_spring
    engine: str = "drake"  # or "mujoco" (lego only; mode in ``coupling``: weld | perturb)
    repeats: int = 3

    def label(self) -> str:
        """Short name for tables and figures: what differs from the scene's defaults."""
        parts = [f"h={self.time_step * 1e3:g}ms"]
        for value in (self.contact, self.approximation, self.coupling, self.shell):
            if value:
                parts.append(value)
        if self.device_rate != 60.0:
            parts.append(f"dev={self.device_rate:g}Hz")
        prefix = "mujoco " if self.engine == "mujoco" else ""
        return prefix + " ".join(parts)

    def argv(self) -> list[str]:
        """The scene script's command line for this configuration."""
        argv = [
            "--time-step",
            repr(self.time_step),
            "--duration",
            repr(self.duration),
            "--device-rate",
            repr(self.device_rate),
            "--no-progress",
        ]
        if self.contact:
            argv += ["--contact", self.contact]
        if self.approximation:
            argv += ["--contact-approximation", self.approximation]
        if self.coupling:
            argv += ["--coupling", self.coupling]
        if self.shell:
            argv += ["--shell", self.shell]
        return argv


def run_config(config: Config) -> dict:
    """Run ``config`` ``repeats`` times; its cost, penetration and first-run trajectory.

    Returns a dict with ``config`` (as a dict), ``label``, ``wall_s_per_sim_s`` (one per
    repeat), ``max_penetration_m``, ``diverged``/``diagnosis``, ``refused`` (the error text
    when the scene refuses the configuration, e.g. gains past the explicit limit at this h),
    and the trajectory ``times``, ``p_WG`` (N×3), ``q_WG`` (N×4, wxyz), ``energy_j`` (N).
    """
    out = {"config": dataclasses.asdict(config), "label": config.label(), "refused": None}
    if config.repeats < 1:
        raise ValueError(f"repeats={config.repeats}; give at least 1 (the report uses ≥ 3)")
    if config.engine == "mujoco":
        return {**out, **_run_mujoco(config)}
    if config.scene not in SCRIPTS:
        raise ValueError(f"scene={config.scene!r}; choose one of {sorted(SCRIPTS)}")
    module = load_scene_script(SCRIPTS[config.scene])
    walls = []
    for k in range(config.repeats):
        args = module.make_parser().parse_args(config.argv())
        try:
            metrics, states = _run_scene(config.scene, module, args)
        except (CouplingGainError, ValueError) as e:
            return {**out, "refused": str(e), "wall_s_per_sim_s": [], "diverged": False}
        walls.append(metrics["wall_time_s"] / max(metrics["sim_time_s"], 1e-12))
        if k == 0:
            first, first_states = metrics, states
        if metrics["diverged"]:
            break  # a diverging run's cost means nothing; one is enough
    plant = module.build(args)[1].plant  # a plant of the same model, to evaluate poses and energy
    times, p, q, energy = trajectory(plant, first_states, config.time_step, GOD_OBJECT_BODY[config.scene])
    return {
        **out,
        "wall_s_per_sim_s": walls,
        "max_penetration_m": first["max_penetration_m"],
        "diverged": bool(first["diverged"]),
        "diagnosis": first["diagnosis"],
        "times": times,
        "p_WG": p,
        "q_WG": q,
        "energy_j": energy,
    }


def _run_scene(scene: str, module, args):
    """Run a scene script once: (metrics, plant states, one row per step)."""
    if scene == "lego":
        result = module.run(args)
        return result.metrics, result.states
    if scene == "laparoscopy":
        metrics, states, _ = module.run(args)
        return metrics, states
    return module.run(args, with_states=True)


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

    from godobject_drake.coupling import graspable_bodies

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


def rigid_energy(p, q, v, w, masses, inertias_B, g: float = 9.81) -> np.ndarray:
    """Kinetic + gravitational energy (J, zero at z = 0) of free rigid bodies, per sample.

    ``p, v, w``: (N, B, 3) centre positions, velocities and angular velocities in W;
    ``q``: (N, B, 4) wxyz; ``masses``: (B,); ``inertias_B``: (B, 3, 3) about the centre in
    the body frame. The formula both engines' trajectories are measured with
    (tests/test_benchmark.py checks it against Drake's own energy).
    """
    from godobject_drake.spatial import quat_to_rotation

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


def _run_mujoco(config: Config) -> dict:
    module = load_scene_script("analysis/mujoco_bricks.py")
    r = module.run_mujoco(
        duration_s=config.duration,
        time_step_s=config.time_step,
        mode=config.coupling or "weld",
        device_rate_hz=config.device_rate,
        sample_dt_s=SAMPLE_DT_S,
        repeats=config.repeats,
    )
    i = r["body_names"].index(GOD_OBJECT_BODY["lego"])
    bodies = _lego_bodies()  # the same masses and inertias as the Drake scene's
    masses = [bodies[name].mass for name in r["body_names"]]
    inertias = [bodies[name].I_Bcm_B for name in r["body_names"]]
    energy = rigid_energy(r["p_WB"], r["q_WB"], r["v_WB"], r["w_WB"], masses, inertias)
    return {
        "wall_s_per_sim_s": list(r["wall_s_per_sim_s"]),
        "max_penetration_m": r["max_penetration_m"],
        "diverged": bool(r["diverged"]),
        "diagnosis": r["diagnosis"],
        "times": r["times"],
        "p_WG": r["p_WB"][:, i],
        "q_WG": r["q_WB"][:, i],
        "energy_j": energy,
        "mujoco_version": r["mujoco_version"],
    }


def _lego_bodies():
    from pydrake.systems.framework import DiagramBuilder

    from godobject_drake.coupling import graspable_bodies
    from godobject_drake.scenes import add_scene_from_directives

    scene = add_scene_from_directives(DiagramBuilder(), load_scene_script(SCRIPTS["lego"]).DIRECTIVES, 1e-3)
    return graspable_bodies(scene.plant)


def coupling_overhead_us(samples: int = 2000, rounds: int = 5) -> dict:
    """Per-step cost (µs) of the brick scene's coupling, measured alone.

    The coupling is evaluated the way the simulator does each step: a new plant state
    arrives (invalidating its cache), then the plant pulls ``generalized_force`` and the
    logger pulls ``terms``. The cost of setting the input is measured separately and
    subtracted. Median and min over ``rounds``.
    """
    from pydrake.common.value import AbstractValue
    from pydrake.math import RigidTransform
    from pydrake.systems.framework import DiagramBuilder

    from godobject_drake.coupling import CouplingGains, GodObjectCoupling
    from godobject_drake.scenes import add_scene_from_directives

    builder = DiagramBuilder()
    scene = add_scene_from_directives(builder, load_scene_script(SCRIPTS["lego"]).DIRECTIVES, 1e-3)
    plant = scene.plant
    coupling = GodObjectCoupling(plant, CouplingGains(40.0, 1.0, 120.0))
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
