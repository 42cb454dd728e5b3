"""How late a run paced to the wall clock is: :class:`RealtimeLag`, in bounded memory, with one
warning when the run cannot hold its rate (:func:`~godobject_drake.simulation.simulate` wraps its
plant steps with it)."""

import logging
import time

from godobject_drake.quantiles import Quantiles


class RealtimeLag:
    """How far each plant step lags behind the wall clock in a run at real-time rate, and a warning
    when the run cannot hold it.

    Step k at simulated time t is due at ``t / rate`` of wall time after t = 0; its lag is how
    much later the simulator reaches it (ahead counts as 0). The lags are counted in a
    :class:`~godobject_drake.quantiles.Quantiles` of bins ``BIN_S`` wide up to 10 ms and of a
    relative width ``REL`` above: the quantiles are exact to a bin (10 µs, or 0.1 % of the lag
    above 10 ms), the maximum and the final lag exactly, and memory stays bounded (at most
    ~20 000 bins for lags up to 10⁶ s).

    **The warning** (``warn``): every ``WINDOW_S`` of wall time the real-time factor of the last
    two windows is measured (simulated time advanced / (rate × wall time), over 0.8 s); below
    ``SLOW_RTF``, or a lag past ``BEHIND_S``, one warning is logged (logger
    ``godobject_drake.realtime``) with what was measured and ``fixes``: a run slower than 0.9 of
    real time from its start is told at 0.8 s of wall time, a slowdown later within 1.2 s of it.
    A pause that the run then catches up (a fold of the logs, a collection) does not warn. The
    run does not drop simulated time to catch up: it goes on in slow motion and says so.

    **The verdict** (:meth:`summary`, one line at the end): what the run held when, from its own
    record of the windows: each stretch of windows below ``SLOW_RTF`` ("fell behind") or not
    ("held"), with its wall-clock times and real-time factor, e.g. "fell behind for the first
    0.8 s (0.76 of real time), then held (1.05) to the end at 4.0 s". A run of more than
    ``MAX_SPANS`` stretches is summed instead (how long behind, in how many stretches, the
    longest), in bounded memory.
    """

    BIN_S = 1e-5
    REL = 1e-3
    WINDOW_S = 0.4
    SLOW_RTF = 0.9
    BEHIND_S = 1.0
    MAX_SPANS = 4  # stretches said one by one; a run of more is summed

    def __init__(self, rate: float, late_s: float, step_s: float | None = None, warn: bool = False,
                 fixes: str = ""):  # fmt: skip
        self.rate, self.late_s = float(rate), float(late_s)
        self.step_s, self.warn, self.fixes = step_s, warn, fixes
        self.lags = Quantiles(self.BIN_S, self.REL)
        self._wall0: float | None = None
        self.max_s, self.last_s, self.late_steps, self.steps = 0.0, 0.0, 0, 0
        self._window: tuple[float, float] | None = None  # (wall, t) where this window began
        self._previous: tuple[float, float] | None = None  # ... and where the one before it began
        self.slowest_window_rtf: float | None = None
        self.warned: str | None = None  # the warning's text, once logged
        # stretches of windows that held real time or fell behind: [behind, wall0, wall1, t0, t1]
        self.spans: list[list] = []  # the first MAX_SPANS
        self._current: list | None = None  # the stretch the newest window is in
        self.overflow = False  # more than MAX_SPANS stretches
        self.behind_s = self.behind_t = 0.0  # wall time behind, and the simulated time it advanced
        self.behind_stretches = 0
        self.longest = (0.0, 0.0)  # the longest stretch behind: (s, its start)
        self.held: bool | None = None  # the verdict: real time held throughout (None: not yet said)
        self._last: tuple[float, float] | None = None  # (wall, t) of the newest step

    def record(self, t: float, now: float | None = None) -> None:
        now = time.perf_counter() if now is None else now
        if self._wall0 is None:
            self._wall0 = now - t / self.rate
            self._window = (now, t)
        lag = max(now - self._wall0 - t / self.rate, 0.0)
        self._last = (now, t)
        self.lags.add(lag)
        self.max_s, self.last_s = max(self.max_s, lag), lag
        self.late_steps += lag > self.late_s
        self.steps += 1
        wall_start, t_start = self._window
        if now - wall_start >= self.WINDOW_S:
            rtf = (t - t_start) / (self.rate * (now - wall_start))
            self._span(rtf < self.SLOW_RTF, wall_start, now, t_start, t)
            self.slowest_window_rtf = (
                rtf if self.slowest_window_rtf is None else min(self.slowest_window_rtf, rtf)
            )
            self._window = (now, t)
            # the last two windows together (0.8 s): a steady slowdown shows there, a pause of
            # a fold or a collection (tens of ms) does not
            previous, self._previous = self._previous, (wall_start, t_start)
            if previous is not None:
                wall_two, t_two = previous
                two = (t - t_two) / (self.rate * (now - wall_two))
                if self.warned is None and self.warn and two < self.SLOW_RTF:
                    self._warn(two, lag, now - self._wall0)
            if self.warned is None and self.warn and lag > self.BEHIND_S:
                self._warn(rtf, lag, now - self._wall0)
        elif self.warned is None and self.warn and lag > self.BEHIND_S:
            self._warn((t / self.rate) / (now - self._wall0), lag, now - self._wall0)

    def _span(self, behind: bool, wall0: float, wall1: float, t0: float, t1: float) -> None:
        """A window into the stretches: the newest one grows, or a new one begins."""
        wall0, wall1 = wall0 - self._wall0, wall1 - self._wall0
        if behind:
            self.behind_s += wall1 - wall0
            self.behind_t += t1 - t0
        current = self._current
        if current is not None and current[0] == behind:
            current[2], current[4] = wall1, t1
        else:
            current = self._current = [behind, wall0, wall1, t0, t1]
            self.behind_stretches += behind
            if len(self.spans) < self.MAX_SPANS:
                self.spans.append(current)
            else:
                self.overflow = True
        if behind and current[2] - current[1] > self.longest[0]:
            self.longest = (current[2] - current[1], current[1])

    def _warn(self, rtf: float, lag: float, wall: float) -> None:
        cost = ""
        if self.step_s is not None and rtf > 0:
            wall_ms = 1e3 * self.step_s / (rtf * self.rate)
            cost = f" (each {1e3 * self.step_s:g} ms step took {wall_ms:.2f} ms of wall time)"
        self.warned = (
            f"the scene cannot hold real time: {wall:.2f} s into the run it ran at {rtf:.2f} of real time"
            f"{cost} and is {lag:.3f} s behind the wall clock, so the tool moves in slow motion and "
            "the device's feedback comes late; the run does not drop simulated time to catch up "
            f"(its last line says whether it caught up). {self.fixes}"
        ).strip()
        logging.getLogger("godobject_drake.realtime").warning("%s", self.warned)

    def summary(self, sim_time_s: float, wall_time_s: float) -> str | None:
        """The verdict (class docstring): one line saying when the run fell behind real time and
        what it held after, how far behind it ended; None before the first step."""
        if self.steps == 0:
            return None
        rtf = sim_time_s / (self.rate * wall_time_s) if wall_time_s > 0 else float("nan")
        if self._last is not None and self._window is not None and self._last[0] > self._window[0]:
            (wall1, t1), (wall0, t0) = self._last, self._window  # the last window, however short
            window = (t1 - t0) / (self.rate * (wall1 - wall0))
            if self.spans or wall1 - wall0 >= 0.5 * self.WINDOW_S:  # too short alone to judge
                self._span(window < self.SLOW_RTF, wall0, wall1, t0, t1)
                self._window = self._last
        late = self.last_s > max(self.late_s, 0.01)
        ended = f"; ended {self.last_s:.3f} s behind the wall clock" if late else ""
        self.held = not (self.behind_s > 0 or late or self.warned is not None)
        if self.held:
            return f"real time held: {rtf:.2f} of real time over {wall_time_s:.1f} s"
        if self.overflow:
            (longest, at), total = self.longest, self._current[2]
            slow = self.behind_t / (self.rate * self.behind_s)
            told = (f"fell behind for {self.behind_s:.1f} s of {total:.1f} s in {self.behind_stretches} "
                    f"stretches (the longest {longest:.1f} s from {at:.1f} s), at {slow:.2f} of real time "
                    "while behind")  # fmt: skip
        else:
            parts = [self._say_span(i, s) for i, s in enumerate(self.spans)]
            told = ", then ".join(parts) if parts else f"ran at {rtf:.2f} of real time"
        return f"real time not held throughout: {told}; {rtf:.2f} of real time over the run{ended}"

    def _say_span(self, i: int, span: list) -> str:
        behind, wall0, wall1, t0, t1 = span
        rtf = (t1 - t0) / (self.rate * (wall1 - wall0)) if wall1 > wall0 else float("nan")
        last = i == len(self.spans) - 1
        if behind:
            when = f"for the first {wall1:.1f} s" if i == 0 else f"from {wall0:.1f} to {wall1:.1f} s"
            return f"fell behind {when} ({rtf:.2f} of real time)"
        kept = f"held ({rtf:.2f})" if rtf >= 0.99 else f"ran at {rtf:.2f} of real time"
        return f"{kept} {'to the end at' if last else f'from {wall0:.1f} to'} {wall1:.1f} s"

    def wrap(self, before_step):
        """``before_step`` (or nothing) with the lag recorded first, at every plant step."""

        def step(plant_context, root_context):
            self.record(root_context.get_time())
            if before_step is not None:
                before_step(plant_context, root_context)

        return step

    def quantile(self, q: float) -> float:
        """The ``q`` quantile of the lags (s), to its bin's upper edge (never past the maximum)."""
        return self.lags.quantile(q)

    def result(self) -> dict:
        return {
            "realtime_lag_p50_s": self.quantile(0.5),
            "realtime_lag_p99_s": self.quantile(0.99),
            "realtime_lag_max_s": self.max_s,
            "realtime_lag_end_s": self.last_s,
            "realtime_late_steps": int(self.late_steps),
            "realtime_late_threshold_s": self.late_s,
            "realtime_warning": self.warned,
        }
