"""The static penetration under a tool's capped pull: of each body the device grasps into what it
can touch, of each free body it can push into what is fixed behind it, and between two tools'
held bodies in a scene of several."""

from __future__ import annotations

import dataclasses

from pydrake.geometry import Role
from pydrake.multibody.tree import BodyIndex

from godobject_drake.config import scenario as sc
from godobject_drake.station.rigid_tool import penetration_fix, penetration_pairs
from godobject_drake.studies.analyze.common import (
    WARN_FRACTION,
    Check,
    _bodies,
    _ge,
    _grasped,
    _verdict_below,
)


def _contact_checks(station, scenario: sc.Scenario, out: dict) -> list[Check]:
    """The static penetration of each body the device grasps (by its path) under the coupling's
    capped pull, into what it can touch; and of each free body it can push, pushed by that pull
    into what is fixed behind it."""
    budget = scenario.metrics.penetration_budget_m
    out["penetration_budget_m"] = budget
    kind = station.god_object.kind
    reason = station.god_object.no_prediction_reason or None
    allowance = scenario.plant.penetration_allowance
    pairs, pushed = [], []
    if not reason:
        held = _grasped(station)
        pairs = penetration_pairs(
            station.plant, station.scene_graph, station.coupling, allowance, bodies=held
        )
        pushed = _pushed_pairs(station, pairs, allowance)
    if not reason and not pairs:
        reason = "no point contact to predict (hydroelastic pressure depends on the contact area)"
    out["contact_pairs"] = [dict(dataclasses.asdict(p), depth_m=p.depth_m) for p in pairs]
    out["pushed_pairs"] = [dict(dataclasses.asdict(p), depth_m=p.depth_m, pushed_by=by) for p, by in pushed]
    if reason:
        return [Check("contact", "static penetration", kind, "info", None, budget, "m", "", why=reason)]
    gains, max_stretch = station.coupling.gains, station.coupling.max_stretch_m
    deepest = max(pairs, key=lambda p: p.depth_m)
    rows = [Check(
        "contact", f"static penetration under the capped pull ({deepest.force_n:.3g} N), into "
        f"{deepest.obstacle} ({deepest.stiffness_n_m:.3g} N/m)",
        f"{deepest.body} ({_bodies(len({p.body for p in pairs}))} the device grasps)",
        _verdict_below(deepest.depth_m, budget), deepest.depth_m, budget, "m",
        penetration_fix(deepest.force_n, deepest.depth_m, budget, gains.omega_n, max_stretch),
    )]  # fmt: skip
    if pushed:
        deep, by = max(pushed, key=lambda p: p[0].depth_m)
        rows.append(Check(
            "contact", f"static penetration of a pushed body under {by}'s capped pull "
            f"({deep.force_n:.3g} N), into {deep.obstacle} ({deep.stiffness_n_m:.3g} N/m)",
            f"{deep.body} (pushed by {by}; {_bodies(len({p.body for p, _ in pushed}))} it can push)",
            _verdict_below(deep.depth_m, budget), deep.depth_m, budget, "m",
            penetration_fix(deep.force_n, deep.depth_m, budget, gains.omega_n, max_stretch),
        ))  # fmt: skip
    return rows


def _pushed_pairs(station, pairs, allowance: float) -> list[tuple]:
    """``(pair, pushed by)`` for each free body a grasped body can touch, against the fixed
    obstacles it can touch, under the grasped body's capped pull."""
    coupling = station.coupling
    by_index = {b.index: b for b in coupling.bodies.values()}
    grasped = {p.body_index for p in pairs}
    pushers: dict[int, tuple[str, float]] = {}
    for p in pairs:
        index = p.obstacle_body_index
        if p.obstacle_anchored or index in grasped or index not in by_index:
            continue
        if p.force_n > pushers.get(index, ("", 0.0))[1]:
            pushers[index] = (p.body, p.force_n)
    out = []
    for index, (by, force) in pushers.items():
        pushed = penetration_pairs(station.plant, station.scene_graph, coupling, allowance,
                                   bodies=[by_index[index]], force_n=force, anchored_only=True)  # fmt: skip
        out += [(q, by) for q in pushed]
    return out


def _between_tools(station, s: sc.Scenario) -> list[Check]:
    """Each two tools' held bodies pressed together: the weaker capped pull of the two sets the
    contact force (the stronger tool pushes the weaker one's body away past it), the pair's
    combined point-contact stiffness the depth. A tool with no force cap (articulated) or nothing
    to hold gives an ``info`` row."""
    budget = s.metrics.penetration_budget_m
    held = {}
    for name, tool in station.tools.items():
        names = (
            sorted(tool.source.grasp_names(s.simulation.duration_s) - {"*"}) if tool.holds_free_bodies else []
        )
        held[name] = (tool, [tool.coupling.body_for_grasp(n) for n in names])
    inspector = station.scene_graph.model_inspector()
    rows, names = [], list(held)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            (ta, bodies_a), (tb, bodies_b) = held[a], held[b]
            subject = f"{a} and {b}"
            reason = ta.no_prediction_reason or tb.no_prediction_reason
            if not reason and not (bodies_a and bodies_b):
                reason = "a tool that holds no free body in its path presses with its own bodies only"
            pairs = [] if reason else _pairs_between(station, s, ta, tb, bodies_a, bodies_b, inspector)
            if not reason and not pairs:
                reason = "no point contact between their held bodies to predict from"
            if reason:
                rows.append(Check("contact", "static penetration between two tools' held bodies",
                                  subject, "info", None, budget, "m", "", why=reason))  # fmt: skip
                continue
            force, k, body_a, body_b = max(pairs, key=lambda p: p[0] / p[1])
            depth = force / k
            rows.append(Check(
                "contact", f"static penetration between two tools' held bodies, under the weaker pull "
                f"({force:.3g} N) into {k:.3g} N/m", f"{subject}: {body_a} against {body_b}",
                _verdict_below(depth, budget), depth, budget, "m",
                f"combined contact stiffness k_A k_B/(k_A + k_B) ≥ "
                f"{_ge(force / (WARN_FRACTION * budget))} N/m, or lower the weaker tool's omega_n or "
                "max_stretch_m",
            ))  # fmt: skip
    return rows


def _pairs_between(station, s, tool_a, tool_b, bodies_a, bodies_b, inspector) -> list[tuple]:
    """``(weaker cap N, combined stiffness N/m, body A, body B)`` for each held body of one tool
    against each of the other's (point contact only)."""
    plant = station.plant
    pairs = penetration_pairs(plant, station.scene_graph, tool_a.coupling, s.plant.penetration_allowance)
    names_b = {}
    for body in bodies_b:
        frame = plant.GetBodyFrameIdOrThrow(BodyIndex(body.index))
        names_b.update({inspector.GetName(g): body for g in inspector.GetGeometries(frame, Role.kProximity)})
    caps = {body.index: tool_b.coupling.force_caps(body)[0] for body in bodies_b}  # the other's own pull
    out = []
    own = {b.index for b in bodies_a}
    for p in pairs:
        other = names_b.get(p.obstacle)
        if p.body_index in own and other is not None and other.index != p.body_index:
            out.append(
                (min(p.force_n, caps.get(other.index, p.force_n)), p.stiffness_n_m, p.body, other.name)
            )
    return out
