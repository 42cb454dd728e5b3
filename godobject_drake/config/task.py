"""A task's success rules, declared in its scenario (``task:``): which object must end on which peg,
what counts as on a peg, and how the run is scored (the FLS peg transfer's score by default).

Plain config types (no Drake system): the names are checked against the plant when the station is
built (:func:`godobject_drake.task_score.resolve_task`), the score is computed from the run's
states and the jaws' grasp events (:mod:`godobject_drake.task_score`). docs/guide/peg_transfer.md
says where each rule comes from.
"""

import dataclasses
import math

# The FLS peg transfer's published lines: a trial is cut at 300 s, and the proficiency level is
# 48 s with no object dropped (Fundamentals of Laparoscopic Surgery manual skills test).
FLS_CUTOFF_S = 300.0
FLS_PROFICIENCY_S = 48.0


@dataclasses.dataclass
class OnPeg:
    """When an object is on a peg: its origin within ``radius_m`` of the peg's axis (the peg body's
    frame's z axis, its origin at the peg's foot) and between the foot and ``height_m`` above it.

    Attributes
    ----------
    radius_m : float
        The largest distance of the object's origin from the peg's axis (m). For a ring, more than
        the play of its hole about the peg and less than its outer radius plus the peg's: threaded
        or not is then unambiguous.
    height_m : float
        The peg's height above its foot (m): an object above it is off the peg.
    """

    radius_m: float = 0.004
    height_m: float = 0.022

    def check(self) -> None:
        for name in ("radius_m", "height_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(
                    f"on_peg.{name}: {value!r}; give a finite length > 0 in m (the peg transfer's: "
                    f"{getattr(OnPeg(), name):g})"
                )


@dataclasses.dataclass
class Task:
    """A task's success rules and score (``task:``); empty ``objects``: no task, no task score.

    Attributes
    ----------
    objects : list[str]
        The free bodies the task moves (``model::body``).
    targets : list[str]
        The peg each object must end on, in the order of ``objects`` (``model::body`` of a body
        whose frame is the peg's foot, z along its axis).
    pegs : list[str]
        Every peg of the board (``model::body``): an object on any of them is not dropped. Each
        target must be one of them.
    on_peg : OnPeg
        What "on a peg" is, geometrically.
    settle_s : float
        An object out of every jaw and off every peg for this long is dropped (s): one drop per
        such spell (a ring let go just above its peg lands within it and is not dropped).
    cutoff_s : float
        The trial's cut (s): the score is ``max(0, cutoff_s - time - drop_penalty_s * drops)``.
    proficiency_s : float
        Proficient: done within this (s) with no drop.
    drop_penalty_s : float
        What each drop costs the score (s).
    """

    objects: list[str] = dataclasses.field(default_factory=list)
    targets: list[str] = dataclasses.field(default_factory=list)
    pegs: list[str] = dataclasses.field(default_factory=list)
    on_peg: OnPeg = dataclasses.field(default_factory=OnPeg)
    settle_s: float = 0.3
    cutoff_s: float = FLS_CUTOFF_S
    proficiency_s: float = FLS_PROFICIENCY_S
    drop_penalty_s: float = 10.0

    def check(self) -> None:
        """Raise ``ValueError`` as ``"field: value, limit and fix"`` (the names are the plant's to
        check: :func:`godobject_drake.task_score.resolve_task`)."""
        if not self.objects and not self.targets:
            return
        if len(self.targets) != len(self.objects):
            raise ValueError(
                f"targets: {len(self.targets)} pegs for {len(self.objects)} objects; give one target peg per "
                "object, in the order of task.objects"
            )
        for field in ("objects", "pegs"):
            names = getattr(self, field)
            twice = sorted({n for n in names if names.count(n) > 1})
            if twice:
                raise ValueError(f"{field}: {', '.join(map(repr, twice))} named twice; name each once")
        strays = [t for t in self.targets if t not in self.pegs]
        if strays:
            raise ValueError(
                f"targets: {', '.join(map(repr, strays))} not in task.pegs; list every peg of the board in "
                "task.pegs (an object on any of them is not dropped)"
            )
        self.on_peg.check()
        for name in ("settle_s", "cutoff_s", "proficiency_s", "drop_penalty_s"):
            value = getattr(self, name)
            least = 0.0 if name == "drop_penalty_s" else None  # a penalty may be 0; the times not
            finite = isinstance(value, int | float) and math.isfinite(value)
            if not (finite and (value >= least if least is not None else value > 0)):
                limit = "≥ 0" if least is not None else "> 0"
                raise ValueError(f"{name}: {value!r} must be a finite number {limit} (s)")
        if self.proficiency_s > self.cutoff_s:
            raise ValueError(
                f"proficiency_s: {self.proficiency_s!r} s is past cutoff_s {self.cutoff_s!r} s; give a "
                f"proficiency line within the trial (the FLS's: {FLS_PROFICIENCY_S:g} s of "
                f"{FLS_CUTOFF_S:g} s)"
            )
