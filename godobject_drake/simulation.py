"""Running a built scenario and measuring it: one result type for every scene.

:func:`simulate` runs a :class:`~godobject_drake.building.Station` under a
plain Drake ``Simulator`` with the safeguards installed
(:mod:`godobject_drake.safeguards`), saves the recording, and measures the run
(:mod:`godobject_drake.metrics`). It returns a :class:`RunResult`: the
metrics, the per-step logs, and the simulator and its context, so a logger
of one's own added to the diagram can be read after the run. Nothing a run
produced is lost to a late failure: a divergence or a Drake error stops the
run with a diagnosis, the recording is written before the metrics are
computed, and a metric that fails is reported in ``metrics_error`` beside
the metrics that did not.
"""

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator

from godobject_drake.building import Station
from godobject_drake.coupling import TERMS_LAYOUT
from godobject_drake.metrics import scene_metrics
from godobject_drake.recording import save_recording
from godobject_drake.safeguards import DivergenceError, Safeguards, install_safeguards
from godobject_drake.scenario import DEVICE_NAMES, Scenario


@dataclasses.dataclass
class RunResult:
    """One run: its metrics, its logs, and what ran it.

    Attributes
    ----------
    metrics : dict
        README "Metrics JSON": the common keys every scene has and the scene's own.
    station : Station
        The diagram and its parts.
    simulator : Simulator
        The simulator, left where the run stopped (``simulator.get_context()``).
    safeguards : Safeguards
        What the monitor saw (``checks``, ``projections``, ``stopped``).
    data : dict[str, numpy.ndarray]
        Every logger of ``station.loggers``, one row per plant step from t = 0, cut to their
        common length.
    """

    metrics: dict
    station: Station
    simulator: Simulator
    safeguards: Safeguards
    data: dict

    @property
    def context(self):
        """The diagram's context at the end of the run."""
        return self.simulator.get_context()

    @property
    def states(self) -> np.ndarray:
        """The plant's ``[q; v]`` at each plant step, ``(N, nq + nv)``."""
        return self.data["state"]

    @property
    def times(self) -> np.ndarray:
        """The logged times (s), one per row of :attr:`states`."""
        h = self.station.plant.time_step()
        return np.arange(len(self.states)) * h

    def coupling_terms(self, key: str) -> np.ndarray:
        """A rigid coupling's logged ``terms`` entry (``held_body``, ``pose_WT``, ``F_Go_W``, ...)."""
        if "terms" not in self.data:
            raise KeyError(f"a {self.station.god_object.kind} god-object logs no coupling terms")
        return self.data["terms"][:, TERMS_LAYOUT[key]]

    @property
    def held(self) -> np.ndarray:
        """The held BodyIndex at each step (−1: none), for a rigid or deformable god-object."""
        return self.coupling_terms("held_body").round().astype(int)


def simulate(
    station: Station,
    *,
    duration_s: float | None = None,
    record: str | Path | None = None,
    realtime_rate: float | None = None,
    progress: bool = True,
) -> RunResult:
    """Run ``station`` and measure it.

    Parameters
    ----------
    duration_s : float | None
        Simulated time (s); None: the scenario's ``simulation.duration_s``.
    record : str | Path | None
        Write the Meshcat HTML recording here; None: the scenario's ``recording.file``
        (empty: no recording). The station needs a Meshcat (built with a recording file, or
        given one).
    realtime_rate : float | None
        None: the scenario's, and 1 for a live device or a served page.
    progress : bool
        A progress bar on stderr.
    """
    scenario = station.scenario
    sim = scenario.simulation
    duration = sim.duration_s if duration_s is None else float(duration_s)
    if not (duration > 0 and np.isfinite(duration)):
        raise ValueError(f"duration_s={duration!r} s must be > 0")
    record = record or scenario.recording.file or None
    meshcat = station.meshcat
    if record and meshcat is None:
        raise ValueError(
            f"record={str(record)!r}: the station has no Meshcat; build it with recording.file set "
            "or pass build_station(..., meshcat=start_meshcat(port=0))"
        )
    live = station.live or scenario.visualization.serve
    rate = 1.0 if live else (sim.realtime_rate if realtime_rate is None else realtime_rate)
    plant, god = station.plant, station.god_object
    h = plant.time_step()

    simulator = Simulator(station.diagram)
    root = simulator.get_mutable_context()
    god.prepare(plant.GetMyMutableContextFromRoot(root))
    simulator.set_target_realtime_rate(rate)
    guard = install_safeguards(
        simulator, plant, check_period_s=sim.check_period_s, max_speed=sim.max_speed,
        meshcat=meshcat if live else None, before_step=god.before_step(plant), mode=god.mode,
    )  # fmt: skip
    simulator.Initialize()
    if record:
        meshcat.StartRecording(
            frames_per_second=scenario.recording.frames_per_second, set_visualizations_while_recording=live
        )

    diagnosis = None
    n_steps = round(duration / h)
    bar = _progress(n_steps, progress)
    wall0 = time.perf_counter()
    k = 0
    try:
        while k < n_steps and not guard.stopped:
            k_next = min(k + guard.every, n_steps)
            simulator.AdvanceTo(k_next * h)
            bar.update(k_next - k)
            k = k_next
        guard.check()
    except DivergenceError:
        diagnosis = guard.diagnosis
    except RuntimeError as e:
        diagnosis = f"Drake stopped at t={root.get_time():.4f} s: {e}"
    finally:
        wall = time.perf_counter() - wall0
        bar.close()

    sim_time = root.get_time()
    metrics = {
        "scene": scenario.name,
        "mode": god.mode,
        "time_step_s": h,
        "sim_time_s": sim_time,
        "wall_time_s": wall,
        "real_time_factor": sim_time / wall if wall > 0 else None,
        "step_cost_us": 1e6 * wall / max(round(sim_time / h), 1),
        "diverged": diagnosis is not None,
        "diagnosis": diagnosis,
        "predicted_static_penetration_m": station.predicted_penetration_m,
        **configuration(scenario, station),
    }
    if guard.stopped:
        metrics["stopped_by_user"] = True
    if record:  # before the metrics: a metric that fails must not lose the recording
        try:
            metrics["recording_bytes"] = save_recording(meshcat, record)
        except OSError as e:
            metrics["recording_error"] = f"{record}: {e}"
    data = _logged(station, root)
    try:
        metrics.update(scene_metrics(station, data))
        metrics.update(god.device_metrics(root))
    except Exception as e:  # reported, never lost: the common metrics and the logs stand
        metrics["metrics_error"] = f"{type(e).__name__}: {e}"
    return RunResult(metrics, station, simulator, guard, data)


def _logged(station: Station, root_context) -> dict:
    logs = {name: logger.FindLog(root_context) for name, logger in station.loggers.items()}
    n = min(log.num_samples() for log in logs.values())
    return {name: log.data()[:, :n].T for name, log in logs.items()}


def configuration(scenario: Scenario, station: Station) -> dict:
    """The metrics' configuration keys: what was run."""
    god = scenario.god_object
    out = {
        "contact": scenario.contact.geometry,
        "contact_approximation": scenario.plant.discrete_contact_approximation,
        "device": DEVICE_NAMES[type(scenario.device)],
        "device_rate_hz": scenario.device.rate_hz,
        "omega_n_rad_s": god.gains.omega_n,
        "omega_n_rot_rad_s": god.gains.omega_r,
        "zeta": god.gains.zeta,
        "seed": scenario.random_seed,
    }
    if scenario.kind == "articulated":
        out["coupling"] = god.coupling
        out["imposed_joints"] = list(god.imposed_joints)
    else:
        out["haptic"] = scenario.haptic.mode
    if scenario.kind == "deformable":
        out["shell"] = god.shell
        out["shell_vertices"] = station.god_object.shell.vertex_count
        out["youngs_modulus_pa"] = god.spec.youngs_modulus_pa
    return out


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
