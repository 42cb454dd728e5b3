"""analysis/cenic_trial.py (issue 31, part 3): CENIC against SAP on the brick scene, end to end on
the path's first half second, as a user runs it."""

import json
import subprocess
import sys
from importlib.metadata import version

import pytest
from conftest import REPO
from pydrake.systems.analysis import GetIntegrationSchemes

SCRIPT = str(REPO / "analysis" / "cenic_trial.py")
DRAKE = version("drake")
NO_CENIC = (
    f"Drake {DRAKE} has no 'cenic' integration scheme (GetIntegrationSchemes()); the project's pins, "
    "1.51.1 and 1.58.0, both have it: pip install -e . installs the one for your Python"
)


@pytest.mark.slow(seconds=15)
@pytest.mark.skipif("cenic" not in GetIntegrationSchemes(), reason=NO_CENIC)
def test_trial_short_path(tmp_path):
    out = tmp_path / "results.json"
    duration = 0.5
    run = subprocess.run(
        [sys.executable, SCRIPT, "--duration", str(duration), "--no-baseline", "--sap-steps", "0.001",
         "--accuracies", "0.01", "--sanity", "--out", str(out)],
        capture_output=True, text=True, cwd=tmp_path, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "| SAP h=1 ms |" in run.stdout and "| cenic accuracy=0.01 |" in run.stdout  # the table
    report = json.loads(out.read_text())
    assert report["machine"]["drake"] == DRAKE and report["machine"]["nproc"] >= 1
    rows = {row["label"]: row for row in report["rows"]}
    assert set(rows) == {"SAP h=1 ms", "cenic accuracy=0.01"}
    sap, cenic = rows["SAP h=1 ms"], rows["cenic accuracy=0.01"]
    for row in (sap, cenic):
        assert not row["diverged"] and row["error"] is None and not row["stopped_early"]
        assert row["sim_time_s"] == pytest.approx(duration)
        assert row["cpu_s_per_sim_s"] > 0
    assert sap["steps"] == round(duration / 0.001)
    # What bounds CENIC's step on this scene: the 60 Hz device's samples and the coupling's grasp
    # check 1 µs after each are events, so a step never spans a device period and every period
    # takes at least two steps (one of them 1 µs long).
    period = 1 / 60
    assert cenic["largest_step_s"] <= period * (1 + 1e-9)
    assert cenic["steps"] >= 2 * int(duration / period)
    # Both measured the same logs the same way: every step's state for the penetration (the path's
    # first 0.5 s lifts the brick off the table, touching nothing else), one sample per device period
    # for the tracking.
    for row in (sap, cenic):
        run0 = row["runs"][0]
        assert run0["logged_rows"] == row["steps"] + 1
        assert row["max_penetration_m"] < 1e-4
        assert row["rms_tracking_error_m"] is None or row["rms_tracking_error_m"] < 0.01


@pytest.mark.slow(seconds=5)
def test_trial_refuses_an_unknown_scheme(tmp_path):
    """A scheme this Drake does not have is refused before anything runs, naming the version and
    the schemes it has and where to get cenic (both of the project's Drake pins have it)."""
    run = subprocess.run(
        [sys.executable, SCRIPT, "--sanity", "no_such_scheme", "--out", str(tmp_path / "r.json")],
        capture_output=True, text=True, cwd=tmp_path, timeout=60,
    )  # fmt: skip
    assert run.returncode == 2
    assert f"'no_such_scheme' is not in this Drake ({DRAKE})" in run.stderr
    assert "runge_kutta3" in run.stderr and "Both of the project's Drake pins have cenic" in run.stderr
    assert not (tmp_path / "r.json").exists()
