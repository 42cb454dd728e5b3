"""Sleeping bodies (README "Sleeping bodies"): resting free bodies are locked and cost nothing,
and wake before anything reaches them, so a run with sleep on is the run with sleep off.

Each check compares a run with sleep on against the same run with every body awake: the held
brick on the default path, a brick the held one pushes after it has slept, a resting stack.
"""

import msgpack
import numpy as np
import pytest
from conftest import REPO, assert_refused, build_scene, meshcat_commands, run_scene, scenario, shared_run

from godobject_drake.config.device_files import Waypoint
from godobject_drake.config.scenario import ScenarioError, check_scenario, replace, scenario_from_yaml
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.station.plant import BRICK_HEIGHT_M, brick_grid_positions
from godobject_drake.systems.coupling import graspable_bodies


def positions(result, name: str) -> np.ndarray:
    body = graspable_bodies(result.station.plant)[name]
    return result.states[:, body.q_start + 4 : body.q_start + 7]


def lego_along(waypoints: list[Waypoint], *flags: str):
    """The brick scene with its device on ``waypoints``, run."""
    s = scenario("lego", *flags)
    s.device.path, s.device.waypoints = "", waypoints
    return simulate(build_station(s), progress=False)


@pytest.mark.slow
def test_the_default_path_is_the_same_asleep_or_awake():
    """Issue 16's budget: the held brick within 0.05 mm RMS, no more penetration; 6 of the 7
    other bricks sleep on average (brick_1, where brick_0 is set down, wakes for it)."""
    # asleep is the default: the run test_lego and test_long_runs read too (conftest.shared_run)
    awake, asleep = run_scene("lego", "--sleep", "off"), shared_run("lego", "--sleep", "on")
    a, b = positions(awake, "brick_0"), positions(asleep, "brick_0")
    assert np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))) <= 0.05e-3
    assert asleep.metrics["max_penetration_m"] <= awake.metrics["max_penetration_m"] + 1e-9
    assert asleep.metrics["sleep_mean_bodies"] > 5.5 and asleep.metrics["sleep_wakeups"] >= 1
    assert awake.metrics["sleep"] is False and "sleep_mean_bodies" not in awake.metrics
    # brick_1 bears brick_0 at the end, asleep or awake alike
    np.testing.assert_allclose(positions(asleep, "brick_1")[-1], positions(awake, "brick_1")[-1], atol=2e-6)


@pytest.mark.slow
def test_a_brick_pushed_after_it_slept_moves_as_if_it_never_had():
    """brick_0 rests 0.6 s (brick_3, 5 cm away in y, falls asleep), then slides along y into
    brick_3 and pushes it 2 cm on. brick_3's path matches the all-awake run's."""
    path = [
        Waypoint(t=0.0, xyz=[-0.10, 0.0, 0.0048], grasp="brick_0"),
        Waypoint(t=0.6, xyz=[-0.10, 0.0, 0.0048], grasp="brick_0"),
        Waypoint(t=1.6, xyz=[-0.10, 0.09, 0.0048], grasp="brick_0"),
    ]
    runs = {mode: lego_along(path, "--sleep", mode, "--duration", "1.8") for mode in ("off", "on")}
    a, b = positions(runs["off"], "brick_3"), positions(runs["on"], "brick_3")
    assert a[-1, 1] - a[0, 1] > 0.015  # it was pushed
    assert np.max(np.linalg.norm(a - b, axis=1)) <= 0.1e-3
    assert runs["on"].metrics["sleep_wakeups"] >= 1


STACK = """
directives:
- add_model: {name: lego_table, file: package://godobject_models/lego/table.sdf}
- add_weld: {parent: world, child: lego_table::baseplate}
- add_model:
    name: brick_0
    file: package://godobject_models/lego/brick_2x4.sdf
    default_free_body_pose: {brick: {translation: [-0.1, 0.0, 0.0048]}}
"""


@pytest.mark.slow
def test_a_resting_stack_stays_put_for_a_minute():
    """Three bricks stacked on the plate (the grid's layers, as ``--bricks`` lays them), the
    device away: asleep from 0.1 s on, each within 0.1 mm of where it was placed after 60 s."""
    text = (REPO / "diagrams/lego.yaml").read_text()
    text = text.split("directives:")[0] + STACK + "contact:" + text.split("\ncontact:")[1]
    for k, (x, y, z) in enumerate([(0.1, 0.1, 0.0048), (0.1, 0.1, 0.0048 + BRICK_HEIGHT_M),
                                   (0.1, 0.1, 0.0048 + 2 * BRICK_HEIGHT_M)], start=1):  # fmt: skip
        text = text.replace(
            "contact:",
            f"""- add_model:
    name: brick_{k}
    file: package://godobject_models/lego/brick_2x4.sdf
    default_free_body_pose: {{brick: {{translation: [{x}, {y}, {z}]}}}}
contact:""",
            1,
        )
    s = scenario_from_yaml(text, REPO / "diagrams")
    s.simulation.duration_s = 60.0
    s.device.path = ""
    s.device.waypoints = [Waypoint(t=0.0, xyz=[-0.10, 0.0, 0.06]), Waypoint(t=60.0, xyz=[-0.10, 0.0, 0.06])]
    result = simulate(build_station(s), progress=False)
    for name in ("brick_1", "brick_2", "brick_3"):
        p = positions(result, name)
        assert np.max(np.linalg.norm(p - p[0], axis=1)) <= 0.1e-3, name
    assert result.metrics["sleep_mean_bodies"] > 0.99 * 3
    # the stack is the grid's: its second layer lies on its first
    places = brick_grid_positions(55)
    assert places[54][:2] == places[0][:2] and places[54][2] - places[0][2] == pytest.approx(BRICK_HEIGHT_M)


def test_sleeping_bodies_are_marked_in_the_recording(tmp_path):
    """The recording shows a blue marker over each sleeping brick, never over the held one."""
    html = tmp_path / "lego.html"
    run_scene("lego", "--duration", "1.0", "--record", str(html))
    (animation,) = [c for c in meshcat_commands(html.read_text()) if b"set_animation" in c]
    shown = set()
    for a in msgpack.unpackb(animation, raw=False)["animations"]:
        for track in a["clip"]["tracks"]:
            if a["path"].startswith("/godobject/sleep/") and track["name"] == ".visible":
                if any(key["value"] for key in track["keys"]):
                    shown.add(a["path"].split("/")[-1])
    assert "brick_5::brick" in shown and "brick_0::brick" not in shown


def test_bad_sleep_and_brick_settings_are_refused():
    assert_refused(
        lambda: check_scenario(replace(scenario("lego"), **{"sleep.hold_s": -1.0})),
        ScenarioError,
        value=r"sleep\.hold_s=-1\.0",
        limit=r"must be ≥ 0",
        fix=r"default 0\.03",
    )
    assert_refused(
        lambda: build_scene("laparoscopy", "--bricks", "4"),
        ScenarioError,
        value=r"bricks: 4",
        limit=r"no brick_k models",
        fix=r"Leave bricks at 0",
    )
    assert_refused(
        lambda: build_scene("lego", "--bricks", "5"),
        ScenarioError,
        value=r"bricks: 5",
        limit=r"fewer than the 8 bricks",
        fix=r"give ≥ 8",
    )
