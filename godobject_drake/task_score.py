"""A task's score (``task:`` of the scenario, :class:`~godobject_drake.config.task.Task`): task time,
transfers completed, drops, and the FLS score with its cut and proficiency line.

From the run's states (each object's origin, every plant step) and the jaws' grasp events (when a
tool took or let go of which body), for any scene whose scenario declares a task:

- an object is **on a peg** when its origin is within ``on_peg.radius_m`` of the peg's axis and
  between its foot and ``on_peg.height_m`` above it (the peg body's frame: its foot, z its axis);
- it is **held** while any tool's jaws hold it, **loose** when neither held nor on a peg;
- a **drop** is a spell loose for ``settle_s`` or more (one drop per spell);
- the task is **done** from the first step after which, to the run's end, every object is on its
  target peg or dropped, and no jaw holds one: the **task time** is that step's time from the run's
  start (None: not done in the run);
- **transfers** are the objects on their target peg, out of the jaws, at the run's end;
- the **FLS score** is ``max(0, cutoff_s - time - drop_penalty_s * drops)``, 0 when not done (a
  trial not done by its cut scores 0); **proficient**: done within ``proficiency_s`` with no drop.

:func:`score_task` is the whole rule on plain arrays; :class:`TaskFold` feeds it from a run.
"""

import dataclasses

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex

from godobject_drake.config.task import Task


class TaskError(ValueError):
    """A task that names what the scene does not have: names the field, the value and the fix."""


@dataclasses.dataclass
class Board:
    """The task's places, resolved on a plant: each peg's foot (``p_WF``, (P, 3)) and axis
    (``z_WF``, (P, 3)), the index in ``pegs`` of each object's target."""

    objects: list[str]
    pegs: list[str]
    targets: list[int]
    p_WF: np.ndarray
    z_WF: np.ndarray


def fls_score(time_s: float | None, drops: int, cutoff_s: float, drop_penalty_s: float) -> float:
    """``max(0, cutoff_s - time_s - drop_penalty_s * drops)``; 0 for a task not done (``time_s`` None)
    or done past its cut."""
    if time_s is None or time_s > cutoff_s:
        return 0.0
    return max(0.0, cutoff_s - time_s - drop_penalty_s * drops)


def on_peg(p_WO: np.ndarray, board: Board, task: Task) -> np.ndarray:
    """For each row of ``p_WO`` (N, 3), the index of the peg the point is on, or -1."""
    d = p_WO[:, None, :] - board.p_WF[None, :, :]  # (N, P, 3)
    along = np.einsum("npk,pk->np", d, board.z_WF)
    across = np.linalg.norm(d - along[..., None] * board.z_WF[None], axis=2)
    inside = (across <= task.on_peg.radius_m) & (along >= 0.0) & (along <= task.on_peg.height_m)
    return np.where(inside.any(axis=1), np.argmax(inside, axis=1), -1)


def held_at(t: np.ndarray, events: list[tuple[float, str, bool]], name: str) -> np.ndarray:
    """Whether some jaw holds ``name`` at each time of ``t``, from the tools' events ``(t, body,
    taken)`` (a jaw takes a body before the step at its time)."""
    mine = sorted((te, 1 if taken else -1) for te, body, taken in events if body == name)
    if not mine:
        return np.zeros(len(t), bool)
    times = np.array([te for te, _ in mine])
    holders = np.cumsum([d for _, d in mine])
    k = np.searchsorted(times, t + 1e-12, side="right") - 1
    return np.where(k >= 0, holders[np.maximum(k, 0)] > 0, False)


def _spells(flag: np.ndarray) -> list[tuple[int, int]]:
    """The runs of True in ``flag``: ``[(first, past the last), ...]``."""
    edges = np.diff(np.concatenate([[0], flag.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def score_task(
    t: np.ndarray, positions: dict[str, np.ndarray], events: list, board: Board, task: Task
) -> dict:
    """The task's score (module docstring) from the times ``t`` (N,) of the rows, each object's
    origin ``positions[name]`` (N, 3) and the jaws' ``events`` ``(t, body, taken)``."""
    n = len(t)
    dt = float(np.median(np.diff(t))) if n > 1 else 0.0
    done = np.ones(n, bool)
    drops, drop_times, where, transfers = 0, [], [], 0
    for name, target in zip(board.objects, board.targets, strict=True):
        peg = on_peg(positions[name], board, task)
        held = held_at(t, events, name)
        dropped = np.zeros(n, bool)
        for first, past in _spells(~held & (peg < 0)):
            if (past - first) * dt >= task.settle_s - 1e-9:
                drops += 1
                drop_times.append(float(t[first]))
                dropped[first:past] = True
        done &= (~held & (peg == target)) | dropped
        if n == 0:
            continue
        end = "held" if held[-1] else (f"on {board.pegs[peg[-1]]}" if peg[-1] >= 0 else "loose")
        where.append(f"{name} {end}")
        transfers += int(not held[-1] and peg[-1] == target)
    time_s = None
    if n and done[-1]:
        undone = np.flatnonzero(~done)
        time_s = float(t[undone[-1] + 1]) if len(undone) else float(t[0])
    return {
        "task_time_s": time_s,
        "task_done": time_s is not None,
        "task_transfers": transfers,
        "task_objects": len(board.objects),
        "task_drops": drops,
        "task_drop_times_s": sorted(drop_times),
        "task_fls_score": fls_score(time_s, drops, task.cutoff_s, task.drop_penalty_s),
        "task_proficient": time_s is not None and time_s <= task.proficiency_s and drops == 0,
        "task_where": where,
    }


def _body(plant: MultibodyPlant, scoped: str, field: str):
    """The body ``model::body`` of ``plant``, or a :class:`TaskError` naming what there is."""
    model, sep, name = scoped.rpartition("::")
    if not sep:
        raise TaskError(f"task.{field}: {scoped!r} is not model::body; name a body as model::body "
                        "(e.g. ring_1::ring)")  # fmt: skip
    if not plant.HasModelInstanceNamed(model):
        models = sorted(_model_names(plant))
        raise TaskError(f"task.{field}: {scoped!r}: the scene has no model {model!r}; its models are "
                        f"{', '.join(models)}")  # fmt: skip
    instance = plant.GetModelInstanceByName(model)
    if not plant.HasBodyNamed(name, instance):
        bodies = [plant.get_body(b).name() for b in plant.GetBodyIndices(instance)]
        raise TaskError(f"task.{field}: {scoped!r}: model {model!r} has no body {name!r}; its bodies are "
                        f"{', '.join(bodies)}")  # fmt: skip
    return plant.GetBodyByName(name, instance)


def _model_names(plant: MultibodyPlant) -> list[str]:
    return [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]


def resolve_task(plant: MultibodyPlant, task: Task) -> tuple[Board, dict[str, int]]:
    """The task's bodies on the (finalized) plant: its :class:`Board` and, for each object, where its
    position starts in the plant's state. Raises :class:`TaskError` for a name the scene does not
    have, or an object that is not a free body."""
    starts = {}
    for i, scoped in enumerate(task.objects):
        body = _body(plant, scoped, f"objects[{i}]")
        if not body.is_floating_base_body():
            raise TaskError(f"task.objects[{i}]: {scoped!r} is not a free body (it is jointed or welded); "
                            "the task's objects are bodies the tools move")  # fmt: skip
        starts[scoped] = body.floating_positions_start() + 4  # after the quaternion
    context = plant.CreateDefaultContext()
    poses: list[RigidTransform] = []
    for i, scoped in enumerate(task.pegs):
        poses.append(plant.EvalBodyPoseInWorld(context, _body(plant, scoped, f"pegs[{i}]")))
    board = Board(
        objects=list(task.objects),
        pegs=list(task.pegs),
        targets=[task.pegs.index(target) for target in task.targets],
        p_WF=np.array([X.translation() for X in poses]).reshape(-1, 3),
        z_WF=np.array([X.rotation().matrix()[:, 2] for X in poses]).reshape(-1, 3),
    )
    return board, starts


class TaskFold:
    """A run's task score: each object's origin folded in from the state rows as they come (row k at
    ``t = k h``), scored with the tools' grasp events at the end (:func:`score_task`). ``resolved``:
    what :func:`resolve_task` gave for ``task`` on the run's plant."""

    def __init__(self, resolved: tuple[Board, dict[str, int]], task: Task, h: float):
        self.task, self.h = task, h
        self.board, starts = resolved
        self._names = list(starts)
        self._rows: list[np.ndarray] = []
        self._columns = np.array([[s, s + 1, s + 2] for s in starts.values()], int).reshape(-1)

    def update(self, state: np.ndarray) -> None:
        if len(state):
            self._rows.append(np.asarray(state, float)[:, self._columns])

    def result(self, events: list[tuple[float, str, bool]]) -> dict:
        rows = np.concatenate(self._rows) if self._rows else np.zeros((0, len(self._columns)))
        t = self.h * np.arange(len(rows))
        positions = {name: rows[:, 3 * i : 3 * i + 3] for i, name in enumerate(self._names)}
        return score_task(t, positions, events, self.board, self.task)
