"""Several tools in one scene (``tools: {NAME: {...}}``): each its own device, coupling, grasp and
feedback, touching the world and each other through contact; one tool named is the one-tool scene.

Numbers from the brick scene's geometry: a 2x4 brick is 31.8 x 15.8 x 9.6 mm (centre 4.8 mm above
the plate), the wall's near face is at x = -4 mm.
"""

import json

import numpy as np
import pytest
from conftest import REPO

from godobject_drake import cli
from godobject_drake.config.scenario import (
    TOOL_FIELDS,
    Scenario,
    ScenarioError,
    Tool,
    load_scenario,
    replace,
    shipped_scenario,
)
from godobject_drake.metrics import format_table
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.studies.analyze import analyze
from godobject_drake.systems.coupling import TERMS_LAYOUT

LEGO = REPO / "diagrams" / "lego.yaml"
BRICK_HEIGHT_M, WALL_FACE_X_M, BRICK_HALF_LENGTH_M = 0.0096, -0.004, 0.0159


def brick_positions(station, states: np.ndarray, name: str) -> np.ndarray:
    """A brick's origin (its centre) at each logged step."""
    plant = station.plant
    body = plant.GetBodyByName("brick", plant.GetModelInstanceByName(name))
    start = body.floating_positions_start()
    return states[:, start + 4 : start + 7]


@pytest.fixture(scope="module")
def two_hands():
    return simulate(build_station(shipped_scenario("lego_two_hands")), progress=False)


@pytest.mark.slow(seconds=40)
def test_one_hand_holds_a_brick_against_the_wall_while_the_other_lays_one_on_it(two_hands):
    m, station = two_hands.metrics, two_hands.station
    assert not m["diverged"] and set(m["tools"]) == {"left", "right"}
    budget = station.scenario.metrics.penetration_budget_m
    for name in ("left", "right"):  # each tool's own figures, each within the scene's budget
        assert m["tools"][name]["max_penetration_m"] <= budget, name
    assert m["max_penetration_m"] == max(t["max_penetration_m"] for t in m["tools"].values())
    states, h = two_hands.states, station.plant.time_step()
    below, above = brick_positions(station, states, "brick_2"), brick_positions(station, states, "brick_1")
    hold = round(3.5 / h)  # both hands on: the left presses brick_2 8 mm past the wall's face
    assert below[hold, 0] == pytest.approx(
        WALL_FACE_X_M - BRICK_HALF_LENGTH_M, abs=0.001
    )  # the wall stops it
    end = -1  # both let go: brick_1 rests on brick_2, one brick height up
    assert above[end, 2] - below[end, 2] == pytest.approx(BRICK_HEIGHT_M, abs=0.001)
    assert np.linalg.norm(above[end, :2] - below[end, :2]) < 0.003
    held = {name: two_hands.data[f"{name}/terms"][:, TERMS_LAYOUT["held_body"]] for name in ("left", "right")}
    assert held["left"][hold] >= 0 and held["right"][hold] >= 0 and held["left"][hold] != held["right"][hold]


def test_the_metrics_table_has_a_column_per_tool(two_hands):
    table = format_table([two_hands.metrics])
    header = table.splitlines()[0].split()
    assert header == ["metric", "scene", "left", "right"]
    row = next(line for line in table.splitlines() if line.startswith("max_penetration_m"))
    assert len(row.split()) == 4  # the scene's worst and each tool's


def two_tools(left: str, right: str, duration: float = 0.6) -> str:
    """Two rigid tools, ``a`` and ``b``, on the brick scene's table, with these two inline paths
    (a live grasp, ``*``, takes the nearest free body within 2 cm)."""
    return f"""
tools:
  a:
    god_object: !Rigid {{gains: {{omega_n: 40.0, zeta: 1.0, omega_n_rot: 120.0}}}}
    device: !Scripted {{waypoints: {left}}}
  b:
    god_object: !Rigid {{gains: {{omega_n: 40.0, zeta: 1.0, omega_n_rot: 120.0}}, grasp_reach_m: 0.02}}
    device: !Scripted {{waypoints: {right}}}
simulation: {{duration_s: {duration}}}
"""


def lego_with(tools_yaml: str):
    """The brick scene's models and contact (SAP, point contact, h = 1 ms), and ``tools_yaml``."""
    return (
        "name: two\ndirectives:\n- add_directives:\n    file: package://godobject_models/lego/lego.dmd.yaml\n"
        "contact: {geometry: proxies}\n" + tools_yaml
    )


def test_two_tools_grasping_one_body_at_once_are_refused(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text(lego_with(two_tools(
        "[{t: 0.0, xyz: [-0.1, 0, 0.0048], grasp: brick_0}, {t: 1.0, xyz: [-0.1, 0, 0.02], grasp: brick_0}]",
        "[{t: 0.0, xyz: [-0.06, 0.05, 0.0048], grasp: ''}, {t: 0.5, xyz: [-0.1, 0, 0.02], grasp: brick_0}]",
    )))  # fmt: skip
    with pytest.raises(
        ScenarioError, match=r"tools\.a and tools\.b both grasp brick_0::brick from t = 0\.5 s"
    ):
        build_station(load_scenario(path))


def test_a_body_another_tool_holds_is_not_taken_by_the_nearest_grasp(tmp_path):
    """Tool b's device waits on brick_0 with the live devices' grasp (``*``: the nearest free body
    within reach, 2 cm here): while tool a holds brick_0 it is passed over (no other brick is
    within reach), so b holds nothing; with a holding nothing, b takes it."""
    a = "[{t: 0.0, xyz: [-0.1, 0, 0.0048], grasp: brick_0}, {t: 1.0, xyz: [-0.1, 0, 0.0048], grasp: brick_0}]"
    b = "[{t: 0.0, xyz: [0.1, 0.0, 0.03], grasp: ''}, {t: 0.2, xyz: [-0.1, 0.0, 0.012], grasp: '*'}]"
    path = tmp_path / "two.yaml"
    path.write_text(lego_with(two_tools(a, b)))
    result = simulate(build_station(load_scenario(path)), progress=False)
    index = result.station.plant.GetBodyByName(
        "brick", result.station.plant.GetModelInstanceByName("brick_0")
    )
    held_a = result.data["a/terms"][:, TERMS_LAYOUT["held_body"]]
    held_b = result.data["b/terms"][:, TERMS_LAYOUT["held_body"]]
    assert held_a[-1] == int(index.index()) and held_b[-1] == -1
    path.write_text(lego_with(two_tools(a.replace("grasp: brick_0", "grasp: ''"), b)))  # a holds nothing
    result = simulate(build_station(load_scenario(path)), progress=False)
    assert result.data["b/terms"][-1, TERMS_LAYOUT["held_body"]] == int(index.index())


@pytest.mark.parametrize("scene", ["lego", "laparoscopy"])
def test_one_named_tool_is_the_one_tool_scene_bit_for_bit(scene):
    """``tools: {hand: ...}`` holding a scene's own tool fields runs the same trajectory as the
    file's top-level form (its systems are named ``hand/...``) and gives the same metrics, its
    kind's configuration keys included (read from the tool, not the unset top-level fields)."""
    s = replace(shipped_scenario(scene), **{"simulation.duration_s": 0.5})
    top = simulate(build_station(s), progress=False)
    named = replace(s)
    named.tools = {"hand": sc_tool(s)}
    for field in TOOL_FIELDS:  # the top-level tool fields left unset (their defaults)
        setattr(named, field, getattr(Scenario(), field))
    named_run = simulate(build_station(named), progress=False)
    np.testing.assert_array_equal(named_run.states, top.states)
    timing = {"wall_time_s", "cpu_time_s", "real_time_factor", "step_cost_us", "metrics_time_s"}
    same = {k: v for k, v in top.metrics.items() if k not in timing}
    assert {k: v for k, v in named_run.metrics.items() if k not in timing} == same


def sc_tool(s):
    return Tool(god_object=s.god_object, device=s.device, feedback=s.feedback, haptic=s.haptic,
                workspace=s.workspace)  # fmt: skip


def test_top_level_tool_fields_beside_tools_are_refused():
    s = replace(shipped_scenario("lego_two_hands"))
    s.feedback.kd = 5.0
    with pytest.raises(
        ScenarioError, match=r"feedback: this scene has tools \(left, right\): give each tool"
    ):
        build_station(s)


@pytest.mark.slow(seconds=30)
def test_the_two_hand_scene_runs_from_the_command_line(tmp_path):
    metrics = tmp_path / "m.json"
    flags = ["--no-progress", "--metrics", str(metrics), "--set", "simulation.duration_s=1.0"]
    assert cli.main(["run", "lego_two_hands", *flags]) == 0
    m = json.loads(metrics.read_text())
    assert set(m["tools"]) == {"left", "right"} and m["tools"]["left"]["device"] == "scripted"


def test_analyze_gives_each_tools_rows_and_the_contact_between_their_bricks():
    """The two-hand scene: each tool's rows named by it, and the two held bricks pressed together:
    the weaker of the two capped pulls into the bricks' combined point stiffness, by hand. A brick
    is 2.3 g with 2e4 N/m contact points (models/lego/brick_2x4.sdf); a cap is m ωn² max_stretch_m
    (0.2 m here): the right hand at ωn 20 pulls at most 0.0023 × 400 × 0.2 = 0.184 N, the left at
    40 four times that; two bricks combine to 2e4·2e4/(2e4 + 2e4) = 1e4 N/m: 18.4 µm."""
    s = shipped_scenario("lego_two_hands")
    s.tools["right"].god_object.gains.omega_n = 20.0
    summary = analyze(s, quick=True)
    assert set(summary["tools"]) == {"left", "right"}
    assert all(c["subject"].startswith(("left: ", "right: ")) for c in summary["checks"][:-1])
    between = summary["checks"][-1]
    assert between["subject"] == "left and right: brick_2::brick against brick_1::brick"
    assert between["value"] == pytest.approx(0.0023 * 20.0**2 * 0.2 / 1e4, rel=1e-9)
    assert between["verdict"] == "ok" and between["limit"] == s.metrics.penetration_budget_m


def test_device_flag_on_a_scene_of_tools_names_the_field_to_set(capsys):
    """``--device`` switches the top-level device, which a scene of tools leaves unset: refused
    (exit 2) naming the tools and the ``--set`` that sets one tool's device."""
    with pytest.raises(SystemExit) as exit_:
        cli.main(["run", "lego_two_hands", "--device", "replay", "--no-progress"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "--device replay: this scene has tools (left, right)" in err
    assert "--set 'tools.NAME.device=!KIND {...}'" in err
