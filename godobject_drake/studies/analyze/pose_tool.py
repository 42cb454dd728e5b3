"""The explicit limit of a rigid or deformable god-object, per body and axis (translation, each
principal rotation): symplectic Euler with the coupling explicit, docs/theory.md §1."""

from __future__ import annotations

import math

import numpy as np

from godobject_drake.limits import explicit_limit_omega_h
from godobject_drake.studies.analyze.common import (
    WARN_FRACTION,
    Check,
    _bodies,
    _grasped,
    _le,
    _verdict_below,
)
from godobject_drake.studies.stability import (
    BodyLoop,
    body_spectral_radius,
    explicit_h_max,
)
from godobject_drake.systems.coupling import graspable_bodies


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
