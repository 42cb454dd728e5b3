"""Speed-vs-error measurements: errors a reader can check by hand, energy against Drake's own,
the recommendation rule, a refused configuration and the MuJoCo peer on the same path."""

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import add_free_boxes, load_script
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config.scenario import replace, shipped_scenario
from godobject_drake.studies.benchmark import (
    compare,
    cpu_model,
    drake_version,
    make_case,
    rigid_energy,
    round_robin,
    run_case,
    summarize_cost,
)


def lego_case(time_step, duration, **kw):
    """The brick scene at this step (s) for this long (s), one run."""
    changes = {"plant.time_step": time_step, "simulation.duration_s": duration}
    return make_case(replace(shipped_scenario("lego"), **changes), repeats=1, **kw)


def run_like(p, q, E):
    return {"times": np.arange(len(p)) * 0.01, "p_WG": np.asarray(p), "q_WG": np.asarray(q), "energy_j": E}


def test_compare_gives_the_offsets_put_in():
    n = 50
    p = np.zeros((n, 3))
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    ref = run_like(p, q, np.linspace(0.0, 1.0, n))
    a = 0.01  # rad about z
    shifted = run_like(
        p + np.array([0.003, 0.004, 0.0]),
        np.tile([math.cos(a / 2), 0, 0, math.sin(a / 2)], (n, 1)),
        np.linspace(0.0, 1.0, n) + 5.0,
    )
    err = compare(shifted, ref)
    assert err["pose_rms_m"] == pytest.approx(0.005)  # a 3-4-5 triangle
    assert err["angle_rms_rad"] == pytest.approx(a)
    assert err["energy_error_j"] == pytest.approx(0.0, abs=1e-12)  # a constant offset is no error
    drift = run_like(p, q, np.linspace(0.0, 1.0, n) * 1.1)
    assert compare(drift, ref)["energy_error_j"] == pytest.approx(0.1)


def test_rigid_energy_matches_drakes():
    """The formula the MuJoCo peer is measured with equals Drake's kinetic + potential energy."""
    builder = DiagramBuilder()
    plant, bodies = add_free_boxes(builder, 1e-3, (0.5, 2.0))
    context = plant.CreateDefaultContext()
    rng = np.random.default_rng(1)
    x = rng.standard_normal(plant.num_multibody_states())
    for i in range(2):
        x[7 * i : 7 * i + 4] /= np.linalg.norm(x[7 * i : 7 * i + 4])
    plant.SetPositionsAndVelocities(context, x)
    p, q, v, w = [], [], [], []
    for b in bodies:
        X = b.EvalPoseInWorld(context)
        V = b.EvalSpatialVelocityInWorld(context)
        p.append(X.translation())
        q.append(X.rotation().ToQuaternion().wxyz())
        v.append(V.translational())
        w.append(V.rotational())
    inertias = [np.diag([1e-3, 2e-3, 3e-3])] * 2
    E = rigid_energy(*(np.array([a]) for a in (p, q, v, w)), [0.5, 2.0], inertias)
    expected = plant.CalcKineticEnergy(context) + plant.CalcPotentialEnergy(context)
    assert E[0] == pytest.approx(expected, rel=1e-12)


def test_recommendation_is_the_cheapest_within_both_budgets():
    sve = load_script("analysis/speed_vs_error.py")
    rows = [
        {
            "label": "a",
            "refused": None,
            "diverged": False,
            "cost_median_s": 0.1,
            "pose_rms_m": 2e-3,
            "max_penetration_m": 1e-4,
        },
        {
            "label": "b",
            "refused": None,
            "diverged": False,
            "cost_median_s": 0.2,
            "pose_rms_m": 5e-4,
            "max_penetration_m": 3e-3,
        },
        {
            "label": "c",
            "refused": None,
            "diverged": False,
            "cost_median_s": 0.4,
            "pose_rms_m": 4e-4,
            "max_penetration_m": 1e-4,
        },
        {
            "label": "d",
            "refused": None,
            "diverged": True,
            "cost_median_s": 0.05,
            "pose_rms_m": 1e-5,
            "max_penetration_m": 0.0,
        },
        {"label": "e", "refused": "past the limit", "diverged": False, "cost_median_s": None},
    ]
    assert sve.recommend(rows, 5e-3, 1e-3)["label"] == "a"
    assert sve.recommend(rows, 1e-3, 1e-3)["label"] == "c"  # b penetrates too far
    assert sve.recommend(rows, 1e-3, 5e-3)["label"] == "b"
    assert sve.recommend(rows, 1e-6, 1e-3) is None
    assert [r["label"] for r in sve.pareto(rows)] == ["a", "b", "c"]
    assert summarize_cost([0.3, 0.1, 0.2])["cost_median_s"] == 0.2
    assert summarize_cost([0.3, 0.1, 0.2])["real_time_factor"] == pytest.approx(5.0)


def test_round_robin_runs_each_scenario_once_a_round_in_turn():
    """Two brick scenes, 0.05 and 0.1 s, two rounds: one CPU cost per scenario and round, per
    simulated second, with the Drake this Python runs and the machine beside them."""
    from importlib.metadata import version

    lego = shipped_scenario("lego")
    runs = {T: replace(lego, **{"simulation.duration_s": T}) for T in (0.05, 0.1)}
    r = round_robin(runs, rounds=2)
    assert [len(r["cpu_s_per_sim_s"][T]) for T in runs] == [2, 2] and len(r["load_1min"]) == 2
    assert all(c > 0.0 for T in runs for c in r["cpu_s_per_sim_s"][T])
    assert r["drake"] == drake_version() == version("drake")
    assert r["machine"].endswith(cpu_model()) and r["rounds"] == 2


def test_the_scale_sentence_gives_the_median_of_each_rounds_ratio():
    """Per round 1.0/0.5 = 2, 0.9/0.4 = 2.25, 0.6/0.45 = 1.33: the median is 2.00, not the
    ratio of the medians (0.9/0.45 = 2); with the Drake, the machine and the load beside it."""
    sve = load_script("analysis/speed_vs_error.py")
    r = sve.with_ratios({"cpu_s_per_sim_s": {8: [0.5, 0.4, 0.45], 64: [1.0, 0.9, 0.6]}, "rounds": 3,
                         "drake": "1.58.0", "machine": "2 cores (2 usable), AMD EPYC",
                         "load_1min": [0.4, 1.6, 0.9]})  # fmt: skip
    assert r["ratio_median"] == pytest.approx(2.0) and r["ratio_rounds"][1] == pytest.approx(2.25)
    (line, _) = sve.interleaved_lines(r)
    assert "interleaved in one process: 2.00×" in line and "rounds 1.33–2.25×" in line
    assert "Drake 1.58.0; 2 cores (2 usable), AMD EPYC; load 0.4–1.6" in line


def test_step_shares_splits_py_spys_samples_by_part(tmp_path):
    """Four stacks inside the loop's AdvanceTo call (3 in SceneGraph's pose update, 4 in SAP, 1 in
    the sleep check) and 2 in its metrics fold: C++ 7/8 = 87.5 %, Python 12.5 %, 2/8 = 25 % on
    top; a stack outside the loop is not counted."""
    import godobject_drake.simulation as simulation

    ss = load_script("analysis/step_shares.py")
    function, advance, fold = ss.loop_lines()
    source = Path(simulation.__file__).read_text().splitlines()
    assert "AdvanceTo(" in source[advance - 1] and "fold()" in source[fold - 1]
    loop = "<module> (run.py:1);simulate (godobject_drake/simulation.py:1);" + function
    loop += " (godobject_drake/simulation.py:{})"
    raw = tmp_path / "raw.txt"
    raw.write_text(
        "\n".join([
            loop.format(advance) + ";drake::geometry::SceneGraph<double>::CalcPoseUpdate (libdrake.so) 3",
            loop.format(advance) + ";drake::multibody::internal::SapDriver<double>::Calc (libdrake.so) 4",
            loop.format(advance) + ";SleepManager.check (godobject_drake/sleeping.py:250) 1",
            loop.format(fold) + ";SceneMetrics.update (godobject_drake/metrics.py:10) 2",
            "<module> (run.py:1);build_station (godobject_drake/station/build.py:9) 5",
        ])
    )  # fmt: skip
    s = ss.shares(raw, (function, advance, fold))
    assert s == {
        "inside": {
            "C++: SceneGraph pose update (every geometry)": 3,
            "C++: SAP (contact problem and solve)": 4,
            "Python: sleep check": 1,
        },
        "outside": 2,
        "fold": 2,
    }
    head = ss.report(raw, s)[0]
    assert "C++ 87.5 %, Python 12.5 %" in head and "25.0 % on top (the metrics fold 25.0 %)" in head


def test_explicit_coupling_refuses_h_10_ms_with_the_limit():
    r = run_case(lego_case(10e-3, 0.1))
    assert "omega_n_rot=120 rad/s at time_step=0.01 s" in r["refused"] and "0.8284" in r["refused"]
    assert r["wall_s_per_sim_s"] == []


@pytest.mark.slow
def test_mujoco_peer_follows_the_same_path():
    """MuJoCo's weld and Drake's coupling lift brick_0 along the same path: after 0.5 s the
    device is at z = 2 cm; both bricks are within 3 mm of it (the weld lags by 2ζv/ωn =
    1.5 mm at the path's 3 cm/s: its mocap body has no velocity for the damping)."""
    pytest.importorskip("mujoco")
    drake = run_case(lego_case(1e-3, 0.5))
    mj = run_case(lego_case(1e-3, 0.5, engine="mujoco", mujoco_mode="weld"))
    assert not mj["diverged"]
    for r in (drake, mj):
        assert abs(r["p_WG"][-1, 2] - 0.02) < 3e-3
    assert len(mj["wall_s_per_sim_s"]) == 1 and mj["mujoco_version"]


@pytest.mark.slow
def test_engine_neutral_errors_agree_with_each_engines_own():
    """Both engines measured by the same code (true shapes, the device's target): on Drake's run the
    held brick's sampled true penetration is Drake's own per-step maximum (pressed statically on
    the wall, a 10 ms sample misses nothing); on MuJoCo's it is MuJoCo's own box-box contact depth
    (the stiff contact) to 0.1 µm, and its weld tracks free space ~2ζv/ωn = 6.7 mm behind, which
    Drake's damper, carrying the target's velocity, does not. MuJoCo's default contact lets the
    weld pull the brick through the wall: flagged, not scored as a small penetration."""
    pytest.importorskip("mujoco")
    drake = run_case(lego_case(1e-3, 3.0))
    assert drake["true_penetration_m"] == pytest.approx(drake["max_penetration_m"], rel=1e-9)
    assert drake["free_tracking_rms_m"] < 1.5e-3 and not drake["crossed_wall"]
    stiff = run_case(lego_case(1e-3, 3.0, engine="mujoco", mujoco_timeconst_s=2e-3))
    assert stiff["true_penetration_m"] == pytest.approx(stiff["max_penetration_m"], abs=1e-7)
    assert 4e-3 < stiff["free_tracking_rms_m"] < 8e-3 and not stiff["crossed_wall"]
    soft = run_case(lego_case(1e-3, 3.0, engine="mujoco"))
    assert soft["crossed_wall"]


@pytest.mark.slow
def test_the_peer_places_extra_bricks_where_drake_does():
    pytest.importorskip("mujoco")
    from godobject_drake.station.plant import add_plant
    from godobject_drake.studies.mujoco_peer import brick_names, brick_positions
    from godobject_drake.systems.coupling import graspable_bodies

    s = replace(shipped_scenario("lego"), bricks=70)
    plant = add_plant(DiagramBuilder(), s).plant
    context = plant.CreateDefaultContext()
    bodies = graspable_bodies(plant)
    for name, xyz in zip(brick_names(70), brick_positions(70), strict=True):
        body = plant.get_body(BodyIndex(bodies[name].index))
        np.testing.assert_allclose(body.EvalPoseInWorld(context).translation(), xyz, atol=1e-12)
    # 62 extra bricks: the grid's 54 places, then 8 on the second layer, on top of the first 8
    assert brick_positions(70)[62][2] == pytest.approx(0.0048 + 0.0096)


def test_free_tracking_samples_at_the_steps_taken_when_h_does_not_divide_10_ms():
    """At h = 4 ms the sampled rows are every 2 steps, 8 ms apart, not 10: read as 10 ms apart,
    the device's target ran ahead of the brick and free-space tracking read 21 mm over these 3 s
    (68 mm over the whole path) where h = 5 ms read 0.72 mm. Both steps carry the same brick
    along the same path, so their tracking must agree to well within a millimetre (measured:
    0.715 and 0.716 mm)."""
    four, five = (run_case(lego_case(h, 3.0)) for h in (4e-3, 5e-3))
    assert abs(four["free_tracking_rms_m"] - five["free_tracking_rms_m"]) < 0.1e-3


def test_step_floor_replays_the_scene_bit_for_bit():
    """analysis/step_floor.py's fair floor is the scene's own plant with no Python per step,
    replaying what the scene did to it; it is fair only if it steps the very states the scene
    stepped: after 0.3 s the plant's state equals the scene's to the bit, for both couplings
    (the explicit coupling's forces from a TrajectorySource, the implicit springs between
    AdvanceTo calls)."""
    floor = load_script("analysis/step_floor.py").measure(0.3, 1)
    assert floor["explicit_replay_bit_identical"] and floor["implicit_replay_bit_identical"]
    assert floor["explicit_events"] > 0 and floor["implicit_events"] > floor["explicit_events"]
