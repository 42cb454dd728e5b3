"""Quantiles of a stream of durations in bounded memory: :class:`Quantiles`, for how late a run
paced to the wall clock is (:mod:`~godobject_drake.realtime`) and for a driver's timing
(:mod:`godobject_drake.driver.process`), both of which run for hours."""

import math


class Quantiles:
    """The quantiles and the maximum of a stream of durations (s), in memory that does not grow with
    the stream.

    The values are counted in bins: ``resolution`` wide up to ``resolution / relative`` (where the
    two widths meet), and above it each ``1 + relative`` times as wide as the last, with no upper
    end (a run 23 s behind is counted as 23 s, not in a last bin); a value below 0 counts as 0. Only
    the bins used are kept: at most ``1 / relative`` of the first kind and ~``ln(top / (resolution /
    relative)) / relative`` of the second. A quantile is the upper edge of the bin that holds the
    value of numpy's ``inverted_cdf`` rank, never past the maximum: at most ``resolution`` above the
    exact value below ``resolution / relative``, at most a share ``relative`` above it beyond. The
    maximum is exact.
    """

    def __init__(self, resolution: float, relative: float):
        if not (math.isfinite(resolution) and resolution > 0 and 0 < relative < 1):
            raise ValueError(
                f"Quantiles(resolution={resolution!r}, relative={relative!r}): give a resolution > 0 (s) and "
                "a relative width in (0, 1), e.g. Quantiles(1e-5, 1e-3)"
            )
        self.resolution, self.relative = float(resolution), float(relative)
        self.fine = self.resolution / self.relative
        self._n_fine = round(self.fine / self.resolution)
        self._log_rel = math.log1p(self.relative)
        self._bins: dict[int, int] = {}
        self.n, self.max = 0, -math.inf

    def _bin(self, x: float) -> int:
        if x < self.fine:
            return int(max(x, 0.0) / self.resolution)
        return self._n_fine + int(math.log(x / self.fine) / self._log_rel)

    def _upper(self, i: int) -> float:
        if i < self._n_fine:
            return (i + 1) * self.resolution
        return self.fine * math.exp((i - self._n_fine + 1) * self._log_rel)

    def add(self, x: float) -> None:
        i = self._bin(x)
        self._bins[i] = self._bins.get(i, 0) + 1
        self.n += 1
        self.max = max(self.max, x)

    def quantile(self, q: float) -> float:
        """The ``q`` quantile (``0 < q ≤ 1``), to its bin's upper edge; NaN before the first value."""
        if self.n == 0:
            return math.nan
        need, seen = max(math.ceil(q * self.n), 1), 0
        for i in sorted(self._bins):
            seen += self._bins[i]
            if seen >= need:
                return min(self._upper(i), self.max)
        return self.max

    def summary(self) -> dict:
        """``p50_s``, ``p99_s``, ``max_s`` and ``n`` (None for each figure before the first value)."""
        if not self.n:
            return {"p50_s": None, "p99_s": None, "max_s": None, "n": 0}
        return {"p50_s": self.quantile(0.5), "p99_s": self.quantile(0.99), "max_s": self.max, "n": self.n}
