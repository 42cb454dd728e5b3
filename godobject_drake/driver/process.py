"""A haptic device's driver, in a process of its own: the device's loop at its rate, the pose to
the scene, the scene's feedback wrench to the device, and every safety on the device's side.

    godobject-driver run FAMILY --scene udp://127.0.0.1:7667 [--key-file K] [--rate 1000]
                     [--watchdog-periods 10] [--max-force N] [--rt-priority 50] [--log F.csv]
                     [--summary F.json] [--stay]
    godobject-driver calibrate FAMILY --scenario S.yaml --out CALIBRATED.yaml [--seconds 20]
    (or python -m godobject_drake.driver.process ...)

FAMILY is ``emulated``, ``haply``, ``forcedimension`` or ``openhaptics``
(:mod:`godobject_drake.driver.families`; docs/haptic_devices.md). The scene runs with
``device: !Lcm {url: udp://127.0.0.1:7667, ...}`` (:mod:`godobject_drake.link.transport`).

**Pairing**: the driver and the scene pair with a key both read from the user's own key file
(``--key-file``, the scene's ``device.key_file``; by default ``~/.config/godobject/link.key``,
created on first use): every datagram is authenticated, replays are dropped, and nothing but
the paired scene's feedback reaches the device (:mod:`godobject_drake.link.transport`). Until a scene
answers, the driver sends only its HELLO and renders nothing. A ``--scene`` that is not
``udp://`` (Drake's multicast) is refused unless ``--allow-unauthenticated``.

Each device period the loop:

1. reads the handle (position in the device's frame, buttons); button 0 is the grasp (``grasp=*``
   while held, ``grasp=`` when let go), button 1 the clutch: while held the pose sent stays put
   and no force is rendered; let go, the handle carries on from where the pose stayed;
2. sends the pose to the scene (``lcmt_robot_state``, ``utime`` the driver's clock in µs);
3. computes the force: from the scene's newest **local model** once one is heard (a scene of
   this version publishes one after each step, on ``GODOBJECT_LOCAL_MODEL``): the spring to a
   proxy kept out of the model's planes, with the handle's pose read this period, paid for by
   an energy budget, valid for 2 scene periods + 25 ms after the scene's last word about it
   (the model, or a heartbeat naming it on ``GODOBJECT_LOCAL_MODEL_ALIVE`` while the scene's
   loop is held up) and faded to zero at 3 scene periods + 50 ms
   (:mod:`~godobject_drake.driver.local_model`, docs/local_model.md; the watchdog below is
   then the model's validity); else (an older scene, or ``--no-local-model``) the newest
   feedback wrench (``lcmt_force_torque``, already in the device's frame: the scene maps it),
   held. Either is rendered through :class:`ForceSafety`:

   - **watchdog**: no feedback for ``watchdog_periods`` device periods (the scene stalled, was
     killed or never started): zero force until feedback comes again (``watchdog_trips``). A
     message's age counts from the poll before the one that handed it over, the earliest it can
     have arrived: one that waited in the socket while the driver itself was held up is as old
     as that wait, so a force the scene sent before it died is never rendered past the watchdog;
   - **stop**: the scene's ``<feedback>_STOP`` message: zero force at once (``scene_stops``);
   - **rated limits**: the force's magnitude is cut to the device's rated maximum
     (``force_clamps``) and its change per period to the rated rate (``rate_clamps``);
   - **buzz**: a feedback force whose changes alternate in sign at nearly every period (an
     oscillation near the device's Nyquist rate, as a too-stiff gain gives) and are larger than
     ``buzz_min_n`` is damped: the force rendered is the mean of the last four requested, which
     cancels the Nyquist component; each onset is counted (``buzz_events``);

4. publishes its counts and what the hand felt (the force rendered: :mod:`~godobject_drake.driver.report`)
   on ``GODOBJECT_DRIVER_STATUS`` ten times a second and at exit, which the scene puts in its
   metrics as ``driver_*``.

The driver ends with its scene (the scene's stop), printing what the hand felt (the peak force
rendered, its mean while in contact: above 0.1 N) and each count with what it means and whether it
mattered; ``--stay`` keeps it for the scene's next run.

On its own exit and on every signal that ends a process and can be caught (SIGTERM, SIGINT,
SIGHUP: a closed terminal or a dropped SSH session, SIGQUIT) the driver renders zero, writes the
log's ``exit`` row and closes the device before it returns (a signal ignored when it starts, as
``nohup`` ignores SIGHUP, stays ignored). SIGTSTP (Ctrl-Z) renders zero, writes a
``paused`` row and only then stops the process (SIGSTOP); on SIGCONT the loop goes on from zero: the
rated-rate ramp starts from the zero rendered, and what the scene sent while it was stopped is as
old as the stop (the watchdog's rule), so nothing is rendered until the scene speaks again. What
no process can do for itself (SIGKILL, SIGSTOP sent by another, a crash of the interpreter) is
covered only outside it, where at all: by the device's own watchdog where its SDK has one (armed at
the start: :attr:`~godobject_drake.driver.families.HapticIO.watchdog`; docs/haptic_devices.md);
``faulthandler`` prints the traceback of a crash.

``--log FILE.csv`` keeps every period (times on ``time.monotonic``, the clock every process on the
machine shares); ``--summary FILE.json`` the counts, the link's counts, the
limits that applied and the loop's timing. Without a log the driver keeps only its last
:attr:`Driver.ROWS_KEPT` periods, and its timing as histograms: its memory does not grow with
the time it runs.

Exit codes: 0 done, 1 the device or an output failed (the log or the summary could not be
written: said why), 2 bad input (a message naming the value, the limit and the fix), refused before
the device is opened where it is an option's.
"""

from __future__ import annotations

import argparse
import faulthandler
import json
import logging
import math
import os
import signal
import stat
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

from godobject_drake.driver.families import FAMILIES, RATED, EmulatedDevice, HandPath, Rated
from godobject_drake.driver.local_model import LocalRenderer
from godobject_drake.driver.report import RenderedForce, exit_lines
from godobject_drake.driver.safety import FeedbackGate, ForceSafety
from godobject_drake.link.keys import KEY_ENV, KeyFileError, key_fingerprint
from godobject_drake.link.logs import StderrHandler
from godobject_drake.link.messages import (
    ALIVE_CHANNEL,
    DRIVER_STATUS_CHANNEL,
    DRIVER_STATUS_KEYS,
    FEEDBACK_CHANNEL,
    LOCAL_MODEL_CHANNEL,
    POSE_CHANNEL,
    STOP_SUFFIX,
    LocalModelError,
    decode,
    parse_alive,
    parse_local_model,
    pose_message,
    status_message,
)
from godobject_drake.link.transport import LINK_REJECTED, driver_lcm, is_udp_url
from godobject_drake.outputs import OutputError, OutputRefused, check_output, is_stream, write_atomically
from godobject_drake.quantiles import Quantiles

__all__ = ["FAMILIES", "RATED", "Driver", "EmulatedDevice", "FeedbackGate", "ForceSafety", "HandPath",
           "main"]  # fmt: skip

DEFAULT_URL = "udp://127.0.0.1:7667"
TIMING_BINS = (1e-6, 0.01)  # the timing figures' bins: 1 µs wide up to 100 µs, 1 % wide above
DEFAULT_WATCHDOG_PERIODS = 10
# The signals that end the driver (each: zero force, the exit row, the device closed, exit 0):
# the terminal's hang-up and quit keys as well as a stop (SIGTERM) and Ctrl-C.
ENDING_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGQUIT)


class Driver:
    """The loop (module docstring), on an opened device and a transport (``Publish``, ``Subscribe``,
    ``HandleSubscriptions``: :class:`~godobject_drake.link.transport.UdpLcm` or a ``DrakeLcm``).

    Its memory stays bounded however long it runs: without a log file it keeps the last
    :attr:`ROWS_KEPT` periods (:attr:`rows`), and the timing figures are histograms
    (:class:`~godobject_drake.quantiles.Quantiles`, to 1 µs or 1 %)."""

    ROWS_KEPT = 2000  # the last 2 s at 1 kHz (~1 MB): every period goes to --log

    def __init__(
        self,
        device,
        lcm,
        rated: Rated,
        *,
        rate_hz: float,
        watchdog_periods: int,
        max_force_n: float,
        grasp: str = "button",
        grasp_button: int = 0,
        clutch_button: int = 1,
        exit_on_stop: bool = False,
        feedback_channel: str = FEEDBACK_CHANNEL,
        channel: str = POSE_CHANNEL,
        local_model: bool = True,
    ):
        self.device, self.lcm, self.rated = device, lcm, rated
        self.period = 1.0 / rate_hz
        self.watchdog_s = watchdog_periods * self.period
        self.safety = ForceSafety(max_force_n, rated.max_force_rate_n_s, self.period)
        self.felt = RenderedForce(self.period)  # what the hand felt: the force rendered
        self.gate = FeedbackGate(self.watchdog_s)
        self.grasp, self.grasp_button, self.clutch_button = grasp, grasp_button, clutch_button
        self.exit_on_stop, self.channel = exit_on_stop, channel
        self.counts = dict.fromkeys(DRIVER_STATUS_KEYS, 0)
        # The earliest a message handled now can have arrived: the previous poll. A message that
        # waited in the socket while this process was not running (a loaded machine) is as old
        # as that wait, and the watchdog must count it so: read at its handling, a command the
        # scene sent before it died rendered past the watchdog time.
        self._arrived_after: float | None = None
        self.heard_scene = False
        self.offset = np.zeros(3)  # the clutch's re-indexing
        self.held = None  # the pose sent while the clutch is held
        self.rows: deque = deque(maxlen=self.ROWS_KEPT)  # kept when there is no log file
        self.log_file = None
        self.log_path = None
        self.output_error: str | None = None  # why an output failed (the loop then stops)
        self.late = Quantiles(*TIMING_BINS)  # how late each period started
        self.gaps = Quantiles(*TIMING_BINS)  # between two feedback messages
        self.stop_requested = False
        self.pause_requested = False  # SIGTSTP: zero, then stop (:meth:`_pause`)
        self.pauses = 0
        self.ended_by = None  # the signal's name that ended the run, if one did
        self.local = LocalRenderer()  # the scene's local model, once it sends one
        # the last POSES_KEPT poses sent and their utimes, a ring allocated once (bounded memory)
        self._sent_utimes = np.full(self.POSES_KEPT, -1, np.int64)
        self._sent_poses = np.zeros((self.POSES_KEPT, 3))
        self.pose_age = Quantiles(*TIMING_BINS)  # from reading the handle to commanding the force it gave
        self.bad_local_models = 0
        self.stiff_local_models = 0  # local models asking more stiffness than the device renders
        lcm.Subscribe(feedback_channel, self._on_feedback)
        lcm.Subscribe(feedback_channel + STOP_SUFFIX, self._on_stop)
        if local_model:
            lcm.Subscribe(LOCAL_MODEL_CHANNEL, self._on_local_model)
            lcm.Subscribe(ALIVE_CHANNEL, self._on_alive)

    POSES_KEPT = 4096  # 4 s at 1 kHz: the pose a local model was computed from is looked up here

    def sent_pose(self, utime: int) -> np.ndarray | None:
        """The pose sent with ``utime`` if among the last :attr:`POSES_KEPT`, else None."""
        found = np.flatnonzero(self._sent_utimes == utime) if utime > 0 else ()
        return self._sent_poses[found[0]].copy() if len(found) else None

    def _on_local_model(self, raw: bytes) -> None:
        try:
            model = parse_local_model(raw)
        except LocalModelError:
            self.bad_local_models += 1
            self.counts["bad_feedback"] += 1
            return
        kd = model.kd  # a matrix coupling (GLM3): its stiffest direction's
        if model.stiffness is not None:
            kd = max(kd, float(np.linalg.eigvalsh(np.reshape(model.stiffness, (3, 3)))[-1]))
        if kd > self.rated.max_stiffness_n_m:  # a wall stiffer than the device renders: it kicks
            self.stiff_local_models += 1
            self.counts["bad_feedback"] += 1
            if self.stiff_local_models == 1:
                logging.getLogger("godobject_drake").warning(
                    f"the scene's local model asks a stiffness kd = {kd:.4g} N/m, past the "
                    f"{self.rated.max_stiffness_n_m:,.0f} N/m the {self.rated.model} renders: refused, no "
                    "force from it (counted in bad_feedback); give the scene a lower --kd"
                )
            return
        now = time.monotonic() if self._arrived_after is None else self._arrived_after
        self.local.take(model, now, self.sent_pose(model.pose_utime))
        if not self.heard_scene:
            self.heard_scene = True
            self.device.on_scene()

    def _on_alive(self, raw: bytes) -> None:
        try:
            scene_utime = parse_alive(raw)
        except LocalModelError:
            self.bad_local_models += 1
            self.counts["bad_feedback"] += 1
            return
        now = time.monotonic() if self._arrived_after is None else self._arrived_after
        self.local.alive(scene_utime, now)

    def _on_feedback(self, raw: bytes) -> None:
        from drake import lcmt_force_torque

        m = decode(lcmt_force_torque, raw)
        now = time.monotonic() if self._arrived_after is None else self._arrived_after
        previous = self.gate.arrived
        if m is None or not self.gate.feedback([m.fx, m.fy, m.fz], m.timestamp * 1e-6, now):
            self.counts["bad_feedback"] += 1
            return
        if previous is not None:
            self.gaps.add(now - previous)
        if not self.heard_scene:
            self.heard_scene = True
            self.device.on_scene()

    def _on_stop(self, raw: bytes) -> None:
        self.gate.stop()
        self.counts["scene_stops"] = self.gate.stops
        if self.exit_on_stop:
            self.stop_requested = True
        else:
            _say("godobject-driver: the scene stopped: zero force; waiting for its next run (--stay; Ctrl-C "
                 "ends the driver)")  # fmt: skip

    def _buttons(self, buttons) -> tuple[bool, bool]:
        def pressed(i):
            return i is not None and 0 <= i < len(buttons) and bool(buttons[i])

        grasp = True if self.grasp == "always" else pressed(self.grasp_button)
        return grasp, pressed(self.clutch_button)

    def link_counts(self) -> dict:
        """The link's own counts (a :class:`~godobject_drake.link.transport.UdpLcm`'s), or none."""
        return dict(getattr(self.lcm, "counts", {}))

    def publish_status(self, now: float) -> None:
        link = self.link_counts()
        counts = {
            **self.counts,
            **{k: self.safety.counts[k] for k in ("force_clamps", "rate_clamps", "buzz_events")},
            "link_rejected": sum(link.get(k, 0) for k in LINK_REJECTED),
            "force_peak_n": self.felt.peak_n,  # what the hand felt, for the scene's metrics
            "force_mean_contact_n": self.felt.mean_in_contact_n,
            "contact_s": self.felt.contact_periods * self.period,
        }
        self.lcm.Publish(DRIVER_STATUS_CHANNEL, status_message(round(now * 1e6), counts).encode())

    def run(self, duration_s: float = math.inf) -> None:
        """Run a period every :attr:`period` until ``duration_s`` or a stop: count it, poll the
        link, read the handle, compute the force, render it, send the pose, log it; then sleep
        to the next period. Zero force and the device closed at the end (:meth:`shutdown`)."""
        start = time.monotonic()
        next_tick = start
        previous_poll = start
        try:
            while not self.stop_requested:
                if self.pause_requested:
                    self._pause()
                    continue  # the stop may have been asked for while stopped
                now = time.monotonic()
                if now - start >= duration_s:
                    break
                next_tick = self._count_period(now, next_tick)
                previous_poll = self._poll(previous_poll)
                sent, q, grasp, clutch, read_at = self._read_handle()
                state, requested, f = self._force(sent, clutch)
                self._render(f, read_at)
                self._send_pose(round((now - start) * 1e6) + 1, sent, q, grasp)
                self._record(now, sent, requested, f, state)
                next_tick += self.period
                wait = next_tick - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
        finally:
            self.run_s = time.monotonic() - start
            self.shutdown()

    def _pause(self) -> None:
        """SIGTSTP (Ctrl-Z): zero rendered and logged, then the process stopped (SIGSTOP); it goes on
        here on SIGCONT. The safety's output is zero too, so its rated-rate ramp starts from zero; the
        poll's clock is not moved on, so what the scene sent while this process was stopped is as old
        as the stop and rendered only after fresh word (module docstring)."""
        self.pause_requested = False
        zero = np.zeros(3)
        self.safety.step(zero, False)
        self.device.render(zero)
        self._row((time.monotonic(), *(math.nan,) * 3, *zero, *zero, math.nan, "paused", 0,
                   *(0.0,) * 3, self.local.energy_in))  # fmt: skip
        if self.log_file is not None:
            try:
                self.log_file.flush()
            except OSError as e:
                self._log_failed(e)  # the stop is still taken: the loop ends on SIGCONT
        self.pauses += 1
        os.kill(os.getpid(), signal.SIGSTOP)

    def _count_period(self, now: float, next_tick: float) -> float:
        """Count the period and how late it started; the tick it runs from (``now`` after an
        overrun: start again from now, no burst of catch-up periods)."""
        late = now - next_tick
        self.late.add(max(late, 0.0))
        if late > self.period:
            self.counts["overruns"] += 1
            next_tick = now
        self.counts["loops"] += 1
        return next_tick

    def _poll(self, previous_poll: float) -> float:
        """Hand what the link holds to the handlers; when this poll started (the next one's
        ``previous_poll``).

        What this poll hands over arrived after the previous poll, at the earliest: its age is
        counted from there (fail-safe: a message that sat out a stall is stale). Its age is
        taken when the force is rendered, after the poll (the process may be held up anywhere
        in the loop). The poll comes first, so the handle's pose is read just before the force
        it gives is computed and commanded."""
        self._arrived_after, poll = previous_poll, time.monotonic()
        self.lcm.HandleSubscriptions(0)
        return poll

    def _read_handle(self) -> tuple:
        """``(sent, q, grasp, clutch, read_at)``: the handle's position as sent to the scene (the
        clutch's offset added; held while the clutch is), its orientation, the buttons, and when
        it was read."""
        p, q, buttons = self.device.read()
        read_at = time.monotonic()
        grasp, clutch = self._buttons(buttons)
        sent = p + self.offset
        if clutch:
            if self.held is None:
                self.held = sent.copy()
            sent = self.held
        elif self.held is not None:  # let go: carry on from where the pose stayed
            self.offset += self.held - (p + self.offset)
            sent, self.held = self.held, None
        return sent, q, grasp, clutch, read_at

    def _force(self, sent, clutch: bool) -> tuple:
        """``(state, requested, f)``: the feedback's state, the force the scene's word asks for
        (the local model's once one is heard, else the newest wrench) and the force the safety
        lets through."""
        state = self.gate.state(time.monotonic(), clutch)
        if self.local.heard:  # the local model decides what is fresh (module docstring)
            live = state not in ("stopped", "clutch")
            requested = self.local.request(sent, time.monotonic(), self.period, live)
            if live:
                state = "ok" if self.local.weight > 0.0 else "watchdog"
            self.counts["watchdog_trips"] = self.local.trips
        else:
            self.counts["watchdog_trips"] = self.gate.trips
            requested = self.gate.force
        f = self.safety.step(requested, state == "ok")
        return state, requested, f

    def _render(self, f, read_at: float) -> None:
        """Command the force; the age of the pose it was computed from."""
        self.device.render(f)
        self.pose_age.add(time.monotonic() - read_at)
        self.felt.add(f)
        self.local.rendered(f)

    def _send_pose(self, utime: int, sent, q, grasp: bool) -> None:
        """Publish the pose to the scene, and keep it (a local model names the pose it used)."""
        self.lcm.Publish(self.channel, pose_message(utime, sent, q, "*" if grasp else "").encode())
        slot = self.counts["loops"] % self.POSES_KEPT
        self._sent_utimes[slot], self._sent_poses[slot] = utime, sent

    def _record(self, now: float, sent, requested, f, state: str) -> None:
        """The period's row; every 100 periods the counts to the scene and the log flushed."""
        local = self.local
        scene_time = local.model.scene_utime * 1e-6 if local.heard else self.gate.scene_time
        self._row((now, *sent, *requested, *f, scene_time, state, int(self.safety.buzzing),
                   local.weight, local.beta, local.damping, local.energy_in))  # fmt: skip
        if self.counts["loops"] % 100 == 0:
            self.publish_status(now)
            if self.log_file is not None:
                try:
                    self.log_file.flush()
                except OSError as e:
                    self._log_failed(e)

    def shutdown(self) -> None:
        """Zero force, close the device, tell the scene the last counts. Safe to call twice."""
        if getattr(self, "_closed", False):
            return
        self._closed = True
        zero = np.zeros(3)
        try:
            self.device.render(zero)
        finally:
            self.device.close()
        now = time.monotonic()
        row = (now, *(math.nan,) * 3, *zero, *zero, math.nan, "exit", 0, *(0.0,) * 3, self.local.energy_in)
        self._row(row)
        if self.log_file is not None:
            try:
                self.log_file.close()
            except OSError as e:
                self._log_failed(e)
        try:
            self.publish_status(now)
        except OSError:
            pass

    def summary(self) -> dict:
        return {
            "counts": {**self.counts, **self.safety.counts},
            "rendered_force": self.felt.result(),
            "link": self.link_counts(),
            "limits": {
                "model": self.rated.model,
                "max_force_n": self.safety.max_force,
                "max_force_rate_n_s": self.safety.max_step / self.period,
                "rated_max_force_n": self.rated.max_force_n,
                "source": self.rated.source,
                "watchdog_s": self.watchdog_s,
                "period_s": self.period,
            },
            "rt_priority": getattr(self, "rt_priority", 0),
            "run_s": getattr(self, "run_s", None),  # the loop's wall time, once it has run
            "ended_by": self.ended_by,
            "output_error": self.output_error,
            "pauses": self.pauses,
            "loop_lateness": self.late.summary(),
            "feedback_gap": self.gaps.summary(),
            "local_model": {
                "models": self.local.models,
                "heartbeats": self.local.beats,
                "bad": self.bad_local_models,
                "too_stiff": self.stiff_local_models,
                "energy_in_j": self.local.energy_in,
                "unpaid_j": self.local.unpaid,
                "trips": self.local.trips,
                "gap_s": self.local.gap() if self.local.heard else None,
                "fade_end_s": self.local.fade_end() if self.local.heard else None,
            },
            "spring_pose_age": self.pose_age.summary(),
        }

    # t_scene: the local model's scene time once one is heard (else the wrench's); weight, beta,
    # damping, energy_in: the local model's validity, budget scale, passivity damper (N·s/m) and
    # the work the hand has done on the device (J) (driver/local_model.py)
    LOG_HEADER = "t,x,y,z,fx_req,fy_req,fz_req,fx,fy,fz,t_scene,state,buzz,weight,beta,damping,energy_in"

    def open_log(self, path: str | Path, file=None) -> None:
        """Write every period to ``path`` as it runs (flushed every 100 periods, closed at exit);
        ``file``: ``path`` already opened (:func:`open_log_file`)."""
        self.log_path = path
        self.log_file = open(path, "w") if file is None else file
        try:
            self.log_file.write(self.LOG_HEADER + "\n")
        except OSError as e:
            self._log_failed(e)

    def _row(self, row: tuple) -> None:
        if self.log_file is None:
            self.rows.append(row)
            return
        try:
            self.log_file.write(",".join(f"{v:.9g}" if isinstance(v, float) else str(v) for v in row) + "\n")
        except OSError as e:
            self._log_failed(e)
            self.rows.append(row)

    def _log_failed(self, error: OSError) -> None:
        """A write to the log failed (a full disk, a file-size limit): the loop stops before its
        next period (zero force, the exit row kept in memory, the device closed) and says why,
        rather than die at the flush or run on unlogged (:attr:`output_error`)."""
        if self.output_error is None:
            self.output_error = (
                f"--log {self.log_path}: could not write ({error.strerror or error}); the force was zeroed "
                "and the driver stopped. Free space on that disk, or give --log another place"
            )
        self.stop_requested = True
        file, self.log_file = self.log_file, None
        try:
            file.close()  # the file is closed even when its last flush fails
        except OSError:
            pass


def read_log(path: str | Path) -> dict:
    """A driver's ``--log`` as arrays by column (``state`` as strings)."""
    text = Path(path).read_text()
    lines = text.splitlines()
    if text and not text.endswith("\n"):  # a running log's, or a log cut by a full disk: its last line
        lines = lines[:-1]  # cut short, even after a comma (as many fields, the last one empty)
    names = (lines or [Driver.LOG_HEADER])[0].split(",")  # not yet flushed: empty
    rows = [r for r in (line.split(",") for line in lines[1:]) if len(r) == len(names)]
    out = {}
    for i, name in enumerate(names):
        column = [r[i] for r in rows]
        out[name] = np.array(column) if name == "state" else np.array(column, dtype=float)
    return out


# -- the command line --------------------------------------------------------------------------------------


class BadInput(ValueError):
    pass


def open_log_file(path: str):
    """``--log``, opened before the device is: a regular file, new or emptied. Refused (naming the
    fix): a folder, a missing folder, a link not to follow, a place not writable
    (:func:`~godobject_drake.outputs.check_output`) and anything but a regular file: the loop writes
    to it every period and must never wait on a reader (a FIFO nobody reads blocked the driver's
    start, deaf to SIGTERM). Opened without blocking, and checked again once open."""
    refused = (
        f"--log {path} is not a regular file (a FIFO, a pipe or a device): the device's loop writes to it "
        "every period and must never wait on a reader; give a file, e.g. driver.csv"
    )
    try:
        check_output(path, "--log", example="driver.csv")
        if is_stream(path):
            raise BadInput(refused)
        flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
        fd = os.open(path, flags, 0o666)
    except OutputRefused as e:
        raise BadInput(str(e)) from None
    except OSError as e:  # ENXIO: a FIFO put there since the check, nobody reading it
        raise BadInput(f"--log {path}: {e.strerror or e}; give a regular file you can write") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise BadInput(refused)
    os.set_blocking(fd, True)
    return os.fdopen(fd, "w")


def check_summary(path: str) -> None:
    """``--summary``, before the device is opened: a folder, a missing folder, a link not to follow or
    a place not writable is refused naming the fix, not found at the end of the run."""
    try:
        check_output(path, "--summary", example="driver.json")
    except OutputRefused as e:
        raise BadInput(str(e)) from None


def open_device(family: str, args) -> tuple:
    rated = RATED[family]
    if family == "emulated":
        hand = HandPath.load(args.hand) if args.hand else None
        return EmulatedDevice(hand), rated
    if family == "haply":
        return FAMILIES[family](args.port), rated
    return FAMILIES[family](), rated


def _check(args) -> None:
    rated = RATED[args.family]
    if not (math.isfinite(args.rate) and 100 <= args.rate <= 10_000):
        raise BadInput(
            f"--rate {args.rate!r} Hz must be within 100 to 10000 Hz (the device's servo rate, "
            f"{rated.rate_hz:g} Hz for the {rated.model})"
        )
    if not (isinstance(args.watchdog_periods, int) and 1 <= args.watchdog_periods <= 1000):
        raise BadInput(
            f"--watchdog-periods {args.watchdog_periods!r} must be a whole number within 1 to 1000 "
            f"(default {DEFAULT_WATCHDOG_PERIODS}: {DEFAULT_WATCHDOG_PERIODS} ms at 1 kHz)"
        )
    if args.max_force is not None and not (0 < args.max_force <= rated.max_force_n):
        raise BadInput(
            f"--max-force {args.max_force!r} N must be > 0 and at most the {rated.model}'s rated "
            f"{rated.max_force_n:g} N ({rated.source})"
        )
    if not args.duration > 0:
        raise BadInput(
            f"--duration {args.duration!r} s must be > 0 (inf, the default: until the scene stops, "
            "SIGTERM or Ctrl-C)"
        )
    if not 0 <= args.rt_priority <= 99:
        raise BadInput(
            f"--rt-priority {args.rt_priority!r} must be within 1 to 99 (SCHED_FIFO), or 0 for none"
        )
    if args.hand and args.family != "emulated":
        raise BadInput(f"--hand moves the emulated device only; {args.family} is moved by your hand")


def _log_to_stderr() -> None:
    """The link's messages (paired, refused) on stderr, as the driver's own lines."""
    logger = logging.getLogger("godobject_drake")
    if not any(getattr(h, "driver_lines", False) for h in logger.handlers):
        handler = StderrHandler()
        handler.setFormatter(logging.Formatter("godobject-driver: %(message)s"))
        handler.driver_lines = True
        handler.level_before = logger.level  # put back with the handler (main's end)
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)


def _run(args) -> int:
    _check(args)
    if not is_udp_url(args.scene) and not args.allow_unauthenticated:
        raise BadInput(
            f"--scene {args.scene!r}: only a udp://HOST:PORT link is paired and authenticated; on "
            "Drake's LCM (udpm:// multicast) any process that reaches it could push the device. "
            "Give udp://HOST:PORT (the scene's device.url), or --allow-unauthenticated to accept that"
        )
    _log_to_stderr()
    try:
        lcm = driver_lcm(args.scene, args.key_file)
    except KeyFileError as e:
        raise BadInput(f"--key-file: {e}") from None
    except ValueError as e:
        raise BadInput(f"--scene: {e}") from None
    if is_udp_url(args.scene):
        link = f"scene {args.scene}, key {lcm.key_file} (fingerprint {key_fingerprint(lcm.end.key)})"
    else:
        link = f"scene {args.scene or 'udpm:// (Drake default)'} UNAUTHENTICATED (--allow-unauthenticated)"
    # the outputs before the device: a bad one is refused before anything can push
    log_file = open_log_file(args.log) if args.log else None
    if args.summary:
        check_summary(args.summary)
    try:
        device, rated = open_device(args.family, args)
    except BaseException:
        if log_file is not None:
            log_file.close()
        raise
    driver = Driver(
        device,
        lcm,
        rated,
        rate_hz=args.rate,
        watchdog_periods=args.watchdog_periods,
        max_force_n=args.max_force or rated.max_force_n,
        grasp=args.grasp,
        exit_on_stop=args.exit_on_stop,
        local_model=not args.no_local_model,
    )
    limits = driver.summary()["limits"]
    print(
        f"godobject-driver {args.family}: {rated.model}, {args.rate:g} Hz, "
        f"force ≤ {limits['max_force_n']:g} N "
        f"(rated {rated.max_force_n:g} N: {rated.source}), change ≤ {limits['max_force_rate_n_s']:g} N/s, "
        f"watchdog {driver.watchdog_s * 1e3:g} ms, {device.watchdog}; {link}",
        file=sys.stderr,
        flush=True,
    )

    driver.rt_priority = 0
    if args.rt_priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.rt_priority))
            driver.rt_priority = args.rt_priority
        except (PermissionError, AttributeError, OSError) as e:
            print(f"godobject-driver: --rt-priority {args.rt_priority} not applied ({e}); "
                  "running on the normal scheduler", file=sys.stderr)  # fmt: skip

    if log_file is not None:
        driver.open_log(args.log, log_file)
    return _loop(driver, args)


def _loop(driver: Driver, args) -> int:
    """Run the driver with its signals handled (module docstring); the summary written whole
    (:func:`~godobject_drake.outputs.write_atomically`). 0, or 1 if an output failed (said why)."""

    def on_signal(signum, frame):
        driver.stop_requested = True
        driver.ended_by = signal.Signals(signum).name

    def on_tstp(signum, frame):
        driver.pause_requested = True

    handlers = {**dict.fromkeys(ENDING_SIGNALS, on_signal), signal.SIGTSTP: on_tstp}
    previous = {  # a signal ignored when the driver began (nohup's SIGHUP) stays ignored
        signum: signal.signal(signum, handler)
        for signum, handler in handlers.items()
        if signal.getsignal(signum) != signal.SIG_IGN
    }
    failed = []
    try:
        driver.run(args.duration)
    finally:
        summary = driver.summary()
        if args.summary:
            try:
                write_atomically(args.summary, json.dumps(summary, indent=1))
            except OutputError as e:
                failed.append(f"--summary: {e}")
        for line in exit_lines(summary):
            _say(f"godobject-driver: {line}")
        if driver.ended_by:
            _say(f"godobject-driver: ended by {driver.ended_by}: zero force commanded, the device closed")
        for message in ([driver.output_error] if driver.output_error else []) + failed:
            _say(f"godobject-driver: {message}")
        for signum, handler in previous.items():  # as they were: main() may run inside another program
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
    return 1 if failed or driver.output_error else 0


def _say(text: str) -> None:
    """A line on stderr, if there is still one: after SIGHUP the terminal may be gone (EIO)."""
    try:
        print(text, file=sys.stderr, flush=True)
    except OSError:
        pass


def calibrate(
    device, seconds: float, rate_hz: float = 1000.0, clock=time.monotonic, sleep=time.sleep
) -> tuple:
    """The box the handle reached (m, the device's frame) while it was moved for ``seconds``."""
    lower, upper = np.full(3, math.inf), np.full(3, -math.inf)
    device.on_scene()  # the emulated hand starts its path
    end = clock() + seconds
    try:
        while clock() < end:
            p, _, _ = device.read()
            device.render(np.zeros(3))
            lower, upper = np.minimum(lower, p), np.maximum(upper, p)
            sleep(1.0 / rate_hz)
    finally:
        device.close()
    return lower, upper


def world_box(lower, upper, X_WDev, scale: float) -> tuple[list[float], list[float]]:
    """The axis-aligned world box holding the device's box mapped by ``X_WDev (scale p)``."""
    corners = np.array([[(lower, upper)[i >> k & 1][k] for k in range(3)] for i in range(8)])
    mapped = np.array([X_WDev.multiply(scale * c) for c in corners])
    return mapped.min(axis=0).tolist(), mapped.max(axis=0).tolist()


def _calibrate(args) -> int:
    # calibrate reads and writes a scenario; loaded here so the device's loop (run) never loads it
    from godobject_drake.config import scenario as sc

    if not args.seconds > 0:
        raise BadInput(
            f"--seconds {args.seconds!r} must be > 0 (how long to move the handle around, e.g. 20)"
        )
    try:
        s = sc.load_scenario(args.scenario)
    except (sc.ScenarioError, OSError) as e:
        raise BadInput(f"--scenario {args.scenario}: {e}") from None
    if type(s.device).__name__ != "Lcm":
        raise BadInput(
            f"--scenario {args.scenario}: its device is !{type(s.device).__name__}; calibrate a "
            "scenario whose device is !Lcm (a driver's)"
        )
    try:  # before the device: a folder or a missing folder is said now, not after the sweep
        check_output(args.out, "--out", example="calibrated.yaml")
    except OutputRefused as e:
        raise BadInput(str(e)) from None
    device, _ = open_device(args.family, args)
    print(f"calibrate: move the handle to every limit of its reach for {args.seconds:g} s", file=sys.stderr)
    lower, upper = calibrate(device, args.seconds)
    if not np.all(upper - lower > 1e-3):
        raise BadInput(
            f"calibrate: the handle moved only {np.round(upper - lower, 4).tolist()} m on x, y, z; "
            "move it to every limit of its reach (or give more --seconds)"
        )
    frame = s.device.device_to_world
    s.workspace.lower_m, s.workspace.upper_m = world_box(lower, upper, frame.transform(), frame.scale)
    text = (
        f"# {args.scenario} with the workspace calibrated by godobject-driver calibrate {args.family}:\n"
        f"# the device reached {np.round(lower, 5).tolist()} to {np.round(upper, 5).tolist()} m (its frame)\n"
        + sc.scenario_to_yaml(s)
    )
    try:
        write_atomically(args.out, text)  # whole, or the previous file kept
    except OutputError as e:
        print(f"calibrate: {e}", file=sys.stderr)
        return 1
    print(
        f"calibrate: workspace {np.round(s.workspace.lower_m, 5).tolist()} to "
        f"{np.round(s.workspace.upper_m, 5).tolist()} m (world) written to {args.out}",
        file=sys.stderr,
    )
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="godobject-driver", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="command", required=True)

    def family_args(q):
        q.add_argument("family", choices=sorted(FAMILIES), help="the device family")
        q.add_argument(
            "--hand", default="", help="emulated: a JSON hand path (HandPath); default: a still hand"
        )
        q.add_argument(
            "--port", default="", help="haply: the serial port (default: the first Inverse3 found)"
        )

    run = sub.add_parser("run", help="run the device's loop against a scene")
    family_args(run)
    run.add_argument("--scene", default=DEFAULT_URL, help=f"the scene's LCM URL (default {DEFAULT_URL})")
    run.add_argument(
        "--key-file",
        default="",
        help=f"the link's key, the scene's device.key_file (default ${KEY_ENV}, else "
        "~/.config/godobject/link.key; created on first use, mode 0600)",
    )
    run.add_argument(
        "--allow-unauthenticated",
        action="store_true",
        help="accept a --scene that is not udp:// (Drake's udpm:// multicast): any process that can "
        "reach it can then push the device",
    )
    run.add_argument("--rate", type=float, default=1000.0, help="the loop's rate (Hz; default 1000)")
    run.add_argument(
        "--watchdog-periods",
        type=int,
        default=DEFAULT_WATCHDOG_PERIODS,
        help=f"periods without feedback before the force is zeroed (default {DEFAULT_WATCHDOG_PERIODS})",
    )
    run.add_argument(
        "--max-force", type=float, default=None, help="N; at most the device's rated force (the default)"
    )
    run.add_argument(
        "--grasp",
        choices=("button", "always"),
        default="button",
        help="button: button 0 grasps while held; always: grasp from the start (no buttons)",
    )
    run.add_argument(
        "--duration",
        type=float,
        default=math.inf,
        help="s (default: until the scene stops, or with --stay until SIGTERM or Ctrl-C)",
    )
    run.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="1-99: run the loop under SCHED_FIFO at this priority (Linux; needs CAP_SYS_NICE), as a "
        "device's servo loop should; 0 (default): the normal scheduler",
    )
    ending = run.add_mutually_exclusive_group()
    ending.add_argument(
        "--stay",
        dest="exit_on_stop",
        action="store_false",
        help="when the scene says it stopped, render zero and wait for its next run (default: exit, "
        "printing what the hand felt and the counts)",
    )
    ending.add_argument(
        "--exit-on-stop",
        dest="exit_on_stop",
        action="store_true",
        default=True,
        help="exit when the scene says it stopped (the default; --stay waits for the next run)",
    )
    run.add_argument(
        "--no-local-model",
        action="store_true",
        help="render the scene's newest wrench, held, without the local model (for comparison): the "
        "scene's local model is ignored",
    )
    run.add_argument(
        "--log",
        default="",
        help="write every period to FILE.csv as the loop runs (a regular file, checked first; flushed every "
        "100 periods, closed at exit)",
    )
    run.add_argument(
        "--summary",
        default="",
        help="write the counts, limits and timing to FILE.json at exit (checked first)",
    )
    cal = sub.add_parser("calibrate", help="record the device's reachable box as a scenario's workspace")
    family_args(cal)
    cal.add_argument("--scenario", required=True, help="a scenario whose device is !Lcm")
    cal.add_argument("--out", required=True, help="where to write the calibrated scenario (YAML)")
    cal.add_argument("--seconds", type=float, default=20.0, help="how long to record (s)")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if not faulthandler.is_enabled():  # a crash of the interpreter at least leaves its traceback
        faulthandler.enable()
    try:
        return _run(args) if args.command == "run" else _calibrate(args)
    except BadInput as e:
        print(f"godobject-driver: {e}", file=sys.stderr)
        return 2
    except ValueError as e:  # a device that would not open, a hand path that would not load
        print(f"godobject-driver: {e}", file=sys.stderr)
        return 2 if "--" in str(e) else 1
    finally:  # run inside another program (a test, a scene), the driver leaves its logger as it was
        logger = logging.getLogger("godobject_drake")
        for handler in [h for h in logger.handlers if getattr(h, "driver_lines", False)]:
            logger.removeHandler(handler)
            logger.setLevel(handler.level_before)


if __name__ == "__main__":
    sys.exit(main())
