"""The stability and passivity report of any scenario: ``python -m godobject_drake analyze``.

:func:`analyze` reads the models of :mod:`godobject_drake.studies.stability` off a built scene (each
god-object body's mass and inertia, the plant's step, the coupling's gains and caps, the
contact stiffness of every pair the held body can touch, the haptic device's rate, mass and
damping and the feedback gains) and returns one :class:`Check` per question, each with a
verdict (``ok``, ``warn``, ``fail`` or ``info``), its number, its limit and the change that fixes
it. With ``verify`` it simulates each prediction in Drake on the user's own scene:

- the static penetration, by holding the target 5 cm inside the nearest fixed obstacle;
- the explicit limit, by bisecting a scale on the coupling's gains until the held body's motion
  grows instead of decaying.

:func:`write_report` writes ``report.md``, ``summary.json`` and ``margins.png``. The JSON
keys are documented in docs/guide/stability.md, "Analysing your own scene". The theory is docs/theory.md.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import control as ct
import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Role
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.tree import BodyIndex

from godobject_drake.config import scenario as sc
from godobject_drake.config.device_files import JointWaypoint, Waypoint
from godobject_drake.config.gains import CouplingGains, CouplingGainWarning
from godobject_drake.limits import explicit_limit_omega_h, semi_implicit_matrix
from godobject_drake.metrics import PenetrationBudgetWarning, TrueShapeMetrics
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.station.haptic_chain import hand_on_handle
from godobject_drake.station.rigid_tool import (
    grasped_bodies,
    penetration_fix,
    penetration_pairs,
)
from godobject_drake.studies.kinds import study_kind
from godobject_drake.studies.stability import (
    BodyLoop,
    DeviceParams,
    Pipeline,
    TwoPort,
    bisect,
    body_spectral_radius,
    closed_loop_radius,
    colgate_required_damping,
    coupled_body_matrices,
    device_model,
    device_stiffness_limit,
    explicit_h_max,
    human_port_admittance,
    llewellyn_eta,
    passivity_check,
    pipeline_impedance,
)
from godobject_drake.studies.tissue_stiffness import contact_stiffness, ray_surface_hit
from godobject_drake.studies.validation import is_growing
from godobject_drake.systems.articulated import joint_space_loop
from godobject_drake.systems.coupling import graspable_bodies
from godobject_drake.systems.tissue import tool_capsules

WARN_FRACTION = 0.8  # a number past 80 % of its limit (less than 25 % margin) warns
PUSH_IN_M = 0.05  # the verification holds the target this far inside the nearest obstacle
VERDICTS = ("ok", "warn", "fail", "info")


@dataclasses.dataclass
class Check:
    """One row of the verdict table.

    ``value`` and ``limit`` are in ``unit``; ``verdict`` is ``ok``, ``warn`` (within 25 % of
    the limit), ``fail`` (past it) or ``info`` (nothing to judge: a reason in ``fix``).
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
    purpose, so the run-end :class:`PenetrationBudgetWarning` (meant for the user's run) is not said."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PenetrationBudgetWarning)
        return simulate(station, progress=False)


def analysis_scenario(scenario: sc.Scenario) -> sc.Scenario:
    """``scenario`` made headless: no recording, no page served, a live or LCM device replaced
    by a scripted one standing at its start (the analysis needs no browser and no driver)."""
    s = sc.replace(scenario, **{"recording.file": "", "visualization.serve": False, "metrics.file": ""})
    s.device = s.device.stand_in()  # the device kind's own (device_kinds): no browser, no driver
    for tool in s.tools.values():
        tool.device = tool.device.stand_in()
    return s


# -- simulation side --------------------------------------------------------------------------------------


def _pose_tool_checks(station, out: dict) -> list[Check]:
    """Explicit limit per body and axis (translation, each principal rotation) of a rigid or
    deformable god-object: symplectic Euler with the coupling explicit, docs/theory.md §1."""
    coupling, plant, h = station.coupling, station.plant, station.plant.time_step()
    g = coupling.gains
    rows, per_body = [], []
    own = {b.index: b for b in graspable_bodies(plant).values()}
    for body in _grasped(station):
        # The coupling sizes its gains on what it carries (a deformable core's shell) and the
        # model takes the carried part as moving with the body. Its explicit force acts on the
        # body alone, though: with the shell left out the limit would be lower (the
        # ``*_alone`` keys); Drake's bisection (verify) shows where the scene really is.
        alone = own[body.index]
        I_c, V = np.linalg.eigh(body.I_Bcm_B)  # principal axes of the inertia the gains use
        I_own = np.einsum("ji,jk,ki->i", V, alone.I_Bcm_B, V)
        axes = [("translation", body.mass, alone.mass, g.omega_n, g.zeta)]
        axes += [(f"rotation {i + 1}", float(I_c[i]), float(I_own[i]), g.omega_r, g.zeta_r) for i in range(3)]
        for axis, m, m_alone, w, z in axes:
            K, B = m * w**2, 2.0 * z * m * w
            loop = BodyLoop(m, K, B, h)
            limit = explicit_limit_omega_h(z)
            w_alone, z_alone = math.sqrt(K / m_alone), B / (2.0 * math.sqrt(K * m_alone))
            per_body.append({
                "body": body.name, "axis": axis, "inertia": m, "omega_rad_s": w, "zeta": z, "k": K,
                "gamma": B, "omega_h": w * h, "omega_h_limit": limit, "margin": limit / (w * h),
                "spectral_radius": body_spectral_radius(loop), "h_max_s": explicit_h_max(m, K, B),
                "omega_max_rad_s": limit / h, "inertia_alone": m_alone,
                "margin_alone": explicit_limit_omega_h(z_alone) / (w_alone * h),
            })  # fmt: skip
    out["explicit"] = per_body
    for axis in ("translation", "rotation"):
        of_axis = [r for r in per_body if r["axis"].startswith(axis)]
        worst = min(of_axis, key=lambda r: r["margin"])
        name = "omega_n" if axis == "translation" else "omega_n_rot"
        rows.append(Check(
            "simulation", f"explicit limit, {axis} (ω·h)",
            f"{worst['body']} ({_bodies(len({r['body'] for r in of_axis}))} the device grasps)",
            _verdict_below(worst["omega_h"], worst["omega_h_limit"]), worst["omega_h"],
            worst["omega_h_limit"],
            "", f"{name} ≤ {_le(WARN_FRACTION * worst['omega_max_rad_s'])} rad/s, or time_step ≤ "
            f"{_le(WARN_FRACTION * worst['omega_h_limit'] / worst['omega_rad_s'])} s "
            f"(limits {worst['omega_max_rad_s']:.4g} rad/s, "
            f"{worst['omega_h_limit'] / worst['omega_rad_s']:.4g} s)",
        ))  # fmt: skip
    h_max = min(r["h_max_s"] for r in per_body)
    out["h_max_s"] = h_max
    rows.append(Check(
        "simulation", "time step (largest stable h for these gains)", "all bodies",
        _verdict_below(h, h_max), h, h_max, "s",
        f"time_step ≤ {_le(WARN_FRACTION * h_max)} s (limit {h_max:.4g} s), or lower the gains",
    ))  # fmt: skip
    return rows


IMPLICIT_RATE_FLOOR = 0.8  # the implicit step response's decay rate, as a fraction of ωn, to pass


def implicit_rate(omega: float, zeta: float, h: float) -> float:
    """The decay rate of the implicit coupling's step response as a fraction of ``omega``:
    ``−ln ρ / (ω h)`` with ρ the pole modulus of backward Euler on the spring (docs/theory.md §7;
    for ζ = 1, ρ = 1/(1 + ω h), so ``ln(1 + ω h)/(ω h)``). 1 in the limit h → 0."""
    radius = body_spectral_radius(BodyLoop.by_bandwidth(1.0, omega, zeta, h, scheme="implicit_euler"))
    return -math.log(radius) / (omega * h)


def _implicit_pose_checks(station, out: dict) -> list[Check]:
    """What limits the implicit coupling instead of the explicit limit (docs/theory.md §7): per
    body and axis, the step response's decay rate under backward Euler against Eq. 3's ωn
    (accuracy: past the floor the scene is slow, not unstable, so it warns), and SAP's near-rigid
    regime, where SAP would soften the springs to its own time scale."""
    coupling, h = station.coupling, station.plant.time_step()
    g = coupling.gains
    beta = station.scenario.plant.sap_near_rigid_threshold
    beta = 1.0 if beta is None else beta
    per_body = []
    for body in _grasped(station):
        I_c = np.linalg.eigvalsh(body.I_Bcm_B)
        axes = [("translation", body.mass, g.omega_n, g.zeta)]
        axes += [(f"rotation {i + 1}", float(I_c[i]), g.omega_r, g.zeta_r) for i in range(3)]
        for axis, m, w, z in axes:
            # SAP calls a compliant constraint near-rigid when h (h k + d) / m > (2π/β)² (the
            # spring's time scale under β h); m here is the body's mass or principal inertia.
            per_body.append({
                "body": body.name, "axis": axis, "inertia": m, "omega_rad_s": w, "zeta": z,
                "omega_h": w * h, "rate_fraction": implicit_rate(w, z, h),
                "near_rigid_value": (w * h) ** 2 + 2 * z * w * h,
                "near_rigid_limit": (2 * math.pi / beta) ** 2 if beta > 0 else math.inf,
            })  # fmt: skip
    out["explicit"] = []
    out["implicit"] = per_body
    # The largest h whose slowest axis keeps the floor: ln(1 + x)/x falls with x = ω h.
    w_max = max(r["omega_rad_s"] for r in per_body)
    z_of = {r["omega_rad_s"]: r["zeta"] for r in per_body}[w_max]
    x_floor = bisect(lambda x: implicit_rate(1.0, z_of, x) >= IMPLICIT_RATE_FLOOR, 1e-9, 1e3, 1e-6)
    h_acc = x_floor / w_max
    out["h_max_s"] = math.inf
    out["h_accurate_s"] = h_acc
    rows = [Check("simulation", "explicit limit", "all bodies", "ok", None, None, "",
                  "none: SAP integrates the implicit coupling's springs, stable at any ω·h")]  # fmt: skip
    for axis in ("translation", "rotation"):
        of_axis = [r for r in per_body if r["axis"].startswith(axis)]
        worst = min(of_axis, key=lambda r: r["rate_fraction"])
        name = "omega_n" if axis == "translation" else "omega_n_rot"
        rate = worst["rate_fraction"]
        rows.append(Check(
            "simulation", f"implicit step response, {axis}: decay rate / ωn (backward Euler)",
            f"{worst['body']} ({_bodies(len({r['body'] for r in of_axis}))} the device grasps)",
            "ok" if rate >= IMPLICIT_RATE_FLOOR else "warn", rate, IMPLICIT_RATE_FLOOR, "",
            f"time_step ≤ {_le(x_floor / worst['omega_rad_s'])} s or {name} ≤ {_le(x_floor / h)} rad/s "
            "for a response within 20 % of Eq. 3's rate (slower past it, never unstable)", bound="lower",
        ))  # fmt: skip
        near = max(of_axis, key=lambda r: r["near_rigid_value"] / r["near_rigid_limit"])
        rows.append(Check(
            "simulation", f"SAP near-rigid regime, {axis}: h(hk + d)/m against (2π/β)², β = {beta:g}",
            near["body"], _verdict_below(near["near_rigid_value"], near["near_rigid_limit"]),
            near["near_rigid_value"], near["near_rigid_limit"], "",
            f"{name} ≤ {_le(2 * math.pi / (beta * h))} rad/s about, or a smaller time_step, or a lower "
            "plant.sap_near_rigid_threshold (SAP softens a near-rigid spring to its own time scale)",
        ))  # fmt: skip
    return rows


def _articulated_checks(station, out: dict, duration_s: float, check_every: int) -> list[Check]:
    """The joint-space check the builder runs (every ``check_every``-th device sample), with its
    margin: the largest bandwidth scale and step that keep the worst configuration stable."""
    coupling, h = station.coupling, station.plant.time_step()
    if coupling.coupling == "joint_pd_sap":
        out["explicit"] = []
        return [Check("simulation", "explicit limit (joint space)", "tool", "ok", None, None, "",
                      "implicit (SAP's PD actuators): unconditionally stable")]  # fmt: skip
    device = station.device
    qs = device.samples(duration_s)[::check_every]
    tool, gains, mode = coupling.tool, coupling.gains, coupling.coupling
    loops = [joint_space_loop(tool, mode, gains, np.asarray(q, float), h) for q in qs]
    i = int(np.argmax([lp.radius for lp in loops]))
    q_worst, worst = np.asarray(qs[i], float), loops[i]

    def stable_at(scale: float, step: float) -> bool:
        g = dataclasses.replace(gains, omega_n=gains.omega_n * scale, omega_n_rot=gains.omega_r * scale)
        return joint_space_loop(tool, mode, g, q_worst, step).radius < 1.0

    scale = bisect(lambda c: stable_at(c, h), 1e-3, 1e3, 1e-4) if stable_at(1e-3, h) else float("nan")
    h_max = (
        bisect(lambda step: stable_at(1.0, step), 1e-7, 1.0, 1e-4) if stable_at(1.0, 1e-7) else float("nan")
    )
    out["explicit"] = [{
        "configurations": len(loops), "worst_q": q_worst.tolist(), "spectral_radius": worst.radius,
        "fastest_mode_rad_s": worst.omega_max, "bandwidth_scale_max": scale, "h_max_s": h_max,
    }]  # fmt: skip
    out["h_max_s"] = h_max
    return [
        Check("simulation", f"explicit limit, joint space ({len(loops)} configurations; "
              f"spectral radius {worst.radius:.4f})", "tool",
              _verdict_below(1.0, scale), 1.0, scale, "× gains (bandwidth scale)",
              f"omega_n ≤ {_le(WARN_FRACTION * gains.omega_n * scale)} and omega_n_rot ≤ "
              f"{_le(WARN_FRACTION * gains.omega_r * scale)} rad/s (limit ×{scale:.4g}), "
              "or coupling joint_pd_sap (implicit)"),
        Check("simulation", "time step (largest stable h for these gains)", "tool",
              _verdict_below(h, h_max), h, h_max, "s",
              f"time_step ≤ {_le(WARN_FRACTION * h_max)} s (limit {h_max:.4g} s), or lower the gains"),
    ]  # fmt: skip


# -- FEM tissue -------------------------------------------------------------------------------------------


def _tissue_pose(station, q_device: np.ndarray) -> dict | None:
    """The articulated tool at ``q_device`` with its imposed joints (the jaws) at 0 (closed: one
    contact) against the FEM organ's rest surface: the tube's axis from the tip body's origin
    (``d``, toward the tip), how far the tool reaches past that origin along it, and where the
    axis meets the surface; None if the axis misses the organ."""

    tool, plant = station.coupling.tool, station.plant
    organ = station.god_object.tissue
    q = np.array(q_device, float)
    for k, joint in enumerate(tool.joints):
        if joint.imposed:
            q[k] = 0.0
    ctx = tool.set_device_state(q)
    # the tip body as the tool's metrics take it: the scenario's, else the last coupled body
    tip_name = station.scenario.god_object.tip_body or plant.get_body(BodyIndex(tool.bodies[-1].index)).name()
    tip = plant.GetBodyByName(tip_name, tool.model)
    X = plant.EvalBodyPoseInWorld(ctx, tip)
    p, d = X.translation(), -X.rotation().matrix()[:, 2]
    reach, radius = -math.inf, math.inf
    for index, X_BG, r, half in tool_capsules(plant, station.scene_graph, tool.model):
        X_WG = plant.EvalBodyPoseInWorld(ctx, plant.get_body(BodyIndex(index))) @ X_BG
        for end in (-half, half):
            e = float((X_WG.translation() + end * X_WG.rotation().matrix()[:, 2] - p) @ d) + r
            if e > reach:
                reach, radius = e, r
    # From behind the tip and outside the organ, so that a tip already inside finds the entry.
    back = float(np.max(np.linalg.norm(organ.rest_W - p, axis=1))) + 0.01
    hit = ray_surface_hit(organ.rest_W, organ.triangles, p - back * d, d)
    if hit is None:
        return None
    return {"q": q, "p": p, "d": d, "reach_m": reach, "tip_radius_m": radius, "distance_m": hit[0] - back,
            "depth_m": reach - (hit[0] - back), "ctx": ctx, "tip": tip}  # fmt: skip


def _tissue_press(station, duration_s: float) -> dict | None:
    """Where the tool presses the FEM organ hardest on the device's path (the sample whose tool
    reaches deepest past the rest surface along its axis), with what the analysis needs there:
    the tissue's stiffness from the FEM model, the coupling's stiffness at the tip along the
    axis, the joint that slides the tip along it, and the joint-space loop."""
    from pydrake.multibody.tree import JacobianWrtVariable

    tool, plant = station.coupling.tool, station.plant
    poses = [_tissue_pose(station, q) for q in station.device.samples(duration_s)]
    poses = [x for x in poses if x is not None]
    if not poses:
        return None
    pose = max(poses, key=lambda x: x["depth_m"])
    q, p, d = pose["q"], pose["p"], pose["d"]
    slide = None  # the device joint that moves the tip body along d (the insertion)
    for k in range(len(q)):
        dq = np.zeros_like(q)
        dq[k] = 1e-4
        moved = _tissue_pose(station, q + dq)
        dp = moved["p"] - p if moved is not None else np.zeros(3)
        if np.linalg.norm(dp) > 0 and abs(dp @ d) > 0.999 * np.linalg.norm(dp):
            slide = (k, float(dp @ d) / 1e-4)
            break
    organ = station.god_object.tissue
    back = float(np.max(np.linalg.norm(organ.rest_W - p, axis=1))) + 0.01
    contact = contact_stiffness(organ, p - back * d, d)
    coupling, h = station.coupling, plant.time_step()
    q_touch = q.copy()
    if slide is not None:
        q_touch[slide[0]] -= pose["depth_m"] / slide[1]
    loop = joint_space_loop(tool, coupling.coupling, coupling.gains, q_touch, h)
    ctx = tool.set_device_state(q_touch)
    W = plant.world_frame()
    J = plant.CalcJacobianTranslationalVelocity(
        ctx, JacobianWrtVariable.kV, pose["tip"].body_frame(), np.zeros(3), W, W
    )
    Jd = d @ J[:, tool.coupled_v()]
    k_tip = 1.0 / float(Jd @ np.linalg.solve(loop.K, Jd))
    spec = organ.spec
    E_star = spec.youngs_modulus_pa / (1.0 - spec.poissons_ratio**2)
    return {
        "q_touch": q_touch, "slide": slide, "loop": loop, "Jd": Jd, "d": d,
        "organ": organ.name, "cells": spec.cells, "point_W": contact["point_W"],
        "direction_W": d.tolist(), "stiffness_n_m": contact["stiffness_n_m"], "tool_stiffness_n_m": k_tip,
        "push_m": max(pose["depth_m"], 0.0), "tip_radius_m": pose["tip_radius_m"],
        "hertz_tangent_1mm_n_m": 2.0 * E_star * math.sqrt(pose["tip_radius_m"] * 1e-3),
        "stiffness_damping_s": spec.stiffness_damping_s,
    }  # fmt: skip


def _tissue_checks(station, scenario: sc.Scenario, out: dict) -> list[Check]:
    """The FEM organ's stiffness where the tool presses it (from the FEM model, not a point
    stiffness), the indentation and force it gives under the device's deepest push, and the
    joint-space explicit limit with the tissue in the loop (docs/theory.md §8)."""
    if station.god_object.tissue is None:
        return []
    press = _tissue_press(station, scenario.simulation.duration_s)
    out["_tissue_press"] = press
    if press is None:
        out["tissue"] = None
        return [Check("tissue", "stiffness at the tool's contact", "organ", "info", None, None, "",
                      "the tool's axis never points at the FEM organ on the device's path")]  # fmt: skip
    k, K = press["stiffness_n_m"], press["tool_stiffness_n_m"]
    push = press["push_m"]
    depth = K * push / (K + k)
    force = k * depth
    tissue = {key: v for key, v in press.items() if key not in ("q_touch", "slide", "loop", "Jd", "d")}
    tissue.update(predicted_indentation_m=depth, predicted_force_n=force)
    rows = [
        Check("tissue", f"stiffness at the tool's contact (linear FEM of the {press['cells']}-cell mesh, "
              "point force)", press["organ"], "info", k, None, "N/m",
              f"Hertz's tangent for the {press['tip_radius_m'] * 1e3:g} mm tip at 1 mm: "
              f"{press['hertz_tangent_1mm_n_m']:.4g} N/m; the mesh is stiffer than the continuum until its "
              "surface triangles are smaller than the contact: raise organs.cells"),
        Check("tissue", f"indentation under the device's deepest push ({push * 1e3:.3g} mm past the surface)",
              press["organ"], "info", depth, None, "m",
              f"k_tip (d − δ) = k δ: the coupling's stiffness at the tip along the tube, "
              f"{K:.4g} N/m, against the tissue's {k:.4g} N/m; force {force:.3g} N"),
    ]  # fmt: skip
    coupling, h = station.coupling, station.plant.time_step()
    if coupling.coupling == "joint_pd_sap":
        why = "implicit (SAP's PD actuators): unconditionally stable"
        rows.append(Check("simulation", "explicit limit, joint space, pressing the tissue", "tool", "ok",
                          None, None, "", why))  # fmt: skip
        out["tissue"] = tissue
        return rows

    loop, Jd = press["loop"], press["Jd"]
    K_i = k * np.outer(Jd, Jd)
    D_i = press["stiffness_damping_s"] * K_i  # the tissue's Rayleigh damping β K at the contact

    def radius(c: float) -> float:
        A = semi_implicit_matrix(loop.M, c * c * loop.K, c * loop.D, K_i, D_i, h)
        return float(np.max(np.abs(np.linalg.eigvals(A))))

    scale = bisect(lambda c: radius(c) < 1.0, 1e-3, 1e3, 1e-4) if radius(1e-3) < 1.0 else float("nan")
    tissue.update(spectral_radius=radius(1.0), bandwidth_scale_max=scale)
    out["tissue"] = tissue
    g = coupling.gains
    rows.append(Check(
        "simulation", f"explicit limit, joint space, pressing the tissue ({k:.4g} N/m at the tip, implicit)",
        "tool", _verdict_below(1.0, scale), 1.0, scale, "× gains (bandwidth scale)",
        f"omega_n ≤ {_le(WARN_FRACTION * g.omega_n * scale)} and omega_n_rot ≤ "
        f"{_le(WARN_FRACTION * g.omega_r * scale)} rad/s (limit ×{scale:.4g}), or coupling joint_pd_sap",
    ))  # fmt: skip
    return rows


def _verify_tissue(station, scenario, out: dict) -> list[Check]:
    """Press the tool into the FEM organ in Drake where the analysis found the deepest push,
    along the tube's axis with the jaws closed, to two holds whose predicted surface displacement
    is 0.5 and 1 mm; at each, the tissue's force over its largest surface displacement against
    the linear FEM's stiffness, and the force on the tool against the coupling's pull."""
    press = out.get("_tissue_press")
    if press is None or press["slide"] is None:
        return []
    k, K = press["stiffness_n_m"], press["tool_stiffness_n_m"]
    device = scenario.device
    mix = np.array(device.mix, float) if device.mix else np.eye(len(device.channels))
    joint, rate = press["slide"]
    d = press["d"]

    def at(t: float, inside: float) -> JointWaypoint:
        q = press["q_touch"].copy()
        q[joint] += inside / rate
        channels = np.linalg.lstsq(mix, q, rcond=None)[0]
        return JointWaypoint(t, dict(zip(device.channels, channels.tolist(), strict=True)))

    displacements = (0.5e-3, 1e-3)
    pushes = [u * (K + k) / K for u in displacements]  # k δ = K (d − δ) with δ = u
    path, t, holds = [at(0.0, -3e-3), at(0.1, -3e-3)], 0.1, []
    for push in pushes:
        path += [at(t + 0.3, push), at(t + 0.7, push)]
        t += 0.7
        holds.append(t)
    s = analysis_scenario(scenario)
    s.device = sc.ScriptedJoints(channels=list(device.channels), mix=device.mix, limits=device.limits,
                                 rate_hz=device.rate_hz, waypoints=path)  # fmt: skip
    s.simulation.duration_s = t
    result = _probe(_quiet_build(s))
    h = station.plant.time_step()
    rows_out, checks = [], []
    for push, u_pred, t_hold in zip(pushes, displacements, holds, strict=True):
        i = round(t_hold / h)
        window = result.data["tissue"][max(i - round(0.05 / h), 0) : i]
        force = float(np.mean(window[:, 4:7] @ d))  # on the tissue, along the push
        u = float(np.mean(window[:, 0]))
        rows_out.append({"push_m": push, "predicted_displacement_m": u_pred, "displacement_m": u,
                         "force_n": force, "stiffness_n_m": force / u if u > 0 else float("nan"),
                         "predicted_force_n": K * (push - u_pred)})  # fmt: skip
    out["verify_tissue"] = {
        "runs": rows_out,
        "predicted_stiffness_n_m": k,
        "diverged": bool(result.metrics["diverged"]),
    }
    last = rows_out[-1]
    err = abs(last["stiffness_n_m"] / k - 1.0)
    checks.append(Check(
        "verify", f"tissue stiffness at the contact: Drake's force / surface displacement at "
        f"{last['displacement_m'] * 1e3:.2g} mm against the linear FEM", press["organ"],
        "ok" if err <= 0.1 else "warn", err, 0.1, "relative error",
        "model and Drake agree" if err <= 0.1 else
        "Drake's corotated tissue under contact departs from linear statics: trust Drake's force",
        predicted=k, simulated=last["stiffness_n_m"],
    ))  # fmt: skip
    err_f = abs(last["force_n"] / last["predicted_force_n"] - 1.0)
    checks.append(Check(
        "verify", f"force on the tool, target {last['push_m'] * 1e3:.3g} mm past the surface", "tool",
        "ok" if err_f <= 0.1 else "warn", err_f, 0.1, "relative error",
        "model and Drake agree" if err_f <= 0.1 else
        "the tool sits deeper than the surface's displacement (contact compliance): trust Drake's force",
        predicted=last["predicted_force_n"], simulated=last["force_n"],
    ))  # fmt: skip
    return checks


# -- contact ----------------------------------------------------------------------------------------------


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
        return [Check("contact", "static penetration", kind, "info", None, budget, "m", reason)]
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


def _bodies(n: int) -> str:
    return f"{n} body" if n == 1 else f"{n} bodies"


def _grasped(station) -> list:
    """The coupling's bodies the device grasps by its path (all, for a live device or ``*``)."""
    return grasped_bodies(station.coupling, station.device, station.scenario.simulation.duration_s)


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


# -- device side ------------------------------------------------------------------------------------------


def _device_checks(station, scenario: sc.Scenario, out: dict) -> list[Check]:
    """Colgate, passivity, Llewellyn and the device's stiffness limit along one axis of the held
    body on its stiffest obstacle (docs/theory.md §2–3), for an impedance-type haptic device."""
    haptic, fb = scenario.haptic, scenario.feedback
    out["device"] = None
    if haptic.mode != "impedance" or (fb.kd == 0 and fb.gamma_d == 0):
        why = (
            "no haptic device (haptic.mode none): the feedback reaches no one"
            if haptic.mode == "none"
            else f"haptic.mode {haptic.mode}: the device follows the sensed force, not analysed here"
            if haptic.mode == "admittance"
            else "feedback gains are zero: the device feels nothing"
        )
        return [Check("device", "haptic loop", "device", "info", None, None, "", why)]
    h, T = station.plant.time_step(), 1.0 / haptic.rate_hz
    coupling = station.coupling
    body = _held_body(station)
    pairs = [p for p in out.get("contact_pairs", []) if p["body"] == body.name]
    k_w = max((p["stiffness_n_m"] for p in pairs), default=0.0)
    tau = scenario.contact.relaxation_time_s or h
    g = coupling.gains
    # The implicit coupling's spring is backward Euler like the contact (docs/theory.md §7).
    scheme = "implicit_euler" if loop_model(station) == "implicit_body" else "drake"
    loop = BodyLoop.by_bandwidth(body.mass, g.omega_n, g.zeta, h, k_w=k_w, b_w=k_w * tau, scheme=scheme)
    dev = DeviceParams(haptic.device_mass_kg, haptic.device_damping, T, 0)
    pipe = Pipeline(loop, fb.kd, fb.gamma_d, T)
    H = pipeline_impedance(pipe)
    colgate = colgate_required_damping(H, T)
    limit = device_stiffness_limit(dev, lambda kd: pipeline_impedance(dataclasses.replace(pipe, kd=kd)))
    radius = closed_loop_radius(dev, H)
    # An unstable device loop is not passive; python-control's LMIs need a stable one, and may
    # call a loop near its stability limit ill-conditioned: Colgate's criterion decides then.
    passivity_method = "ispassive"
    if radius >= 1.0:
        passive, passivity_method = False, "unstable"
    else:
        try:
            passive = passivity_check(human_port_admittance(dev, H)).passive
        except (ValueError, RuntimeError):
            passive, passivity_method = colgate.required_b <= dev.damping, "colgate"
    lle = llewellyn_eta(TwoPort(body.mass, loop.k, loop.gamma, fb.kd, fb.gamma_d))
    proportional = (
        fb.gamma_d > 0 and abs(fb.kd * loop.gamma - fb.gamma_d * loop.k) <= 1e-9 * loop.k * fb.gamma_d
    )

    def colgate_ok(kd: float) -> bool:
        H_kd = pipeline_impedance(dataclasses.replace(pipe, kd=kd))
        return colgate_required_damping(H_kd, T, n=800, refine=False).required_b <= dev.damping

    kd_safe = bisect(colgate_ok, 1e-9, limit, 1e-3) if colgate_ok(1e-9) else 0.0
    kd_safe = min(kd_safe, limit)
    out["device"] = {
        "body": body.name, "mass_kg": body.mass, "k_w": k_w, "tau_w": tau, "period_s": T,
        "device_mass_kg": dev.mass, "device_damping": dev.damping, "kd": fb.kd, "gamma_d": fb.gamma_d,
        "colgate_required_b": colgate.required_b, "passivity_margin": colgate.margin(dev.damping),
        "closed_loop_radius": radius, "kd_limit": limit, "kd_max_passive": kd_safe,
        "ispassive": passive, "passivity_method": passivity_method, "eta_min": lle.eta_min,
        "proportional": proportional,
    }  # fmt: skip
    ratio = f"kd/gamma_d = k/gamma = {loop.k / loop.gamma:.4g} s⁻¹"
    return [
        Check("device", "Colgate: required device damping", body.name,
              "ok" if colgate.required_b <= dev.damping else "fail", colgate.required_b, dev.damping, "N·s/m",
              f"kd ≤ {_le(kd_safe)} N/m for device_damping {dev.damping:g}, or device_damping ≥ "
              f"{_ge(colgate.required_b)} N·s/m, or haptic.passivity_damping > 0"),
        Check("device", "device stiffness limit (closed-loop poles)", body.name,
              _verdict_below(fb.kd, limit), fb.kd, limit, "N/m", f"kd ≤ {_le(WARN_FRACTION * limit)} N/m"),
        Check("device", "passive against the user (python-control ispassive)", body.name,
              "ok" if passive else "fail", float(passive), 1.0, "",
              f"proportional gains ({ratio}) with kd ≤ {_le(kd_safe)} N/m", bound="lower"),
        Check("device", "Llewellyn η_min (1: absolutely stable two-port)", body.name,
              "ok" if lle.eta_min >= 1 - 1e-9 else "warn", lle.eta_min, 1.0, "",
              "proportional gains: " + ratio, bound="lower"),
    ]  # fmt: skip


def _held_body(station):
    """The body the scenario's device grasps first, else the lightest it may hold."""
    coupling = station.coupling
    names = sorted(station.device.grasp_names(station.scenario.simulation.duration_s) - {"*"})
    if names:
        return coupling.body_for_grasp(names[0])
    return min({b.index: b for b in coupling.bodies.values()}.values(), key=lambda b: b.mass)


# -- checked in Drake -------------------------------------------------------------------------------------


def _hold_scenario(scenario, body, X_WD0: RigidTransform, X_WD1: RigidTransform, duration: float,
                   move: tuple[float, float] = (0.0, 0.05)):  # fmt: skip
    """``scenario`` driven by a device that grasps ``body`` at ``X_WD0`` and moves to ``X_WD1``
    from ``move[0]`` to ``move[1]`` s (default over the first 0.05 s), then holds;
    ``random_seed`` and everything else as the user wrote them."""

    def waypoint(t, X):
        rpy = np.degrees(RollPitchYaw(X.rotation()).vector()).tolist()
        return Waypoint(t=t, xyz=X.translation().tolist(), rpy_deg=rpy, grasp=body)

    path = [waypoint(0.0, X_WD0)] if move[0] > 0 else []
    path += [waypoint(move[0], X_WD0), waypoint(move[1], X_WD1), waypoint(duration, X_WD1)]
    device = sc.Scripted(rate_hz=scenario.device.rate_hz, waypoints=path)
    s = sc.replace(scenario, **{"simulation.duration_s": duration})
    s.device = device
    return s


def _without_haptics(scenario: sc.Scenario) -> sc.Scenario:
    """The device's pose as the target, held: what the one-body models assume."""
    return sc.replace(scenario, **{"haptic.mode": "none", "haptic.passivity_damping": 0.0})


def _start_pose(station, body) -> RigidTransform:
    """The body's centre-of-mass frame at the scene's start (its default pose)."""
    plant = station.plant
    ctx = plant.CreateDefaultContext()
    X_WB = plant.EvalBodyPoseInWorld(ctx, plant.get_body(BodyIndex(body.index)))
    return X_WB.multiply(RigidTransform(body.p_BoBcm_B))


def _nearest_fixed_obstacle(station, body):
    """``(distance, unit direction from the body toward the obstacle, obstacle, contacts)``
    for the fixed obstacle geometry nearest ``body`` at the start; ``contacts``: how many of the
    body's geometries are within 0.1 mm of that distance (the points that share a push)."""
    diagram, plant, sg = station.diagram, station.plant, station.scene_graph
    ctx = diagram.CreateDefaultContext()
    query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(ctx))
    inspector = query.inspector()
    frame = plant.GetBodyFrameIdOrThrow(BodyIndex(body.index))
    welded = {plant.GetBodyFrameIdOrThrow(b.index()) for b in plant.GetBodiesWeldedTo(plant.world_body())}
    own = inspector.GetGeometries(frame, Role.kProximity)
    X_WB = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(ctx), plant.get_body(BodyIndex(body.index)))
    found = {}
    for b in inspector.GetAllGeometryIds(Role.kProximity):
        if inspector.GetFrameId(b) not in welded or inspector.IsDeformableGeometry(b):
            continue
        for a in own:
            if inspector.CollisionFiltered(a, b):
                continue
            try:
                r = query.ComputeSignedDistancePairClosestPoints(a, b)
            except RuntimeError:  # a pair Drake's signed distance does not support (docs/design.md)
                continue
            # nhat_BA_W points from the pair's B toward its A; Drake may order the pair by id.
            toward = -np.asarray(r.nhat_BA_W) if r.id_A == a else np.asarray(r.nhat_BA_W)
            if not np.all(np.isfinite(toward)):  # touching (distance 0): Drake gives no normal
                toward = _toward_obstacle(query, b, X_WB)
                if toward is None:
                    continue
            found.setdefault(b, []).append((r.distance, toward))
    if not found:
        return None
    b = min(found, key=lambda g: min(d for d, _ in found[g]))
    dists = found[b]
    d0, direction = min(dists, key=lambda x: x[0])
    contacts = sum(1 for d, _ in dists if d <= d0 + 1e-4)
    return d0, direction, inspector.GetName(b), contacts


def _toward_obstacle(query, obstacle, X_WB):
    """For a pair in contact, where Drake's signed distance gives no normal: the direction from the
    body's origin toward the obstacle, down the obstacle's distance gradient there (for a body
    resting on a table, straight down), or None where that is not defined either."""
    for d in query.ComputeSignedDistanceToPoint(X_WB.translation(), np.inf):
        if d.id_G == obstacle:
            g = -np.asarray(d.grad_W)
            n = float(np.linalg.norm(g))
            return g / n if n > 1e-12 and np.all(np.isfinite(g)) else None
    return None


def _push_in(station, out: dict):
    """The held body, the nearest fixed obstacle, its ``n`` touching geometries and their pair
    stiffness ``k``, the push direction, and the device poses that grasp the body at its start
    (``X0``) and hold its target ``PUSH_IN_M`` inside the obstacle (``X1``); None without one."""
    body = _held_body(station)
    near = _nearest_fixed_obstacle(station, body)
    if near is None:
        return None
    d0, direction, obstacle, n = near
    k = min(p["stiffness_n_m"] for p in out["contact_pairs"]
            if p["body"] == body.name and p["obstacle"] == obstacle)  # fmt: skip
    X0 = _start_pose(station, body)
    X1 = RigidTransform(X0.rotation(), X0.translation() + (max(d0, 0.0) + PUSH_IN_M) * direction)
    return body, obstacle, n, k, direction, X0, X1


def _verify_penetration(station, scenario, out: dict) -> Check | None:
    """Hold the target 5 cm inside the nearest fixed obstacle; the body settles where the
    spring's pull equals the contacts' push, ``δ = F/(n k)`` with ``F = K (5 cm − δ)``."""
    if not station.god_object.predicts_penetration or not out.get("contact_pairs"):
        return None
    push = _push_in(station, out)
    if push is None:
        return None
    body, obstacle, n, k, direction, X0, X1 = push
    coupling = station.coupling
    K = body.mass * coupling.gains.omega_n**2
    f_cap, _ = coupling.force_caps(body)
    gravity = 0.0
    if not scenario.god_object.gravity_compensation:
        gravity = body.mass * float(np.dot(station.plant.gravity_field().gravity_vector(), direction))
    depth = (K * PUSH_IN_M + gravity) / (n * k + K)
    if K * (PUSH_IN_M - depth) > f_cap:
        depth = (f_cap + gravity) / (n * k)
    settle = 1.0 + 20.0 / coupling.gains.omega_n
    s = _hold_scenario(_without_haptics(analysis_scenario(scenario)), body.name, X0, X1, settle)

    run_station = _quiet_build(s)
    result = _probe(run_station)
    states = result.data["state"][-1:]
    shapes = TrueShapeMetrics(run_station.plant, run_station.scene_graph, run_station.diagram)
    simulated = float(np.max(shapes.overlaps(body.index, states)))
    out["verify_penetration"] = {
        "body": body.name, "obstacle": obstacle, "contacts": n, "pair_stiffness_n_m": k,
        "push_in_m": PUSH_IN_M, "predicted_m": depth, "simulated_m": simulated,
        "relative_error": simulated / depth - 1.0, "diverged": bool(result.metrics["diverged"]),
    }  # fmt: skip
    err = abs(simulated / depth - 1.0)
    name = f"static penetration, target {PUSH_IN_M * 100:g} cm inside {obstacle} ({n} contacts)"
    return Check("verify", name, body.name, "ok" if err <= 0.1 else "warn", err, 0.1, "relative error",
                 "model and Drake agree" if err <= 0.1 else
                 "the contact differs from SAP's linear point law (near-rigid regime?): trust Drake's depth",
                 predicted=depth, simulated=simulated)  # fmt: skip


def _verify_explicit_limit(station, scenario, out: dict, rel_tol: float) -> Check | None:
    """Bisect a scale ``c`` on both bandwidths (``omega_n``, ``omega_n_rot``) in the user's
    scene: the held body is grasped at its start, pulled 3 cm away from the nearest obstacle
    and turned by 10°; stable if its error decays. Predicted: the smallest ``limit/(ω h)``."""
    if not out.get("explicit"):
        return None
    body = _held_body(station)
    rows = [r for r in out["explicit"] if r["body"] == body.name]
    predicted = min(r["margin"] for r in rows)
    binding = min(rows, key=lambda r: r["margin"])["axis"]
    near = _nearest_fixed_obstacle(station, body) if station.god_object.predicts_penetration else None
    away = -near[1] if near else np.array([0.0, 0.0, 1.0])
    X0 = _start_pose(station, body)
    X1 = RigidTransform(X0.rotation().multiply(RotationMatrix.MakeXRotation(np.radians(10.0))),
                        X0.translation() + 0.03 * away)  # fmt: skip
    h = station.plant.time_step()
    duration = 0.05 + 600 * h
    # The one-body model's target is the device's pose, held: a haptic device's handle moving
    # with the feedback would make it another loop (the device rows check that one).
    base = _without_haptics(analysis_scenario(scenario))
    gains = base.god_object.gains
    runs: dict[float, bool] = {}

    def stable(c: float) -> bool:
        if c not in runs:
            runs[c] = _stable_at(c)
        return runs[c]

    def _stable_at(c: float) -> bool:
        return hold_is_stable(base, body.name, X0, X1, _scaled(gains, c), duration)

    simulated = _bisect_widening(stable, predicted, rel_tol, out, "verify_explicit_limit_error")
    err = abs(simulated / predicted - 1.0)
    out["verify_explicit_limit"] = {
        "body": body.name, "binding_axis": binding, "predicted_scale": predicted,
        "simulated_scale": simulated,
        "relative_error": simulated / predicted - 1.0, "bisection_tolerance": rel_tol,
        "runs": [{"scale": c, "stable": ok} for c, ok in sorted(runs.items())],
    }  # fmt: skip
    g = gains
    # What run accepts (CouplingGains.check): never advise past it, whatever Drake's boundary says.
    run_n, run_r = explicit_limit_omega_h(g.zeta) / h, explicit_limit_omega_h(g.zeta_r) / h
    beyond = math.isfinite(simulated) and simulated > predicted
    fix = (
        "model and Drake agree"
        if err <= 0.02
        else f"trust Drake's boundary: omega_n ≤ {_le(g.omega_n * simulated)}, omega_n_rot ≤ "
        f"{_le(g.omega_r * simulated)} rad/s (the one-body model misses how the scene moves with the body)"
        if math.isfinite(simulated) and not beyond
        else f"Drake's boundary is past the model's; run refuses past the model's explicit limit: omega_n < "
        f"{run_n:.4g}, omega_n_rot < {run_r:.4g} rad/s at this time_step"
        if beyond
        else "no boundary found in Drake: " + out.get("verify_explicit_limit_error", "")
    )
    return Check("verify", f"explicit limit: gain scale at the boundary ({binding})", body.name,
                 "ok" if err <= 0.02 else "warn", err, 0.02, "relative error", fix,
                 predicted=predicted, simulated=simulated)  # fmt: skip


def hold_is_stable(base: sc.Scenario, body: str, X0: RigidTransform, X1: RigidTransform,
                   gains: CouplingGains, duration: float) -> bool:  # fmt: skip
    """Whether ``body``, grasped at ``X0`` and moved to ``X1`` over 0.05 s with ``gains``, settles
    there in Drake (the explicit limit's verification, :func:`_verify_explicit_limit`)."""
    s = _hold_scenario(base, body, X0, X1, duration)
    s.god_object.gains = gains
    try:
        result = _probe(_quiet_build(s))
    except RuntimeError:  # Drake gave up on a blown-up state: unstable
        return False
    if result.metrics["diverged"]:
        return False
    h = s.time_step
    start = round(0.05 / h) + 1  # from the end of the move
    if "terms" in result.data:  # rigid: the coupling's body pose G
        pose_G = result.data["terms"][start:, 14:21]
    else:  # deformable: the core
        pose_G = result.data["pose_WC"][start:]
    # Motion per step, not the error: a steady offset (a carried shell's sag) never grows,
    # a decaying transient shrinks, and a growing mode or a capped limit cycle does not.
    dp = np.linalg.norm(np.diff(pose_G[:, 4:], axis=0), axis=1)
    dq = np.linalg.norm(np.diff(pose_G[:, :4], axis=0), axis=1)
    if is_growing(dp) or is_growing(dq):
        return False
    # ... and the body must have got to its target. Past the limit a body can blow up, be thrown
    # into the table and stop there, still, far from its target (the brick at 1.06x the limit:
    # 3.9 cm off after a 3 cm pull, its quaternion projected back to unit norm); "no motion" read
    # as stable put Drake's boundary past the limit run enforces (omega_n 1004 rad/s advised on
    # the brick scene with omega_n_rot 40, where run refuses past 828.4).
    return _reached(pose_G[-1], X1)


IMPLICIT_STEP_M = 0.03  # the implicit coupling's verification steps the target this far


def _verify_implicit_rate(station, scenario, out: dict) -> Check | None:
    """The implicit coupling's step response in Drake against its one-body model, twice: the held
    body is grasped at its start and its target jumps 3 cm away from the nearest obstacle
    (``along``: for the brick, up, along the gravity raise), or, lifted 3 cm away first, 3 cm
    across it (``across``: horizontal), between two device samples. From
    the first step after the target stops (one sample after the jump) the model (backward Euler
    on the spring, :func:`~godobject_drake.studies.stability.coupled_body_matrices`) is started
    from Drake's own state and both error curves are compared until the model's falls to 1 %.
    Checked: the time each takes to fall to 10 % of the error at that start, the worse of the
    two directions."""
    if not out.get("implicit"):
        return None
    body = _held_body(station)
    near = _nearest_fixed_obstacle(station, body) if station.god_object.predicts_penetration else None
    away = -near[1] if near else np.array([0.0, 0.0, 1.0])
    X0 = _start_pose(station, body)
    g, h = station.coupling.gains, station.plant.time_step()
    period = 1.0 / scenario.device.rate_hz
    # A step: the target jumps between two device samples, once the grasp has settled. The
    # sample after the jump reports its velocity (the backward difference, which leads the
    # springs' world ends); from the next one the target is still.
    jump = (math.ceil(0.1 / period) + 0.5) * period
    still = (math.ceil(jump / period) + 1) * period
    start = math.ceil(still / h) + 2
    model = BodyLoop.by_bandwidth(body.mass, g.omega_n, g.zeta, h, scheme="implicit_euler")
    A, _ = coupled_body_matrices(model)
    # Long enough for the model's error to fall to 1 % from any start state of the move.
    horizon = max(math.ceil(8.0 / (implicit_rate(g.omega_n, g.zeta, h) * g.omega_n * h)), 50)
    base = _without_haptics(analysis_scenario(scenario))

    def step(X_from: RigidTransform, direction: np.ndarray) -> dict:
        X_to = RigidTransform(X_from.rotation(), X_from.translation() + IMPLICIT_STEP_M * direction)
        s = _hold_scenario(base, body.name, X0, X_to, (start + horizon + 2) * h, move=(jump, jump + 1e-6))
        if X_from is not X0:  # lifted clear first, over the first 0.05 s, then held
            rpy = np.degrees(RollPitchYaw(X0.rotation()).vector()).tolist()
            lifted = Waypoint(t=0.05, xyz=X_from.translation().tolist(), rpy_deg=rpy, grasp=body.name)
            path = s.device.waypoints
            s.device = sc.Scripted(rate_hz=s.device.rate_hz, waypoints=[path[0], lifted,
                                   dataclasses.replace(lifted, t=jump), *path[2:]])  # fmt: skip
        result = _probe(_quiet_build(s))
        target = float(np.dot(X_to.translation(), direction))
        x_sim = result.data["terms"][:, 18:21] @ direction - target  # the body's G along the step
        x0, v0 = x_sim[start], (x_sim[start] - x_sim[start - 1]) / h
        x_model, state = [], np.array([x0, v0])
        for _ in range(horizon):
            x_model.append(state[0])
            state = A @ state
        x_sim, x_model = x_sim[start : start + horizon], np.asarray(x_model)

        def t10(x):
            below = np.nonzero(np.abs(x) <= 0.1 * abs(x[0]))[0]
            return below[0] * h if below.size else math.nan

        predicted, simulated = t10(x_model), t10(x_sim)
        return {
            "direction": direction.tolist(), "start_error_m": float(x0),
            "predicted_t10_s": predicted, "simulated_t10_s": simulated,
            "relative_error": abs(simulated / predicted - 1.0) if predicted > 0 else math.nan,
            "worst_gap_over_start": float(np.max(np.abs(x_sim - x_model)) / abs(x0)),
            "diverged": bool(result.metrics["diverged"]),
        }  # fmt: skip

    # Along the gravity raise (vertical), and across it 3 cm clear of the obstacle: a distance
    # constraint damps only along its own line, so the springs lie along x, y and z of the world
    # (godobject_drake/implicit.py) and both directions must be the model's.
    up = np.array([0.0, 0.0, 1.0])
    across = away - np.dot(away, up) * up
    across = across / np.linalg.norm(across) if np.linalg.norm(across) > 1e-6 else np.array([1.0, 0.0, 0.0])
    lifted = RigidTransform(X0.rotation(), X0.translation() + IMPLICIT_STEP_M * away)
    runs = {"along": step(X0, away), "across": step(lifted, across)}
    out["verify_implicit_rate"] = {"body": body.name, "step_m": IMPLICIT_STEP_M, **runs}
    worst = max(runs, key=lambda k: runs[k]["relative_error"])
    err, ok = runs[worst]["relative_error"], runs[worst]["relative_error"] <= 0.1
    return Check("verify", f"implicit step response: time to fall to 10 %, worst of along and across the "
                 f"gravity raise ({worst})", body.name, "ok" if ok else "warn", err, 0.1, "relative error",
                 "model and Drake agree" if ok else
                 "trust Drake's response: the implicit coupling is not the paper's damper in this "
                 "direction (docs/design.md, \"The implicit coupling\")",
                 predicted=runs[worst]["predicted_t10_s"],
                 simulated=runs[worst]["simulated_t10_s"])  # fmt: skip


def _verify_joint_space_limit(station, scenario, out: dict, rel_tol: float) -> Check | None:
    """The articulated tool's explicit limit in Drake: the device holds the worst configuration
    of the check, then steps every channel by 0.02; a scale ``c`` on both bandwidths is stable
    if the tool's joint speeds decay. Predicted: the joint-space model's largest scale."""
    if not out.get("explicit"):
        return None
    row = out["explicit"][0]
    predicted = row["bandwidth_scale_max"]
    device = scenario.device
    mix = np.array(device.mix, float) if device.mix else np.eye(len(device.channels))
    channels = np.linalg.lstsq(mix, np.asarray(row["worst_q"], float), rcond=None)[0]
    h = station.plant.time_step()
    duration = 0.05 + 600 * h

    def at(t, values):
        return JointWaypoint(t, dict(zip(device.channels, np.asarray(values).tolist(), strict=True)))

    path = [at(0.0, channels), at(0.03, channels), at(0.05, channels + 0.02), at(duration, channels + 0.02)]
    base = analysis_scenario(scenario)
    base.device = sc.ScriptedJoints(channels=list(device.channels), mix=device.mix, limits=device.limits,
                                    rate_hz=device.rate_hz, waypoints=path)  # fmt: skip
    base.simulation.duration_s = duration
    gains = base.god_object.gains
    tool_v = np.asarray(station.coupling.tool.coupled_v())
    nq = station.plant.num_positions()
    runs: dict[float, bool] = {}

    def stable(c: float) -> bool:
        if c in runs:
            return runs[c]
        s = copy.deepcopy(base)
        s.god_object.gains = _scaled(gains, c)
        try:
            result = _probe(_quiet_build(s))
            ok = not result.metrics["diverged"]
        except RuntimeError:  # Drake gave up on a blown-up state: unstable
            ok = False
        if ok:
            v = result.data["state"][round(0.05 / h) + 1 :, nq + tool_v]
            ok = not is_growing(np.max(np.abs(v), axis=1))
        runs[c] = ok
        return ok

    simulated = _bisect_widening(stable, predicted, rel_tol, out, "verify_explicit_limit_error")
    err = abs(simulated / predicted - 1.0)
    out["verify_explicit_limit"] = {
        "body": "tool", "binding_axis": "joint space", "predicted_scale": predicted,
        "simulated_scale": simulated, "relative_error": simulated / predicted - 1.0,
        "bisection_tolerance": rel_tol,
        "runs": [{"scale": c, "stable": ok} for c, ok in sorted(runs.items())],
    }  # fmt: skip
    fix = "model and Drake agree" if err <= 0.02 else (
        f"trust Drake's boundary: omega_n ≤ {_le(gains.omega_n * simulated)}, omega_n_rot ≤ "
        f"{_le(gains.omega_r * simulated)} rad/s"
    )  # fmt: skip
    organ = station.god_object.tissue
    if err > 0.02 and organ is not None and organ.spec.relaxation_time_s > h:
        tau = organ.spec.relaxation_time_s
        fix += (f"; the tissue's contact relaxation time ({tau:g} s) may set it: on the 8-cell organ "
                f"Drake's boundary was ×7.0 at 0.01 s and ×33.4 at 0.001 s; try "
                f"organs.relaxation_time_s={h:g} (docs/guide/laparoscopy.md)")  # fmt: skip
    return Check("verify", "explicit limit: gain scale at the boundary (joint space, worst configuration)",
                 "tool", "ok" if err <= 0.02 else "warn", err, 0.02, "relative error", fix,
                 predicted=predicted, simulated=simulated)  # fmt: skip


def _device_with_hand(dev: DeviceParams, haptic: sc.Haptic) -> ct.StateSpace:
    """The device's sampled mechanics with the simulated hand on its handle: the hand's force
    ``−k x − b v`` is computed from the device's state at each sample and held (state feedback)."""
    G = device_model(dev)
    A, B, C, D = (np.asarray(M, float) for M in (G.A, G.B, G.C, G.D))
    hand = hand_on_handle(haptic)
    return ct.ss(A - B @ np.array([[hand.k, hand.b]]), B, C, D, dt=dev.period_s)


def _verify_device_boundary(station, scenario, out: dict, rel_tol: float) -> Check | None:
    """The largest stable kd in Drake on the user's scene, against the model's: the held body
    grasped at its start, the hand's target 5 cm inside the nearest fixed obstacle, γd as the
    scenario has it; stable if the handle's motion per step decays once the push has settled.
    The model: the pipeline on that obstacle's ``n k`` with the hand on the handle."""
    if out.get("device") is None or not station.god_object.predicts_penetration:
        return None
    push = _push_in(station, out)
    if push is None:
        return None
    body, obstacle, n, k, _, X0, X1 = push
    haptic, h = scenario.haptic, station.plant.time_step()
    T = 1.0 / haptic.rate_hz
    tau = scenario.contact.relaxation_time_s or h
    g = station.coupling.gains
    loop = BodyLoop.by_bandwidth(body.mass, g.omega_n, g.zeta, h, k_w=n * k, b_w=n * k * tau)
    dev = DeviceParams(haptic.device_mass_kg, haptic.device_damping, T, 0)
    G = _device_with_hand(dev, haptic)
    pipe = Pipeline(loop, scenario.feedback.kd, scenario.feedback.gamma_d, T)

    def model_stable(kd: float) -> bool:
        H = pipeline_impedance(dataclasses.replace(pipe, kd=kd))
        return float(np.max(np.abs(ct.feedback(G, H, sign=-1).poles()))) < 1.0

    hi = 100.0 * dev.mass / T**2
    predicted = bisect(model_stable, 1e-9 * hi, hi, 1e-5) if not model_stable(hi) else float("nan")
    base = _hold_scenario(analysis_scenario(scenario), body.name, X0, X1, 3.0)
    settled = round(0.5 / h)
    runs: dict[float, bool] = {}

    def stable(kd: float) -> bool:
        if kd in runs:
            return runs[kd]
        s = copy.deepcopy(base)
        s.feedback.kd = kd
        try:
            result = _probe(_quiet_build(s))
            ok = not result.metrics["diverged"]
        except RuntimeError:
            ok = False
        if ok:
            handle = result.data["terms"][settled:, 5:8]  # the target: the handle's pose
            ok = _decays(np.linalg.norm(np.diff(handle, axis=0), axis=1))
        runs[kd] = ok
        return ok

    simulated = _bisect_widening(stable, predicted, rel_tol, out, "verify_device_boundary_error")
    err = abs(simulated / predicted - 1.0)
    out["verify_device_boundary"] = {
        "body": body.name, "obstacle": obstacle, "contacts": n, "k_w": n * k, "gamma_d": pipe.gamma_d,
        "predicted_kd": predicted, "simulated_kd": simulated, "relative_error": simulated / predicted - 1.0,
        "bisection_tolerance": rel_tol, "runs": [{"kd": c, "stable": ok} for c, ok in sorted(runs.items())],
    }  # fmt: skip
    fix = "model and Drake agree" if err <= 0.05 else f"trust Drake's boundary: kd ≤ {_le(simulated)} N/m"
    return Check("verify", f"device stiffness boundary kd, pushing {obstacle} (simulated hand)", body.name,
                 "ok" if err <= 0.05 else "warn", err, 0.05, "relative error", fix,
                 predicted=predicted, simulated=simulated)  # fmt: skip


def _decays(signal: np.ndarray, factor: float = 0.5, floor: float = 1e-9) -> bool:
    """The peak of the last quarter is below ``factor`` times that of the second (or below
    ``floor`` times the first). Stricter than :func:`is_growing`: the device pressing a
    one-sided contact turns an unstable loop into a chatter of constant amplitude, which
    never grows. With 2.5 s at h = 1 ms it calls a pole of modulus above 0.99889 unstable."""
    a = np.abs(np.asarray(signal, float))
    if not np.all(np.isfinite(a)):
        return False
    n = len(a) // 4
    first, second, last = a[:n].max(), a[n : 2 * n].max(), a[-n:].max()
    return bool(last < floor * first or last < factor * second)


REACH_FRACTION = 0.5  # a stable hold ends within this share of the 3 cm, 10° move from its target


def _reached(pose: np.ndarray, X_target: RigidTransform) -> bool:
    """Whether ``pose`` (``[qw qx qy qz x y z]``) is within :data:`REACH_FRACTION` of the verify's
    3 cm, 10° move from ``X_target`` (a steady sag stays well inside it)."""
    if not np.all(np.isfinite(pose)):
        return False
    q = pose[:4] / np.linalg.norm(pose[:4])
    R = RotationMatrix(Quaternion(q))
    angle = R.InvertAndCompose(X_target.rotation()).ToAngleAxis().angle()
    off = float(np.linalg.norm(pose[4:] - X_target.translation()))
    return off < REACH_FRACTION * 0.03 and angle < REACH_FRACTION * math.radians(10.0)


def _scaled(gains: CouplingGains, c: float) -> CouplingGains:
    """Both bandwidths times ``c``, the damping ratios kept."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CouplingGainWarning)
        return CouplingGains(
            omega_n=gains.omega_n * c, zeta=gains.zeta, omega_n_rot=gains.omega_r * c, zeta_rot=gains.zeta_r
        )


def _bisect_widening(stable, predicted: float, rel_tol: float, out: dict, error_key: str) -> float:
    """The boundary of ``stable`` near ``predicted`` (bracket [0.8, 1.25]× widened while the
    model is off), or NaN with the reason in ``out[error_key]``."""
    lo, hi = 0.8 * predicted, 1.25 * predicted
    while not stable(lo) and lo > 1e-3 * predicted:
        lo, hi = lo / 2.0, lo
    while stable(hi) and hi < 1e3 * predicted:
        lo, hi = hi, hi * 2.0
    try:
        return bisect(stable, lo, hi, rel_tol)
    except ValueError as e:
        out[error_key] = str(e)
        return float("nan")


# -- the whole analysis -----------------------------------------------------------------------------------


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
    checks += loop.device_checks(station, s, out)
    if verify:
        tol = 0.02 if quick else 0.005
        for row in (_verify_penetration(station, s, out), loop.verify(station, s, out, tol),
                    _verify_device_boundary(station, s, out, tol)):  # fmt: skip
            if row is not None:
                checks.append(row)
        checks += _verify_tissue(station, s, out)
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
                                  subject, "info", None, budget, "m", reason))  # fmt: skip
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


def _body_checks(station, out: dict) -> list[Check]:
    """A rigid or deformable tool's per-body explicit limits (symplectic Euler on its spring)."""
    _gains_row(station, out)
    return _pose_tool_checks(station, out)


def _implicit_body_checks(station, out: dict) -> list[Check]:
    """The implicit coupling's per-body decay rate and SAP regime (backward Euler on its spring)."""
    _gains_row(station, out)
    out["coupling"] = "implicit"
    return _implicit_pose_checks(station, out)


def _joint_checks(station, out: dict) -> list[Check]:
    """The articulated tool's joint-space loop at every ``check_every``-th device sample."""
    cfg = station.scenario.god_object
    out["coupling"] = cfg.coupling
    return _articulated_checks(station, out, station.scenario.simulation.duration_s, cfg.check_every)


def _gains_row(station, out: dict) -> None:
    g = station.coupling.gains
    out["gains"] = {"omega_n": g.omega_n, "zeta": g.zeta, "omega_n_rot": g.omega_r, "zeta_rot": g.zeta_r}


def _no_haptic_device(station, scenario, out: dict) -> list[Check]:
    return [Check("device", "haptic loop", "device", "info", None, None, "",
                  "joint-space devices here are not haptic")]  # fmt: skip


def _verify_implicit(station, scenario, out: dict, rel_tol: float) -> Check | None:
    return _verify_implicit_rate(station, scenario, out)


def loop_model(station) -> str:
    """How the station's tool's loop is modelled: its kind's study entry
    (:attr:`~godobject_drake.studies.kinds.StudyKind.loop_model`) on its config."""
    return study_kind(station.god_object.kind).loop_model(station.scenario.god_object)


@dataclasses.dataclass(frozen=True)
class Loop:
    """How ``analyze`` checks a loop model (:func:`loop_model`): its own rows, its haptic
    device's rows, and the prediction it simulates in Drake with ``--verify``."""

    checks: Callable
    device_checks: Callable
    verify: Callable


LOOPS = {
    "body": Loop(_body_checks, _device_checks, _verify_explicit_limit),
    "implicit_body": Loop(_implicit_body_checks, _device_checks, _verify_implicit),
    "joint": Loop(_joint_checks, _no_haptic_device, _verify_joint_space_limit),
}


# -- the report -------------------------------------------------------------------------------------------


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return str(v)


def verdict_table(summary: dict) -> str:
    """The verdict table as Markdown."""
    lines = ["| verdict | check | subject | value | limit | unit | predicted | simulated | fix |",
             "|---|---|---|---:|---:|---|---:|---:|---|"]  # fmt: skip
    for c in summary["checks"]:
        cells = [c["verdict"], c["name"], c["subject"], _fmt(c["value"]), _fmt(c["limit"]), c["unit"],
                 _fmt(c["predicted"]), _fmt(c["simulated"]), c["fix"]]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_report(summary: dict, out_dir: str | Path) -> Path:
    """``report.md``, ``summary.json`` and ``margins.png`` in ``out_dir``; returns the report's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    _margins_figure(summary, out / "margins.png")
    md = [
        f"# Stability and passivity of `{summary['scene']}` ({summary['kind']} god-object)",
        "",
        f"Verdict: **{summary['verdict']}**. h = {summary['time_step_s']:g} s; "
        f"{'quick' if summary['quick'] else 'full'} analysis, "
        f"{'checked in Drake' if summary['verify'] else 'not checked in Drake'}; "
        f"{summary['elapsed_s']:.1f} s.",
        "",
        "A row passes (`ok`) with more than 25 % margin, `warn`s within 25 % of its limit, `fail`s past it;",
        "`info` rows say why there is nothing to judge. `fix` is the change that makes the row pass.",
        "",
        verdict_table(summary),
        "",
        "![margins](margins.png)",
        "",
    ]
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


def _margins_figure(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [
        c for c in summary["checks"]
        if c["value"] is not None and c["limit"] and c["section"] != "verify" and c["bound"] == "upper"
    ]  # fmt: skip
    fig, ax = plt.subplots(figsize=(11, 0.45 * len(rows) + 1.4))
    colors = {"ok": "tab:green", "warn": "tab:orange", "fail": "tab:red"}
    ratios = [c["value"] / c["limit"] for c in rows]
    ax.barh(range(len(rows)), ratios, color=[colors.get(c["verdict"], "grey") for c in rows])
    ax.axvline(1.0, color="k", lw=1)
    ax.axvline(WARN_FRACTION, color="k", lw=0.5, ls="--")
    ax.set_yticks(range(len(rows)), [f"{c['name']} [{c['subject']}]"[:64] for c in rows], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("value / limit (past 1: fails; past 0.8: warns)")
    ax.set_title(f"{summary['scene']}: how close each check is to its limit")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
