"""A haptic device's driver, in a process of its own: the device's loop at its rate, the pose to
the scene, the scene's feedback wrench to the device, and every safety on the device's side.

    godobject-driver run FAMILY --scene udp://127.0.0.1:7667 [--rate 1000] [--watchdog-periods 10]
                     [--max-force N] [--rt-priority 50] [--log F.csv] [--summary F.json]
    godobject-driver calibrate FAMILY --scenario S.yaml --out CALIBRATED.yaml [--seconds 20]
    (or python -m godobject_drake.driver.process ...)

FAMILY is ``emulated``, ``haply``, ``forcedimension`` or ``openhaptics``
(:mod:`godobject_drake.driver.families`; docs/haptic_devices.md). The scene runs with
``device: !Lcm {url: udp://127.0.0.1:7667, ...}`` (:mod:`godobject_drake.protocol`).

Each device period the loop:

1. reads the handle (position in the device's frame, buttons); button 0 is the grasp (``grasp=*``
   while held, ``grasp=`` when let go), button 1 the clutch: while held the pose sent stays put
   and no force is rendered; let go, the handle carries on from where the pose stayed;
2. sends the pose to the scene (``lcmt_robot_state``, ``utime`` the driver's clock in µs);
3. takes the newest feedback (``lcmt_force_torque``, already in the device's frame: the scene
   maps it) and renders it through :class:`ForceSafety`:

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

4. publishes its counts (``GODOBJECT_DRIVER_STATUS``) ten times a second and at exit, which the
   scene puts in its metrics as ``driver_*``.

On its own exit, SIGTERM or SIGINT the driver renders zero and closes the device before it
returns. ``--log FILE.csv`` keeps every period (times on ``time.monotonic``, the clock every
process on the machine shares); ``--summary FILE.json`` the counts, the limits that applied and
the loop's timing.

Exit codes: 0 done, 1 the device failed, 2 bad input (a message naming the value, the limit and
the fix).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

from godobject_drake.driver.families import FAMILIES, RATED, EmulatedDevice, HandPath, Rated
from godobject_drake.protocol import (
    DRIVER_STATUS_CHANNEL,
    DRIVER_STATUS_KEYS,
    FEEDBACK_CHANNEL,
    POSE_CHANNEL,
    STOP_SUFFIX,
    driver_lcm,
    pose_message,
    status_message,
)

DEFAULT_URL = "udp://127.0.0.1:7667"
DEFAULT_WATCHDOG_PERIODS = 10


class ForceSafety:
    """The force a device may render, from the force the scene asks (module docstring, step 3).

    ``step(f_requested, live)``: ``live`` False (no fresh feedback, a stop, the clutch) renders
    zero at once (no rate limit on the way to zero). Counts in :attr:`counts`.
    """

    BUZZ_WINDOW = 24  # periods looked at
    BUZZ_ALTERNATION = 0.8  # the share of successive changes that flip sign
    DAMP_TAPS = 4

    def __init__(
        self, max_force_n: float, max_rate_n_s: float, period_s: float, buzz_min_n: float | None = None
    ):
        self.max_force, self.max_step = float(max_force_n), float(max_rate_n_s) * period_s
        self.buzz_min = 0.02 * self.max_force if buzz_min_n is None else float(buzz_min_n)
        self.history: deque = deque(maxlen=self.BUZZ_WINDOW + 1)
        self.out = np.zeros(3)
        self.buzzing = False
        self.counts = {"force_clamps": 0, "rate_clamps": 0, "buzz_events": 0, "buzz_periods": 0}

    def buzz(self) -> bool:
        """Do the requested force's changes over the window alternate in sign, near the Nyquist rate?"""
        if len(self.history) < self.history.maxlen:
            return False
        d = np.diff(np.array(self.history), axis=0)  # (window, 3)
        for axis in range(3):
            step = d[:, axis]
            big = np.abs(step) > self.buzz_min
            if big.sum() < 0.8 * len(step):
                continue
            flips = np.sum(np.sign(step[1:]) * np.sign(step[:-1]) < 0)
            if flips >= self.BUZZ_ALTERNATION * (len(step) - 1):
                return True
        return False

    def step(self, f_requested, live: bool) -> np.ndarray:
        f = np.asarray(f_requested, float)
        if not live or not np.all(np.isfinite(f)):
            self.history.clear()
            self.buzzing = False
            self.out = np.zeros(3)
            return self.out
        self.history.append(f.copy())
        buzzing = self.buzz()
        if buzzing and not self.buzzing:
            self.counts["buzz_events"] += 1
        self.buzzing = buzzing
        if buzzing:
            self.counts["buzz_periods"] += 1
            f = np.mean(list(self.history)[-self.DAMP_TAPS :], axis=0)
        norm = float(np.linalg.norm(f))
        if norm > self.max_force:
            f = f * (self.max_force / norm)
            self.counts["force_clamps"] += 1
        change = f - self.out
        size = float(np.linalg.norm(change))
        if size > self.max_step:
            f = self.out + change * (self.max_step / size)
            self.counts["rate_clamps"] += 1
        self.out = f
        return f


class Driver:
    """The loop (module docstring), on an opened device and a transport (``Publish``, ``Subscribe``,
    ``HandleSubscriptions``: :class:`~godobject_drake.protocol.UdpLcm` or a ``DrakeLcm``)."""

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
    ):
        self.device, self.lcm, self.rated = device, lcm, rated
        self.period = 1.0 / rate_hz
        self.watchdog_s = watchdog_periods * self.period
        self.safety = ForceSafety(max_force_n, rated.max_force_rate_n_s, self.period)
        self.grasp, self.grasp_button, self.clutch_button = grasp, grasp_button, clutch_button
        self.exit_on_stop, self.channel = exit_on_stop, channel
        self.counts = dict.fromkeys(DRIVER_STATUS_KEYS, 0)
        self.feedback = None  # (force in the device frame, scene time s, arrival time)
        # The earliest a message handled now can have arrived: the previous poll. A message that
        # waited in the socket while this process was not running (a loaded machine) is as old
        # as that wait, and the watchdog must count it so: read at its handling, a command the
        # scene sent before it died rendered past the watchdog time.
        self._arrived_after: float | None = None
        self.stopped = False
        self.heard_scene = False
        self.offset = np.zeros(3)  # the clutch's re-indexing
        self.held = None  # the pose sent while the clutch is held
        self.rows: list[tuple] = []  # kept when there is no log file
        self.log_file = None
        self.late: deque = deque(maxlen=1_000_000)  # the last 17 min at 1 kHz
        self.gaps: deque = deque(maxlen=1_000_000)
        self.stop_requested = False
        lcm.Subscribe(feedback_channel, self._on_feedback)
        lcm.Subscribe(feedback_channel + STOP_SUFFIX, self._on_stop)

    def _on_feedback(self, raw: bytes) -> None:
        from drake import lcmt_force_torque

        try:
            m = lcmt_force_torque.decode(raw)
        except ValueError:
            self.counts["bad_feedback"] += 1
            return
        f = np.array([m.fx, m.fy, m.fz], float)
        if not np.all(np.isfinite(f)):
            self.counts["bad_feedback"] += 1
            return
        now = time.monotonic() if self._arrived_after is None else self._arrived_after
        if self.feedback is not None:
            self.gaps.append(now - self.feedback[2])
        self.feedback = (f, m.timestamp * 1e-6, now)
        self.stopped = False
        if not self.heard_scene:
            self.heard_scene = True
            self.device.on_scene()

    def _on_stop(self, raw: bytes) -> None:
        self.stopped = True
        self.counts["scene_stops"] += 1
        if self.exit_on_stop:
            self.stop_requested = True

    def _buttons(self, buttons) -> tuple[bool, bool]:
        def pressed(i):
            return i is not None and 0 <= i < len(buttons) and bool(buttons[i])

        grasp = True if self.grasp == "always" else pressed(self.grasp_button)
        return grasp, pressed(self.clutch_button)

    def publish_status(self, now: float) -> None:
        counts = {
            **self.counts,
            **{k: self.safety.counts[k] for k in ("force_clamps", "rate_clamps", "buzz_events")},
        }
        self.lcm.Publish(DRIVER_STATUS_CHANNEL, status_message(round(now * 1e6), counts).encode())

    def run(self, duration_s: float = math.inf) -> None:
        start = time.monotonic()
        next_tick = start
        was_fresh = False
        previous_poll = start
        try:
            while not self.stop_requested:
                now = time.monotonic()
                if now - start >= duration_s:
                    break
                late = now - next_tick
                self.late.append(max(late, 0.0))
                if late > self.period:
                    self.counts["overruns"] += 1
                    next_tick = now  # start again from now: no burst of catch-up periods
                self.counts["loops"] += 1
                p, q, buttons = self.device.read()
                grasp, clutch = self._buttons(buttons)
                sent = p + self.offset
                if clutch:
                    if self.held is None:
                        self.held = sent.copy()
                    sent = self.held
                elif self.held is not None:  # let go: carry on from where the pose stayed
                    self.offset += self.held - (p + self.offset)
                    sent, self.held = self.held, None
                utime = round((now - start) * 1e6) + 1
                self.lcm.Publish(self.channel, pose_message(utime, sent, q, "*" if grasp else "").encode())
                # What this poll hands over arrived after the previous poll, at the earliest: its
                # age is counted from there (fail-safe: a message that sat out a stall is stale).
                # Its age is taken when the force is rendered, after the poll (the process may be
                # held up anywhere in the loop).
                self._arrived_after, poll = previous_poll, time.monotonic()
                self.lcm.HandleSubscriptions(0)
                previous_poll = poll
                rendered_at = time.monotonic()
                fresh = self.feedback is not None and rendered_at - self.feedback[2] <= self.watchdog_s
                if was_fresh and not fresh:
                    self.counts["watchdog_trips"] += 1
                was_fresh = fresh
                live = fresh and not self.stopped and not clutch
                requested = self.feedback[0] if self.feedback is not None else np.zeros(3)
                f = self.safety.step(requested, live)
                self.device.render(f)
                state = (
                    "stopped"
                    if self.stopped
                    else "clutch"
                    if clutch
                    else "ok"
                    if fresh
                    else "watchdog"
                    if self.feedback is not None
                    else "waiting"
                )
                t_scene = self.feedback[1] if self.feedback is not None else math.nan
                self._row((now, *sent, *requested, *f, t_scene, state, int(self.safety.buzzing)))
                if self.counts["loops"] % 100 == 0:
                    self.publish_status(now)
                    if self.log_file is not None:
                        self.log_file.flush()
                next_tick += self.period
                wait = next_tick - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
        finally:
            self.shutdown()

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
        self._row((now, *(math.nan,) * 3, *zero, *zero, math.nan, "exit", 0))
        if self.log_file is not None:
            self.log_file.close()
        try:
            self.publish_status(now)
        except OSError:
            pass

    def summary(self) -> dict:
        def quantiles(values):
            if not values:
                return {"p50_s": None, "p99_s": None, "max_s": None, "n": 0}
            a = np.asarray(values)
            return {
                "p50_s": float(np.quantile(a, 0.5)),
                "p99_s": float(np.quantile(a, 0.99)),
                "max_s": float(a.max()),
                "n": len(a),
            }

        return {
            "counts": {**self.counts, **self.safety.counts},
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
            "loop_lateness": quantiles(self.late),
            "feedback_gap": quantiles(self.gaps),
        }

    LOG_HEADER = "t,x,y,z,fx_req,fy_req,fz_req,fx,fy,fz,t_scene,state,buzz"

    def open_log(self, path: str | Path) -> None:
        """Write every period to ``path`` as it runs (flushed every 100 periods, closed at exit)."""
        self.log_file = open(path, "w")
        self.log_file.write(self.LOG_HEADER + "\n")

    def _row(self, row: tuple) -> None:
        if self.log_file is None:
            self.rows.append(row)
        else:
            self.log_file.write(",".join(f"{v:.9g}" if isinstance(v, float) else str(v) for v in row) + "\n")


def read_log(path: str | Path) -> dict:
    """A driver's ``--log`` as arrays by column (``state`` as strings)."""
    lines = Path(path).read_text().splitlines() or [Driver.LOG_HEADER]  # not yet flushed: empty
    names = lines[0].split(",")
    # a running log's last line may be cut short
    rows = [r for r in (line.split(",") for line in lines[1:]) if len(r) == len(names)]
    out = {}
    for i, name in enumerate(names):
        column = [r[i] for r in rows]
        out[name] = np.array(column) if name == "state" else np.array(column, dtype=float)
    return out


# -- the command line --------------------------------------------------------------------------------------


class BadInput(ValueError):
    pass


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
        raise BadInput(f"--duration {args.duration!r} s must be > 0 (inf: until SIGTERM or Ctrl-C)")
    if not 0 <= args.rt_priority <= 99:
        raise BadInput(
            f"--rt-priority {args.rt_priority!r} must be within 1 to 99 (SCHED_FIFO), or 0 for none"
        )
    if args.hand and args.family != "emulated":
        raise BadInput(f"--hand moves the emulated device only; {args.family} is moved by your hand")


def _run(args) -> int:
    _check(args)
    try:
        lcm = driver_lcm(args.scene)
    except ValueError as e:
        raise BadInput(f"--scene: {e}") from None
    device, rated = open_device(args.family, args)
    driver = Driver(
        device,
        lcm,
        rated,
        rate_hz=args.rate,
        watchdog_periods=args.watchdog_periods,
        max_force_n=args.max_force or rated.max_force_n,
        grasp=args.grasp,
        exit_on_stop=args.exit_on_stop,
    )
    limits = driver.summary()["limits"]
    print(
        f"godobject-driver {args.family}: {rated.model}, {args.rate:g} Hz, "
        f"force ≤ {limits['max_force_n']:g} N "
        f"(rated {rated.max_force_n:g} N: {rated.source}), change ≤ {limits['max_force_rate_n_s']:g} N/s, "
        f"watchdog {driver.watchdog_s * 1e3:g} ms; scene {args.scene}",
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

    def on_signal(signum, frame):
        driver.stop_requested = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    if args.log:
        driver.open_log(args.log)
    try:
        driver.run(args.duration)
    finally:
        summary = driver.summary()
        if args.summary:
            Path(args.summary).write_text(json.dumps(summary, indent=1))
        print(f"godobject-driver: {json.dumps(summary['counts'])}", file=sys.stderr, flush=True)
    return 0


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
    Path(args.out).write_text(
        f"# {args.scenario} with the workspace calibrated by godobject-driver calibrate {args.family}:\n"
        f"# the device reached {np.round(lower, 5).tolist()} to {np.round(upper, 5).tolist()} m (its frame)\n"
        + sc.scenario_to_yaml(s)
    )
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
    run.add_argument("--duration", type=float, default=math.inf, help="s (default: until SIGTERM or Ctrl-C)")
    run.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="1-99: run the loop under SCHED_FIFO at this priority (Linux; needs CAP_SYS_NICE), as a "
        "device's servo loop should; 0 (default): the normal scheduler",
    )
    run.add_argument("--exit-on-stop", action="store_true", help="exit when the scene says it stopped")
    run.add_argument("--log", default="", help="write every period to FILE.csv at exit")
    run.add_argument("--summary", default="", help="write the counts, limits and timing to FILE.json at exit")
    cal = sub.add_parser("calibrate", help="record the device's reachable box as a scenario's workspace")
    family_args(cal)
    cal.add_argument("--scenario", required=True, help="a scenario whose device is !Lcm")
    cal.add_argument("--out", required=True, help="where to write the calibrated scenario (YAML)")
    cal.add_argument("--seconds", type=float, default=20.0, help="how long to record (s)")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    try:
        return _run(args) if args.command == "run" else _calibrate(args)
    except BadInput as e:
        print(f"godobject-driver: {e}", file=sys.stderr)
        return 2
    except ValueError as e:  # a device that would not open, a hand path that would not load
        print(f"godobject-driver: {e}", file=sys.stderr)
        return 2 if "--" in str(e) else 1


if __name__ == "__main__":
    sys.exit(main())
