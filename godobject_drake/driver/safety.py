"""What a driver may render (:mod:`godobject_drake.driver.process`, its module docstring, step 3):
the scene's newest feedback while it is fresh and the scene has not stopped (:class:`FeedbackGate`),
cut to the device's rated force and rate, with a buzz damped (:class:`ForceSafety`).

Both are plain arithmetic on the times and forces handed to them (no clock, no socket), so each
rule is checked exactly by the fast tests (``tests/test_driver_safety.py``) and mutation-tested
(docs/mutation.md).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np


class FeedbackGate:
    """The scene's newest feedback, and whether it may be rendered now.

    - :meth:`feedback` takes a message's force (the device's frame, N), its scene time (s) and
      when it arrived (the driver's clock, s); a force that is not finite is refused (the caller
      counts it);
    - :meth:`stop`: the scene said it stopped; nothing is rendered until its next feedback;
    - :meth:`state` at the moment of rendering: ``ok`` (render), ``stopped``, ``clutch``,
      ``watchdog`` (the newest feedback is older than ``watchdog_s``: counted in
      :attr:`trips` each time it goes stale) or ``waiting`` (no feedback yet).
    """

    def __init__(self, watchdog_s: float):
        self.watchdog_s = float(watchdog_s)
        self.force = np.zeros(3)
        self.scene_time = math.nan
        self.arrived: float | None = None
        self.stopped = False
        self.trips = 0
        self.stops = 0
        self._was_fresh = False

    def feedback(self, force, scene_time: float, arrived: float) -> bool:
        f = np.array(force, float)
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            return False
        self.force, self.scene_time, self.arrived = f, float(scene_time), float(arrived)
        self.stopped = False
        return True

    def stop(self) -> None:
        self.stopped = True
        self.stops += 1

    def state(self, now: float, clutch: bool) -> str:
        fresh = self.arrived is not None and now - self.arrived <= self.watchdog_s
        if self._was_fresh and not fresh:
            self.trips += 1
        self._was_fresh = fresh
        if self.stopped:
            return "stopped"
        if clutch:
            return "clutch"
        if fresh:
            return "ok"
        return "waiting" if self.arrived is None else "watchdog"


class ForceSafety:
    """The force a device may render, from the force the scene asks (module docstring).

    ``step(f_requested, live)``: ``live`` False (no fresh feedback, a stop, the clutch) renders
    zero at once (no rate limit on the way to zero). Counts in :attr:`counts`.
    """

    BUZZ_WINDOW = 24  # changes looked at (the last 25 requests)
    BUZZ_BIG_CHANGES = math.ceil(0.8 * BUZZ_WINDOW)  # 20: how many must be larger than buzz_min
    BUZZ_FLIPS = math.ceil(0.8 * (BUZZ_WINDOW - 1))  # 19 of the 23 successive pairs flip sign
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
            if big.sum() < self.BUZZ_BIG_CHANGES:
                continue
            flips = np.sum(np.sign(step[1:]) * np.sign(step[:-1]) < 0)
            if flips >= self.BUZZ_FLIPS:
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
        norm = math.hypot(*f)  # no overflow: a 1e300 N request is cut to the rated force, not to zero
        if norm > self.max_force:
            f = f * (self.max_force / norm)
            self.counts["force_clamps"] += 1
        change = f - self.out
        size = math.hypot(*change)
        if size > self.max_step:
            f = self.out + change * (self.max_step / size)
            self.counts["rate_clamps"] += 1
        self.out = f
        return f
