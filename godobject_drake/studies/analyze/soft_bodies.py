"""Soft bodies of one's own (``deformables:``) under a pose tool: where the device's path brings
the held body nearest (or deepest into) each soft body, and the body's stiffness there from its
own FEM mesh (linear statics, its attached vertices held: :func:`~godobject_drake.studies.
tissue_stiffness.contact_stiffness`, as the laparoscopy's organ's). Drake's press at such a point
answers within 0.03 % on the example lobe (tests/test_own_soft_body.py)."""

from __future__ import annotations

import numpy as np

from godobject_drake.config import scenario as sc
from godobject_drake.studies.analyze.common import Check, _probe, _quiet_build, analysis_scenario
from godobject_drake.studies.analyze.tissue import _tissue_pose
from godobject_drake.systems.tissue import capsule_against_surface
from godobject_drake.systems.tissue_stiffness import contact_stiffness

# A held body's target farther than this from a soft body's surface (m) does not press it.
REACH_M = 0.05


def _nearest_press(body, points: np.ndarray) -> tuple[int, float, np.ndarray] | None:
    """The device sample whose point lies deepest in (or nearest outside) the soft body's rest
    surface: ``(its index, its distance to the nearest surface vertex, the press direction)``, the
    direction the path moves in there if it moves into the surface, else along the nearest
    vertex's inward normal; None when none comes within :data:`REACH_M`."""
    surface = body.rest_W[body.surface]
    best = None
    for k, p in enumerate(points):
        d = np.linalg.norm(surface - p, axis=1)
        inside = capsule_against_surface(body.rest_W, body.surface, body.triangles, p, np.eye(3)[2], 0, 0)[1]
        score = -d.min() if inside else d.min()
        if (best is None or score < best[0]) and (inside or d.min() <= REACH_M):
            best = (score, k, int(body.surface[np.argmin(d)]))
    if best is None:
        return None
    _, k, vertex = best
    V, tri = body.rest_W, body.triangles
    n = np.zeros(3)
    for a, b, c in tri[np.any(tri == vertex, axis=1)]:  # the vertex's normal: its faces' summed
        n += np.cross(V[b] - V[a], V[c] - V[a])
    inward = -n / np.linalg.norm(n)
    step = points[k] - points[k - 1] if k > 0 else np.zeros(3)
    if np.linalg.norm(step) > 0 and step @ inward > 0:  # the path's own motion into the surface
        return k, float(abs(best[0])), step / np.linalg.norm(step)
    return k, float(abs(best[0])), inward


def _articulated_rows(station, scenario, bodies: dict, out: dict) -> list[Check]:
    """An articulated tool: the device sample whose closed tool reaches deepest past each soft
    body's rest surface along its tube's axis (as the organ's analysis), and the stiffness there."""
    rows, found = [], {}
    samples = station.device.samples(scenario.simulation.duration_s)
    for name, body in bodies.items():
        poses = [x for x in (_tissue_pose(station, q, body) for q in samples) if x is not None]
        pose = max(poses, key=lambda x: x["depth_m"], default=None)
        if pose is None or pose["depth_m"] < -REACH_M:
            rows.append(Check("soft bodies", "stiffness where the tool presses it", name, "info", None, None,
                              "", "", why=f"the tool's axis never comes within {REACH_M * 1e3:g} mm of it "
                              "on the device's path"))  # fmt: skip
            continue
        back = float(np.max(np.linalg.norm(body.rest_W - pose["p"], axis=1))) + 0.01
        stiffness = contact_stiffness(body, pose["p"] - back * pose["d"], pose["d"])
        found[name] = {"push_m": pose["depth_m"], **stiffness}
        rows.append(Check(
            "soft bodies", f"stiffness where the tool presses it (linear FEM of its {body.vertex_count} "
            "vertices, its attached ones held, point force)", name, "info", stiffness["stiffness_n_m"], None,
            "N/m", "", why=f"at {np.round(stiffness['point_W'], 4).tolist()} m, along the tube's axis "
            f"{np.round(pose['d'], 3).tolist()}: the device's deepest push, {pose['depth_m'] * 1e3:.3g} mm "
            "past its rest surface; a finer mesh answers softer",
        ))  # fmt: skip
    out["soft_bodies"] = found
    return rows


def _glued(body, grasp: str) -> bool:
    """Whether the grasped name is a body glued to the soft body (its site moves with it)."""
    return any(grasp == full or full.endswith(f"::{grasp}") or full.startswith(f"{grasp}::")
               for full in body.glued_bodies)  # fmt: skip


def _soft_body_checks(station, scenario, out: dict) -> list[Check]:
    """Each soft body's stiffness where the tool's device path presses it (module docstring)."""
    bodies = getattr(station, "soft_bodies", {})
    if not bodies:
        return []
    rows, found = [], {}
    if station.god_object.device_space != "pose":
        return _articulated_rows(station, scenario, bodies, out)
    samples = station.device.samples(scenario.simulation.duration_s)
    for name, body in bodies.items():  # what the device holds presses, but a site glued to the body
        held = [(t, s[0]) for t, s in samples if s is not None and s[2] and not _glued(body, s[2])]
        times = np.array([t for t, _ in held])
        points = np.array([p for _, p in held]).reshape(-1, 3)
        press = _nearest_press(body, points)
        if press is None:
            rows.append(Check("soft bodies", "stiffness where the tool presses it", name, "info", None, None,
                              "", "", why=f"the device's path never brings a held body (but a site "
                              f"glued to it) within {REACH_M * 1e3:g} mm of it"))  # fmt: skip
            continue
        k, distance, d = press
        stiffness = contact_stiffness(body, points[k] - 0.05 * d, d)
        found[name] = {"time_s": float(times[k]), "target_m": points[k].tolist(), "direction": d.tolist(),
                       **stiffness}  # fmt: skip
        rows.append(Check(
            "soft bodies", f"stiffness where the tool presses it (linear FEM of its {body.vertex_count} "
            "vertices, its attached ones held, point force)", name, "info", stiffness["stiffness_n_m"], None,
            "N/m", "", why=f"at {np.round(stiffness['point_W'], 4).tolist()} m, along "
            f"{np.round(d, 3).tolist()}: the surface under the held body's target at t = {times[k]:.3g} s "
            f"({distance * 1e3:.3g} mm from its nearest vertex); a finer mesh answers softer",
        ))  # fmt: skip
    out["soft_bodies"] = found
    return rows


# The verification's indentation is measured this long before the end of the path's deepest hold
# (s), where the tissue has settled under the held body (its Rayleigh damping's force gone).
SETTLE_S = 0.05
# The verification's reference state: the last step before the press whose contact force on the
# soft body is under this (N): the body settled, not yet touched.
UNTOUCHED_N = 1e-3


def _verify_soft_bodies(station, scenario, out: dict) -> list[Check]:
    """Each soft body's stiffness where the device presses it (:func:`_soft_body_checks`) checked in
    Drake, as the laparoscopy organ's is: the scene run on its own path to the end of the deepest
    hold, and to its last step before the press with no contact force on the soft body; the
    contact force's change over the indentation between the two (the surface triangle's vertices'
    displacement along the press, by the point force's weights), against the linear FEM's
    stiffness, within 15 %."""
    found = out.get("soft_bodies") or {}
    if not found or station.god_object.device_space != "pose":
        return []
    samples = station.device.samples(scenario.simulation.duration_s)
    held = [(t, s[0]) for t, s in samples if s is not None and s[2]]
    times = np.array([t for t, _ in held])
    points = np.array([p for _, p in held]).reshape(-1, 3)
    h = station.plant.time_step()
    checks = []
    for name, press in found.items():
        d = np.asarray(press["direction"], float)
        k = int(np.argmin(np.abs(times - press["time_s"])))
        end = k
        while end + 1 < len(points) and np.linalg.norm(points[end + 1] - points[k]) < 1e-9:
            end += 1
        pressed = _soft_state(scenario, name, float(times[end]) - SETTLE_S)
        force = np.linalg.norm(pressed[2][:, 4:7], axis=1)
        untouched = np.flatnonzero(force[: round(times[k] / h)] < UNTOUCHED_N)
        pressing = pressed[2][-1, 4:7] @ d > 10 * UNTOUCHED_N
        if times[end] - times[k] < 2 * SETTLE_S or not len(untouched) or not pressing:
            why = (
                "not checked: the device's path holds no press there (a hold at the deepest target, "
                "reached from out of contact)"
            )
            checks.append(Check("verify", "soft body's stiffness where the tool presses it", name, "info",
                                None, None, "", "", why=why))  # fmt: skip
            continue
        before = _soft_state(scenario, name, untouched[-1] * h)
        moved = pressed[0] - before[0]
        indentation = sum(w * moved[v] @ d for v, w in zip(press["vertices"], press["weights"], strict=True))
        force = float((pressed[1] - before[1]) @ d)
        k_fem = press["stiffness_n_m"]
        simulated = force / indentation if indentation > 1e-6 else float("nan")
        err = abs(simulated / k_fem - 1.0) if np.isfinite(simulated) else float("inf")
        out.setdefault("verify_soft_bodies", {})[name] = {
            "times_s": [float(untouched[-1] * h), float(times[end]) - SETTLE_S],
            "indentation_m": float(indentation), "force_n": force, "stiffness_n_m": float(simulated),
            "predicted_stiffness_n_m": k_fem,
        }  # fmt: skip
        checks.append(Check(
            "verify", f"soft body's stiffness where the tool presses it: Drake's force / indentation at "
            f"{indentation * 1e3:.2g} mm against the linear FEM", name, "ok" if err <= 0.15 else "warn",
            float(err), 0.15, "relative error", "", why="model and Drake agree" if err <= 0.15 else
            "Drake's corotated tissue under contact departs from linear statics (or the press is too "
            "shallow to measure): trust Drake's force", predicted=k_fem, simulated=float(simulated),
        ))  # fmt: skip
    return checks


def _soft_state(scenario, name: str, t: float):
    """The soft body ``name``'s vertex positions (W), the contact force on it (N, W) at ``t`` of the
    scene's own path, run in Drake, and its summary rows (every step to ``t``)."""
    s = sc.replace(analysis_scenario(scenario), **{"simulation.duration_s": t})
    station = _quiet_build(s)
    result = _probe(station)
    (observer,) = [x for x in station.diagram.GetSystems() if x.get_name() == f"{name}_soft_body_observer"]
    context = observer.GetMyContextFromRoot(result.context)
    return observer.positions(context), observer.contact_force(context), result.data[f"{name}_soft_body"]
