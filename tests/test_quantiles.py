"""The one streaming-quantile type (godobject_drake.quantiles): each quantile against numpy's on the
same values (a second method), to the bin's width the docstring states."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from godobject_drake.driver.process import TIMING_BINS
from godobject_drake.quantiles import Quantiles
from godobject_drake.realtime import RealtimeLag


def _width(q: Quantiles, x: float) -> float:
    """The bin's width at ``x``: ``resolution`` below ``resolution / relative``, a share above."""
    return q.resolution if x < q.fine else q.relative * x * (1 + q.relative)


@pytest.mark.parametrize("bins", [(RealtimeLag.BIN_S, RealtimeLag.REL), TIMING_BINS])
@settings(max_examples=60, deadline=None)
@given(values=st.lists(st.floats(0.0, 1e3, allow_nan=False), min_size=1, max_size=300))
def test_each_quantile_is_numpys_to_its_bin(bins, values):
    q = Quantiles(*bins)
    for x in values:
        q.add(x)
    for p in (0.01, 0.5, 0.99, 1.0):
        exact = float(np.quantile(values, p, method="inverted_cdf"))
        got = q.quantile(p)
        assert exact - 1e-12 * max(exact, 1.0) <= got <= min(exact + _width(q, exact), max(values)) + 1e-12
    assert q.max == max(values) and q.n == len(values)


def test_the_bins_by_hand():
    """Bins 10 µs wide up to 10 ms, 0.1 % above: 25 µs is in [20, 30) µs, reported 30 µs; 2 s is
    in the bin whose upper edge is 10 ms × 1.001^k for the first k with 10 ms × 1.001^k > 2 s."""
    q = Quantiles(1e-5, 1e-3)
    assert q.fine == pytest.approx(1e-2)
    q.add(25e-6)
    q.add(1.0)  # the maximum, so 30 µs is not capped by it
    assert q.quantile(0.5) == pytest.approx(30e-6)
    r = Quantiles(1e-5, 1e-3)
    r.add(2.0)
    r.add(3.0)
    k = math.floor(math.log(2.0 / 1e-2) / math.log(1.001)) + 1
    assert r.quantile(0.5) == pytest.approx(1e-2 * 1.001**k) and 2.0 < r.quantile(0.5) < 2.0 * 1.001


def test_negative_values_count_as_zero_and_nothing_gives_nan_and_none():
    q = Quantiles(*TIMING_BINS)
    assert math.isnan(q.quantile(0.5))
    assert q.summary() == {"p50_s": None, "p99_s": None, "max_s": None, "n": 0}
    q.add(-1.0)
    q.add(5e-6)
    assert q.quantile(0.5) == pytest.approx(1e-6)  # the median, -1 s, counted in [0, 1) µs
    q.add(1.0)
    assert q.quantile(0.5) == pytest.approx(6e-6)  # 5 µs in [5, 6) µs


@pytest.mark.parametrize("resolution, relative", [(0.0, 0.01), (1e-6, 0.0), (1e-6, 1.0), (math.inf, 0.01)])
def test_bad_bins_are_refused_naming_the_values(resolution, relative):
    with pytest.raises(ValueError, match=rf"resolution={resolution!r}, relative={relative!r}.*e\.g\."):
        Quantiles(resolution, relative)
