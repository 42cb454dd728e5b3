"""The driver's force safety alone (godobject_drake.driver.safety): the watchdog and the scene's
stop (FeedbackGate), the rated force and rate and the buzz damping (ForceSafety), number by number.
No clock, no socket: each test hands the times and forces, so every figure is exact. Fast, and
the mutation goal's tests for the driver's safety (pyproject ``[tool.mutmut]``)."""

import math

import numpy as np
import pytest

from godobject_drake.driver.safety import FeedbackGate, ForceSafety

# -- the rated limits --------------------------------------------------------------------------------------


def test_force_is_cut_to_the_rated_maximum_and_rate():
    """12 N rated, 1200 N/s: a 20 N request is cut to 12 N along its direction, reached by
    1.2 N steps (ten periods); going dead renders zero at once."""
    safety = ForceSafety(12.0, 1200.0, 0.001)
    request = np.array([0.0, 16.0, -12.0])  # |f| = 20 N
    out = [safety.step(request, True) for _ in range(12)]
    np.testing.assert_allclose(np.linalg.norm(out[0]), 1.2, rtol=1e-12)
    np.testing.assert_allclose(out[0], request * 1.2 / 20.0, rtol=1e-12)
    np.testing.assert_allclose(out[9], request * 12.0 / 20.0, rtol=1e-12)
    np.testing.assert_allclose(out[11], out[9], rtol=1e-12)
    assert safety.counts["force_clamps"] == 12 and safety.counts["rate_clamps"] == 10
    assert np.all(safety.step(request, False) == 0.0)  # no ramp on the way to zero
    assert np.all(safety.out == 0.0)
    np.testing.assert_allclose(np.linalg.norm(safety.step(request, True)), 1.2, rtol=1e-12)  # ramps again
    assert np.all(safety.step([math.nan, 0, 0], True) == 0.0)
    assert np.all(safety.step([0, math.inf, 0], True) == 0.0)


def test_an_absurd_request_is_cut_to_the_rated_force_along_its_direction():
    """1e300 N along x and y (its square overflows a double): 12 N along the diagonal, not zero."""
    safety = ForceSafety(12.0, 1e9, 0.001)
    np.testing.assert_allclose(safety.step([1e300, 1e300, 0.0], True), [12 / 2**0.5, 12 / 2**0.5, 0.0])
    np.testing.assert_allclose(safety.step([-1e300, 0.0, 0.0], True), [-12.0, 0.0, 0.0])


def test_exactly_the_rated_force_and_step_are_not_clamped():
    safety = ForceSafety(12.0, 12_000.0, 0.001)  # 12 N per period
    assert safety.buzzing is False and safety.step([1, 0, 0], True).dtype == np.float64
    np.testing.assert_array_equal(safety.step([12.0, 0.0, 0.0], True), [12.0, 0.0, 0.0])
    assert safety.counts == {"force_clamps": 0, "rate_clamps": 0, "buzz_events": 0, "buzz_periods": 0}
    np.testing.assert_array_equal(safety.step([-12.0, 0.0, 0.0], True), [0.0, 0.0, 0.0])  # 24 N cut to 12
    np.testing.assert_array_equal(safety.step([-12.0, 0.0, 0.0], True), [-12.0, 0.0, 0.0])  # 12 N: not cut
    assert safety.counts["rate_clamps"] == 1 and safety.counts["force_clamps"] == 0
    over = ForceSafety(12.0, 1e9, 0.001)
    np.testing.assert_allclose(over.step([0.0, 0.0, 12.5], True), [0.0, 0.0, 12.0], rtol=1e-12)
    assert over.counts["force_clamps"] == 1 and over.counts["rate_clamps"] == 0
    assert over.max_step == pytest.approx(1e6) and over.max_force == 12.0


# -- the buzz ----------------------------------------------------------------------------------------------


def test_a_buzz_near_nyquist_is_damped_from_the_25th_request_and_counted_once():
    """Requested f_x = 1 + 0.5 (−1)^k N (the device's Nyquist rate): the window (25 requests,
    24 changes) first holds it at k = 24; from there the 4-tap mean renders exactly 1 N; the
    periods before are rendered as asked."""
    safety = ForceSafety(12.0, 1e9, 0.001)
    asked = [1.0 + 0.5 * (-1) ** k for k in range(100)]
    out = [safety.step([a, 0.0, 0.0], True)[0] for a in asked]
    assert safety.counts["buzz_events"] == 1 and safety.counts["buzz_periods"] == 100 - 24
    np.testing.assert_array_equal(out[:24], asked[:24])
    np.testing.assert_allclose(out[24:], 1.0, rtol=1e-12)
    assert safety.buzzing
    safety.step([1.0, 0.0, 0.0], False)  # dead: the window starts again
    assert safety.buzzing is False
    out = [safety.step([a, 0.0, 0.0], True)[0] for a in asked[:30]]
    np.testing.assert_array_equal(out[:24], asked[:24])
    assert safety.counts["buzz_events"] == 2


def test_a_slow_wave_is_left_alone():
    calm = ForceSafety(12.0, 1e9, 0.001)
    wave = [2.0 * math.sin(2 * math.pi * 5 * k * 0.001) for k in range(1000)]
    out = [calm.step([w, 0.0, 0.0], True)[0] for w in wave]
    assert calm.counts["buzz_events"] == 0
    np.testing.assert_array_equal(out, wave)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_buzz_on_any_axis_is_caught(axis):
    safety = ForceSafety(12.0, 1e9, 0.001)
    for k in range(25):
        f = np.full(3, 2.0)
        f[axis] += 0.5 * (-1) ** k
        safety.step(f, True)
    assert safety.counts["buzz_events"] == 1


def _changes(steps, start=3.0):
    """Requests whose successive changes are ``steps`` (24 of them: the window)."""
    return np.concatenate([[start], start + np.cumsum(steps)])


def _buzzes(requests, **options) -> bool:
    safety = ForceSafety(12.0, 1e9, 0.001, **options)
    for r in requests:
        safety.step([r, 0.0, 0.0], True)
    return safety.buzzing


def test_the_buzz_needs_big_changes_past_2_percent_of_the_rated_force():
    """buzz_min is 2 % of 12 N, 0.24 N: alternating changes of 0.25 N are a buzz, of 0.23 N not,
    nor of 0.25 N when buzz_min_n is 0.3 N."""
    assert ForceSafety(12.0, 1e9, 0.001).buzz_min == pytest.approx(0.24)
    alternate = np.array([(-1) ** k for k in range(24)], float)
    assert _buzzes(_changes(0.25 * alternate))
    assert not _buzzes(_changes(0.23 * alternate))
    assert not _buzzes(_changes(0.25 * alternate), buzz_min_n=0.3)
    assert _buzzes(_changes(0.25 * alternate), buzz_min_n=0.2)


def test_a_change_of_exactly_buzz_min_is_not_big():
    alternate = np.array([(-1) ** k for k in range(24)], float)
    assert not _buzzes(_changes(0.25 * alternate), buzz_min_n=0.25)  # 0.25 is exact in binary
    assert _buzzes(_changes(0.25 * alternate), buzz_min_n=0.25 - 2**-20)


def test_the_buzz_needs_20_of_24_changes_big():
    """0.8 × 24 = 19.2: 20 big changes (and 4 small, all alternating) are a buzz, 19 are not."""
    for big, buzz in ((20, True), (19, False), (24, True)):
        sizes = np.array([1.0] * big + [0.1] * (24 - big))
        steps = sizes * np.array([(-1) ** k for k in range(24)])
        assert _buzzes(_changes(steps)) == buzz, big


def test_the_buzz_needs_19_of_23_sign_flips():
    """0.8 × 23 = 18.4: changes whose signs flip at 19 of the 23 successive pairs are a buzz, at
    18 not (each pair of equal signs in a row takes one flip away)."""

    def signs(repeats):
        out, s = [], 1.0
        for k in range(24):
            out.append(s)
            if k not in repeats:
                s = -s
        return np.array(out)

    assert np.sum(signs({1, 5, 9, 13})[1:] * signs({1, 5, 9, 13})[:-1] < 0) == 19
    assert _buzzes(_changes(signs({1, 5, 9, 13})))
    assert not _buzzes(_changes(signs({1, 5, 9, 13, 17})))


def test_zero_changes_do_not_count_as_sign_flips():
    """20 big alternating changes and 4 zero ones, placed so that 18 pairs flip sign and the 5
    pairs that touch a zero do not: no buzz (a zero is no change of direction)."""
    steps = np.array([(-1) ** k for k in range(24)], float)
    steps[[2, 8, 14, 20]] = 0.0
    flips = np.sum(np.sign(steps[1:]) * np.sign(steps[:-1]) < 0)
    assert flips == 15
    assert not _buzzes(_changes(steps))


# -- the watchdog and the scene's stop ---------------------------------------------------------------------


def test_fresh_feedback_is_rendered_until_the_watchdog_time_then_not():
    """Watchdog 0.25 s, feedback at t = 1: fresh through t = 1.25 exactly, stale after; one trip
    when it goes stale (not one per stale period); fresh again with the next message."""
    gate = FeedbackGate(0.25)
    assert gate.stopped is False and gate.arrived is None
    assert gate.state(0.0, False) == "waiting" and gate.trips == 0
    np.testing.assert_array_equal(gate.force, [0.0, 0.0, 0.0])
    assert math.isnan(gate.scene_time)
    assert gate.feedback([1.0, -2.0, 3.0], 0.5, 1.0)
    assert gate.state(1.0, False) == "ok" and gate.state(1.25, False) == "ok"
    np.testing.assert_array_equal(gate.force, [1.0, -2.0, 3.0])
    assert gate.scene_time == 0.5 and gate.arrived == 1.0
    assert gate.state(1.25 + 2**-20, False) == "watchdog" and gate.trips == 1
    assert gate.state(2.0, False) == "watchdog" and gate.trips == 1
    assert gate.feedback([0.0, 0.0, 1.0], 0.6, 2.0)
    assert gate.state(2.0, False) == "ok" and gate.trips == 1
    assert gate.state(3.0, False) == "watchdog" and gate.trips == 2


def test_the_stop_holds_until_the_next_feedback_and_outranks_the_clutch():
    gate = FeedbackGate(0.25)
    gate.feedback([1.0, 0.0, 0.0], 0.0, 0.0)
    assert gate.state(0.1, True) == "clutch"
    gate.stop()
    assert gate.stopped and gate.stops == 1
    assert gate.state(0.1, False) == "stopped" and gate.state(0.1, True) == "stopped"
    assert gate.state(5.0, False) == "stopped" and gate.trips == 1  # stale under the stop: still a trip
    gate.stop()
    assert gate.stops == 2
    gate.feedback([1, 0, 0], 0.1, 5.0)  # integers: still newtons as doubles
    assert gate.stopped is False and gate.state(5.0, False) == "ok" and gate.force.dtype == np.float64
    assert FeedbackGate(0.25).state(0.0, True) == "clutch"  # before any feedback too


@pytest.mark.parametrize(
    "force", [[math.nan, 0, 0], [0, math.inf, 0], [0, 0, -math.inf], [1.0, 2.0], [[1, 2, 3]]]
)
def test_feedback_that_is_not_three_finite_newtons_is_refused_and_changes_nothing(force):
    gate = FeedbackGate(0.25)
    gate.feedback([1.0, 0.0, 0.0], 0.0, 0.0)
    gate.stop()
    assert not gate.feedback(force, 1.0, 0.1)
    assert gate.stopped and gate.arrived == 0.0 and gate.scene_time == 0.0
    np.testing.assert_array_equal(gate.force, [1.0, 0.0, 0.0])
    assert gate.watchdog_s == 0.25
