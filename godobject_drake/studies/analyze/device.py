"""The impedance-type haptic device's loop (docs/theory.md §2–3): Colgate's required damping, the
device's stiffness limit, passivity against the user and Llewellyn's η, on the held body's
stiffest obstacle."""

from __future__ import annotations

import dataclasses

from godobject_drake.config import scenario as sc
from godobject_drake.studies.analyze.common import (
    WARN_FRACTION,
    Check,
    _ge,
    _held_body,
    _le,
    _verdict_below,
    loop_model,
)
from godobject_drake.studies.stability import (
    BodyLoop,
    DeviceParams,
    Pipeline,
    TwoPort,
    bisect,
    closed_loop_radius,
    colgate_required_damping,
    device_stiffness_limit,
    human_port_admittance,
    llewellyn_eta,
    passivity_check,
    pipeline_impedance,
)


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
        return [Check("device", "haptic loop", "device", "info", None, None, "", "", why=why)]
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
