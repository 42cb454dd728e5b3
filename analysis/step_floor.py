"""The brick scene's per-step cost against the plant's own, on the same motion.

``speed_vs_error.brick_profile`` compares the scene's step with the plant's step while every
brick rests (the held one too). That floor is low: in the scene the held brick moves, slides
along the baseplate and climbs the wall, and SAP works harder for it. This tool builds a fair
floor: the scene's plant alone, replaying what the scene did to it, with no Python per plant
step:

- the explicit coupling's generalized forces, recorded at each plant step of a scene run, come
  from a ``TrajectorySource`` (a zero-order-hold ``PiecewisePolynomial``, C++);
- the implicit coupling's springs are set to the recorded targets at the steps the scene set
  them (``SpringHook.apply``, at the device rate), between ``AdvanceTo`` calls;
- the sleeping bricks are locked and unlocked, and the quaternions projected, at the steps the
  scene did it (every 10 ms and 50 ms at most), between ``AdvanceTo`` calls.

The scene's run is read through ``simulate``'s ``observe`` hook, before every plant step: the
plant's force input, the sleeper's bodies, the springs' moves; the replay's projections are its
own safeguards' checks, polled at the scene's check steps (public ports and attributes only).

The replay is checked against the scene: the plant's final state must agree bit for bit, so
the floor steps exactly the states the scene stepped. Then the scene (both couplings), the
replays and the resting floor run round-robin in one process, timed by CPU time
(``time.process_time``) around ``AdvanceTo`` only, as ``simulate`` times the scene.

    python analysis/step_floor.py                       # the lego path, 3 rounds
    python analysis/step_floor.py --seconds 4 --rounds 5 --json /tmp/floor.json
    python analysis/step_floor.py --seconds 3 --bricks 64 --filter   # the scale, and the filter candidate
"""

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.multibody.tree import JointIndex
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from godobject_drake import safeguards as sg
from godobject_drake.config.scenario import replace, shipped_scenario
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.station.plant import add_plant


def scenario_for(coupling: str, seconds: float | None, bricks: int | None = None):
    scenario = shipped_scenario("lego")
    overrides = {}
    if seconds is not None:
        overrides["simulation.duration_s"] = seconds
    if coupling == "implicit":
        overrides["god_object.coupling"] = "implicit"
    if bricks is not None:
        overrides["bricks"] = bricks
    return replace(scenario, **overrides) if overrides else scenario


def record(scenario, keep_logs: bool = False):
    """Run the scene once, recording what it did to its plant: ``(result, forces, events)``.

    Read before every plant step through ``simulate``'s ``observe``, after the safeguards and the
    tools' hooks at that step. ``forces``: {t: generalized force vector} the plant's
    ``applied_generalized_force`` input at t, what its step at t reads (the explicit coupling's;
    none when that input is not connected). ``events``: what was done to the plant's context
    before its step at t, ``(t, kind, payload)``: ``project`` at each safeguard check (the
    quaternions put back on unit norm), ``lock`` and ``unlock`` for each body the sleeper put to
    sleep or woke (its name), ``springs`` when the implicit coupling's hook moved the springs
    (the coupling's state it applied).
    """
    forces: dict[float, np.ndarray] = {}
    events: list = []
    station = build_station(scenario)
    plant = station.plant
    h = plant.time_step()
    every = sg.Safeguards(plant, check_period_s=scenario.simulation.check_period_s).every
    port = plant.get_applied_generalized_force_input_port()
    sleeper = station.sleeper
    hook = getattr(station.god_object, "hook", None)
    seen = {"asleep": None, "moves": 0}  # what the last step saw: the sleepers, the springs' moves

    def observe(plant_context, root_context):
        t = root_context.get_time()
        n = round(t / h)
        if n >= every and n % every == 0:
            events.append((t, "project", None))
        if sleeper is not None:
            before = seen["asleep"] if seen["asleep"] is not None else np.zeros_like(sleeper.asleep)
            for k in np.flatnonzero(before != sleeper.asleep):
                events.append((t, "lock" if sleeper.asleep[k] else "unlock", sleeper.bodies[k].name))
            seen["asleep"] = sleeper.asleep.copy()
        if hook is not None and hook.moves != seen["moves"]:
            seen["moves"] = hook.moves
            coupling = hook.coupling
            s = coupling.state(coupling.GetMyContextFromRoot(root_context))
            events.append((t, "springs", np.array(s, copy=True)))
        if port.HasValue(plant_context):
            forces[t] = np.array(port.Eval(plant_context), copy=True)

    result = simulate(station, progress=False, keep_logs=keep_logs, observe=observe)
    return result, forces, events


class Floor:
    """The scene's plant alone, replaying a recorded run (module docstring)."""

    def __init__(self, scenario, station, forces, events):
        self.h = scenario.plant.time_step
        self.duration = scenario.simulation.duration_s
        builder = DiagramBuilder()
        implicit = getattr(station.god_object, "hook", None) is not None
        if implicit:
            from godobject_drake.systems.implicit import SpringHook, add_springs

            springs = []
            parts = add_plant(
                builder, scenario, lambda plant, scene_graph: springs.extend(add_springs(plant))
            )
        else:
            parts = add_plant(builder, scenario)
        self.plant = plant = parts.plant
        self.scene_graph = parts.scene_graph
        if forces:
            # breakpoints half a step early: a step at t_n reads mid-segment, sample n exactly; a
            # zero-order hold's last sample only ends its last segment, so the last one is repeated
            order = sorted(forces)
            times = np.array([*order, order[-1] + self.h]) - 0.5 * self.h
            values = np.column_stack([forces[t] for t in [*order, order[-1]]])
            source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(times, values)))
            builder.Connect(source.get_output_port(), plant.get_applied_generalized_force_input_port())
        self.diagram = builder.Build()
        self.simulator = Simulator(self.diagram)
        self.root = self.simulator.get_mutable_context()
        self.ctx = plant.GetMyMutableContextFromRoot(self.root)
        # the scene's coupling with this plant's springs (constraint ids are unique across plants)
        self.hook = (
            SpringHook(plant, _WithSprings(station.god_object.coupling, springs)) if implicit else None
        )
        if self.hook is not None:
            self.hook.deactivate(self.ctx)
        joints = {}
        for j in range(plant.num_joints()):
            joint = plant.get_joint(JointIndex(j))
            joints[joint.child_body().scoped_name().get_full()] = joint
        self.joints = joints
        # the scene's safeguards on this simulator, polled at the recorded checks (``project``)
        self.guard = sg.Safeguards(plant, check_period_s=scenario.simulation.check_period_s)
        self.guard.install(self.simulator, polled=True)
        by_time: dict[float, list] = {}
        for t, kind, payload in events:
            by_time.setdefault(t, []).append((kind, payload))
        self.events = sorted(by_time.items())
        self.simulator.Initialize()

    def run(self, filter_sleeping: bool = False) -> tuple[float, float]:
        """Replay the whole run: (CPU s inside AdvanceTo, CPU s of the events between).

        ``filter_sleeping``: also exclude the pairs among the locked bodies and the welded
        geometry in the SceneGraph context (a transient collision filter, changed at each lock
        or unlock), as a candidate for sleeping to do."""
        advance = between = 0.0
        locked, filter_id = set(), None
        if filter_sleeping:
            from pydrake.geometry import CollisionFilterDeclaration, GeometrySet

            plant = self.plant
            free = set(plant.GetFloatingBaseBodies())
            from pydrake.multibody.tree import BodyIndex

            anchored = [plant.GetBodyFrameIdIfExists(BodyIndex(i)) for i in range(plant.num_bodies())
                        if BodyIndex(i) not in free]  # fmt: skip
            anchored = [f for f in anchored if f is not None]
            sg_ctx = self.scene_graph.GetMyMutableContextFromRoot(self.root)
            manager = self.scene_graph.collision_filter_manager(sg_ctx)
        for t, todo in self.events:
            if t > 0.0:
                c0 = time.process_time()
                self.simulator.AdvanceTo(t)
                advance += time.process_time() - c0
            c0 = time.process_time()
            for kind, payload in todo:
                if kind == "project":
                    self.guard.poll()  # the check due at t: the quaternions back on unit norm
                elif kind == "lock":
                    self.joints[payload].Lock(self.ctx)
                    locked.add(payload)
                elif kind == "unlock":
                    self.joints[payload].Unlock(self.ctx)
                    locked.discard(payload)
                else:
                    self.hook.apply(self.ctx, payload)
            if filter_sleeping and any(kind in ("lock", "unlock") for kind, _ in todo):
                if filter_id is not None:
                    manager.RemoveDeclaration(filter_id)
                    filter_id = None
                if locked:
                    frames = [
                        self.plant.GetBodyFrameIdIfExists(self.joints[n].child_body().index()) for n in locked
                    ]
                    group = GeometrySet(frames + anchored)
                    filter_id = manager.ApplyTransient(CollisionFilterDeclaration().ExcludeWithin(group))
            between += time.process_time() - c0
        c0 = time.process_time()
        end = round(self.duration / self.h) * self.h
        if self.root.get_time() < end:  # AdvanceTo(t) at t would step the plant once more
            self.simulator.AdvanceTo(end)
        advance += time.process_time() - c0
        return advance, between

    def state(self) -> np.ndarray:
        return self.plant.GetPositionsAndVelocities(self.ctx)


class _WithSprings:
    def __init__(self, coupling, springs):
        self._coupling, self.springs = coupling, tuple(springs)

    def __getattr__(self, name):
        return getattr(self._coupling, name)


def resting_floor(scenario, seconds: float) -> float:
    """``brick_profile``'s floor: the plant alone, every brick resting, all but brick_0 locked;
    CPU s for ``seconds`` after 1.1 s of settling."""
    builder = DiagramBuilder()
    bare = add_plant(builder, scenario)
    sim = Simulator(builder.Build())
    sim.Initialize()
    sim.AdvanceTo(1.1)
    ctx = bare.plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    free = bare.plant.GetModelInstanceByName("brick_0")
    for j in range(bare.plant.num_joints()):
        joint = bare.plant.get_joint(JointIndex(j))
        if joint.num_velocities() == 6 and joint.child_body().model_instance() != free:
            joint.Lock(ctx)
    c0 = time.process_time()
    sim.AdvanceTo(1.1 + seconds)
    return time.process_time() - c0


def measure(
    seconds: float | None,
    rounds: int,
    bricks: int | None = None,
    filter_sleeping: bool = False,
    echo=lambda *a: None,
) -> dict:
    """Record both couplings' scenes, check each replay bit for bit, then time scene, replay and
    resting floor round-robin (CPU time); the medians (µs per step) and their ratios."""
    out: dict = {"machine": machine(), "bricks": bricks or 8, "seconds": seconds}
    floors, steps = {}, {}
    for coupling in ("explicit", "implicit"):
        scenario = scenario_for(coupling, seconds, bricks)
        result, forces, events = record(scenario)
        floor = Floor(scenario, result.station, forces, events)
        floor.run()
        scene_x = result.station.plant.GetPositionsAndVelocities(
            result.station.plant.GetMyContextFromRoot(result.context)
        )
        same = np.array_equal(scene_x.view(np.uint64), floor.state().view(np.uint64))
        out[f"{coupling}_replay_bit_identical"] = bool(same)
        out[f"{coupling}_replay_max_abs_diff"] = float(np.max(np.abs(scene_x - floor.state())))
        out[f"{coupling}_events"] = len(events)
        floors[coupling] = (scenario, result.station, forces, events)
        steps[coupling] = round(scenario.simulation.duration_s / scenario.plant.time_step)
        echo(f"{coupling}: replay bit-identical={same}, {len(events)} events between AdvanceTo calls")
    cpu: dict[str, list] = {}
    path_s = floors["explicit"][0].simulation.duration_s
    for r in range(rounds):
        for coupling in ("explicit", "implicit"):
            scenario, station, forces, events = floors[coupling]
            res = simulate(build_station(scenario), progress=False, keep_logs=True)
            cpu.setdefault(f"scene_{coupling}", []).append(res.metrics["cpu_time_s"] / steps[coupling])
            floor = Floor(scenario, station, forces, events)
            advance, between = floor.run()
            cpu.setdefault(f"floor_{coupling}", []).append(advance / steps[coupling])
            cpu.setdefault(f"floor_{coupling}_events", []).append(between / steps[coupling])
            if filter_sleeping:
                advance, between = Floor(scenario, station, forces, events).run(filter_sleeping=True)
                cpu.setdefault(f"floor_{coupling}_filtered", []).append(advance / steps[coupling])
                cpu.setdefault(f"floor_{coupling}_filter_changes", []).append(between / steps[coupling])
        cpu.setdefault("floor_resting", []).append(
            resting_floor(floors["explicit"][0], path_s) / steps["explicit"]
        )
        echo(f"round {r + 1}: " + ", ".join(f"{k} {v[-1] * 1e6:.0f}" for k, v in cpu.items()) + " µs/step")
    med = {k: statistics.median(v) * 1e6 for k, v in cpu.items()}
    out["cpu_us_per_step_median"] = med
    out["cpu_us_per_step_rounds"] = {k: [x * 1e6 for x in v] for k, v in cpu.items()}
    ratios = {
        "explicit_over_replay": med["scene_explicit"] / med["floor_explicit"],
        "implicit_over_replay": med["scene_implicit"] / med["floor_implicit"],
        "explicit_over_resting": med["scene_explicit"] / med["floor_resting"],
        "implicit_over_resting": med["scene_implicit"] / med["floor_resting"],
        "replay_explicit_over_resting": med["floor_explicit"] / med["floor_resting"],
        "replay_implicit_over_resting": med["floor_implicit"] / med["floor_resting"],
    }
    out["ratios"] = ratios
    # Each round's scene over its own replay, then the median: a round's two runs share its load.
    out["ratio_rounds"] = {
        f"{c}_over_replay": [a / b for a, b in zip(cpu[f"scene_{c}"], cpu[f"floor_{c}"], strict=True)]
        for c in ("explicit", "implicit")
    }
    out["ratio_rounds_median"] = {k: statistics.median(v) for k, v in out["ratio_rounds"].items()}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=None, help="simulated s (default: the whole path)")
    parser.add_argument("--rounds", type=int, default=3, help="round-robin rounds (≥ 3)")
    parser.add_argument("--bricks", type=int, help="the scene with this many bricks (scenario 'bricks')")
    parser.add_argument("--filter", action="store_true", help="also replay with the sleeping pairs filtered")
    parser.add_argument("--json", type=Path, help="write the measurements here")
    args = parser.parse_args(argv)
    if args.rounds < 3:
        parser.error("--rounds: at least 3")
    out = measure(args.seconds, args.rounds, args.bricks, args.filter, echo=print)
    for k, v in out["ratios"].items():
        print(f"{k:32s} {v:.3f}")
    for k, v in out["ratio_rounds"].items():
        print(f"{k:32s} per round {', '.join(f'{x:.3f}' for x in v)}; median {statistics.median(v):.3f}")
    for k, v in out["cpu_us_per_step_median"].items():
        print(f"{k:32s} {v:8.1f} µs/step (median CPU)")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


def machine() -> str:
    from godobject_drake.studies.benchmark import machine as bm_machine

    return bm_machine()


if __name__ == "__main__":
    sys.exit(main())
