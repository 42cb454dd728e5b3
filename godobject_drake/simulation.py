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
import logging
import shlex
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator

from godobject_drake.config import scenario as sc
from godobject_drake.metrics import (
    SceneMetrics,
    TissueMetrics,
    configuration,
    scene_configuration,
    soft_body_result,
    verdict,
    worst_of,
)
from godobject_drake.outputs import SignalsHeld
from godobject_drake.realtime import RealtimeLag
from godobject_drake.safeguards import (
    FALL_WATCH_S,
    DivergenceError,
    FallWatch,
    Safeguards,
    install_safeguards,
)
from godobject_drake.station.build import Station
from godobject_drake.systems.contacts import PER_TOOL
from godobject_drake.systems.coupling import TERMS_LAYOUT
from godobject_drake.systems.page import page_of, save_recording, server_stopped
from godobject_drake.task_metrics import CollisionFold
from godobject_drake.task_score import TaskFold


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
        common length, and each soft body's summary rows as ``NAME_soft_body``
        (:class:`~godobject_drake.systems.soft_body.SoftBodyObserver`) (``simulate(keep_logs=True)``,
        the default; empty otherwise).
    traces : dict[str, numpy.ndarray]
        Each tool's tip position and net contact force every 10 ms, rows ``[t, x, y, z, |F|]``
        (:meth:`~godobject_drake.metrics.SceneMetrics.trace`), by tool name (``keep_logs=True``;
        empty otherwise).
    """

    metrics: dict
    station: Station
    simulator: Simulator
    safeguards: Safeguards
    data: dict
    traces: dict = dataclasses.field(default_factory=dict)

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
# ... unless a fold costs more than this share of the simulated time it covers: a fold's cost is
# mostly per call (the brick scene's true-shape penetration: ~15 numpy calls per box pair), ~50 ms
# on a loaded 2-core machine, which at every 50 ms held a 5 ms step's scene at half real time. The
# period then grows (up to FOLD_PERIOD_S) until the folds take at most this share.
REAL_TIME_FOLD_SHARE = 0.05
# What a live run that cannot hold real time is told to change (RealtimeLag's warning).
REALTIME_FIXES = (
    "Fixes: a larger plant step with the implicit coupling (--time-step 0.005 --coupling implicit; "
    "articulated tools: joint_pd_sap; the haptic recipe diagrams/lego_haptic.yaml), fewer awake "
    "bodies (--sleep on, fewer free bodies), a coarser organ (organs.cells 6 or 4); "
    "docs/guide/haptic_recipe.md"
)


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
    observe=None,
    hold: SignalsHeld | None = None,
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
        size is stated in advance: docs/guide/visual.md). The station needs a Meshcat (built
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
    observe : callable | None
        ``observe(plant_context, root_context)`` before every plant step, after the safeguards'
        checks and the tools' own hooks at that step: the context the plant steps from, for an
        analysis to read through public ports and attributes (analysis/step_floor.py). It makes
        the safeguards a monitor called at every step; the run is the same bit for bit.
    hold : SignalsHeld | None
        Ctrl-C, SIGTERM and SIGHUP are held from the end of the loop (:meth:`SignalsHeld.start`):
        a signal while the recording is saved and the metrics made cannot lose them. Given, the
        hold is left on for the caller to end once it has written its outputs (the command line);
        else it ends here, acting on a signal it caught (unless the run was already interrupted).

    Notes
    -----
    A run that stops early (a divergence, a Drake error, the Stop button) still measures what
    it ran, its metrics marked ``partial``; Ctrl-C does too, then raises :class:`RunInterrupted`
    carrying the result.
    """
    run = _Run(station, duration_s, record, realtime_rate, keep_logs, observe)
    own = hold is None
    run.hold = hold = hold or SignalsHeld()
    try:
        run.loop(progress, checkpoint, checkpoint_period_s)
    except BaseException:  # not the loop's own ends (it keeps those): nothing to finish
        if own:
            hold.end(act=False)
        raise
    try:
        result = run.finish()
    except RunInterrupted:  # a signal while it finished only asked for what it already does
        if own:
            hold.end(act=False)
        raise
    if own:
        hold.end()
    return result


class _Run:
    """One run of :func:`simulate`: its setup (the constructor), its :meth:`loop` and its
    :meth:`finish`, sharing what they measure as attributes."""

    def __init__(self, station: Station, duration_s, record, realtime_rate, keep_logs: bool, observe=None):
        scenario = self.scenario = station.scenario
        sim = scenario.simulation
        duration = sim.duration_s if duration_s is None else float(duration_s)
        if not (duration > 0 and np.isfinite(duration)):
            raise ValueError(f"duration_s={duration!r} s must be > 0")
        records = station.records
        logged = any(r.device.needs_log for r in records.values())
        if duration > sim.duration_s and logged:
            raise ValueError(
                f"duration_s={duration!r} s is past the scenario's simulation.duration_s={sim.duration_s!r} "
                "s, and its device's log was read only that far: build the station with the longer duration"
            )
        self.record = record or scenario.recording.file or None
        self.meshcat = meshcat = station.meshcat
        if self.record and meshcat is None:
            raise ValueError(
                f"record={str(self.record)!r}: the station has no Meshcat; build it with recording.file set "
                "or pass build_station(..., meshcat=start_meshcat(port=0))"
            )
        live = station.live or scenario.visualization.serve
        on_wall_clock = live or any(r.device.real_time for r in records.values())
        rate = 1.0 if on_wall_clock else (sim.realtime_rate if realtime_rate is None else realtime_rate)
        self.station, self.plant, self.god = station, station.plant, _AllTools(station)
        self.h = h = self.plant.time_step()
        self.simulator = Simulator(station.diagram)
        self.root = root = self.simulator.get_mutable_context()
        self.god.prepare(self.plant.GetMyMutableContextFromRoot(root))
        self.simulator.set_target_realtime_rate(rate)
        before_step = _then(self.god.before_step(self.plant), observe)
        self.lag = None
        if rate > 0:  # at real time: how late each plant step comes, against the wall clock
            periods = [getattr(tool.source, "period_s", h) for tool in station.tools.values()]
            self.lag = RealtimeLag(
                rate, late_s=min(periods), step_s=h, warn=on_wall_clock, fixes=REALTIME_FIXES
            )
            before_step = self.lag.wrap(before_step)
        self.guard = install_safeguards(
            self.simulator, self.plant, check_period_s=sim.check_period_s, max_speed=sim.max_speed,
            meshcat=meshcat if live else None, before_step=before_step, mode=self.god.mode,
            sleeper=station.sleeper, wiring_checked=True,  # when the station was built (station.build.finish)
            watch=self.god.diverged_part, polled=True,  # no Python call every step where none is needed
        )  # fmt: skip
        self.falls = FallWatch(self.plant, self.plant.GetMyContextFromRoot(root), self.god,
                               min(FALL_WATCH_S, duration))  # fmt: skip
        self.recording_steps = None
        if self.record:
            # Before Initialize: what the drawing sets at t = 0 (which ghost shows, its cue's colour)
            # is a keyframe. Started after it, those went to the scene only, and the first keyframe of
            # a later change (a release hiding the ghost) held for the whole recording before it.
            meshcat.StartRecording(
                frames_per_second=scenario.recording.frames_per_second,
                set_visualizations_while_recording=live,
            )
            page_of(meshcat).start_recording(
                scenario.recording.max_duration_s, live=live
            )  # the surfaces' frames
            self.recording_steps = round(scenario.recording.max_duration_s / h)
            if station.sleeper is not None:
                station.sleeper.draw_marks(0.0)  # every body awake in the first frame
        self.device_logs = record_devices(station)  # before Initialize: its update at t = 0 is a tick
        wait_for_devices(station)  # the run's clock starts when its devices are first heard
        self.simulator.Initialize()
        self.logs = _Logs(station, root, keep_logs)
        self.soft = {name: (logger.FindMutableLog(root), TissueMetrics())
                     for name, logger in station.soft_loggers.items()}  # fmt: skip
        self.soft_kept = {} if keep_logs else None  # each soft body's summary rows, with keep_logs
        try:  # each tool's metrics, on its own view of the station
            self.measured = {
                name: SceneMetrics(view, trace=keep_logs) for name, view in station.views.items()
            }
            self.metrics_error = None
        except Exception as e:  # a scene the metrics cannot measure still runs, and says why
            self.measured, self.metrics_error = None, f"{type(e).__name__}: {e}"
        # the task's score (scenario.task), folded from the state rows like the tools' metrics
        self.task = TaskFold(station.task, scenario.task, h) if station.task is not None else None
        meter = station.contact_meter
        self.collisions = CollisionFold(h) if meter is not None and len(meter.tools) > 1 else None
        self.n_steps = round(duration / h)
        self.fold_every = max(
            self.guard.every, round((REAL_TIME_FOLD_PERIOD_S if rate > 0 else FOLD_PERIOD_S) / h)
        )
        self.wall = self.folding = self.cpu = (
            0.0  # cpu: the process's CPU time in the loop (load moves it less)
        )
        self.diagnosis, self.interrupted, self.zeroed, self.viewer_stopped_at = None, None, False, None
        self.hold = SignalsHeld()  # simulate's

    def real_time_fold_every(self, cost_s: float) -> int:
        """Steps between folds at real time after a fold that took ``cost_s`` of wall time: every
        :data:`REAL_TIME_FOLD_PERIOD_S`, or as much longer (up to :data:`FOLD_PERIOD_S`) as keeps the
        folds within :data:`REAL_TIME_FOLD_SHARE` of the simulated time."""
        period = min(
            max(REAL_TIME_FOLD_PERIOD_S, cost_s * self.lag.rate / REAL_TIME_FOLD_SHARE), FOLD_PERIOD_S
        )
        return max(self.guard.every, round(period / self.h))

    def fold(self) -> None:
        """The logs drained into each tool's running metrics; a metric that fails is reported,
        never lost."""
        chunks = self.logs.drain()
        for name, (log, measured) in self.soft.items():  # each soft body's rows, folded on their own
            rows = log.data().T.copy()
            log.Clear()
            measured.update(rows)
            if self.soft_kept is not None:
                self.soft_kept.setdefault(f"{name}_soft_body", []).append(rows)
        if self.measured is not None and self.metrics_error is None:
            try:
                # A diverged state's huge numbers overflow: what they give is non-finite, and the
                # metrics say so (non_finite), the diagnosis why; numpy's own warning said nothing more.
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    for name, chunk in chunks.items():
                        self.measured[name].update(chunk)
                    if self.task is not None and chunks:
                        self.task.update(next(iter(chunks.values()))["state"])
                    if self.collisions is not None and chunks:  # any two tools touching
                        self._fold_collisions(next(iter(chunks.values()))["contacts"])
            except Exception as e:  # reported, never lost: the common metrics and the logs stand
                self.metrics_error = f"{type(e).__name__}: {e}"

    def _fold_collisions(self, contacts: np.ndarray) -> None:
        meter = self.station.contact_meter
        pairs = contacts[:, len(meter.tools) * PER_TOOL :]
        self.collisions.update(np.max(pairs[np.all(np.isfinite(contacts), axis=1)], axis=1))

    def common(self, partial: bool) -> dict:
        """The metrics every scene has: what ran, how long it took, whether it diverged."""
        sim_time, station = self.root.get_time(), self.station
        return {
            "scene": self.scenario.name,
            "mode": self.god.mode,
            "time_step_s": self.h,
            "sim_time_s": sim_time,
            "wall_time_s": self.wall,
            "cpu_time_s": self.cpu,
            "real_time_factor": sim_time / self.wall if self.wall > 0 else None,
            "step_cost_us": 1e6 * self.wall / max(round(sim_time / self.h), 1),
            "metrics_time_s": self.folding,
            "diverged": self.diagnosis is not None,
            "diagnosis": self.diagnosis,
            "partial": partial,
            "predicted_static_penetration_m": station.predicted_penetration_m,
            **scene_configuration(station),
            **(station.sleeper.result() if station.sleeper is not None else {}),
        }

    def loop(self, progress: bool, checkpoint, checkpoint_period_s: float) -> None:
        """Advance to the end, a safeguard check period at a time, folding the logs as it goes; a
        divergence, a Drake error or Ctrl-C ends it with its diagnosis, the device's feedback
        zeroed whatever stopped it."""
        h, guard, root = self.h, self.guard, self.root
        bar = _progress(self.n_steps, progress)
        k, next_fold = 0, self.fold_every
        last_checkpoint = time.perf_counter()
        chunk = guard.poll_every if guard.polled else guard.every  # polled: each check's step ends a chunk
        try:
            while k < self.n_steps and not guard.stopped:
                k_next = min(k + chunk, self.n_steps)
                t0, c0 = time.perf_counter(), time.process_time()
                self.simulator.AdvanceTo(k_next * h)
                if guard.polled:
                    guard.poll()
                self.wall += time.perf_counter() - t0
                self.cpu += time.process_time() - c0
                bar.update(k_next - k)
                k = k_next
                if self.recording_steps is not None and k >= self.recording_steps:
                    self.meshcat.StopRecording()  # the cap: the rest of the run is not recorded
                    self.recording_steps = None
                if self.falls.pending and k * h >= self.falls.at_s - 0.5 * h:
                    self.falls.check(self.plant.GetMyContextFromRoot(root), root)
                if k >= next_fold:
                    t0 = time.perf_counter()
                    self.fold()
                    cost = time.perf_counter() - t0
                    self.folding += cost
                    if self.lag is not None:  # at real time: folds take at most their share of it
                        self.fold_every = self.real_time_fold_every(cost)
                    next_fold = k + self.fold_every
                if checkpoint is not None and time.perf_counter() - last_checkpoint >= checkpoint_period_s:
                    checkpoint({**self.common(True), **self.tool_metrics(with_devices=False)})
                    last_checkpoint = time.perf_counter()
            guard.check()
        except DivergenceError:
            self.diagnosis = guard.diagnosis
        except RuntimeError as e:
            if self.meshcat is not None and server_stopped(self.meshcat) is not None:
                self.viewer_stopped_at = root.get_time()  # the viewer's, not the simulation's: no diagnosis
                return
            self.diagnosis = f"Drake stopped at t={root.get_time():.4f} s: {e}"
            found = self.god.diverged_part(root, guard.max_speed)  # the likely cause, when it is ours
            if found is not None:
                self.diagnosis = f"{found[0]} diverged: {found[1]}. {self.diagnosis}"
        except KeyboardInterrupt as e:  # Ctrl-C, or SIGTERM through the command line's handler
            self.interrupted = e
        finally:
            self.hold.start()  # from here to the outputs written, a signal is held (simulate)
            bar.close()
            self.zeroed = self.god.zero_feedback(root.get_time())  # never left pushing

    def tool_metrics(self, with_devices: bool) -> dict:
        """Each tool's metrics (and its device's counts at the end): flat in a scene of one tool;
        in a scene of several, under ``tools: {NAME: {...}}``, each tool's configuration with them,
        and the scene's worst beside (:data:`~godobject_drake.metrics.METRIC_KEYS`)."""
        if self.metrics_error is not None:
            return {"metrics_error": self.metrics_error}
        out, errors = {}, []
        for name, tool in self.station.tools.items():
            own = self.measured[name].result()
            if with_devices:
                try:
                    own.update(tool.device_metrics(self.root))
                except Exception as e:
                    errors.append(f"{self.station.records[name].who}{type(e).__name__}: {e}")
            out[name] = own
        if len(out) == 1:
            flat = dict(next(iter(out.values())))
        else:
            for name, view in self.station.views.items():
                out[name] = {**configuration(view.scenario, view), **out[name]}
            flat = {**worst_of(out), "tools": out}
            if self.collisions is not None:
                flat.update(self.collisions.result())
        if errors:
            flat["metrics_error"] = "; ".join(errors)
        return flat

    def task_score(self) -> dict:
        """The task's score (:mod:`godobject_drake.task_score`) from every tool's grasp events; a
        score that fails is reported, never the run's metrics lost."""
        events = []
        for tool in self.station.tools.values():
            hold = getattr(tool, "grasp", None)  # an articulated tool's jaws (JawHold)
            events += list(getattr(hold, "events", []))
        try:
            return self.task.result(events)
        except Exception as e:
            return {"metrics_error": f"task score: {type(e).__name__}: {e}"}

    def finish(self) -> RunResult:
        """The metrics of what ran (the recording saved first: a metric that fails must not lose
        it), the result; Ctrl-C raises :class:`RunInterrupted` carrying it."""
        root = self.root
        partial = self.interrupted is not None or root.get_time() < self.n_steps * self.h - 0.5 * self.h
        metrics = self.common(partial)
        if self.lag is not None:
            metrics.update(self.lag.result())
            summary = self.lag.summary(root.get_time(), self.wall) if self.lag.warn else None
            if summary is not None:  # the verdict: a warning unless real time held throughout
                level = logging.INFO if self.lag.held else logging.WARNING
                logging.getLogger("godobject_drake.realtime").log(level, "%s", summary)
        if self.guard.stopped:
            metrics["stopped_by_user"] = True
        if self.interrupted is not None:
            metrics["interrupted"] = True
        if self.zeroed:
            metrics["feedback_zeroed_at_s"] = root.get_time()
        if self.falls.fallen:
            metrics["unsupported_bodies"] = self.falls.fallen
        stopped = server_stopped(self.meshcat) if self.meshcat is not None else None
        if stopped is not None:  # a client ended it; Drake's drawing raised at its next call to it
            at = self.viewer_stopped_at
            metrics["meshcat_error"] = stopped + (
                "; the run went on to its end without it" if at is None
                else f"; the run ended at t = {at:.4f} s, when Drake's drawing next called the server"
            )  # fmt: skip
        if self.record and stopped is not None:
            metrics["recording_error"] = f"{self.record}: not made, Meshcat's scene went with its server"
        elif self.record:
            try:
                metrics["recording_bytes"] = save_recording(self.meshcat, self.record)
                metrics["recording_s"] = min(root.get_time(), self.scenario.recording.max_duration_s)
            except OSError as e:  # outputs.OutputError names the file and keeps the last complete one
                metrics["recording_error"] = str(e)
        if self.device_logs:  # each tool's device log closed, what it holds said
            for recorder in self.device_logs.values():
                recorder.close()
            metrics["device_logs"] = ", ".join(str(r.path) for r in self.device_logs.values())
            metrics["device_log_rows"] = sum(r.rows for r in self.device_logs.values())
        t0 = time.perf_counter()
        self.fold()
        metrics["metrics_time_s"] = self.folding + time.perf_counter() - t0
        metrics.update(self.tool_metrics(with_devices=True))
        if self.task is not None and self.metrics_error is None:
            metrics.update(self.task_score())
        for name, (_, measured) in self.soft.items():  # each soft body's, its name first
            metrics.update({f"{name}_{k}": v for k, v in soft_body_result(measured).items()})
            if isinstance(metrics.get("max_penetration_m"), float):  # a tool in a soft body is in the budget
                metrics["max_penetration_m"] = max(metrics["max_penetration_m"], measured.max_pen)
        metrics.update(verdict(metrics, self.scenario, self.station.records))
        data = self.logs.kept()
        data.update({key: np.concatenate(chunks) for key, chunks in (self.soft_kept or {}).items()})
        traces = {}
        if self.soft_kept is not None and self.measured is not None:  # keep_logs: the tips' traces too
            traces = {name: measured.trace() for name, measured in self.measured.items()}
        result = RunResult(metrics, self.station, self.simulator, self.guard, data, traces)
        if self.interrupted is not None:
            raise RunInterrupted(result) from self.interrupted
        return result


def record_devices(station: Station) -> dict:
    """Each tool's device written to its device log as it is sampled (``recording.device_log``):
    its :class:`~godobject_drake.devices.sources.SampleRecorder` by tool name; none without."""
    recording = station.scenario.recording
    if not recording.device_log:
        return {}
    out = {}
    for name, tool in station.tools.items():
        try:
            out[name] = tool.source.record_to(recording.device_log_for(name))
        except OSError as e:
            raise sc.ScenarioError(
                f"recording.device_log: {recording.device_log_for(name)}: cannot be written ({e.strerror}): "
                "give a file in a folder that exists and can be written"
            ) from None
    return out


class DeviceNotHeardError(RuntimeError):
    """A device's driver sent nothing within ``device.wait_s`` before the run."""


# The families a driver runs (godobject_drake.driver.families.FAMILIES; tests/test_bad_files.py
# checks the two agree): the scene does not import the driver's process.
DRIVER_FAMILIES = ("emulated", "forcedimension", "haply", "openhaptics")


def driver_command(url: str, key_file=None) -> str:
    """The command that starts a device's driver for the scene's link at ``url``, with the scene's
    key file where it has one (``--allow-unauthenticated`` for a link that is not ``udp://``):
    ``FAMILY`` stands for one of :data:`DRIVER_FAMILIES`."""
    key = f" --key-file {shlex.quote(str(key_file))}" if key_file else ""
    if not url.startswith("udp://"):  # the driver takes Drake's unpaired LCM only when told to
        key = " --allow-unauthenticated"
    return (
        f"godobject-driver run FAMILY --scene {shlex.quote(url)}{key} (FAMILY: {', '.join(DRIVER_FAMILIES)})"
    )


def wait_for_devices(station: Station, clock=time.monotonic) -> None:
    """Wait for each LCM device's first sample (``device.wait_s``: the run's clock starts when its
    device is first heard, so starting the scene or the driver first gives the same run); saying
    so while waiting, and raising :class:`DeviceNotHeardError` naming the fix past the wait."""
    log = logging.getLogger("godobject_drake.realtime")
    for name, tool in station.tools.items():
        source = getattr(tool.source, "pose_device", tool.source)  # a pose device on a grasper: its own
        receiver = getattr(source, "receiver", None)
        config = station.records[name].view.device
        wait_s = config.first_wait_s() if hasattr(config, "first_wait_s") else 0.0
        if receiver is None or wait_s <= 0 or receiver.latest is not None:
            continue
        url = source.lcm.get_lcm_url()
        who = f"tools.{name}: " if name else ""
        command = driver_command(url, getattr(source.lcm, "key_file", None))
        log.info(
            "%swaiting up to %g s for the device's first sample on %s (channel %s); the run's clock starts "
            "then. Start its driver: %s",
            who, wait_s, url, receiver.channel, command,
        )  # fmt: skip
        t0 = clock()
        if not receiver.wait_first(wait_s, clock):
            # the run never starts: every device that has a driver (another tool's, paired while
            # this one was awaited) hears zero and the scene's stop, and its driver ends
            for other in station.tools.values():
                other.source.zero_feedback(0.0)
            raise DeviceNotHeardError(
                f"{who}no sample from the device's driver on {url} (channel {receiver.channel}) in "
                f"device.wait_s = {wait_s:g} s: start the driver ({command}), check its URL, channel and "
                "key file (a driver with another key is named in the lines above), or raise device.wait_s "
                "(0: start without it, the device at its start pose)"
            )
        log.info("%sdevice heard after %.2f s: the run starts", who, clock() - t0)


def _then(first, second):
    """``first`` then ``second``, two ``before_step`` hooks or None, as one hook or None."""
    if first is None or second is None:
        return second if first is None else first

    def both(plant_context, root_context):
        first(plant_context, root_context)
        second(plant_context, root_context)

    return both


SHARED_LOGS = ("state", "contacts")  # logs every tool reads, kept once under their own name


class _Logs:
    """The station's loggers, emptied into each tool's chunk (one row per plant step, the tool's own
    logger names, with what its kind computes from them after the run); optionally all kept."""

    def __init__(self, station: Station, root_context, keep: bool):
        self._logs = {name: logger.FindMutableLog(root_context) for name, logger in station.loggers.items()}
        self._tools = station.tools
        self._names = station.tool_loggers
        self._pending = {name: None for name in self._logs}
        self._keep = [] if keep else None

    def drain(self) -> dict:
        """Each tool's rows logged since the last drain, the same number from every logger."""
        rows = {}
        for name, log in self._logs.items():
            new = log.data().T.copy()
            log.Clear()
            pending = self._pending[name]
            rows[name] = new if pending is None else np.concatenate([pending, new])
        n = min(len(r) for r in rows.values())
        self._pending = {name: (r[n:] if len(r) > n else None) for name, r in rows.items()}
        chunks = {
            tool: self._tools[tool].complete_logs({own: rows[full][:n] for own, full in names.items()})
            for tool, names in self._names.items()
        }
        if self._keep is not None:  # by the station's logger names (a tool's computed rows with its name)
            kept = {}
            for tool, chunk in chunks.items():
                kept.update(
                    {(k if k in SHARED_LOGS or not tool else f"{tool}/{k}"): v for k, v in chunk.items()}
                )
            self._keep.append(kept)
        return chunks

    def kept(self) -> dict:
        if not self._keep:
            return {}
        return {name: np.concatenate([c[name] for c in self._keep]) for name in self._keep[0]}


class _AllTools:
    """The station's tools, as one for what the run asks of every tool alike: before the run, before
    each plant step, whether a part diverged, what is held, the feedback zeroed at the end."""

    def __init__(self, station: Station):
        self.tools = station.tools
        self.mode = next(iter(self.tools.values())).mode  # the scene's simulation.mode, every tool's

    def prepare(self, plant_context) -> None:
        for tool in self.tools.values():
            tool.prepare(plant_context)

    def before_step(self, plant):
        hooks = [hook for tool in self.tools.values() if (hook := tool.before_step(plant)) is not None]
        if len(hooks) <= 1:
            return hooks[0] if hooks else None

        def every(plant_context, root_context):
            for hook in hooks:
                hook(plant_context, root_context)

        return every

    def diverged_part(self, root_context, max_speed: float):
        for name, tool in self.tools.items():
            found = tool.diverged_part(root_context, max_speed)
            if found is not None:
                return (f"{name}: {found[0]}" if name else found[0]), found[1]
        return None

    def held_bodies(self, root_context) -> set[int]:
        return set().union(*(tool.held_bodies(root_context) for tool in self.tools.values()))

    def zero_feedback(self, t: float) -> bool:
        return any([tool.source.zero_feedback(t) for tool in self.tools.values()])  # every one, not the first


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
