"""The report script end to end on its quick grid, as a user runs it."""

import json
import subprocess
import sys

import pytest
from conftest import REPO

KEYS = {
    "explicit_limit",
    "colgate",
    "llewellyn",
    "device_boundary",
    "passivity",
    "recommended_gains",
    "h_max",
}


@pytest.mark.slow
def test_stability_report_quick(tmp_path):
    out = tmp_path / "stability"
    subprocess.run(
        [sys.executable, str(REPO / "analysis" / "stability_report.py"), "--out", str(out), "--quick"],
        check=True,
        cwd=tmp_path,
    )
    summary = json.loads((out / "summary.json").read_text())
    assert KEYS <= set(summary)
    # --quick's grid (analysis/stability_report.py): 2 explicit-limit cases, 1 device boundary,
    # 2 energy runs, 6 walls and 3 pipelines for Colgate, 4 gain pairs for Llewellyn. Every loop
    # below runs over a non-empty list, so none can pass by having nothing to check.
    counts = {key: len(summary[key]) for key in ("explicit_limit", "device_boundary", "passivity", "colgate",
                                                 "llewellyn")}  # fmt: skip
    assert counts == {"explicit_limit": 2, "device_boundary": 1, "passivity": 2, "colgate": 9, "llewellyn": 4}
    # Drake's bisection against the closed form: measured ±0.044 % (Drake 1.51.1, --quick), the
    # bisection's own tolerance being 0.1 %; 2 % is the acceptance bound, 45× the measurement.
    for e in summary["explicit_limit"]:
        assert abs(e["k_crit_simulated"] / e["k_crit_predicted"] - 1) < 0.02
    # Drake's bisection against the poles of the sampled device loop: measured +0.005 %; 5 % is
    # the acceptance bound for a boundary found by simulation (the README quotes the full run's 0.01 %).
    for e in summary["device_boundary"]:
        assert abs(e["simulated"] / e["predicted"] - 1) < 0.05
    walls = [c for c in summary["colgate"] if c["label"] == "wall" and c["delay"] == 0]
    assert len(walls) == 4 and all(abs(c["required_b"] / c["closed_form"] - 1) < 1e-6 for c in walls)
    # Llewellyn rows by their gains, not their labels: η_min = 1 exactly for (kd, γd) ∝ (k, γ)
    # (docs/theory.md §2), and < 1 with γd = 0.
    rows = summary["llewellyn"]
    (proportional,) = [
        r for r in rows if r["gamma_d"] > 0 and abs(r["kd"] * r["gamma"] - r["gamma_d"] * r["k"]) < 1e-9
    ]
    (undamped,) = [r for r in rows if r["gamma_d"] == 0.0]
    assert abs(proportional["eta_min"] - 1) < 1e-9
    assert undamped["eta_min"] < 1
    verdicts = {c["verdict"] for c in summary["passivity"]}
    assert verdicts == {"passive", "active"}  # one of each, so both branches below are exercised
    for c in summary["passivity"]:
        if c["verdict"] == "passive":
            assert c["energy_to_user_max_J"] <= 1e-12
        else:
            assert c["energy_to_user_end_J"] > 0
    report = (out / "report.md").read_text()
    for fig in ("body_regions", "k_crit", "colgate", "margin_maps", "llewellyn", "impedance", "energy"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
        assert f"({fig}.png)" in report
