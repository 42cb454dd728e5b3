"""What the studies ask of each tool kind, keyed by the kind's name (``GodObject.kind``).

The station's tool kinds (:mod:`godobject_drake.station.kinds`) answer what building and running a
scene asks; the studies' questions are answered here, one :class:`StudyKind` per kind in
:data:`STUDY_KINDS`: the words of a benchmark run's label, the speed report's columns, the body
whose pose is "the god-object's pose", whether the brick scene's engine-neutral errors apply, and
how :mod:`~godobject_drake.studies.analyze` models the kind's loop. :func:`study_kind` is the one
look-up; a kind with no entry is refused, naming it and the entry to add.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from godobject_drake.config.scenario import Scenario

# The speed report's columns a tool kind fills (the rest stay None).
COLUMNS = ("contact", "approximation", "coupling", "shell", "bricks", "sleep")


def columns(**given) -> dict:
    """The speed report's kind columns (:data:`COLUMNS`), None but for ``given``."""
    unknown = set(given) - set(COLUMNS)
    if unknown:
        raise ValueError(f"study columns {sorted(unknown)}: a kind fills only {COLUMNS}")
    return {**dict.fromkeys(COLUMNS), **given}


def no_words(scenario: Scenario) -> list[str]:
    """A label part a kind leaves empty."""
    return []


@dataclasses.dataclass(frozen=True)
class StudyKind:
    """What the studies ask of one tool kind.

    Attributes
    ----------
    describe : Callable[[Scenario], list[str]]
        The words of a run's label that say what the kind varies (after ``h=...``).
    study_config : Callable[[Scenario], dict]
        What it varies, as the speed report's columns (:func:`columns`).
    pose_body : Callable[[Scenario, set[str]], str]
        The body whose pose is "the god-object's pose" in a study; its second argument: the grasp
        names the device reports.
    loop_model : Callable[[object], str]
        How ``analyze`` models the loop, from the tool's config (``scenario.god_object``):
        ``body`` (each held body's explicit spring, symplectic Euler), ``implicit_body`` (SAP's
        backward Euler on it) or ``joint`` (the articulated tool's joint-space loop);
        :data:`godobject_drake.studies.analyze.LOOPS` says what each is checked with.
    describe_tail : Callable[[Scenario], list[str]]
        The words a run's label ends with (after the device rate and brick count); none by default.
    compares_engines : bool
        Whether the brick scene's engine-neutral errors apply to its runs (no by default).
    """

    describe: Callable[[Scenario], list[str]]
    study_config: Callable[[Scenario], dict]
    pose_body: Callable[[Scenario, set[str]], str]
    loop_model: Callable[[object], str]
    describe_tail: Callable[[Scenario], list[str]] = no_words
    compares_engines: bool = False


# -- the rigid kind: free bodies a pose device grasps --------------------------------------------------


def _rigid_describe(scenario: Scenario) -> list[str]:
    parts = [scenario.contact.geometry, scenario.plant.discrete_contact_approximation]
    if scenario.god_object.coupling != "explicit":  # the explicit coupling's labels stay as they were
        parts.append(scenario.god_object.coupling)
    return parts


def _rigid_tail(scenario: Scenario) -> list[str]:
    return [] if scenario.sleep.enabled else ["awake"]


def _rigid_config(scenario: Scenario) -> dict:
    return columns(
        contact=scenario.contact.geometry,
        approximation=scenario.plant.discrete_contact_approximation,
        coupling=scenario.god_object.coupling,
        bricks=max(scenario.bricks, 8),
        sleep=scenario.sleep.enabled,
    )


def first_grasp(scenario: Scenario, grasp_names) -> str:
    """The first body the device grasps (by name)."""
    names = sorted(grasp_names)
    if not names:
        raise ValueError("the scenario's device grasps no body: no god-object pose to compare")
    return names[0]


def _rigid_loop(config) -> str:
    # The implicit coupling's springs are SAP constraints (station.rigid_tool.ImplicitGodObject).
    return "implicit_body" if config.coupling == "implicit" else "body"


RIGID = StudyKind(
    describe=_rigid_describe,
    study_config=_rigid_config,
    pose_body=first_grasp,
    loop_model=_rigid_loop,
    describe_tail=_rigid_tail,
    compares_engines=True,
)

# -- the articulated kind: a tree model a joint-space device drives -------------------------------------

ARTICULATED = StudyKind(
    describe=lambda scenario: [scenario.god_object.coupling],
    study_config=lambda scenario: columns(coupling=scenario.god_object.coupling),
    pose_body=lambda scenario, grasp_names: scenario.god_object.tip_body,  # the tool's tip body
    loop_model=lambda config: "joint",
)

# -- the deformable kind: a rigid core carrying a shell ----------------------------------------------

DEFORMABLE = StudyKind(
    describe=lambda scenario: [scenario.god_object.shell],
    study_config=lambda scenario: columns(shell=scenario.god_object.shell),
    pose_body=lambda scenario, grasp_names: scenario.god_object.name,  # the probe's core
    loop_model=lambda config: "body",
)

# Each tool kind's answers, by its name (``GodObject.kind``). A kind of one's own adds its entry:
# ``STUDY_KINDS["mine"] = StudyKind(...)`` (or ``dataclasses.replace(RIGID, ...)``).
STUDY_KINDS: dict[str, StudyKind] = {"rigid": RIGID, "articulated": ARTICULATED, "deformable": DEFORMABLE}


def study_kind(kind: str) -> StudyKind:
    """What the studies ask of the tool kind named ``kind``; a kind with no entry is refused."""
    entry = STUDY_KINDS.get(kind)
    if entry is None:
        raise ValueError(
            f"tool kind {kind!r} has no study entry (the kinds with one: {', '.join(STUDY_KINDS)}): add "
            f"godobject_drake.studies.kinds.STUDY_KINDS[{kind!r}] = StudyKind(...) to run the studies on it"
        )
    return entry
