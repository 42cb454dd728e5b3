"""The pose tool's predictions simulated in Drake on the user's own scene (``--verify``): the static
penetration with the target held inside the nearest fixed obstacle, the explicit limit by bisecting
a scale on the gains (:func:`hold_is_stable`), the implicit coupling's step response, and the haptic
device's stiffness boundary; with the holds, scalings and bisections they share."""

from __future__ import annotations

import copy
import dataclasses
import math
import warnings

import control as ct
import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Role
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.tree import BodyIndex

from godobject_drake.config import scenario as sc
from godobject_drake.config.device_files import Waypoint
from godobject_drake.config.gains import CouplingGains, CouplingGainWarning
from godobject_drake.limits import explicit_limit_omega_h
from godobject_drake.metrics import TrueShapeMetrics
from godobject_drake.station.haptic_chain import hand_on_handle
from godobject_drake.studies.analyze.common import (
    Check,
    _held_body,
    _le,
    _probe,
    _quiet_build,
    analysis_scenario,
)
from godobject_drake.studies.analyze.implicit import implicit_rate
from godobject_drake.studies.stability import (
    BodyLoop,
    DeviceParams,
    Pipeline,
    bisect,
    coupled_body_matrices,
    device_model,
    pipeline_impedance,
)
from godobject_drake.studies.validation import is_growing

PUSH_IN_M = 0.05  # the verification holds the target this far inside the nearest obstacle


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
    return Check("verify", name, body.name, "ok" if err <= 0.1 else "warn", err, 0.1, "relative error", "",
                 predicted=depth, simulated=simulated, why="model and Drake agree" if err <= 0.1 else
                 "the contact differs from SAP's linear point law (near-rigid regime?): trust Drake's depth",
                 )  # fmt: skip


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
    fix, why = (
        ("", "model and Drake agree")
        if err <= 0.02
        else (f"omega_n ≤ {_le(g.omega_n * simulated)}, omega_n_rot ≤ {_le(g.omega_r * simulated)} rad/s",
              "trust Drake's boundary: the one-body model misses how the scene moves with the body")
        if math.isfinite(simulated) and not beyond
        else (f"omega_n < {run_n:.4g}, omega_n_rot < {run_r:.4g} rad/s at this time_step",
              "Drake's boundary is past the model's; run refuses past the model's explicit limit")
        if beyond
        else ("", "no boundary found in Drake: " + out.get("verify_explicit_limit_error", ""))
    )  # fmt: skip
    return Check("verify", f"explicit limit: gain scale at the boundary ({binding})", body.name,
                 "ok" if err <= 0.02 else "warn", err, 0.02, "relative error", fix,
                 predicted=predicted, simulated=simulated, why=why)  # fmt: skip


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
                 "", why="model and Drake agree" if ok else
                 "trust Drake's response: the implicit coupling is not the paper's damper in this "
                 "direction (docs/design.md, \"The implicit coupling\")",
                 predicted=runs[worst]["predicted_t10_s"],
                 simulated=runs[worst]["simulated_t10_s"])  # fmt: skip


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
    fix = "" if err <= 0.05 else f"kd ≤ {_le(simulated)} N/m"
    why = "model and Drake agree" if err <= 0.05 else "trust Drake's boundary: the model's differs"
    return Check("verify", f"device stiffness boundary kd, pushing {obstacle} (simulated hand)", body.name,
                 "ok" if err <= 0.05 else "warn", err, 0.05, "relative error", fix,
                 predicted=predicted, simulated=simulated, why=why)  # fmt: skip
