"""The motion, force and safety scores (godobject_drake.task_metrics), each against a number a person
can compute by hand, a second method where one exists, and a real run of the shipped scenes."""

import json
import math

import numpy as np
import pytest
from conftest import REPO, load_script
from scipy.integrate import quad

from godobject_drake.cli import load_with_sets
from godobject_drake.config.scenario import ScenarioError, load_scenario
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.systems.coupling import TERMS_LAYOUT
from godobject_drake.task_metrics import (
    IDLE_SPEED_MPS,
    CameraView,
    CollisionFold,
    ForceFold,
    TipMotion,
    economy_of_motion,
    log_dimensionless_jerk,
    path_length,
    window_samples,
)

H = 1e-3


def helix(r, c, turns, n):
    """``n`` samples of the helix (r cos θ, r sin θ, c θ), θ from 0 to 2π turns."""
    theta = np.linspace(0.0, 2.0 * math.pi * turns, n)
    return np.column_stack([r * np.cos(theta), r * np.sin(theta), c * theta])


def minimum_jerk(t, amplitude, duration):
    """Hogan's minimum-jerk reach, A (10τ³ − 15τ⁴ + 6τ⁵), held at its ends outside [0, T]."""
    tau = np.clip(np.asarray(t, float) / duration, 0.0, 1.0)
    return amplitude * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)


def test_helix_path_length_is_its_closed_form_and_the_integral_of_its_speed():
    r, c, turns = 0.05, 0.01, 3  # 5 cm radius, 2π·1 cm a turn: 2π n √(r² + c²) = 0.96114 m
    closed = 2 * math.pi * turns * math.hypot(r, c)
    assert closed == pytest.approx(0.96114, abs=1e-5)
    p = helix(r, c, turns, 200_001)
    assert path_length(p) == pytest.approx(closed, rel=1e-9)
    speed = quad(lambda theta: math.hypot(r, c), 0.0, 2 * math.pi * turns)[0]  # |dp/dθ| integrated
    assert path_length(p) == pytest.approx(speed, rel=1e-9)
    chunks = TipMotion(H)  # the fold, in uneven chunks, gives the polyline's sum
    for part in np.array_split(p, 7):
        chunks.update(part)
    assert chunks.result()["tip_path_m"] == pytest.approx(path_length(p), rel=1e-12)


def test_economy_of_motion_is_one_on_a_line_and_two_over_pi_on_a_semicircle():
    line = np.linspace([0.0, 0.0, 0.0], [0.1, 0.2, -0.05], 50)
    assert economy_of_motion(line) == pytest.approx(1.0, abs=1e-12)
    theta = np.linspace(0.0, math.pi, 100_001)
    semicircle = np.column_stack([0.03 * np.cos(theta), 0.03 * np.sin(theta), np.zeros_like(theta)])
    assert economy_of_motion(semicircle) == pytest.approx(2 / math.pi, rel=1e-9)  # 0.6366
    assert economy_of_motion(np.zeros((5, 3))) is None  # no path: undefined, not 0 or 1
    fold = TipMotion(H)
    fold.update(semicircle)
    assert fold.result()["tip_economy_of_motion"] == pytest.approx(2 / math.pi, rel=1e-9)


def test_constant_jerk_cubic_gives_its_jerk_and_dimensionless_jerk():
    # x = c (t + t0)³: jerk 6c everywhere; t0 = 1 s keeps its speed 3c(t + t0)² = 0.03 m/s over the idle
    # speed, so every estimated row is active and T is the estimated span
    c, t0 = 0.01, 1.0
    t = np.arange(0.0, 2.0 + H / 2, H)
    p = np.zeros((len(t), 3))
    p[:, 1] = c * (t + t0) ** 3
    fold = TipMotion(H)
    for part in np.array_split(p, 3):
        fold.update(part)
    w = window_samples(H)
    assert w == 101  # 0.1 s at 1 ms
    m = len(t) - w + 1  # rows with an estimate: the centres of full windows
    assert fold.estimated == m
    # 0.0036 m²/s⁶ · 1.9 s; exact but for rounding, which the third derivative multiplies by h⁻³
    assert fold.jerk_sq == pytest.approx((6 * c) ** 2 * m * H, rel=1e-4)
    t_last = t[len(t) - 1 - w // 2]  # the last estimated row
    assert fold.peak_speed == pytest.approx(3 * c * (t_last + t0) ** 2, rel=1e-9)
    T = m * H
    expected = -math.log(T**3 / (3 * c * (t_last + t0) ** 2) ** 2 * (6 * c) ** 2 * T)
    assert fold.result()["tip_log_dimensionless_jerk"] == pytest.approx(expected, abs=1e-4)
    assert fold.result()["task_time_s"] == pytest.approx(T, abs=1e-12)


def test_minimum_jerk_reach_dimensionless_jerk_closed_form():
    A, T = 0.1, 1.0  # ∫ jerk² = 720 A²/T⁵, v_peak = 1.875 A/T: T³/v_peak² ∫ jerk² = 720/1.875² = 204.8
    jerk = quad(lambda t: (A / T**3 * 60 * (1 - 6 * t / T + 6 * (t / T) ** 2)) ** 2, 0.0, T)[0]
    assert jerk == pytest.approx(720 * A**2 / T**5, rel=1e-12)
    assert log_dimensionless_jerk(jerk, T, 1.875 * A / T) == pytest.approx(-math.log(204.8), rel=1e-12)
    # The filter on the sampled reach: exact inside (a quintic); the jerk's steps at the reach's ends
    # are smoothed over the 0.1 s window, which loses under 4 % of the integral
    t = np.arange(-0.5, T + 0.5 + H / 2, H)
    p = np.zeros((len(t), 3))
    p[:, 0] = minimum_jerk(t, A, T)
    fold = TipMotion(H)
    fold.update(p)
    assert fold.jerk_sq == pytest.approx(720 * A**2 / T**5, rel=0.04)
    assert fold.peak_speed == pytest.approx(1.875 * A / T, rel=1e-9)


def test_idle_and_task_time_of_a_path_with_known_pauses():
    # rest 0.5 s, a 10 cm minimum-jerk reach in 1 s, rest 1 s, back in 1 s, rest 0.5 s
    A, T = 0.1, 1.0
    t = np.arange(0.0, 4.0 + H / 2, H)
    x = minimum_jerk(t - 0.5, A, T) - minimum_jerk(t - 2.5, A, T)
    p = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    fold = TipMotion(H)
    for part in np.array_split(p, 5):
        fold.update(part)
    # a reach is idle where 30 (A/T) τ²(1 − τ)² < 5 mm/s: τ(1 − τ) < √(1/600), τ < 0.04264 at each end
    tau = (1 - math.sqrt(1 - 4 * math.sqrt(IDLE_SPEED_MPS * T / (30 * A)))) / 2
    assert tau == pytest.approx(0.04264, abs=1e-5)
    # the estimated rows run from 0.05 s to 3.95 s (half a window at each end): pauses 0.45 + 1 + 0.45 s
    idle = 0.45 + 1.0 + 0.45 + 4 * tau * T
    assert fold.result()["tip_idle_time_s"] == pytest.approx(idle, abs=0.005)  # 2.070 s
    task = (3.5 - tau * T) - (0.5 + tau * T)  # first to last moving row: 2.915 s
    assert fold.result()["task_time_s"] == pytest.approx(task, abs=0.005)
    assert fold.result()["tip_path_m"] == pytest.approx(2 * A, rel=1e-9)
    assert fold.result()["tip_economy_of_motion"] == pytest.approx(0.0, abs=1e-12)  # back where it began


def test_a_switch_of_the_tips_point_is_not_a_motion():
    # a straight 1 cm/s line whose reference point jumps 5 cm at row 500 (a rigid tool's grasp)
    t = np.arange(0.0, 1.0 + H / 2, H)
    p = np.column_stack([0.01 * t, np.zeros_like(t), np.zeros_like(t)])
    jumped = p.copy()
    jumped[500:, 2] += 0.05
    switched = np.zeros(len(t), bool)
    switched[500] = True
    fold = TipMotion(H)
    fold.update(jumped[:300], switched[:300])
    fold.update(jumped[300:], switched[300:])
    # the path loses row 500's own 10 µm step with the jump: 1 cm − 10 µm
    assert fold.result()["tip_path_m"] == pytest.approx(0.01 - 0.01 * H, rel=1e-9)
    assert fold.result()["tip_economy_of_motion"] == pytest.approx(1.0, rel=1e-9)
    # no spike from the jump: the missing 10 µm step is a kink the filter sees as under 1 % more speed
    assert fold.peak_speed == pytest.approx(0.01, rel=0.01)
    unswitched = TipMotion(H)
    unswitched.update(jumped)  # the jump taken as a motion: 5 cm in one step, a spike of metres a second
    assert unswitched.peak_speed > 0.1
    assert unswitched.result()["tip_path_m"] == pytest.approx(0.06 - 0.01 * H, rel=1e-6)


def test_force_fold_max_and_mean_over_the_time_in_contact():
    # 2 N for 1 s, apart for 1 s, then a ramp 0 → 4 N over 1 s: max 4 N, mean over the 2 s in contact
    # (2 N · 1 s + 2 N mean · 1 s) / 2 s = 2 N
    n = 1000
    ramp = np.linspace(0.0, 4.0, n)
    magnitude = np.concatenate([np.full(n, 2.0), np.zeros(n), ramp])
    contacts = np.concatenate([np.ones(n), np.zeros(n), np.ones(n)])
    direction = np.array([0.6, 0.0, 0.8])
    fold = ForceFold(H)
    for part in np.array_split(np.arange(3 * n), 4):
        fold.update(magnitude[part, None] * direction, contacts[part])
    out = fold.result()
    assert out["tool_max_force_N"] == pytest.approx(4.0, rel=1e-12)
    assert out["tool_mean_force_N"] == pytest.approx(2.0, rel=1e-12)
    assert out["tool_contact_time_s"] == pytest.approx(2.0, rel=1e-12)
    assert ForceFold(H).result()["tool_mean_force_N"] is None  # never in contact: no mean


def test_collisions_count_events_and_merge_a_chattering_contact():
    touching = np.zeros(3000)
    touching[100:200] = 1  # event 1: 0.1 s
    touching[250:260] = 1  # 50 ms after it: the same collision
    touching[1000:1001] = 1  # event 2
    touching[2000:2500:10] = 1  # event 3: a chattering contact, 50 rows
    fold = CollisionFold(H)
    for part in np.array_split(touching, 9):
        fold.update(part)
    assert fold.result() == {"instrument_collisions": 3, "instrument_collision_time_s": pytest.approx(0.161)}
    with pytest.raises(ValueError, match=r"collision gap -1 s must be finite and ≥ 0"):
        CollisionFold(H, gap_s=-1)


def test_camera_view_cone():
    view = CameraView((0.0, 0.0, 1.0), (0.0, 0.0, 0.0))  # looking down from 1 m, 75° wide
    on_axis, edge_in, edge_out, behind = (0, 0, 0), (math.tan(math.radians(37)), 0, 0), (0.8, 0, 0), (0, 0, 2)
    assert view.in_view(np.array([on_axis, edge_in, edge_out, behind], float)).tolist() == [
        True, True, False, False,
    ]  # fmt: skip
    fold = TipMotion(H, view)
    fold.update(np.array([on_axis] * 300 + [edge_out] * 200, float))
    assert fold.result()["tip_out_of_view_s"] == pytest.approx(0.2)
    with pytest.raises(ValueError, match="the target must differ from the position"):
        CameraView((0.1, 0.2, 0.3), (0.1, 0.2, 0.3))


def test_bad_input_is_refused_naming_the_value():
    with pytest.raises(ValueError, match=r"time step h = 0 s must be finite and > 0"):
        TipMotion(0)
    with pytest.raises(ValueError, match=r"smoothing window -0.1 s must be finite and > 0"):
        TipMotion(H, window_s=-0.1)
    with pytest.raises(ValueError, match=r"idle speed nan m/s must be finite"):
        TipMotion(H, idle_speed_mps=float("nan"))
    assert window_samples(0.01) == 11  # 0.1 s at 10 ms
    assert window_samples(0.05) == 7  # never fewer than a quintic's fit needs


def _polyline_with_switches(tip, reference):
    """The path from the logs: the polyline, the steps where the reference point switched left out."""
    steps = np.linalg.norm(np.diff(tip, axis=0), axis=1)
    return float(np.sum(steps[reference[1:] == reference[:-1]]))


def test_brick_scene_reports_path_and_forces_that_its_logs_confirm():
    station = build_station(load_scenario("diagrams/lego.yaml"))
    result = simulate(station, duration_s=3.0, progress=False)
    m = result.metrics
    keys = ("tip_path_m", "tip_economy_of_motion", "tip_log_dimensionless_jerk", "tip_idle_time_s",
            "task_time_s", "tip_out_of_view_s", "tool_max_force_N", "tool_mean_force_N",
            "tool_contact_time_s")  # fmt: skip
    assert all(m[k] is not None and math.isfinite(m[k]) for k in keys), {k: m.get(k) for k in keys}
    terms = result.data["terms"]
    tip = terms[:, TERMS_LAYOUT["pose_WG"]][:, 4:]
    held = terms[:, TERMS_LAYOUT["held_body"]]
    assert m["tip_path_m"] == pytest.approx(_polyline_with_switches(tip, held), rel=1e-9)
    # in 3 s the device lifts the brick 15 mm, carries it 20 cm along x and 3 cm up (245 mm): the
    # brick stops at the wall on the way, so its path is shorter, and no shorter than start to end
    assert np.linalg.norm(tip[-1] - tip[0]) <= m["tip_path_m"] < 0.245
    assert 0 < m["task_time_s"] <= 3.0 and m["tip_idle_time_s"] < 3.0
    # the held brick is on the table and then pushed into the wall: it presses by at most the
    # coupling's force cap on it (0.736 N), its weight (gravity compensated: 0.023 N) and its momentum
    # stopped in one step (m v_peak / h)
    body = station.coupling.body_for_grasp("brick_0")
    bound = station.coupling.force_caps(body)[0] + body.mass * (9.81 + m["tip_peak_speed_mps"] / 1e-3)
    assert 0 < m["tool_mean_force_N"] <= m["tool_max_force_N"] <= bound, (m["tool_max_force_N"], bound)
    assert m["tool_contact_time_s"] > 1.0
    assert m["tip_out_of_view_s"] == 0.0  # the scene's camera keeps the brick in view
    trace = result.traces[""]
    assert trace[:, 4].max() <= m["tool_max_force_N"] + 1e-12  # the trace is every 10th row of the same


def test_bimanual_graspers_forces_match_the_tissue_observers():
    station = build_station(load_scenario("diagrams/laparoscopy_bimanual.yaml"))
    result = simulate(station, progress=False)
    m = result.metrics
    assert m["instrument_collisions"] == 0 and m["instrument_collision_time_s"] == 0.0
    for name in ("left", "right"):
        tool = m["tools"][name]
        # the contact meter and the tissue's own observer read the same contacts: the one largest
        # force (the graspers touch nothing but the soft uterus on this path)
        assert tool["tool_max_force_N"] == pytest.approx(tool["max_tissue_contact_force_N"], rel=1e-9)
        trace = result.traces[name]
        # h = 10 ms: the trace has every row, so its polyline is the path
        assert tool["tip_path_m"] == pytest.approx(path_length(trace[:, 1:4]), rel=1e-9)
        assert all(math.isfinite(tool[k]) for k in ("tip_log_dimensionless_jerk", "tip_idle_time_s"))
    assert m["tools"]["right"]["tool_max_force_N"] > 1.0  # the right grasper presses the uterus's top


def test_two_hands_bricks_touching_is_an_instrument_collision():
    result = simulate(build_station(load_scenario("diagrams/lego_two_hands.yaml")), progress=False)
    m = result.metrics
    # the right hand lays its brick on the left hand's: the two held bricks touch, once
    assert m["instrument_collisions"] >= 1 and m["instrument_collision_time_s"] > 0.1
    for name in ("left", "right"):
        assert m["tools"][name]["tool_collisions"] == m["instrument_collisions"]
    columns = result.station.contact_meter.pair_columns("left")
    touching = result.data["contacts"][:, columns].max(axis=1) > 0.5
    assert m["instrument_collision_time_s"] == pytest.approx(touching.sum() * 1e-3)


def test_compare_runs_prints_both_sessions_and_plots_them(tmp_path, capsys):
    compare = load_script("analysis/compare_runs.py")
    out = tmp_path / "cmp"
    argv = ["lego", "lego", "--set-b", "device.noise_m=0.002", "--names", "clean", "shaky",
            "--duration", "1.0", "--out", str(out)]  # fmt: skip
    assert compare.main(argv) == 0
    table = capsys.readouterr().out
    scores = json.loads((out / "scores.json").read_text())
    clean, shaky = scores["clean"], scores["shaky"]
    line = next(row for row in table.splitlines() if " tip_path_m " in row)
    assert line.split()[-2:] == [f"{clean['tip_path_m']:.4g}", f"{shaky['tip_path_m']:.4g}"]
    assert shaky["tip_path_m"] > clean["tip_path_m"]  # the shaky hand's noise lengthens the path
    for png in ("tip_paths.png", "forces.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # two metrics files: the same table from what the runs wrote
    for name in ("clean", "shaky"):
        (tmp_path / f"{name}.json").write_text(json.dumps(scores[name]))
    assert compare.main([str(tmp_path / "clean.json"), str(tmp_path / "shaky.json"), "--names", "clean",
                         "shaky"]) == 0  # fmt: skip
    assert line in capsys.readouterr().out
    with pytest.raises(SystemExit):
        compare.main(["lego", str(tmp_path / "clean.json")])
    assert "give two scenarios, or two metrics JSON files, not one of each" in capsys.readouterr().err


@pytest.mark.parametrize("contact", ["proxies", "hydroelastic"])
def test_the_held_brick_pushes_the_wall_along_the_devices_pull(contact):
    """The force is the one the tool applies: at t = 1.99 s the device pulls the brick 0.3 m/s along
    +x into the wall, so the brick pushes the wall along +x (point and hydroelastic contacts alike)."""
    model = "point" if contact == "proxies" else "hydroelastic_with_fallback"  # as --contact sets it
    sets = [f"contact.geometry={contact}", f"plant.contact_model={model}"]
    scenario = load_with_sets(REPO / "diagrams/lego.yaml", sets)
    result = simulate(build_station(scenario), duration_s=2.0, progress=False)
    row = result.data["contacts"][1990, result.station.contact_meter.columns("")]
    force, contacts = row[:3], row[3]
    assert contacts >= 1
    assert force[0] > 0.95 * np.linalg.norm(force) > 0.3  # N: along +x, about the spring's pull


def test_a_camera_looking_away_sees_no_tip():
    """The brick scene's camera turned to look straight up: the tip (on the table) is out of its view
    at every step; turned back to the table, in it at every step. A time is its rows times h, and a
    0.3 s run logs 301 rows (t = 0 to 0.3 s), as impossible_pose_time_s counts them."""
    away = ["visualization.camera.position_m=[-0.18, -0.20, 0.13]",
            "visualization.camera.target_m=[-0.18, -0.20, 1.0]"]  # fmt: skip
    for sets, out_of_view in ((away, 0.301), ([], 0.0)):
        scenario = load_with_sets(REPO / "diagrams/lego.yaml", sets)
        m = simulate(build_station(scenario), duration_s=0.3, progress=False).metrics
        assert m["tip_out_of_view_s"] == pytest.approx(out_of_view, abs=1e-9)


def test_the_idle_speed_and_window_are_the_scenarios():
    """``metrics.idle_speed_mps`` and ``metrics.smoothing_window_s`` reach the run; bad values are
    refused naming the field, the value and an example."""
    base = ["metrics.idle_speed_mps=1000"]  # nothing moves at 1 km/s: every estimated row is idle
    m = simulate(build_station(load_with_sets(REPO / "diagrams/lego.yaml", base)), duration_s=0.5,
                 progress=False).metrics  # fmt: skip
    # 501 rows (t = 0 to 0.5 s), a 101-row window: 401 rows with a speed, all idle, none moving
    assert m["tip_idle_time_s"] == pytest.approx(0.401, abs=1e-9) and m["task_time_s"] == 0.0
    assert m["tip_log_dimensionless_jerk"] is None  # no time moving: undefined
    for item, message in (
        ("metrics.idle_speed_mps=-1",
         r"metrics\.idle_speed_mps: -1\.0 m/s must be finite and ≥ 0 \(e\.g\. 0\.005\)"),
        ("metrics.smoothing_window_s=0",
         r"metrics\.smoothing_window_s: 0\.0 s must be finite and > 0 \(e\.g\. 0\.1\)"),
    ):  # fmt: skip
        with pytest.raises(ScenarioError, match=message):
            load_with_sets(REPO / "diagrams/lego.yaml", [item])


def test_the_meters_shortcut_gives_the_contact_lists_rows():
    """A rigid tool alone holding a body reads its net contact force from the plant's generalized
    contact forces; walking Drake's contact list gives the same rows (the brick pressed into the
    wall, on the table and laid on another brick: the whole path)."""
    rows = {}
    for shortcut in (True, False):
        station = build_station(load_scenario("diagrams/lego.yaml"))
        station.contact_meter.shortcut = shortcut
        rows[shortcut] = simulate(station, progress=False).data["contacts"]
    assert np.count_nonzero(rows[True][:, 3]) > 1000  # in contact for over a second
    np.testing.assert_allclose(rows[True], rows[False], rtol=0, atol=1e-12)


def test_without_tool_forces_no_meter_runs_the_forces_are_left_out_and_the_run_is_the_same():
    """``metrics.tool_forces: false``: no contact meter in the diagram, no force or collision key
    (not a 0 N that would read as no force), the tips' motion measured as with it, and the plant
    moves bit for bit as with the meter (it only reads)."""
    from godobject_drake.config.scenario import replace

    s = replace(load_scenario("diagrams/lego.yaml"), **{"simulation.duration_s": 1.0})
    runs = []
    for forces in (True, False):
        station = build_station(replace(s, **{"metrics.tool_forces": forces}))
        names = {system.get_name() for system in station.diagram.GetSystems()}
        assert ("contact_meter" in names) == forces
        runs.append(simulate(station, progress=False))
    with_meter, without = runs
    assert not any(k.startswith("tool_") and "force" in k for k in without.metrics)
    assert "tool_contact_time_s" not in without.metrics and "tool_max_force_N" in with_meter.metrics
    assert without.metrics["tip_path_m"] == with_meter.metrics["tip_path_m"]
    assert np.array_equal(without.data["state"], with_meter.data["state"])
