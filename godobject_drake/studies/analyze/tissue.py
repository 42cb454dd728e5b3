"""The FEM organ under an articulated tool: where the tool presses it hardest on the device's
path, its stiffness there (from the FEM model), the indentation and force of the deepest push, and
the joint-space explicit limit with the tissue in the loop (docs/theory.md §8)."""

from __future__ import annotations

import math

import numpy as np
from pydrake.multibody.tree import BodyIndex

from godobject_drake.config import scenario as sc
from godobject_drake.limits import semi_implicit_matrix
from godobject_drake.studies.analyze.common import WARN_FRACTION, Check, _le, _verdict_below
from godobject_drake.studies.analyze.implicit import implicit_joint_rows
from godobject_drake.studies.stability import (
    bisect,
)
from godobject_drake.systems.articulated import joint_space_loop
from godobject_drake.systems.tissue import tool_capsules
from godobject_drake.systems.tissue_stiffness import contact_stiffness, ray_surface_hit


def _tissue_pose(station, q_device: np.ndarray, organ=None) -> dict | None:
    """The articulated tool at ``q_device`` with its imposed joints (the jaws) at 0 (closed: one
    contact) against the FEM organ's rest surface (``organ``, or the tool's organ): the tube's axis
    from the tip body's origin (``d``, toward the tip), how far the tool reaches past that origin
    along it, and where the axis meets the surface; None if the axis misses the organ."""

    tool, plant = station.coupling.tool, station.plant
    organ = station.god_object.tissue if organ is None else organ
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
        return [Check("tissue", "stiffness at the tool's contact", "organ", "info", None, None, "", "",
                      why="the tool's axis never points at the FEM organ on the device's path")]  # fmt: skip
    k, K = press["stiffness_n_m"], press["tool_stiffness_n_m"]
    push = press["push_m"]
    depth = K * push / (K + k)
    force = k * depth
    tissue = {key: v for key, v in press.items() if key not in ("q_touch", "slide", "loop", "Jd", "d")}
    tissue.update(predicted_indentation_m=depth, predicted_force_n=force)
    rows = [
        Check("tissue", f"stiffness at the tool's contact (linear FEM of the {press['cells']}-cell mesh, "
              "point force)", press["organ"], "info", k, None, "N/m",
              f"organs.cells above {press['cells']}",
              why=f"Hertz's tangent for the {press['tip_radius_m'] * 1e3:g} mm tip at 1 mm: "
              f"{press['hertz_tangent_1mm_n_m']:.4g} N/m; the mesh is stiffer than the continuum until its "
              "surface triangles are smaller than the contact"),
        Check("tissue", f"indentation under the device's deepest push ({push * 1e3:.3g} mm past the surface)",
              press["organ"], "info", depth, None, "m", "",
              why=f"k_tip (d − δ) = k δ: the coupling's stiffness at the tip along the tube, "
              f"{K:.4g} N/m, against the tissue's {k:.4g} N/m; force {force:.3g} N"),
    ]  # fmt: skip
    coupling, h = station.coupling, station.plant.time_step()
    loop, Jd = press["loop"], press["Jd"]
    K_i = k * np.outer(Jd, Jd)
    if coupling.coupling == "joint_pd_sap":  # implicit, the tissue's contact too: no explicit limit
        modes = np.linalg.eigvals(np.linalg.solve(loop.M, loop.K + K_i)).real
        fastest = float(np.sqrt(max(modes.max(), 0.0)))
        tissue.update(fastest_mode_rad_s=fastest)
        out["tissue"] = tissue
        beta = station.scenario.plant.sap_near_rigid_threshold
        what = f"pressing the tissue ({k:.4g} N/m at the tip)"
        beta = 1.0 if beta is None else beta
        return rows + implicit_joint_rows(fastest, coupling.gains.zeta, h, beta, what, lambda w: "")
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
