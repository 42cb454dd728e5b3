"""The articulated tool's joint-space explicit limit at the device's sampled configurations, with
its margin (the largest bandwidth scale and time step that keep the worst one stable)."""

from __future__ import annotations

import dataclasses

import numpy as np

from godobject_drake.studies.analyze.common import WARN_FRACTION, Check, _le, _verdict_below
from godobject_drake.studies.analyze.implicit import implicit_joint_rows
from godobject_drake.studies.stability import (
    bisect,
)
from godobject_drake.systems.articulated import joint_space_loop


def _articulated_checks(station, out: dict, duration_s: float, check_every: int) -> list[Check]:
    """The joint-space check the builder runs (every ``check_every``-th device sample), with its
    margin: the largest bandwidth scale and step that keep the worst configuration stable."""
    coupling, h = station.coupling, station.plant.time_step()
    device = station.device
    qs = device.samples(duration_s)[::check_every]
    tool, gains, mode = coupling.tool, coupling.gains, coupling.coupling
    loops = [joint_space_loop(tool, mode, gains, np.asarray(q, float), h) for q in qs]
    if mode == "joint_pd_sap":
        out["explicit"] = []
        fastest = max(lp.omega_max for lp in loops)
        out["implicit"] = [{"configurations": len(loops), "fastest_mode_rad_s": fastest}]
        beta = station.scenario.plant.sap_near_rigid_threshold
        return implicit_joint_rows(
            fastest,
            gains.zeta,
            h,
            1.0 if beta is None else beta,
            f"joint space ({len(loops)} configurations)",
            lambda w: f"omega_n ≤ {_le(gains.omega_n * w / fastest)} rad/s",
        )
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
