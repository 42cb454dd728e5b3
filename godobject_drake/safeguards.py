"""Safeguards that work under a plain ``Simulator``: divergence, quaternion drift, Stop, wiring.

A god-object diagram needs a few things no Drake system can do for it:

- **Divergence.** A run whose state turns non-finite, or moves a body faster
  than anything physical (:data:`DIVERGED_SPEED`), is stopped at the next
  check with a :class:`DivergenceError` that names the body, the value and
  the time, before NaNs fill the logs.
- **Quaternion drift.** Drake's discrete update integrates ``q̇ = ½ q ⊗ w``
  without projecting, so a free body's ``|q|`` grows by about ``(h|w|)²/8``
  per step (170 after 274 s of a brick twisted at ~10 rad/s). Every check puts
  each free body's quaternion back on unit norm (same rotation, same
  velocities); over a 50 ms check period ``|q|`` stays within 1e-3 of 1.
- **Stop.** A live page's Stop button (or Escape) ends the run at the next
  check, as a normal end.
- **Before each plant step** (``before_step``): the position baseline sets
  the held body to its target (paper Fig. 5), an articulated tool's imposed
  joints are set to the device's values.

:func:`install_safeguards` puts all of this on a simulator as its monitor
(called by Drake after every simulator step; ~2 µs when it has nothing to
do), and checks the diagram's wiring first (:func:`check_wiring`)::

    simulator = Simulator(diagram)
    install_safeguards(simulator)
    simulator.AdvanceTo(10.0)  # raises DivergenceError naming the body if the run blows up

The checks run every ``check_period_s`` of simulated time, at multiples of
the plant step, so a run is the same whatever chunks it is advanced in.

``install_safeguards(..., polled=True)`` puts no monitor on the simulator when
nothing must happen before every step: the caller advances in chunks of
:attr:`Safeguards.poll_every` plant steps and calls :meth:`Safeguards.poll`
after each (:func:`~godobject_drake.simulation.simulate` does), which runs the
same checks at the same steps, so the run is the same bit for bit, without a
Python call at every step.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np
from pydrake.multibody.plant import ExternallyAppliedSpatialForceMultiplexer, MultibodyPlant
from pydrake.multibody.tree import JointIndex
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, EventStatus
from pydrake.systems.primitives import Adder

from godobject_drake.devices.live import add_stop_button, stop_requested
from godobject_drake.systems.coupling import GodObjectCoupling

DIVERGED_SPEED = 1000.0  # m/s or rad/s: any generalized velocity past this is a blow-up
CHECK_PERIOD_S = 0.05


class DivergenceError(RuntimeError):
    """The simulation left physics (a non-finite state or an absurd speed).

    Attributes
    ----------
    time_s : float
        Simulated time of the check that caught it (s).
    body : str
        Scoped name of the body whose state went wrong.
    """

    def __init__(self, message: str, time_s: float, body: str):
        super().__init__(message)
        self.time_s, self.body = time_s, body


class WiringError(ValueError):
    """A diagram wired so that the god-object cannot work as intended; the message says what to connect."""


def find_plant(diagram: Diagram) -> MultibodyPlant:
    """The one MultibodyPlant of ``diagram`` (searched in nested diagrams too)."""
    plants = [s for s in _all_systems(diagram) if isinstance(s, MultibodyPlant)]
    if len(plants) != 1:
        raise WiringError(
            f"the diagram has {len(plants)} MultibodyPlants; pass the one to guard as plant=..."
        )
    return plants[0]


def _all_systems(diagram: Diagram):
    for system in diagram.GetSystems():
        yield system
        if isinstance(system, Diagram):
            yield from _all_systems(system)


class Safeguards:
    """The monitor :func:`install_safeguards` puts on a simulator, and what it saw.

    Attributes
    ----------
    diagnosis : str | None
        Why the run was stopped as diverged (also the :class:`DivergenceError`'s message).
    stopped : bool
        The Stop button ended the run.
    checks : int
        Checks made so far.
    projections : int
        Checks at which some free body's quaternion had drifted off unit norm and was projected back.
    polled : bool
        No monitor: the caller calls :meth:`poll` (``install(..., polled=True)``).
    """

    def __init__(
        self,
        plant: MultibodyPlant,
        *,
        check_period_s: float = CHECK_PERIOD_S,
        max_speed: float = DIVERGED_SPEED,
        stop: Callable[[], bool] | None = None,
        before_step: Callable | None = None,
        project_quaternions: bool = True,
        sleeper=None,
        watch: Callable | None = None,
    ):
        h = plant.time_step()
        if not h > 0.0:
            raise ValueError(f"plant time_step={h!r} s: the safeguards check a discrete plant; give h > 0")
        if not (math.isfinite(check_period_s) and check_period_s > 0.0):
            raise ValueError(f"check_period_s={check_period_s!r} s must be > 0")
        if not max_speed > 0.0:
            raise ValueError(f"max_speed={max_speed!r} (m/s or rad/s) must be > 0")
        self.plant, self.time_step = plant, h
        self.every = max(1, round(check_period_s / h))  # plant steps between checks
        self.max_speed, self.stop, self.before_step = float(max_speed), stop, before_step
        self.project_quaternions = project_quaternions
        self.sleeper = sleeper
        self.watch = watch
        self.diagnosis: str | None = None
        self.stopped = self.polled = False
        self.checks = self.projections = 0
        self._quaternion_starts = [
            plant.get_body(i).floating_positions_start()
            for i in plant.GetFloatingBaseBodies()
            if plant.get_body(i).has_quaternion_dofs()
        ]
        self._velocity_names = plant.GetVelocityNames()
        self._simulator = None
        self._plant_context = None
        self._root = None

    def install(self, simulator: Simulator, polled: bool = False) -> Safeguards:
        """Become ``simulator``'s monitor (replacing any other); ``polled`` and nothing to do before
        each step: no monitor, the caller calls :meth:`poll` (module docstring)."""
        self._simulator = simulator
        self._root = simulator.get_mutable_context()
        self._plant_context = self.plant.GetMyMutableContextFromRoot(self._root)
        self._next_check = self.every
        self._next_sleep = None
        if self.sleeper is not None:
            self.sleeper.reset()  # a new simulator's context: every body awake
            self._next_sleep = self.sleeper.every
        self.polled = polled and self.before_step is None
        if self.polled:
            simulator.clear_monitor()
        else:
            simulator.set_monitor(self._monitor)
        return self

    @property
    def poll_every(self) -> int:
        """Plant steps between two calls of :meth:`poll` that reach every check at its step."""
        return math.gcd(self.every, self.sleeper.every) if self._next_sleep is not None else self.every

    def poll(self) -> bool:
        """The checks due at the simulator's time, for a run with no monitor (``polled``): call it
        after each ``AdvanceTo`` to a multiple of :attr:`poll_every` plant steps. Raises
        :class:`DivergenceError`; True when the Stop button ended the run."""
        t = self._root.get_time()
        n = round(t / self.time_step)
        if n * self.time_step == t:
            self._checks_at(n, t)
        return self.stopped

    def _monitor(self, context) -> EventStatus:
        t = context.get_time()
        n = round(t / self.time_step)
        if n * self.time_step != t:
            return EventStatus.DidNothing()  # between plant steps (a device or drawing event)
        if self._checks_at(n, t):
            system = self._simulator.get_system()
            return EventStatus.ReachedTermination(system, f"Stop pressed at t={t:.3f} s")
        if self.before_step is not None:
            self.before_step(self._plant_context, self._root)
        return EventStatus.DidNothing()

    def _checks_at(self, n: int, t: float) -> bool:
        """The checks due at plant step ``n`` (time ``t``); True when Stop was pressed."""
        if n >= self._next_check:
            self._next_check = n + self.every
            self.checks += 1
            self.check(t)  # raises DivergenceError
            if self.project_quaternions:
                self._project()
            if self.stop is not None and self.stop():
                self.stopped = True
                return True
        if self._next_sleep is not None and n >= self._next_sleep:
            self._next_sleep = n + self.sleeper.every
            self.sleeper.check(self._plant_context, self._root)
        return False

    def check(self, t: float | None = None) -> None:
        """Raise :class:`DivergenceError` if the plant's state is non-finite or too fast, or if
        ``watch`` (what a god-object adds outside the plant: a haptic device) says it diverged."""
        ctx = self._plant_context
        t = ctx.get_time() if t is None else t
        if self.watch is not None and self._root is not None:
            found = self.watch(self._root, self.max_speed)
            if found is not None:
                part, what = found
                self.diagnosis = f"{part} diverged at t={t:.4f} s: {what}. The run was stopped there"
                raise DivergenceError(self.diagnosis, t, part)
        x = self.plant.GetPositionsAndVelocities(ctx)
        nq = self.plant.num_positions()
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            i = int(bad[0])
            what = self.plant.GetPositionNames()[i] if i < nq else self._velocity_names[i - nq]
            self._fail(f"non-finite state ({what} = {x[i]}) at t={t:.4f} s", t, i, nq)
        v = x[nq:]
        if v.size:
            i = int(np.argmax(np.abs(v)))
            if abs(v[i]) > self.max_speed:
                self._fail(
                    f"its velocity {self._velocity_names[i]} reached {v[i]:.3g} (> {self.max_speed:g} m/s "
                    f"or rad/s) at t={t:.4f} s",
                    t,
                    nq + i,
                    nq,
                )

    def _fail(self, what: str, t: float, index: int, nq: int) -> None:
        body = self._body_of(index, nq)
        self.diagnosis = (
            f"{body} diverged: {what}. The run was stopped there; lower the coupling's bandwidth "
            "(omega_n, omega_n_rot) or the time step, or stiffen/soften the contact it met"
        )
        raise DivergenceError(self.diagnosis, t, body)

    def _body_of(self, index: int, nq: int) -> str:
        """The scoped name of the body moved by state entry ``index`` of ``[q; v]``."""
        plant = self.plant
        for j in range(plant.num_joints()):
            joint = plant.get_joint(JointIndex(j))
            start, size = (
                (joint.position_start(), joint.num_positions())
                if index < nq
                else (nq + joint.velocity_start(), joint.num_velocities())
            )
            if start <= index < start + size:
                return joint.child_body().scoped_name().get_full()
        return "a body"

    def _project(self) -> None:
        """Put every free body's quaternion back on unit norm (same rotation, same velocities)."""
        if not self._quaternion_starts:
            return
        ctx = self._plant_context
        q = self.plant.GetPositions(ctx)
        changed = False
        for i in self._quaternion_starts:
            n = float(np.linalg.norm(q[i : i + 4]))
            if n > 0.0 and abs(n - 1.0) > 1e-9:
                q[i : i + 4] /= n
                changed = True
        if changed:
            self.projections += 1
            self.plant.SetPositions(ctx, q)


def install_safeguards(
    simulator: Simulator,
    plant: MultibodyPlant | None = None,
    *,
    check_period_s: float = CHECK_PERIOD_S,
    max_speed: float = DIVERGED_SPEED,
    meshcat=None,
    before_step: Callable | None = None,
    project_quaternions: bool = True,
    mode: str = "god_object",
    sleeper=None,
    wiring_checked: bool = False,
    watch: Callable | None = None,
    polled: bool = False,
) -> Safeguards:
    """Check ``simulator``'s diagram's wiring, then watch the run (module docstring).

    Parameters
    ----------
    plant : MultibodyPlant | None
        The plant to watch; None finds the diagram's only one.
    check_period_s : float
        Simulated time between checks (s); rounded to whole plant steps.
    max_speed : float
        A generalized velocity past this (m/s or rad/s) is a divergence.
    meshcat : Meshcat | None
        A live page: its Stop button (added if missing, key Escape) ends the run.
    before_step : callable | None
        ``before_step(plant_context, root_context)``, called before every plant step.
    project_quaternions : bool
        Put free bodies' quaternions back on unit norm at every check.
    mode : str
        ``god_object`` (the coupling's force must reach the plant) or ``position`` (it must not:
        the position baseline sets the body instead); see :func:`check_wiring`.
    sleeper : SleepManager | None
        Checked every ``sleeper.every`` plant steps (:mod:`godobject_drake.sleeping`).
    wiring_checked : bool
        The diagram's wiring was checked already (a built station's was, when it was built:
        :func:`~godobject_drake.station.build.finish`), so it is not checked twice.
    watch : callable | None
        ``watch(root_context, max_speed)`` → ``(part, what)`` when a part outside the plant (a
        simulated haptic device) diverged, else None; asked at every check, before the plant.
    polled : bool
        No monitor where nothing must happen before each step: the caller advances
        :attr:`Safeguards.poll_every` plant steps at a time and calls :meth:`Safeguards.poll`
        after each (the same checks at the same steps, without a Python call every step).
    """
    diagram = simulator.get_system()
    plant = plant or find_plant(diagram)
    if not wiring_checked:
        check_wiring(diagram, mode=mode)
    stop = None
    if meshcat is not None:
        add_stop_button(meshcat)

        def stop():
            return stop_requested(meshcat)

    guard = Safeguards(
        plant,
        check_period_s=check_period_s,
        max_speed=max_speed,
        stop=stop,
        before_step=before_step,
        project_quaternions=project_quaternions,
        sleeper=sleeper,
        watch=watch,
    )
    return guard.install(simulator, polled=polled)


MODES = ("god_object", "position")
_FORCE_PORTS = {"generalized_force": "applied_generalized_force", "spatial_forces": "applied_spatial_force"}
# What joins several tools' forces into one plant input (station.loop.ForceBus).
_JOINS = (Adder, ExternallyAppliedSpatialForceMultiplexer)


def check_wiring(diagram: Diagram, mode: str = "god_object") -> None:
    """Raise :class:`WiringError` where a god-object coupling is wired so that it cannot work.

    For every :class:`~godobject_drake.systems.coupling.GodObjectCoupling` in ``diagram`` (at any
    depth, with its plant in the same diagram):

    - ``god_object`` mode: exactly one of its ``generalized_force`` and ``spatial_forces``
      outputs reaches the plant's matching input (none: the body never moves; both: it gets
      the wrench twice);
    - ``position`` mode: neither does (the baseline sets the body's pose instead);
    - its ``plant_state`` comes from the plant's ``state`` output;
    - every grasp name a connected device can report names a free body of the plant.
    """
    if mode not in MODES:
        raise ValueError(f"mode={mode!r}; choose one of {MODES}")

    for sub in [diagram, *(s for s in _all_systems(diagram) if isinstance(s, Diagram))]:
        children = set(sub.GetSystems())
        wires: dict = {}
        for (dst, i), (src, o) in sub.connection_map().items():
            wires.setdefault((src, src.get_output_port(o).get_name()), []).append(
                (dst, dst.get_input_port(i).get_name())
            )

        for coupling in (s for s in children if isinstance(s, GodObjectCoupling)):
            plant = coupling.plant
            if plant not in children:
                continue
            name = coupling.get_name()
            into_plant = [
                port
                for port, plant_port in _FORCE_PORTS.items()
                if (plant, plant_port) in _reaches(wires, (coupling, port))
            ]
            fix = (
                f"builder.Connect({name}.GetOutputPort('generalized_force'), "
                "plant.get_applied_generalized_force_input_port())"
            )
            if mode == "god_object" and not into_plant:
                raise WiringError(
                    f"coupling {name!r} drives no force into the plant: the held body would never move "
                    f"while the feedback reads its weight. Connect it: {fix} (or build with "
                    "godobject_drake.add_god_object, which wires it)"
                )
            if mode == "god_object" and len(into_plant) > 1:
                raise WiringError(
                    f"coupling {name!r} drives both 'generalized_force' and 'spatial_forces' into the "
                    "plant: the held body gets the coupling's wrench twice. Connect only one "
                    "('generalized_force' is the cheaper)"
                )
            if mode == "position" and into_plant:
                raise WiringError(
                    f"mode=position imposes the held body's pose, but coupling {name!r} also drives "
                    f"{into_plant} into the plant; leave its force outputs unconnected in this mode"
                )
            state_from = [src for (src, _), dsts in wires.items() if (coupling, "plant_state") in dsts]
            if state_from and state_from[0] is not plant:
                raise WiringError(
                    f"coupling {name!r} reads 'plant_state' from {state_from[0].get_name()!r}; connect "
                    "plant.get_state_output_port() to it"
                )
            for (src, _), dsts in wires.items():
                if (coupling, "grasp") in dsts and hasattr(src, "grasp_names"):
                    coupling.validate_grasp_names(src.grasp_names())


def _reaches(wires: dict, source) -> list:
    """Where ``source`` (a system and its output port's name) ends: through the adders and
    multiplexers that join several tools' forces into one of the plant's inputs."""
    ends = []
    for dst, port in wires.get(source, []):
        if isinstance(dst, _JOINS):
            ends += _reaches(wires, (dst, dst.get_output_port(0).get_name()))
        else:
            ends.append((dst, port))
    return ends


# -- free bodies left unsupported ---------------------------------------------------------------------------

FALL_WATCH_S = 1.0  # a free body that drops this early on its own was left unsupported
FALL_DROP_M = 0.1  # how far below its start it must be: a second of free fall is 4.9 m
TOOL_NEAR_M = 0.005  # a body this close to a tool's may have been pushed there, not thrown


class UnsupportedBodyWarning(UserWarning):
    """A free body nobody held fell in the run's first second: a fixed model left unwelded?"""


class FallWatch:
    """Free bodies that fall or are thrown on their own at the start of a run (a model someone
    forgot to weld, one that starts inside another: nothing else would say so). At
    ``at_s`` every free body not held then that is more than :data:`FALL_DROP_M` below its start,
    or that has moved more than that in any direction while no tool is within
    :data:`TOOL_NEAR_M` of it (so not a body a tool pushed there), is named in a warning, and in
    the metrics (``unsupported_bodies``)."""

    def __init__(self, plant, plant_context, god, at_s: float):
        self.plant, self.god, self.at_s = plant, god, at_s
        self.start = {b: plant.EvalBodyPoseInWorld(plant_context, plant.get_body(b)).translation().copy()
                      for b in plant.GetFloatingBaseBodies()}  # fmt: skip
        self.pending, self.fallen, self.thrown = bool(self.start), [], []

    def check(self, plant_context, root_context) -> None:
        self.pending = False
        plant = self.plant
        held = self.god.held_bodies(root_context)
        free = {int(b) for b in self.start}
        welded = {int(b.index()) for b in plant.GetBodiesWeldedTo(plant.world_body())}
        # what pushes: the held bodies, and the bodies neither free nor welded (a tool's links)
        tools = held | (set(range(plant.num_bodies())) - free - welded)
        near = self._near(plant_context, tools) if tools else set()
        for b, p0 in self.start.items():
            if int(b) in held:
                continue
            body = plant.get_body(b)
            p = plant.EvalBodyPoseInWorld(plant_context, body).translation()
            name = body.scoped_name().get_full()
            if p0[2] - p[2] > FALL_DROP_M:
                self.fallen.append(name)
            elif np.linalg.norm(p - p0) > FALL_DROP_M and int(b) not in near:
                self.thrown.append(name)
        if self.fallen:
            warnings.warn(
                f"{', '.join(self.fallen)} fell more than {FALL_DROP_M:g} m in the first {self.at_s:g} s "
                "without being held: a model that should stay put needs a weld (add_weld, or a fixed joint "
                "to world in its file), or a support under it",
                UnsupportedBodyWarning,
                stacklevel=3,
            )
        if self.thrown:
            warnings.warn(
                f"{', '.join(self.thrown)} moved more than {FALL_DROP_M:g} m in the first {self.at_s:g} s "
                "with no tool near it: thrown by contact (a model that starts inside another, or one that "
                "should be welded: add_weld it, or move its starting pose out)",
                UnsupportedBodyWarning,
                stacklevel=3,
            )
        self.fallen += self.thrown

    def _near(self, plant_context, tools: set[int]) -> set[int]:
        """The bodies within :data:`TOOL_NEAR_M` of one of ``tools``."""
        plant = self.plant
        query = plant.get_geometry_query_input_port().Eval(plant_context)
        inspector = query.inspector()
        out = set()
        try:
            pairs = query.ComputeSignedDistancePairwiseClosestPoints(TOOL_NEAR_M)
        except RuntimeError:  # a shape pair Drake's signed distance does not support: say nothing
            return {int(b) for b in self.start}
        for pair in pairs:
            a, b = (
                int(plant.GetBodyFromFrameId(inspector.GetFrameId(g)).index()) for g in (pair.id_A, pair.id_B)
            )
            if a in tools:
                out.add(b)
            if b in tools:
                out.add(a)
        return out
