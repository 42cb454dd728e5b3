"""The stability and passivity report of any scenario: ``python -m godobject_drake analyze``.

:func:`analyze` reads the models of :mod:`godobject_drake.studies.stability` off a built scene (each
god-object body's mass and inertia, the plant's step, the coupling's gains and caps, the
contact stiffness of every pair the held body can touch, the haptic device's rate, mass and
damping and the feedback gains) and returns one :class:`Check` per question, each with a
verdict (``ok``, ``warn``, ``fail`` or ``info``), its number, its limit, the change that fixes
it (``fix``) and what it rests on (``why``). With ``verify`` it simulates each prediction in
Drake on the user's own scene:

- the static penetration, by holding the target 5 cm inside the nearest fixed obstacle;
- the explicit limit, by bisecting a scale on the coupling's gains until the held body's motion
  grows instead of decaying.

:func:`write_report` writes ``report.md``, ``summary.json`` and ``margins.png`` (when a row has a
value and an upper limit). The JSON
keys are documented in docs/guide/stability.md, "Analysing your own scene". The theory is docs/theory.md.

The checks, by concern, each a module of this package:

- ``common``: the verdict table's row (:class:`Check`), the headless build and run, the grasped bodies;
- ``pose_tool``, ``implicit``, ``articulated``: a tool's own loop (the explicit limit per body and
  axis; the implicit coupling's decay rate and SAP's regime; the joint-space limit);
- ``tissue``, ``contact``, ``device``: the FEM organ under the tool, the static penetration (of
  one tool, and between two tools' held bodies), the haptic device's loop;
- ``verify``, ``verify_joint``: the predictions simulated in Drake (``--verify``), for a pose tool
  and for an articulated one;
- ``loops``: :data:`LOOPS`, what each loop model (a tool kind's, :mod:`godobject_drake.studies.kinds`)
  is checked with;
- ``report``: :func:`verdict_table` and :func:`write_report`.
"""

from __future__ import annotations

import time

from godobject_drake.config import scenario as sc
from godobject_drake.studies.analyze.common import (
    VERDICTS,
    WARN_FRACTION,
    Check,
    _quiet_build,
    analysis_scenario,
    loop_model,
)
from godobject_drake.studies.analyze.contact import _between_tools, _contact_checks
from godobject_drake.studies.analyze.implicit import IMPLICIT_RATE_FLOOR, implicit_rate
from godobject_drake.studies.analyze.loops import LOOPS, Loop
from godobject_drake.studies.analyze.report import verdict_table, write_report
from godobject_drake.studies.analyze.soft_bodies import _soft_body_checks, _verify_soft_bodies
from godobject_drake.studies.analyze.tissue import _tissue_checks
from godobject_drake.studies.analyze.verify import (
    IMPLICIT_STEP_M,
    PUSH_IN_M,
    REACH_FRACTION,
    _verify_device_boundary,
    _verify_penetration,
    hold_is_stable,
)
from godobject_drake.studies.analyze.verify_joint import _verify_tissue

__all__ = [
    "IMPLICIT_RATE_FLOOR",
    "IMPLICIT_STEP_M",
    "LOOPS",
    "PUSH_IN_M",
    "REACH_FRACTION",
    "VERDICTS",
    "WARN_FRACTION",
    "Check",
    "Loop",
    "analysis_scenario",
    "analyze",
    "hold_is_stable",
    "implicit_rate",
    "loop_model",
    "verdict_table",
    "write_report",
]


def analyze(scenario: sc.Scenario, *, quick: bool = False, verify: bool | None = None) -> dict:
    """Every check of ``scenario`` (module docstring) as a JSON-ready dict: ``checks`` (the
    verdict table's rows, :class:`Check`), the numbers behind them, and ``verdict`` (the worst).
    ``verify`` None: on unless ``quick``."""
    start = time.perf_counter()
    verify = (not quick) if verify is None else verify
    s = analysis_scenario(scenario)
    records = sc.check_scenario(s)
    if s.tools:
        return _analyze_tools(s, records, quick, verify, start)
    station = _quiet_build(s)
    out: dict = {
        "scene": s.name,
        "kind": station.god_object.kind,
        "time_step_s": s.time_step,
        "quick": quick,
        "verify": verify,
    }
    loop = LOOPS[loop_model(station)]
    checks = loop.checks(station, out)
    checks += _contact_checks(station, s, out)
    checks += _tissue_checks(station, s, out)
    checks += _soft_body_checks(station, s, out)
    checks += loop.device_checks(station, s, out)
    if verify:
        tol = 0.02 if quick else 0.005
        for row in (_verify_penetration(station, s, out), loop.verify(station, s, out, tol),
                    _verify_device_boundary(station, s, out, tol)):  # fmt: skip
            if row is not None:
                checks.append(row)
        checks += _verify_tissue(station, s, out)
        checks += _verify_soft_bodies(station, s, out)
    order = {"fail": 3, "warn": 2, "ok": 1, "info": 0}
    out.pop("_tissue_press", None)
    out["checks"] = [c.as_dict() for c in checks]
    out["verdict"] = max((c.verdict for c in checks), key=order.__getitem__, default="ok")
    out["elapsed_s"] = time.perf_counter() - start
    return out


def _analyze_tools(s: sc.Scenario, records: dict, quick: bool, verify: bool, start: float) -> dict:
    """A scene of several tools: each tool's rows from its own view of the scene (its loop, its
    contacts, its device; the other tools' models there as bodies no loop drives), named by the
    tool, under ``tools``; then the contact between each two tools' held bodies."""
    out: dict = {"scene": s.name, "time_step_s": s.time_step, "quick": quick, "verify": verify, "tools": {}}
    checks: list[dict] = []
    for name, record in records.items():
        own = analyze(record.view, quick=quick, verify=verify)
        for row in own["checks"]:
            row["subject"] = f"{name}: {row['subject']}"
        out["tools"][name] = own
        checks += own["checks"]
    out["kind"] = ", ".join(f"{name} {own['kind']}" for name, own in out["tools"].items())
    checks += [c.as_dict() for c in _between_tools(_quiet_build(s), s)]
    order = {"fail": 3, "warn": 2, "ok": 1, "info": 0}
    out["checks"] = checks
    out["verdict"] = max((c["verdict"] for c in checks), key=order.__getitem__, default="ok")
    out["elapsed_s"] = time.perf_counter() - start
    return out
