"""What the hand felt and what the driver's counts mean: the force rendered (:class:`RenderedForce`,
kept in constant memory every period) and the lines the driver prints when it ends
(:func:`exit_lines`), each count with its meaning and whether it mattered in this run
(docs/haptic_devices.md, "What the driver's counts mean")."""

from __future__ import annotations

import math

# A period is "in contact" when the force rendered is above this (N): a hand feels the scene
# push back. Below it are the small forces of carrying a light body (the quick start's brick,
# 2.3 g: 0.023 N) and a spring settling to zero.
CONTACT_N = 0.1

# Overruns matter (this project's rule of thumb, not a vendor's) when more than this share of
# the periods began late, or when one began later than the watchdog time: a late period holds the
# last force that long, which a stiff wall renders less stably, and past the watchdog time the
# force goes to zero.
OVERRUN_SHARE = 0.05


class RenderedForce:
    """The magnitude of the force rendered, every period: its peak, and its mean over the periods
    above ``contact_n`` (:data:`CONTACT_N`), in constant memory (no list: a driver runs for hours)."""

    def __init__(self, period_s: float, contact_n: float = CONTACT_N):
        self.period_s, self.contact_n = float(period_s), float(contact_n)
        self.peak_n = 0.0
        self.periods = 0
        self.contact_periods = 0
        self._contact_sum = 0.0

    def add(self, f) -> None:
        """One period's force rendered (N, any frame: only its magnitude counts)."""
        magnitude = math.hypot(f[0], f[1], f[2])
        self.periods += 1
        self.peak_n = max(self.peak_n, magnitude)
        if magnitude > self.contact_n:
            self.contact_periods += 1
            self._contact_sum += magnitude

    @property
    def mean_in_contact_n(self) -> float | None:
        """The mean magnitude over the periods in contact; None if there was none."""
        return self._contact_sum / self.contact_periods if self.contact_periods else None

    def result(self) -> dict:
        return {
            "peak_n": self.peak_n,
            "mean_in_contact_n": self.mean_in_contact_n,
            "contact_s": self.contact_periods * self.period_s,
            "contact_periods": self.contact_periods,
            "contact_threshold_n": self.contact_n,
            "periods": self.periods,
        }


def felt_line(felt: dict) -> str:
    """One line: what the hand felt (the summary's ``rendered_force``)."""
    if not felt["contact_periods"]:
        return (
            f"the hand felt no contact: the force rendered stayed at or below "
            f"{felt['contact_threshold_n']:g} N (peak {felt['peak_n']:.3g} N) over {felt['periods']} periods"
        )
    return (
        f"the hand felt: peak {felt['peak_n']:.3g} N, mean {felt['mean_in_contact_n']:.3g} N over "
        f"{felt['contact_s']:.2f} s in contact (the periods rendering over {felt['contact_threshold_n']:g} N)"
    )


def _overruns(n: int, s: dict) -> str:
    loops = max(s["counts"]["loops"], 1)
    worst = s["loop_lateness"].get("max_s")
    late = "" if worst is None else f", the latest {1e3 * worst:.1f} ms late"
    share = n / loops
    watchdog = f"{1e3 * s['limits']['watchdog_s']:g} ms"
    if share <= OVERRUN_SHARE and (worst is None or worst < s["limits"]["watchdog_s"]):
        return f"did not matter ({share:.1%} of the periods{late}, under the watchdog's {watchdog})"
    return (
        f"MATTERED: {share:.1%} of the periods{late}; the device held its force that long (a busy machine): "
        "--rt-priority 50, or fewer programs beside it"
    )


def _loops(n: int, s: dict) -> str:
    period, ran = s["limits"]["period_s"], s.get("run_s")
    due = None if ran is None else round(ran / period)
    if due is None or n >= 0.99 * due:
        return f"{n * period:.2f} s at {1 / period:g} Hz"
    return (f"{n} of the {due} periods of its {ran:.2f} s at {1 / period:g} Hz: an overrun skips the periods "
            "it missed (a Ctrl-Z pause too)")  # fmt: skip


def _some(n: int, mattered: str, none: str = "none") -> str:
    return none if n == 0 else f"MATTERED: {mattered}"


def _watchdog(n: int, s: dict) -> str:
    lost = f"the hand lost the force {n} times (the scene's word came late: a slow or stalled scene)"
    return _some(n, lost, "none: the hand never lost the force")


def _clamps(n: int, s: dict) -> str:
    return _some(n, f"{n} periods felt {s['limits']['max_force_n']:g} N instead of what the scene asked: "
                 "lower feedback.kd (or the device's scale)")  # fmt: skip


def _rate(n: int, s: dict) -> str:
    if n == 0:
        return "none"
    return (f"{n} periods: a wall, or the force's return after a watchdog trip, came over a few ms "
            "instead of at once (the device's protection; it matters only with many)")  # fmt: skip


# Each count: what it means, and whether it mattered in this run (from its value and the summary).
COUNTS = {
    "loops": ("device periods run", _loops),
    "overruns": ("periods that began more than one period late", _overruns),
    "watchdog_trips": ("times the scene's word went stale and the force went to zero", _watchdog),
    "scene_stops": ("times the scene said it stopped (its end, Stop, an error): zero force at once",
                    lambda n, s: {0: "none heard", 1: "the scene's end"}.get(n, f"{n} runs ended")),
    "force_clamps": ("periods with the force cut to the device's rated maximum", _clamps),
    "rate_clamps": ("periods with the force's change cut to the rated rate", _rate),
    "buzz_events": ("times the force oscillated near the device's Nyquist rate (damped)",
                    lambda n, s: _some(n, "the gain is too stiff for the device: lower feedback.kd or "
                                       "raise feedback.gamma_d")),
    "buzz_periods": ("periods rendered damped", lambda n, s: "none" if n == 0 else "see buzz_events"),
    "bad_feedback": ("scene messages ignored (unreadable, not finite, or a local model stiffer than the "
                     "device renders)", lambda n, s: _some(n, f"{n} ignored: the lines above say why")),
    "link_rejected": ("datagrams the link dropped (another key, a replay, a stranger, a second scene)",
                      lambda n, s: "none" if n == 0 else f"{n} dropped; it matters only if the scene "
                      "never paired (the summary's link counts say which)"),
}  # fmt: skip


def exit_lines(summary: dict) -> list[str]:
    """What the driver prints when it ends: what the hand felt, then each count, its meaning and
    whether it mattered (``summary``: :meth:`~godobject_drake.driver.process.Driver.summary`)."""
    lines = [felt_line(summary["rendered_force"]), "its counts (what each means: whether it mattered here):"]
    counts = summary["counts"]
    width = max(len(k) for k in counts)
    digits = max(len(str(v)) for v in counts.values())
    for key in [*(k for k in COUNTS if k in counts), *(k for k in counts if k not in COUNTS)]:
        n = counts[key]
        meaning, verdict = COUNTS.get(key, ("", lambda n, s: ""))
        lines.append(f"  {key:<{width}} {n:>{digits}}  {meaning}: {verdict(n, summary)}")
    return lines
