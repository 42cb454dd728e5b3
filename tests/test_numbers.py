"""Numbers (issue 45): a run past its penetration budget says so at the end, whatever got it there;
a refusal names every limit passed; ``analyze --verify`` and ``run`` give one explicit limit, with
no numpy warning leaked."""

import json
import math
import warnings

import numpy as np
import pytest
from conftest import scenario, shared_run
from pydrake.math import RigidTransform, RotationMatrix

from godobject_drake import cli
from godobject_drake.config.scenario import shipped_scenario
from godobject_drake.limits import explicit_limit_omega_h
from godobject_drake.metrics import PenetrationBudgetWarning, penetration_verdict
from godobject_drake.studies.analyze import common as C
from godobject_drake.studies.analyze import verify as V

LIMIT_H = explicit_limit_omega_h(1.0)  # 0.8284 for ζ = 1


def test_a_run_past_its_penetration_budget_says_so_at_the_end(tmp_path):
    """At time_step 0.0069 s the brick scene's rotational coupling is at 99.95 % of its limit: the
    build predicts 0.074 mm (the capped pull), nothing is refused, and the run rings 8.5 mm into the
    wall against a 1 mm budget. It said nothing; now a warning line names the depth, the budget and
    the gain near its limit, and the metrics say so."""
    path = tmp_path / "m.json"
    with pytest.warns(PenetrationBudgetWarning) as said:
        assert (
            cli.main(["run", "lego", "--time-step", "0.0069", "--no-progress", "--metrics", str(path)]) == 0
        )
    text = " ".join(str(w.message) for w in said)
    m = json.loads(path.read_text())
    depth = m["max_penetration_m"]
    assert 0.005 < depth < 0.012 and m["predicted_static_penetration_m"] < 1e-4
    assert m["over_penetration_budget"] is True and m["penetration_budget_m"] == 0.001
    assert (
        f"the run went {depth * 1e3:.3g} mm into an obstacle, past its budget "
        "metrics.penetration_budget_m = 1 mm" in text
    )
    assert (
        "omega_n_rot 120 rad/s is at 99.95 %; omega_n 40 rad/s is at 33.32 % of its explicit stability limit"
        in text
    )
    assert "Lower the time step or that gain" in text


def test_the_position_baseline_is_over_its_budget_without_a_warning():
    """The position baseline imposes the device's pose: it goes into the wall by design (the
    paper's Fig. 5; 21 mm on the brick path). The metrics say it is over the budget; no warning
    tells the user to lower a gain that does not act."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning fails
        verdict = penetration_verdict({"max_penetration_m": 0.021}, scenario("lego", "--mode", "position"))
    assert verdict == {"penetration_budget_m": 0.001, "over_penetration_budget": True}
    with pytest.warns(PenetrationBudgetWarning):
        penetration_verdict({"max_penetration_m": 0.021}, scenario("lego"))


def test_a_run_within_its_budget_says_so_in_the_metrics():
    m = shared_run("lego").metrics  # the brick scene's default path, shared with other tests
    assert m["max_penetration_m"] < 0.001
    assert m["over_penetration_budget"] is False and m["penetration_budget_m"] == 0.001


def test_a_refusal_names_every_limit_passed(capsys):
    """At h = 0.0208 s both bandwidths are past the limit (ωn·h = 0.832, ωr·h = 2.496); the refusal
    named omega_n only, and its fix (time_step < 0.02071 s) was still refused for omega_n_rot."""
    with pytest.raises(SystemExit) as ended:
        cli.main(["run", "lego", "--time-step", "0.0208", "--no-progress"])
    assert ended.value.code == 2
    err = capsys.readouterr().err
    assert "omega_n=40 rad/s at time_step=0.0208 s gives ωn·h=0.832, past the explicit" in err
    assert "omega_n_rot=120 rad/s gives ωn·h=2.496, past the explicit" in err
    assert "Use omega_n < 39.83 rad/s and omega_n_rot < 39.83 rad/s, or time_step < 0.006904 s." in err
    with pytest.raises(SystemExit):
        cli.main(["run", "lego", "--omega-n", "1000", "--no-progress"])  # the rotation keeps its ratio: 3000
    err = capsys.readouterr().err
    assert "omega_n=1000 rad/s" in err and "omega_n_rot=3000 rad/s gives ωn·h=3" in err
    assert "Use omega_n < 828.4 rad/s and omega_n_rot < 828.4 rad/s, or time_step < 0.0002761 s." in err


def _pull(scale: float) -> bool:
    """The explicit limit's verification at ``scale`` × the brick scene's bandwidths (both 40 rad/s)."""
    s = shipped_scenario("lego", "god_object: {gains: {omega_n_rot: 40}}")
    base = V._without_haptics(C.analysis_scenario(s))
    station = C._quiet_build(base)
    body = C._held_body(station)
    away = -V._nearest_fixed_obstacle(station, body)[1]
    X0 = V._start_pose(station, body)
    X1 = RigidTransform(
        X0.rotation().multiply(RotationMatrix.MakeXRotation(np.radians(10.0))), X0.translation() + 0.03 * away
    )
    return V.hold_is_stable(base, body.name, X0, X1, V._scaled(base.god_object.gains, scale), 0.05 + 0.6)


def test_a_body_thrown_still_past_the_limit_is_not_read_as_stable():
    """Past the limit (1.06 x: ωn·h = 0.88 against 0.8284) the brick blows up, is thrown into the
    table and stops there 3.9 cm from its target: no motion was read as stable, and the bisection
    put Drake's boundary at 25 x 40 = 1004 rad/s where run refuses past 828.4. Below it (0.9 x)
    the brick settles on its target."""
    scale = LIMIT_H / (40 * 0.001)  # 20.71: the model's limit
    assert _pull(0.9 * scale) is True
    assert _pull(1.06 * scale) is False


@pytest.mark.slow(seconds=90)
def test_analyze_and_run_give_the_same_explicit_limit(tmp_path, capsys):
    """``godobject analyze lego --verify --set god_object.gains.omega_n_rot=40``: Drake's boundary
    now agrees with the model (the limit run enforces, 828.4 rad/s at 1 ms), and neither numpy's
    overflow warning nor a penetration warning from the analysis's own runs is printed."""
    code = cli.main(
        ["analyze", "lego", "--out", str(tmp_path), "--verify", "--set", "god_object.gains.omega_n_rot=40"]
    )
    out, err = capsys.readouterr()
    assert code == 0, out + err
    summary = json.loads((tmp_path / "summary.json").read_text())
    v = summary["verify_explicit_limit"]
    assert v["predicted_scale"] == pytest.approx(LIMIT_H / 0.04)
    assert abs(v["relative_error"]) <= 0.02  # Drake's boundary within 2 % of 828.4 rad/s
    assert 40 * v["simulated_scale"] <= 1.02 * LIMIT_H / 0.001
    assert "model and Drake agree" in out and "trust Drake's boundary" not in out
    assert "RuntimeWarning" not in err and "overflow" not in err and "PenetrationBudgetWarning" not in err
    assert math.isfinite(v["simulated_scale"])
