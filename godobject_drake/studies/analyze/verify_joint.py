"""The articulated tool's predictions simulated in Drake (``--verify``): its joint-space explicit
limit at the worst configuration, and the FEM tissue's stiffness and force where the tool presses
it hardest."""

from __future__ import annotations

import copy

import numpy as np

from godobject_drake.config import scenario as sc
from godobject_drake.config.device_files import JointWaypoint
from godobject_drake.studies.analyze.common import Check, _le, _probe, _quiet_build, analysis_scenario
from godobject_drake.studies.analyze.verify import _bisect_widening, _scaled
from godobject_drake.studies.validation import is_growing

# A tissue's contact relaxed over one plant step holds up to this step; from h = 2 ms it chatters
# (docs/results.md, the FEM tissue's levers).
ONE_STEP_RELAXATION_MAX_H_S = 0.001


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
    fix = "" if err <= 0.02 else (
        f"omega_n ≤ {_le(gains.omega_n * simulated)}, omega_n_rot ≤ {_le(gains.omega_r * simulated)} rad/s"
    )  # fmt: skip
    why = "model and Drake agree" if err <= 0.02 else "trust Drake's boundary"
    organ = station.god_object.tissue
    if err > 0.02 and organ is not None and organ.spec.relaxation_time_s > h:
        tau = organ.spec.relaxation_time_s
        why += (f"; the tissue's contact relaxation time ({tau:g} s) may set it: on the 8-cell organ "
                f"Drake's boundary was ×7.0 at 0.01 s and ×33.4 at 0.001 s "
                "(docs/guide/laparoscopy.md)")  # fmt: skip
        if h <= ONE_STEP_RELAXATION_MAX_H_S:
            fix += f", or organs.relaxation_time_s={h:g}"
        else:  # relaxed over one step, the tissue's contact chatters at this step
            why += f"; relaxed over one step ({h:g} s), its contact chatters at this step"
    return Check("verify", "explicit limit: gain scale at the boundary (joint space, worst configuration)",
                 "tool", "ok" if err <= 0.02 else "warn", err, 0.02, "relative error", fix,
                 predicted=predicted, simulated=simulated, why=why)  # fmt: skip


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
        "ok" if err <= 0.1 else "warn", err, 0.1, "relative error", "",
        why="model and Drake agree" if err <= 0.1 else
        "Drake's corotated tissue under contact departs from linear statics: trust Drake's force",
        predicted=k, simulated=last["stiffness_n_m"],
    ))  # fmt: skip
    err_f = abs(last["force_n"] / last["predicted_force_n"] - 1.0)
    checks.append(Check(
        "verify", f"force on the tool, target {last['push_m'] * 1e3:.3g} mm past the surface", "tool",
        "ok" if err_f <= 0.1 else "warn", err_f, 0.1, "relative error", "",
        why="model and Drake agree" if err_f <= 0.1 else
        "the tool sits deeper than the surface's displacement (contact compliance): trust Drake's force",
        predicted=last["predicted_force_n"], simulated=last["force_n"],
    ))  # fmt: skip
    return checks
