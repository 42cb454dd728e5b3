"""A scene whose driver link publishes at most RATE times a second of *wall* time, to emulate a
scene that sustains only that rate (docs/local_model.md, "The test-only throttle"; used by
analysis/local_model_bench.py). Test-only: a scene never needs it, and the package knows nothing
of it beyond its publishers' ``throttle`` hook (None: every step).

    python analysis/throttled_scene.py RATE run SCENARIO.yaml [flags of ``godobject run``]

Each publisher gets a :class:`WallThrottle` of its own (the wrench's and the local model's steps
differ); within one, a step's answer is memoised, so a step publishes the wrench and the local
model both or neither.
"""

from __future__ import annotations

import math
import sys
import time


class WallThrottle:
    """Lets a publisher publish at most ``rate_hz`` times a second of wall time (module docstring)."""

    def __init__(self, rate_hz: float, clock=None):
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"a throttle of {rate_hz!r} Hz: give a rate in Hz > 0 (e.g. 30)")
        self.interval, self.clock = 1.0 / rate_hz, clock or time.monotonic
        self._next = -math.inf
        self._step, self._due = None, False

    def due(self, step_time: float) -> bool:
        """Whether the step at simulated ``step_time`` is published (the same answer for every
        publisher of that step)."""
        if step_time != self._step:
            now = self.clock()
            self._step, self._due = step_time, now >= self._next
            if self._due:
                self._next = max(self._next + self.interval, now - self.interval)
        return self._due


def throttle(cls, rate_hz: float) -> None:
    """Every ``cls`` made from now on gets a :class:`WallThrottle` of its own."""
    init = cls.__init__

    def __init__(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self.throttle = WallThrottle(rate_hz)

    cls.__init__ = __init__


def main(argv: list[str]) -> int:
    from godobject_drake.cli import main as godobject
    from godobject_drake.devices.lcm import LcmDevice
    from godobject_drake.link.scene_model import LocalModelPublisher

    rate_hz, args = float(argv[0]), argv[1:]
    throttle(LcmDevice, rate_hz)  # the wrench's publisher takes its device's
    throttle(LocalModelPublisher, rate_hz)
    return godobject(args)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
