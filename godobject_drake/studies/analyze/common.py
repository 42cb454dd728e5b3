"""What every check of ``analyze`` shares: the verdict table's row (:class:`Check`), its verdicts
and the bounds a fix names, the headless scenario and station the analysis builds and runs, the
bodies the device grasps, and the loop model of the station's tool (its kind's study entry)."""

from __future__ import annotations

import dataclasses
import warnings

from godobject_drake.config import scenario as sc
from godobject_drake.config.gains import CouplingGainWarning
from godobject_drake.metrics import PenetrationBudgetWarning
from godobject_drake.safeguards import UnsupportedBodyWarning
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.station.rigid_tool import grasped_bodies
from godobject_drake.studies.kinds import study_kind

WARN_FRACTION = 0.8  # a number past 80 % of its limit (less than 25 % margin) warns


VERDICTS = ("ok", "warn", "fail", "info")


@dataclasses.dataclass
class Check:
    """One row of the verdict table.

    ``value`` and ``limit`` are in ``unit`` (None where the row has none: an ``info`` row, or a
    loop with no limit); ``verdict`` is ``ok``, ``warn`` (within 25 % of the limit), ``fail``
    (past it) or ``info`` (nothing to judge). ``fix`` says only what to change for the row to
    pass (empty when nothing needs changing); ``why`` what the row rests on: the model's terms,
    the reason an ``info`` row judges nothing, how the verification compares.
    ``predicted`` and ``simulated`` are the verification's pair, when it ran.
    """

    section: str
    name: str
    subject: str
    verdict: str
    value: float | None
    limit: float | None
    unit: str
    fix: str
    predicted: float | None = None
    simulated: float | None = None
    bound: str = "upper"  # "upper": passes with value below limit; "lower": at or above it
    why: str = ""

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def _le(x: float) -> str:
    """An upper bound for a fix, rounded to 4 digits on the safe side (down)."""
    return f"{x * (1 - 1e-3):.4g}"


def _ge(x: float) -> str:
    """A lower bound for a fix, rounded to 4 digits on the safe side (up)."""
    return f"{x * (1 + 1e-3):.4g}"


def _verdict_below(value: float, limit: float) -> str:
    """``value`` must stay below ``limit``."""
    if not value < limit:
        return "fail"
    return "warn" if value > WARN_FRACTION * limit else "ok"


def _quiet_build(scenario: sc.Scenario):
    """The scenario's station, built for analysis: no Meshcat, gains past the limit allowed."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PenetrationBudgetWarning)
        warnings.simplefilter("ignore", CouplingGainWarning)
        return build_station(scenario, meshcat=None, check_gains=False)


def _probe(station):
    """One of the analysis's own runs in Drake: they push into obstacles and past the limits on
    purpose, so the run-end :class:`PenetrationBudgetWarning` (meant for the user's run) is not said;
    and they run each tool of a scene alone, where a body another tool holds falls, so neither is
    :class:`UnsupportedBodyWarning`."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PenetrationBudgetWarning)
        warnings.simplefilter("ignore", UnsupportedBodyWarning)
        return simulate(station, progress=False)


def analysis_scenario(scenario: sc.Scenario) -> sc.Scenario:
    """``scenario`` made headless: no recording, no page served, a live or LCM device replaced
    by a scripted one standing at its start (the analysis needs no browser and no driver)."""
    s = sc.replace(
        scenario,
        **{
            "recording.file": "",
            "recording.device_log": "",
            "visualization.serve": False,
            "metrics.file": "",
        },
    )
    s.device = s.device.stand_in()  # the device kind's own (device_kinds): no browser, no driver
    for tool in s.tools.values():
        tool.device = tool.device.stand_in()
    return s


def _bodies(n: int) -> str:
    return f"{n} body" if n == 1 else f"{n} bodies"


def _grasped(station) -> list:
    """The coupling's bodies the device grasps by its path (all, for a live device or ``*``)."""
    return grasped_bodies(station.coupling, station.device, station.scenario.simulation.duration_s)


def _held_body(station):
    """The body the scenario's device grasps first, else the lightest it may hold."""
    coupling = station.coupling
    names = sorted(station.device.grasp_names(station.scenario.simulation.duration_s) - {"*"})
    if names:
        return coupling.body_for_grasp(names[0])
    return min({b.index: b for b in coupling.bodies.values()}.values(), key=lambda b: b.mass)


def loop_model(station) -> str:
    """How the station's tool's loop is modelled: its kind's study entry
    (:attr:`~godobject_drake.studies.kinds.StudyKind.loop_model`) on its config."""
    return study_kind(station.god_object.kind).loop_model(station.scenario.god_object)
