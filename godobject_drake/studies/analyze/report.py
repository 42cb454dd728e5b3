"""The report of an analysis: the verdict table as Markdown (:func:`verdict_table`), and
``report.md``, ``summary.json`` and, when a row has a value and an upper limit to draw,
``margins.png`` (:func:`write_report`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from godobject_drake.studies.analyze.common import WARN_FRACTION


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return str(v)


def verdict_table(summary: dict) -> str:
    """The verdict table as Markdown."""
    lines = ["| verdict | check | subject | value | limit | unit | predicted | simulated | fix | why |",
             "|---|---|---|---:|---:|---|---:|---:|---|---|"]  # fmt: skip
    for c in summary["checks"]:
        cells = [c["verdict"], c["name"], c["subject"], _fmt(c["value"]), _fmt(c["limit"]), c["unit"],
                 _fmt(c["predicted"]), _fmt(c["simulated"]), c["fix"], c.get("why", "")]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def header(summary: dict, figure: bool) -> list[str]:
    """The report's opening: the verdict, each term of the run that made it, what the columns hold."""
    quick = summary["quick"]
    return [
        f"# Stability and passivity of `{summary['scene']}` ({summary['kind']} god-object)",
        "",
        f"Verdict: **{summary['verdict']}** (the worst row's).",
        "",
        f"- h = {summary['time_step_s']:g} s: the plant's time step (`plant.time_step`), the step every "
        "limit below is for.",
        f"- {'quick analysis (`--quick`)' if quick else 'full analysis'}: "
        + ("its Drake checks (with `--verify`) bisect to 2 %, not 0.5 %." if quick
           else "its Drake checks bisect to 0.5 % (2 % with `--quick`)."),
        "- " + ("checked in Drake: each prediction simulated (`predicted` against `simulated`)."
                if summary["verify"] else
                "not checked in Drake: the predictions are not simulated (`--verify` runs them)."),
        f"- {summary['elapsed_s']:.1f} s: the wall time the analysis took.",
        "",
        "A row passes (`ok`) with more than 25 % margin, `warn`s within 25 % of its limit, `fail`s past it;",
        "`info` rows judge nothing (`why` says why). `value` and `limit` are in `unit`; a decay rate or",
        "passivity row passes at or above its limit, the others below it. `fix` says what to change (the",
        "bound that keeps the row passing); `why` what the row rests on.",
        "",
        verdict_table(summary),
        "",
        "![how close each row is to its limit](margins.png)" if figure else
        "No row has a value and an upper limit to draw, so there is no `margins.png`.",
        "",
    ]  # fmt: skip


def write_report(summary: dict, out_dir: str | Path) -> Path:
    """``report.md``, ``summary.json`` and ``margins.png`` (the rows with a value and an upper
    limit, each as value / limit; none, and a stale one removed, when no row has both) in
    ``out_dir``; returns the report's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    figure = _margins_figure(summary, out / "margins.png")
    md = header(summary, figure)
    if summary.get("explicit") and "axis" in summary["explicit"][0]:
        md += ["## Explicit limit per body and axis", "",
               "| body | axis | inertia (kg, kg·m²) | ω (rad/s) | ζ | ω·h | limit | radius | h_max (s) |",
               "|---|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
        for r in summary["explicit"]:
            md.append(f"| {r['body']} | {r['axis']} | {r['inertia']:.4g} | {r['omega_rad_s']:.4g} "
                      f"| {r['zeta']:.3g} "
                      f"| {r['omega_h']:.4g} | {r['omega_h_limit']:.4g} | {r['spectral_radius']:.5f} "
                      f"| {r['h_max_s']:.4g} |")  # fmt: skip
        md.append("")
    (out / "report.md").write_text("\n".join(md))
    return out / "report.md"


def plotted_rows(summary: dict) -> list[dict]:
    """The rows ``margins.png`` draws: a value and an upper limit, not a verification's."""
    return [
        c for c in summary["checks"]
        if c["value"] is not None and c["limit"] and c["section"] != "verify" and c["bound"] == "upper"
    ]  # fmt: skip


def _margins_figure(summary: dict, path: Path) -> bool:
    """Draw :func:`plotted_rows` at ``path``; with none, draw nothing (and remove an older figure
    there). Whether it drew."""
    rows = plotted_rows(summary)
    if not rows:
        path.unlink(missing_ok=True)
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 0.45 * len(rows) + 1.4))
    colors = {"ok": "tab:green", "warn": "tab:orange", "fail": "tab:red"}
    ratios = [c["value"] / c["limit"] for c in rows]
    ax.barh(range(len(rows)), ratios, color=[colors.get(c["verdict"], "grey") for c in rows])
    ax.axvline(1.0, color="k", lw=1)
    ax.axvline(WARN_FRACTION, color="k", lw=0.5, ls="--")
    labels = [f"{c['subject']}: {c['name']}" for c in rows]  # the subject first: a long name is cut
    ax.set_yticks(range(len(rows)), [x if len(x) <= 70 else x[:69] + "…" for x in labels], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("value / limit (past 1: fails; past 0.8: warns)")
    ax.set_title(f"{summary['scene']}: how close each check is to its limit")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
