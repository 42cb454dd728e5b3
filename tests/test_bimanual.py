"""The bimanual laparoscopy scene (``laparoscopy_bimanual``): two graspers through two trocars, the
left one holding and lifting the uterus's edge while the right one presses its top.

Numbers from the scene's geometry (models/laparoscopy/bimanual.dmd.yaml): the uterus is the
ellipsoid of radii 45, 30, 25 mm about the origin, the grasp site starts on its upper surface at
(32, 0, 17.6) mm, and a grasper's jaws end 17 mm below its tube's origin (the jaw capsules'
tips, models/laparoscopy/grasper.sdf).
"""

import json
import math

import numpy as np
import pytest

from godobject_drake import cli
from godobject_drake.config.scenario import ScenarioError, replace, shipped_scenario
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station
from godobject_drake.studies.analyze import analyze

RADII_M = np.array([0.045, 0.030, 0.025])
SITE_Z_M = 0.0176
JAW_TIP_M = np.array([0.0, 0.0, -0.017])
TROCAR_TOLERANCE_M = 1e-6


def surface_z(x: float, y: float) -> float:
    """The rest surface's height above (x, y): the ellipsoid's top."""
    return RADII_M[2] * math.sqrt(max(0.0, 1.0 - (x / RADII_M[0]) ** 2 - (y / RADII_M[1]) ** 2))


def jaw_tip(result, name: str, t: float) -> np.ndarray:
    """Where grasper ``name``'s jaws end at time ``t`` (W, m)."""
    station = result.station
    plant = station.plant
    context = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(context, result.states[round(t / plant.time_step())])
    tube = plant.GetBodyByName("tube", plant.GetModelInstanceByName(f"grasper_{name}"))
    return plant.EvalBodyPoseInWorld(context, tube).multiply(JAW_TIP_M)


def site_z(result) -> np.ndarray:
    plant = result.station.plant
    site = plant.GetBodyByName("site", plant.GetModelInstanceByName("edge"))
    return result.states[:, site.floating_positions_start() + 6]


@pytest.fixture(scope="module")
def rigid():
    s = replace(shipped_scenario("laparoscopy_bimanual"), **{"organs.model": "rigid"})
    return simulate(build_station(s), progress=False)


def test_on_rigid_organs_each_grasper_keeps_to_its_trocar_and_its_budget(rigid):
    m = rigid.metrics
    assert not m["diverged"] and set(m["tools"]) == {"left", "right"}
    budget = rigid.station.scenario.metrics.penetration_budget_m
    for name, tool in m["tools"].items():
        assert tool["max_trocar_offset_m"] <= TROCAR_TOLERANCE_M, name
        assert tool["max_penetration_m"] <= budget, name
    # the right one presses the soft contact (627 N/m) by millimetres: more than the left one
    assert 0.001 < m["tools"]["right"]["max_penetration_m"]
    assert m["tools"]["left"]["max_penetration_m"] < m["tools"]["right"]["max_penetration_m"]


def test_the_left_jaws_take_the_site_as_they_close_and_let_go_as_they_open(rigid):
    """The left path closes its jaw channel 0.6 -> 0 over 1.5-2 s (each jaw joint half of it):
    below ``closed_below_rad`` 0.1 after 1.833 s, the device's first 60 Hz sample past it is at
    1.85 s; it opens them 0 -> 0.6 over 6-6.3 s: open again from 6.1 s. A rigid organ's site is
    welded: it cannot rise."""
    events = rigid.metrics["tools"]["left"]["grasp_events"]
    assert (
        len(events) == 2
        and events[0].endswith("took edge::site")
        and events[1].endswith("let go of edge::site")
    )
    took, let_go = (float(e.split()[0]) for e in events)
    assert 1.8 <= took <= 1.9 and 6.0 <= let_go <= 6.2
    assert "grasp_events" not in rigid.metrics["tools"]["right"]  # the right one grasps nothing
    assert rigid.metrics["tools"]["left"]["grasped_max_rise_m"] == 0.0


@pytest.fixture(scope="module")
def fem():
    return simulate(build_station(shipped_scenario("laparoscopy_bimanual")), progress=False)


@pytest.mark.slow(seconds=60)
def test_on_fem_tissue_the_left_lifts_the_edge_while_the_right_presses_the_top(fem):
    m = fem.metrics
    assert not m["diverged"]
    left, right = m["tools"]["left"], m["tools"]["right"]
    for tool in (left, right):
        assert tool["max_trocar_offset_m"] <= TROCAR_TOLERANCE_M
    z = site_z(fem)
    assert z[0] == pytest.approx(SITE_Z_M, abs=1e-4)
    lift = z[round(5.0 / fem.station.plant.time_step())] - SITE_Z_M
    assert lift > 0.005  # the left grasper lifts the edge (5.5 mm here; 5.8 with the 8-cell reference organ)
    assert left["grasped_max_rise_m"] == pytest.approx(float(np.max(z - z[0])), abs=1e-9)
    tip = jaw_tip(fem, "right", 5.0)  # while the left one holds the edge up
    press = surface_z(tip[0], tip[1]) - tip[2]
    assert press > 0.001  # the right jaws' tips below the rest surface (3.3 mm here)
    # each tool its own contact force: the right one pushes the tissue, the left one holds it by its
    # grasp (a constraint, not a contact)
    assert right["max_tissue_contact_force_N"] > 1.0
    assert left["max_tissue_contact_force_N"] < 0.2 * right["max_tissue_contact_force_N"]
    assert z[-1] - SITE_Z_M < 0.001  # let go: the edge falls back


def test_a_jointed_body_glued_to_the_organ_is_refused():
    s = replace(shipped_scenario("laparoscopy_bimanual"), **{"organs.glued": ["grasper_left::tube"]})
    with pytest.raises(ScenarioError, match=r"organs\.glued: grasper_left::tube: a jointed or welded body"):
        build_station(s)


def test_a_grasp_body_that_is_not_in_the_scene_is_refused():
    s = replace(shipped_scenario("laparoscopy_bimanual"), **{"organs.model": "rigid"})
    s.tools["left"].god_object.grasp.bodies = ["nowhere::site"]
    with pytest.raises(
        ScenarioError, match=r"tools\.left\.god_object\.grasp\.bodies: 'nowhere::site': no such body"
    ):
        build_station(s)


def test_a_grasp_jaw_that_is_not_a_device_joint_is_refused():
    s = replace(shipped_scenario("laparoscopy_bimanual"))
    s.tools["left"].god_object.grasp.jaw = "thumb"
    with pytest.raises(ScenarioError, match=r"grasp\.jaw: 'thumb' is not one of the device joints"):
        build_station(s)


@pytest.mark.slow(seconds=30)
def test_the_bimanual_scene_runs_from_the_command_line(tmp_path):
    metrics = tmp_path / "m.json"
    flags = ["--no-progress", "--metrics", str(metrics), "--set", "organs.model=rigid",
             "--set", "simulation.duration_s=2.0"]  # fmt: skip
    assert cli.main(["run", "laparoscopy_bimanual", *flags]) == 0
    m = json.loads(metrics.read_text())
    assert m["tools"]["left"]["grasp_events"][0].endswith("took edge::site")


def test_a_tools_device_file_set_from_the_command_line_is_the_users_and_keeps_its_kind(tmp_path, monkeypatch):
    """``--set tools.right.device.path=FILE``: a relative FILE is taken from the working folder (not
    the installed scene's), and the device stays a ``!ScriptedJoints`` one (Drake's loader reads an
    untagged mapping as the first kind)."""
    path = tmp_path / "press.yaml"
    path.write_text("channels: [yaw]\nwaypoints:\n- {t: 0.0, values: {yaw: 0.1}}\n")
    monkeypatch.chdir(tmp_path)
    s = cli.load_with_sets(
        cli.sc.shipped_scenario_file("laparoscopy_bimanual"), ["tools.right.device.path=press.yaml"]
    )
    device = s.tools["right"].device
    assert type(device).__name__ == "ScriptedJoints" and device.path == str(path)
    assert s.tools["left"].device.path.endswith("bimanual_left_path.yaml")


@pytest.mark.slow(seconds=30)
def test_analyze_gives_each_graspers_rows_and_predicts_the_press_drake_simulates(fem):
    """``analyze`` on the two-tool scene: each tool's own rows, named by it; the right grasper's
    predicted tissue force (linear FEM stiffness at its contact in series with its coupling's
    stiffness at the tip) against the force Drake's run gives (3.7 N against 4.0 N here)."""
    summary = analyze(shipped_scenario("laparoscopy_bimanual"), quick=True)
    assert set(summary["tools"]) == {"left", "right"}
    subjects = [c["subject"] for c in summary["checks"]]
    assert any(s.startswith("left: ") for s in subjects) and any(s.startswith("right: ") for s in subjects)
    assert summary["checks"][-1]["subject"] == "left and right"  # the contact between the two tools
    predicted = summary["tools"]["right"]["tissue"]["predicted_force_n"]
    simulated = fem.metrics["tools"]["right"]["max_tissue_contact_force_N"]
    assert predicted == pytest.approx(simulated, rel=0.15)


def _organ_and_site_at(offset) -> np.ndarray:
    """The bimanual scene's pelvis welded at ``offset`` and its grasp site glued where it sits on
    the uterus, nothing else; the site's displacement after 0.3 s under gravity (m)."""
    import yaml
    from pydrake.common.yaml import yaml_load_typed
    from pydrake.multibody.parsing import ModelDirectives
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from godobject_drake.station.plant import add_plant

    offset = [float(c) for c in offset]
    site_at = [o + p for o, p in zip(offset, (0.032, 0.0, SITE_Z_M), strict=True)]
    directives = [
        {"add_model": {"name": "pelvis", "file": "package://godobject_models/laparoscopy/organs.sdf"}},
        {"add_weld": {"parent": "world", "child": "pelvis::pelvis", "X_PC": {"translation": offset}}},
        {"add_model": {"name": "edge", "file": "package://godobject_models/laparoscopy/grasp_site.sdf",
                       "default_free_body_pose": {"site": {"translation": site_at}}}},
    ]  # fmt: skip
    loaded = yaml_load_typed(schema=ModelDirectives, data=yaml.safe_dump({"directives": directives}))
    builder = DiagramBuilder()
    scenario = replace(shipped_scenario("laparoscopy_bimanual"), directives=loaded.directives)
    parts = add_plant(builder, scenario)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.3)
    plant = parts.plant
    context = plant.GetMyContextFromRoot(simulator.get_context())
    return plant.EvalBodyPoseInWorld(context, plant.GetBodyByName("site")).translation() - site_at


def test_an_organ_away_from_the_origin_holds_its_glued_site_as_at_the_origin():
    """Drake's fixed constraint takes the organ's registered frame in the site's body (``X_BA``),
    not the world's: glued with the world's, an organ welded 0.2 m off the origin selected no
    vertex and Drake refused the scene ("No constraint has been added"). The site, 2 g on the
    tissue under gravity, sinks by the same few tens of µm wherever the pelvis is: the whole
    scene moved is the same scene."""
    at_origin, moved = _organ_and_site_at((0.0, 0.0, 0.0)), _organ_and_site_at((0.2, -0.1, 0.05))
    assert np.linalg.norm(at_origin) < 2e-4
    assert np.allclose(moved, at_origin, atol=1e-9)
