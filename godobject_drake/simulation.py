"""Running a built scenario and measuring it: one result type for every scene.

:func:`simulate` runs a :class:`~godobject_drake.station.build.Station` under a
plain Drake ``Simulator`` with the safeguards installed
(:mod:`godobject_drake.safeguards`), saves the recording, and measures the run
(:mod:`godobject_drake.metrics`). It returns a :class:`RunResult`: the
metrics, the per-step logs, and the simulator and its context, so a logger
of one's own added to the diagram can be read after the run. Nothing a run
produced is lost to a late failure: a divergence or a Drake error stops the
run with a diagnosis, the recording is written before the metrics are
computed, and a metric that fails is reported in ``metrics_error`` beside
the metrics that did not. Memory stays flat however long a run goes: the logs are folded
into running metrics every simulated second (unless kept on request), and a recording
covers at most ``recording.max_duration_s``.
"""

import dataclasses
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator

from godobject_drake.config.devices import kind_of
from godobject_drake.config.scenario import Scenario
from godobject_drake.metrics import SceneMetrics
from godobject_drake.safeguards import DivergenceError, Safeguards, install_safeguards
from godobject_drake.station.build import Station
from godobject_drake.systems.coupling import TERMS_LAYOUT
from godobject_drake.systems.drawing import save_recording


@dataclasses.dataclass
class RunResult:
    """One run: its metrics, its logs, and what ran it.

    Attributes
    ----------
    metrics : dict
        docs/metrics.md: the common keys every scene has and the scene's own.
    station : Station
        The diagram and its parts.
    simulator : Simulator
        The simulator, left where the run stopped (``simulator.get_context()``).
    safeguards : Safeguards
        What the monitor saw (``checks``, ``projections``, ``stopped``).
    data : dict[str, numpy.ndarray]
        Every logger of ``station.loggers``, one row per plant step from t = 0, cut to their
        common length (``simulate(keep_logs=True)``, the default; empty otherwise).
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
        if "state" not in self.data:
            raise ValueError("this run kept no logs: simulate(..., keep_logs=True) keeps them")
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


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`simulate`: the run stopped, and ``result`` holds what it produced
    (its recording written, its metrics so far, marked ``partial``)."""

    def __init__(self, result: "RunResult"):
        super().__init__(f"interrupted at t = {result.metrics['sim_time_s']:.3f} s (metrics are partial)")
        self.result = result


FOLD_PERIOD_S = 1.0  # simulated seconds of logs kept before they are folded into the metrics
# At real time the fold is a pause in the loop (~15 ms for a second of the brick scene's logs):
# folding at every safeguard check instead keeps each pause near 1 ms, under a device period.
REAL_TIME_FOLD_PERIOD_S = 0.05


def simulate(
    station: Station,
    *,
    duration_s: float | None = None,
    record: str | Path | None = None,
    realtime_rate: float | None = None,
    progress: bool = True,
    keep_logs: bool = True,
    checkpoint=None,
    checkpoint_period_s: float = 10.0,
) -> RunResult:
    """Run ``station`` and measure it, in memory that does not grow with the run's length.

    The loggers are emptied every :data:`FOLD_PERIOD_S` of simulated time into running
    metrics (:class:`~godobject_drake.metrics.SceneMetrics`: the same values as measuring the
    whole logs at the end, to the last bits of a sum), so only ``keep_logs`` makes memory
    grow with the run. ``wall_time_s`` and the real-time factor count the simulation alone;
    folding the logs is ``metrics_time_s``.

    Parameters
    ----------
    duration_s : float | None
        Simulated time (s); None: the scenario's ``simulation.duration_s``.
    record : str | Path | None
        Write the Meshcat HTML recording here; None: the scenario's ``recording.file``
        (empty: no recording). It covers at most ``recording.max_duration_s`` of the run (its
        size is stated in advance: README "Recordings"). The station needs a Meshcat (built
        with a recording file, or given one).
    realtime_rate : float | None
        None: the scenario's, and 1 for a live device or a served page.
    progress : bool
        A progress bar on stderr.
    keep_logs : bool
        Keep every logged row for :attr:`RunResult.data` (memory grows ~2 MB per simulated
        second for the brick scene); False keeps only the metrics.
    checkpoint : callable | None
        ``checkpoint(metrics)`` every ``checkpoint_period_s`` of wall time with the metrics so far
        (marked ``partial``): the command line writes them, so a killed run leaves its last ones.

    Notes
    -----
    A run that stops early (a divergence, a Drake error, the Stop button) still measures what
    it ran, its metrics marked ``partial``; Ctrl-C does too, then raises :class:`RunInterrupted`
    carrying the result.
    """
    scenario = station.scenario
    sim = scenario.simulation
    duration = sim.duration_s if duration_s is None else float(duration_s)
    if not (duration > 0 and np.isfinite(duration)):
        raise ValueError(f"duration_s={duration!r} s must be > 0")
    if duration > sim.duration_s and kind_of(scenario.device).needs_log:
        raise ValueError(
            f"duration_s={duration!r} s is past the scenario's simulation.duration_s={sim.duration_s!r} s, "
            "and its device's log was read only that far: build the station with the longer duration"
        )
    record = record or scenario.recording.file or None
    meshcat = station.meshcat
    if record and meshcat is None:
        raise ValueError(
            f"record={str(record)!r}: the station has no Meshcat; build it with recording.file set "
            "or pass build_station(..., meshcat=start_meshcat(port=0))"
        )
    live = station.live or scenario.visualization.serve
    on_wall_clock = live or kind_of(scenario.device).real_time
    rate = 1.0 if on_wall_clock else (sim.realtime_rate if realtime_rate is None else realtime_rate)
    plant, god = station.plant, station.god_object
    h = plant.time_step()

    simulator = Simulator(station.diagram)
    root = simulator.get_mutable_context()
    god.prepare(plant.GetMyMutableContextFromRoot(root))
    simulator.set_target_realtime_rate(rate)
    before_step = god.before_step(plant)
    lag = None
    if rate > 0:  # at real time: how late each plant step comes, against the wall clock
        lag = RealtimeLag(rate, late_s=getattr(station.device, "period_s", h))
        before_step = lag.wrap(before_step)
    guard = install_safeguards(
        simulator, plant, check_period_s=sim.check_period_s, max_speed=sim.max_speed,
        meshcat=meshcat if live else None, before_step=before_step, mode=god.mode, sleeper=station.sleeper,
        wiring_checked=True,  # when the station was built (station.build.finish)
        watch=god.diverged_part,
    )  # fmt: skip
    recording_steps = None
    if record:
        # Before Initialize: what the drawing sets at t = 0 (which ghost shows, its cue's colour)
        # is a keyframe. Started after it, those went to the scene only, and the first keyframe of
        # a later change (a release hiding the ghost) held for the whole recording before it.
        meshcat.StartRecording(
            frames_per_second=scenario.recording.frames_per_second, set_visualizations_while_recording=live
        )
        recording_steps = round(scenario.recording.max_duration_s / h)
    simulator.Initialize()
    falls = FallWatch(plant, plant.GetMyContextFromRoot(root), god, min(FALL_WATCH_S, duration))

    logs = _Logs(station, root, keep_logs)
    try:
        measured, metrics_error = SceneMetrics(station), None
    except Exception as e:  # a scene the metrics cannot measure still runs, and says why
        measured, metrics_error = None, f"{type(e).__name__}: {e}"

    def fold():
        nonlocal metrics_error
        chunk = logs.drain()
        if measured is not None and metrics_error is None:
            try:
                measured.update(chunk)
            except Exception as e:  # reported, never lost: the common metrics and the logs stand
                metrics_error = f"{type(e).__name__}: {e}"

    def common(wall: float, folding: float, diagnosis: str | None, partial: bool) -> dict:
        sim_time = root.get_time()
        return {
            "scene": scenario.name,
            "mode": god.mode,
            "time_step_s": h,
            "sim_time_s": sim_time,
            "wall_time_s": wall,
            "cpu_time_s": cpu[0],
            "real_time_factor": sim_time / wall if wall > 0 else None,
            "step_cost_us": 1e6 * wall / max(round(sim_time / h), 1),
            "metrics_time_s": folding,
            "diverged": diagnosis is not None,
            "diagnosis": diagnosis,
            "partial": partial,
            "predicted_static_penetration_m": station.predicted_penetration_m,
            **configuration(scenario, station),
            **(station.sleeper.result() if station.sleeper is not None else {}),
        }

    diagnosis, interrupted = None, None
    n_steps = round(duration / h)
    fold_every = max(guard.every, round((REAL_TIME_FOLD_PERIOD_S if rate > 0 else FOLD_PERIOD_S) / h))
    bar = _progress(n_steps, progress)
    wall, folding = 0.0, 0.0
    cpu = [0.0]  # the process's CPU time in the loop: less sensitive than the wall to a loaded machine
    k, next_fold = 0, fold_every
    last_checkpoint = time.perf_counter()
    try:
        while k < n_steps and not guard.stopped:
            k_next = min(k + guard.every, n_steps)
            t0, c0 = time.perf_counter(), time.process_time()
            simulator.AdvanceTo(k_next * h)
            wall += time.perf_counter() - t0
            cpu[0] += time.process_time() - c0
            bar.update(k_next - k)
            k = k_next
            if recording_steps is not None and k >= recording_steps:
                meshcat.StopRecording()  # the cap: the rest of the run is not recorded
                recording_steps = None
            if falls.pending and k * h >= falls.at_s - 0.5 * h:
                falls.check(plant.GetMyContextFromRoot(root), root)
            if k >= next_fold:
                t0 = time.perf_counter()
                fold()
                folding += time.perf_counter() - t0
                next_fold = k + fold_every
            if checkpoint is not None and time.perf_counter() - last_checkpoint >= checkpoint_period_s:
                checkpoint({**common(wall, folding, None, True), **_measured(measured, metrics_error)})
                last_checkpoint = time.perf_counter()
        guard.check()
    except DivergenceError:
        diagnosis = guard.diagnosis
    except RuntimeError as e:
        diagnosis = f"Drake stopped at t={root.get_time():.4f} s: {e}"
        found = god.diverged_part(root, guard.max_speed)  # the likely cause, when it is ours
        if found is not None:
            diagnosis = f"{found[0]} diverged: {found[1]}. {diagnosis}"
    except KeyboardInterrupt as e:  # Ctrl-C, or SIGTERM through the command line's handler
        interrupted = e
    finally:
        bar.close()
        zeroed = god.source.zero_feedback(root.get_time())  # never left pushing, whatever stopped it

    partial = interrupted is not None or root.get_time() < n_steps * h - 0.5 * h
    metrics = common(wall, folding, diagnosis, partial)
    if lag is not None:
        metrics.update(lag.result())
    if guard.stopped:
        metrics["stopped_by_user"] = True
    if interrupted is not None:
        metrics["interrupted"] = True
    if zeroed:
        metrics["feedback_zeroed_at_s"] = root.get_time()
    if falls.fallen:
        metrics["unsupported_bodies"] = falls.fallen
    if record:  # before the last metrics: a metric that fails must not lose the recording
        try:
            metrics["recording_bytes"] = save_recording(meshcat, record)
            metrics["recording_s"] = min(root.get_time(), scenario.recording.max_duration_s)
        except OSError as e:  # outputs.OutputError names the file and keeps the last complete one
            metrics["recording_error"] = str(e)
    t0 = time.perf_counter()
    fold()
    metrics["metrics_time_s"] = folding + time.perf_counter() - t0
    metrics.update(_measured(measured, metrics_error))
    try:
        metrics.update(god.device_metrics(root))
    except Exception as e:
        metrics.setdefault("metrics_error", f"{type(e).__name__}: {e}")
    result = RunResult(metrics, station, simulator, guard, logs.kept())
    if interrupted is not None:
        raise RunInterrupted(result) from interrupted
    return result


FALL_WATCH_S = 1.0  # a free body that drops this early on its own was left unsupported
FALL_DROP_M = 0.1  # how far below its start it must be: a second of free fall is 4.9 m


class UnsupportedBodyWarning(UserWarning):
    """A free body nobody held fell in the run's first second: a fixed model left unwelded?"""


class FallWatch:
    """Free bodies that fall on their own at the start of a run (a model someone forgot to weld:
    the run used to exit 0 while it fell away). At ``at_s`` every free body not held then and more
    than :data:`FALL_DROP_M` below its start is named in a warning, and in the metrics
    (``unsupported_bodies``)."""

    def __init__(self, plant, plant_context, god, at_s: float):
        self.plant, self.god, self.at_s = plant, god, at_s
        self.start = {b: plant.EvalBodyPoseInWorld(plant_context, plant.get_body(b)).translation()[2]
                      for b in plant.GetFloatingBaseBodies()}  # fmt: skip
        self.pending, self.fallen = bool(self.start), []

    def check(self, plant_context, root_context) -> None:
        self.pending = False
        held = self.god.held_bodies(root_context)
        for b, z0 in self.start.items():
            body = self.plant.get_body(b)
            drop = z0 - self.plant.EvalBodyPoseInWorld(plant_context, body).translation()[2]
            if int(b) not in held and drop > FALL_DROP_M:
                self.fallen.append(body.scoped_name().get_full())
        if self.fallen:
            warnings.warn(
                f"{', '.join(self.fallen)} fell more than {FALL_DROP_M:g} m in the first {self.at_s:g} s "
                "without being held: a model that should stay put needs a weld (add_weld, or a fixed joint "
                "to world in its file), or a support under it",
                UnsupportedBodyWarning,
                stacklevel=3,
            )


class RealtimeLag:
    """How far each plant step lags behind the wall clock in a run at real-time rate.

    Step k at simulated time t is due at ``t / rate`` of wall time after t = 0; its lag is how
    much later the simulator reaches it (ahead counts as 0). Kept as a histogram of
    ``BIN_S`` bins up to ``MAX_S`` (memory does not grow with the run; a lag past ``MAX_S``
    falls in the last bin), so the quantiles are exact to a bin and the maximum exactly.
    """

    BIN_S = 1e-5
    MAX_S = 1.0

    def __init__(self, rate: float, late_s: float):
        self.rate, self.late_s = float(rate), float(late_s)
        self._hist = np.zeros(round(self.MAX_S / self.BIN_S) + 1, dtype=np.int64)
        self._wall0: float | None = None
        self.max_s, self.late_steps = 0.0, 0

    def record(self, t: float, now: float | None = None) -> None:
        now = time.perf_counter() if now is None else now
        if self._wall0 is None:
            self._wall0 = now - t / self.rate
        lag = max(now - self._wall0 - t / self.rate, 0.0)
        self._hist[min(int(lag / self.BIN_S), len(self._hist) - 1)] += 1
        self.max_s = max(self.max_s, lag)
        self.late_steps += lag > self.late_s

    def wrap(self, before_step):
        """``before_step`` (or nothing) with the lag recorded first, at every plant step."""

        def step(plant_context, root_context):
            self.record(root_context.get_time())
            if before_step is not None:
                before_step(plant_context, root_context)

        return step

    def quantile(self, q: float) -> float:
        """The ``q`` quantile of the lags (s), to the bin's upper edge."""
        n = int(self._hist.sum())
        if n == 0:
            return float("nan")
        i = int(np.searchsorted(np.cumsum(self._hist), math.ceil(q * n)))
        return min((i + 1) * self.BIN_S, self.max_s)

    def result(self) -> dict:
        return {
            "realtime_lag_p50_s": self.quantile(0.5),
            "realtime_lag_p99_s": self.quantile(0.99),
            "realtime_lag_max_s": self.max_s,
            "realtime_late_steps": int(self.late_steps),
            "realtime_late_threshold_s": self.late_s,
        }


def _measured(measured, metrics_error) -> dict:
    if metrics_error is not None:
        return {"metrics_error": metrics_error}
    return measured.result()


class _Logs:
    """The station's loggers, emptied into chunks (one row per plant step); optionally all kept."""

    def __init__(self, station: Station, root_context, keep: bool):
        self._logs = {name: logger.FindMutableLog(root_context) for name, logger in station.loggers.items()}
        self._complete = station.god_object.complete_logs
        self._pending = {name: None for name in self._logs}
        self._keep = [] if keep else None

    def drain(self) -> dict:
        """The rows logged since the last drain, the same number from every logger."""
        rows = {}
        for name, log in self._logs.items():
            new = log.data().T.copy()
            log.Clear()
            pending = self._pending[name]
            rows[name] = new if pending is None else np.concatenate([pending, new])
        n = min(len(r) for r in rows.values())
        self._pending = {name: (r[n:] if len(r) > n else None) for name, r in rows.items()}
        chunk = self._complete({name: r[:n] for name, r in rows.items()})
        if self._keep is not None:
            self._keep.append(chunk)
        return chunk

    def kept(self) -> dict:
        if not self._keep:
            return {}
        return {name: np.concatenate([c[name] for c in self._keep]) for name in self._keep[0]}


def configuration(scenario: Scenario, station: Station) -> dict:
    """The metrics' configuration keys: what was run."""
    god = scenario.god_object
    out = {
        "contact": scenario.contact.geometry,
        "contact_approximation": scenario.plant.discrete_contact_approximation,
        "device": kind_of(scenario.device).name,
        "device_rate_hz": scenario.device.rate_hz,
        "omega_n_rad_s": god.gains.omega_n,
        "omega_n_rot_rad_s": god.gains.omega_r,
        "zeta": god.gains.zeta,
        "seed": scenario.random_seed,
        "sleep": station.sleeper is not None,
        "free_bodies": len(station.plant.GetFloatingBaseBodies()),
    }
    out.update(station.god_object.configuration(scenario, station))  # the kind's own keys
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

    # disable=None: no bar when stderr is not a terminal (a log file, CI), so no \r frames there
    return tqdm(total=total, unit="step", file=sys.stderr, leave=False, mininterval=0.5, disable=None)
