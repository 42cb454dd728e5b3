"""What limits the implicit coupling instead of the explicit limit (docs/theory.md §7): the step
response's decay rate under backward Euler, per body and axis, and SAP's near-rigid regime."""

from __future__ import annotations

import math

import numpy as np

from godobject_drake.studies.analyze.common import Check, _bodies, _grasped, _le, _verdict_below
from godobject_drake.studies.stability import (
    BodyLoop,
    bisect,
    body_spectral_radius,
)

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
    rows = [Check("simulation", "explicit limit", "all bodies", "ok", None, None, "", "",
                  why="none: SAP integrates the implicit coupling's springs, stable at any ω·h")]  # fmt: skip
    for axis in ("translation", "rotation"):
        of_axis = [r for r in per_body if r["axis"].startswith(axis)]
        worst = min(of_axis, key=lambda r: r["rate_fraction"])
        name = "omega_n" if axis == "translation" else "omega_n_rot"
        rate = worst["rate_fraction"]
        rows.append(Check(
            "simulation", f"implicit step response, {axis}: decay rate / ωn (backward Euler)",
            f"{worst['body']} ({_bodies(len({r['body'] for r in of_axis}))} the device grasps)",
            "ok" if rate >= IMPLICIT_RATE_FLOOR else "warn", rate, IMPLICIT_RATE_FLOOR, "",
            f"time_step ≤ {_le(x_floor / worst['omega_rad_s'])} s or {name} ≤ {_le(x_floor / h)} rad/s",
            bound="lower", why="a response within 20 % of Eq. 3's rate passes (slower past it, never "
            "unstable)",
        ))  # fmt: skip
        near = max(of_axis, key=lambda r: r["near_rigid_value"] / r["near_rigid_limit"])
        rows.append(Check(
            "simulation", f"SAP near-rigid regime, {axis}: h(hk + d)/m against (2π/β)², β = {beta:g}",
            near["body"], _verdict_below(near["near_rigid_value"], near["near_rigid_limit"]),
            near["near_rigid_value"], near["near_rigid_limit"], "",
            f"{name} ≤ {_le(2 * math.pi / (beta * h))} rad/s about, or a smaller time_step, or a lower "
            "plant.sap_near_rigid_threshold", why="SAP softens a near-rigid spring to its own time scale",
        ))  # fmt: skip
    return rows


def implicit_joint_rows(omega: float, zeta: float, h: float, beta: float, what: str, gain_fix) -> list[Check]:
    """An implicit joint-space loop's rows (SAP's joint PD, ``joint_pd_sap``): stable at any ω·h, so
    no explicit limit; what limits it instead, as for the implicit pose coupling (docs/theory.md
    §7): the step response's decay rate under backward Euler at its fastest mode ``omega`` (rad/s)
    against :data:`IMPLICIT_RATE_FLOOR`, and SAP's near-rigid regime ``(ω h)² + 2 ζ ω h`` against
    ``(2π/β)²``. ``gain_fix(ω_max)``: the gain change that brings the fastest mode to ``ω_max``
    ("" when no gain sets it alone)."""
    x_floor = bisect(lambda x: implicit_rate(1.0, zeta, x) >= IMPLICIT_RATE_FLOOR, 1e-9, 1e3, 1e-6)
    rate = implicit_rate(omega, zeta, h)
    near = (omega * h) ** 2 + 2 * zeta * omega * h
    near_limit = (2 * math.pi / beta) ** 2 if beta > 0 else math.inf
    x_near = math.sqrt(zeta**2 + near_limit) - zeta  # the ω h where near reaches its limit
    or_gain = lambda w: f" or {gain_fix(w)}" if gain_fix(w) else ""  # noqa: E731
    return [
        Check("simulation", f"implicit step response, {what}: decay rate / ω of the fastest mode "
              f"({omega:.4g} rad/s, backward Euler)", "tool",
              "ok" if rate >= IMPLICIT_RATE_FLOOR else "warn", rate, IMPLICIT_RATE_FLOOR, "",
              f"time_step ≤ {_le(x_floor / omega)} s{or_gain(x_floor / h)}", bound="lower",
              why="SAP's joint PD is implicit: stable at any ω·h, no explicit limit; a response within 20 % "
              "of the spring's own rate passes (slower past it, never unstable)"),
        Check("simulation", f"SAP near-rigid regime, {what}: (ωh)² + 2ζωh against (2π/β)², β = {beta:g}",
              "tool", _verdict_below(near, near_limit), near, near_limit, "",
              f"time_step ≤ {_le(x_near / omega)} s{or_gain(x_near / h)}, or a lower "
              "plant.sap_near_rigid_threshold",
              why="SAP softens a near-rigid joint spring to its own time scale"),
    ]  # fmt: skip
