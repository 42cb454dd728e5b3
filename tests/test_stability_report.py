"""The report script end to end on its quick grid, as a user runs it."""

import json
import subprocess
import sys

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


def test_stability_report_quick(tmp_path):
    out = tmp_path / "stability"
    subprocess.run(
        [sys.executable, str(REPO / "analysis" / "stability_report.py"), "--out", str(out), "--quick"],
        check=True,
        cwd=tmp_path,
    )
    summary = json.loads((out / "summary.json").read_text())
    assert KEYS <= set(summary)
    for e in summary["explicit_limit"]:
        assert abs(e["k_crit_simulated"] / e["k_crit_predicted"] - 1) < 0.02
    for e in summary["device_boundary"]:
        assert abs(e["simulated"] / e["predicted"] - 1) < 0.05
    walls = [c for c in summary["colgate"] if c["label"] == "wall" and c["delay"] == 0]
    assert walls and all(abs(c["required_b"] / c["closed_form"] - 1) < 1e-6 for c in walls)
    labels = {c["label"]: c for c in summary["llewellyn"]}
    assert abs(labels["proportional (kd,γd) = (k,γ)/80"]["eta_min"] - 1) < 1e-9
    assert labels["γd = 0"]["eta_min"] < 1
    for c in summary["passivity"]:
        if c["verdict"] == "passive":
            assert c["energy_to_user_max_J"] <= 1e-12
        else:
            assert c["energy_to_user_end_J"] > 0
    report = (out / "report.md").read_text()
    for fig in ("body_regions", "k_crit", "colgate", "margin_maps", "llewellyn", "impedance", "energy"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
        assert f"({fig}.png)" in report
