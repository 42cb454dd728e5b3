"""Soft bodies of one's own (``deformables:``): a tetrahedral VTK mesh or a primitive in any scene,
held where the scenario says; a bad mesh refused before the run (exit 2), naming the file, the
value and the fix."""

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from godobject_drake.config.scenario import (
    ScenarioError,
    check_scenario,
    load_scenario,
    replace,
    scenario_from_yaml,
)
from godobject_drake.systems.tissue import grid_tet_mesh, write_vtk

REPO = Path(__file__).resolve().parents[1]
SDF = REPO / "examples" / "cube_post.sdf"

# The cube-and-post scene of examples/ (its cube, post and floor), its tool resting, and a soft pad.
SCENE = """name: soft_pad
directives:
- add_model:
    name: cube_post
    file: {sdf}
    default_free_body_pose:
      cube: {{translation: [-0.15, 0.0, 0.025]}}
device: !Scripted
  waypoints:
  - {{t: 0.0, xyz: [0.15, 0.1, 0.1]}}
  - {{t: 1.0, xyz: [0.15, 0.1, 0.1]}}
simulation: {{duration_s: {duration}}}
deformables:
  pad:
{body}
"""
PAD = """    mesh: pad.vtk
    xyz_m: [0.0, -0.08, 0.1]
    attach: [{to: world, lower_m: [-0.05, -0.13, 0.114], upper_m: [0.05, -0.03, 0.116]}]"""


def pad_mesh(n=(4, 4, 2), size=(0.08, 0.08, 0.03)):
    """A box grid's tetrahedra about the origin (m)."""
    return grid_tet_mesh(*(np.linspace(-s / 2, s / 2, k + 1) for s, k in zip(size, n, strict=True)))


def write_scene(tmp_path, V=None, T=None, body=PAD, duration=0.01) -> Path:
    if V is not None:
        write_vtk(tmp_path / "pad.vtk", V, T)
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE.format(sdf=SDF, duration=duration, body=body))
    return scene


def run(scene: Path):
    return subprocess.run(
        [sys.executable, "-m", "godobject_drake", "run", str(scene), "--no-progress"],
        capture_output=True, text=True, timeout=120, cwd=REPO,
    )  # fmt: skip


def refused(scene: Path, *said: str) -> str:
    done = run(scene)
    assert done.returncode == 2, (done.returncode, done.stderr[-800:])
    for words in said:
        assert words in done.stderr, (words, done.stderr[-800:])
    assert "Traceback" not in done.stderr
    return done.stderr


def test_a_mesh_of_triangles_not_tetrahedra_exits_2_naming_the_file_the_cell_type_and_the_fix(tmp_path):
    V, T = pad_mesh()
    write_scene(tmp_path, V, T)
    text = (tmp_path / "pad.vtk").read_text()
    tets = text.split("CELLS")[1].split("CELL_TYPES")[0].splitlines()[1:]
    tris = [" ".join(["3", *line.split()[1:4]]) for line in tets if line]
    text = text.split("CELLS")[0] + f"CELLS {len(tris)} {4 * len(tris)}\n" + "\n".join(tris)
    (tmp_path / "pad.vtk").write_text(text + f"\nCELL_TYPES {len(tris)}\n" + "5\n" * len(tris))
    refused(tmp_path / "scene.yaml", "pad.vtk", "cell types [5]", "tetrahedralize it")


def test_inverted_tetrahedra_exit_2_naming_the_file_the_volume_and_the_fix(tmp_path):
    V, T = pad_mesh()
    T = T.copy()
    T[3] = T[3][[0, 2, 1, 3]]
    scene = write_scene(tmp_path, V, T)
    said = refused(scene, "pad.vtk", "1 of 192 tetrahedra are inverted", "swap two points")
    assert "cell 3" in said


def test_a_flat_tetrahedron_exits_2_naming_the_file_and_remeshing(tmp_path):
    V, T = pad_mesh()
    n = len(V)
    flat = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.01, 0.01, 0.0]])
    refused(
        write_scene(tmp_path, np.vstack([V, flat]), np.vstack([T, [n, n + 1, n + 2, n + 3]])),
        "pad.vtk", "1 degenerate tetrahedra", f"cell {len(T)}", "remesh it",
    )  # fmt: skip


def test_a_mesh_in_millimetres_exits_2_naming_its_size_and_the_scale(tmp_path):
    V, T = pad_mesh()
    refused(
        write_scene(tmp_path, V * 1000, T), "pad.vtk", "is 80 m across",
        "267 times the scene's workspace (0.3 m", "Give scale: 0.001",
    )  # fmt: skip


def test_a_mesh_file_that_is_not_there_exits_2_naming_the_field_and_where_paths_start(tmp_path):
    """Before: Python's bare "[Errno 2] No such file or directory"."""
    refused(write_scene(tmp_path), "deformables.pad.mesh:", "pad.vtk does not exist", "scenario's folder")


def test_a_soft_body_held_by_nothing_exits_2_saying_it_will_fall(tmp_path):
    V, T = pad_mesh()
    body = "    mesh: pad.vtk\n    xyz_m: [0.0, -0.08, 0.1]"
    refused(write_scene(tmp_path, V, T, body), "deformables.pad.attach: none", "will fall", "free: true")


def test_an_attachment_that_holds_no_vertex_exits_2_naming_the_box_and_where_the_body_is(tmp_path):
    V, T = pad_mesh()
    body = PAD.replace("0.114], upper_m: [0.05, -0.03, 0.116]", "0.3], upper_m: [0.05, -0.03, 0.4]")
    refused(
        write_scene(tmp_path, V, T, body),
        "deformables.pad.attach[0]: no vertex", "[-0.05, -0.13, 0.3] to [0.05, -0.03, 0.4]",
        "[-0.04, -0.12, 0.085] to [0.04, -0.04, 0.115]", "move the box onto it",
    )  # fmt: skip


def test_a_mesh_too_fine_for_the_time_step_exits_2_estimating_its_cost(tmp_path):
    V, T = pad_mesh((12, 12, 6))  # 1183 vertices: about 0.18 s a step against h = 1 ms
    said = refused(write_scene(tmp_path, V, T), "1183 vertices", "ms (docs/results.md)", "coarser mesh")
    assert "past max_slowdown 20" in said


def build(scenario):
    from godobject_drake.station.build import build_station

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return build_station(scenario)


def test_the_held_face_stays_where_it_is_and_the_rest_hangs_from_it(tmp_path):
    """Drake's fixed constraint holds the vertices in the attach box where they are (X_BA is the
    registered geometry's frame in B: with X_BA = I the whole pad dropped 0.1 m, its pose's z, at
    once); the free vertices sag under gravity a little, by about ρ g L² / E."""
    from godobject_drake.simulation import simulate

    V, T = pad_mesh()
    scenario = load_scenario(write_scene(tmp_path, V, T, duration=0.3))
    station = build(scenario)
    (body,) = [s._body for s in station.diagram.GetSystems() if s.get_name() == "pad_soft_body_observer"]
    assert body.attached == 25  # the top face's 5 x 5 vertices
    assert np.allclose(body.rest_W.mean(axis=0), [0.0, -0.08, 0.1])  # the mesh placed at xyz_m
    result = simulate(station, progress=False, keep_logs=True)
    plant = station.plant
    context = plant.GetMyContextFromRoot(result.context)
    p = plant.get_deformable_body_configuration_output_port().Eval(context).value(body.geometry_id)
    p = np.asarray(p).reshape(-1, 3)
    moved = np.linalg.norm(p - body.rest_W, axis=1)
    assert moved[body.held].max() < 1e-5
    assert moved.max() < 2e-3  # 1000 kg/m³ · 9.8 · (0.03 m)² / 50 kPa ≈ 0.2 mm: hanging, not falling
    soft = {k[4:]: v for k, v in result.metrics.items() if k.startswith("pad_")}
    assert soft["steps"] == 301 and soft["rigid_penetration_m"] == 0.0 and soft["rigid_inside_steps"] == 0
    assert soft["max_displacement_m"] == pytest.approx(moved[body.surface].max(), rel=0.2)


def test_a_primitive_is_meshed_at_its_resolution_and_checked_like_a_file():
    from godobject_drake.config.scene import SoftBody
    from godobject_drake.systems.soft_body import soft_body_mesh

    box = SoftBody(shape="box", size_m=[0.08, 0.04, 0.02], resolution_m=0.01, free=True)
    V, T = soft_body_mesh(box, "deformables.b", 1e-3)
    assert len(V) == 9 * 5 * 3 and len(T) == 6 * 8 * 4 * 2
    assert np.ptp(V, axis=0) == pytest.approx([0.08, 0.04, 0.02])
    ball = SoftBody(shape="sphere", size_m=[0.02], resolution_m=0.01, free=True)
    V, T = soft_body_mesh(ball, "deformables.b", 1e-3)
    assert np.linalg.norm(V, axis=1).max() == pytest.approx(0.02)
    huge = SoftBody(shape="box", size_m=[3.0, 0.1, 0.1], resolution_m=0.5, free=True)
    soft_body_mesh(huge, "deformables.b", 1e-3, workspace_m=0.35)  # 8.6 workspaces: a large scene's body
    with pytest.raises(
        ValueError, match=r"3 m across .* 15 times the scene's workspace \(0\.2 m .* scale: 0\.001"
    ):
        soft_body_mesh(huge, "deformables.b", 1e-3, workspace_m=0.2)


def test_a_mesh_point_in_no_tetrahedron_is_refused_naming_how_many(tmp_path):
    from godobject_drake.config.scene import SoftBody
    from godobject_drake.systems.soft_body import soft_body_mesh

    V, T = pad_mesh()
    write_vtk(tmp_path / "pad.vtk", np.vstack([V, [[0.0, 0.0, 0.2]]]), T)
    spec = SoftBody(mesh=str(tmp_path / "pad.vtk"), free=True)
    with pytest.raises(ValueError, match=r"1 of its 76 points belong to no tetrahedron .*remove them"):
        soft_body_mesh(spec, "deformables.pad", 1e-3)
    write_vtk(tmp_path / "pad.vtk", V, T)
    assert len(soft_body_mesh(spec, "deformables.pad", 1e-3)[0]) == 75


@pytest.mark.parametrize(
    ("body", "said"),
    [
        ("{shape: cube, size_m: [0.1]}", "deformables.x.shape: 'cube'; choose one of"),
        ("{shape: box, size_m: [0.1], free: true}", "deformables.x.size_m: [0.1]; a box takes 3"),
        ("{mesh: a.vtk, shape: box, free: true}", "give one, a tetrahedral VTK file as mesh"),
        ("{shape: sphere, size_m: [0.1], poissons_ratio: 0.5, free: true}", "poissons_ratio: 0.5"),
        ("{shape: sphere, size_m: [0.1], attach: [{within_m: 0.01}]}", "of the world: give a box"),
        ("{replaces: pelvis::uterus, xyz_m: [0, 0, 0.1], free: true}", "takes the replaced shape's pose"),
        ("{replaces: uterus, free: true}", "replaces: 'uterus'; give the collision geometry as model::name"),
        ("{mesh: a.vtk, cells: 4, free: true}", "a mesh file is meshed already"),
        (
            "{shape: box, size_m: [0.1, 0.1, 0.1], grading: 1.5, free: true}",
            "grades a sphere or an ellipsoid",
        ),
        ("{shape: box, size_m: [0.1, 0.1, 0.1], cells: 3, free: true}", "cells: 3 must be 0"),
        (
            "{shape: box, size_m: [0.1, 0.1, 0.1], attach: [{below_top_m: 0.01, within_m: 0.01}]}",
            "give one way",
        ),
    ],
)
def test_a_soft_bodys_fields_are_checked_naming_the_field(body, said):
    with pytest.raises(ScenarioError) as e:
        check_scenario(scenario_from_yaml(f"deformables: {{x: {body}}}\n"))
    assert said in str(e.value)


EXAMPLE = REPO / "examples" / "own_soft_body" / "own_soft_body.yaml"


def run_example_to(t: float, overrides: str | None = None):
    """The example run to ``t``: its station, result and the lobe's observer and its context."""
    from godobject_drake.simulation import simulate

    scenario = load_scenario(EXAMPLE, overrides)
    station = build(replace(scenario, **{"simulation.duration_s": t}))
    result = simulate(station, progress=False)
    (observer,) = [s for s in station.diagram.GetSystems() if s.get_name() == "lobe_soft_body_observer"]
    return station, result, observer, observer.GetMyContextFromRoot(result.context)


@pytest.mark.slow
def test_the_example_lobe_pressed_answers_with_analyzes_stiffness_there():
    """analyze finds where the probe's path presses the lobe (straight down at (0.01, 0.004)) and
    the lobe's stiffness there from its own mesh (linear statics of its tetrahedra, its attached
    face held, a point force on the surface triangle: 2242 N/m); the lifter, which holds a site
    glued to the lobe, presses nothing. Drake's run, the probe held 4 mm past the surface for 1 s:
    its force over the indentation there (the triangle's vertices' displacement by the same
    weights), from the settled lobe before the probe touches, within 15 % (measured: 0.315 N over
    0.141 mm, 2242 N/m, 0.03 % from analyze's)."""
    from godobject_drake.studies.analyze import analyze

    report = analyze(load_scenario(EXAMPLE), quick=True, verify=True)
    rows = {(r["section"], r["subject"]): r for r in report["checks"]}
    row, lifter = rows["soft bodies", "probe: lobe"], rows["soft bodies", "lifter: lobe"]
    assert lifter["value"] is None and "glued to it" in lifter["why"]
    press = report["tools"]["probe"]["soft_bodies"]["lobe"]
    assert press["time_s"] == pytest.approx(1.5) and press["point_W"][:2] == pytest.approx([0.01, 0.004])
    _, _, observer, before = run_example_to(0.9)
    _, _, observer2, pressed = run_example_to(2.45)
    d = np.array([0.0, 0.0, -1.0])
    moved = observer2.positions(pressed) - observer.positions(before)
    indentation = sum(w * moved[v] @ d for v, w in zip(press["vertices"], press["weights"], strict=True))
    force = (observer2.contact_force(pressed) - observer.contact_force(before)) @ d
    assert 0.05e-3 < indentation < 3e-3 and force > 0.1, (indentation, force)
    assert force / indentation == pytest.approx(row["value"], rel=0.15)
    # analyze --verify does the same in Drake, from the last step before the probe touches (1.216 s)
    verified = rows["verify", "probe: lobe"]
    assert verified["verdict"] == "ok" and verified["predicted"] == row["value"]
    assert verified["simulated"] == pytest.approx(force / indentation, rel=0.02)


@pytest.mark.slow
def test_the_example_runs_its_probe_never_inside_its_site_lifted_its_metrics_and_recording(tmp_path):
    record = tmp_path / "lobe.html"
    _, result, _, _ = run_example_to(5.5, f"recording: {{file: {record}}}")
    m = result.metrics
    assert not m["diverged"] and m["lobe_steps"] == round(5.5 / 0.004) + 1
    assert m["lobe_rigid_inside_steps"] == 0  # the probe's centre never inside the deformed lobe
    # the probe's ball in the lobe's deformed surface as deep as SAP's contact compliance lets it:
    # under a millimetre, and seen (no vertex of the coarse surface is inside the 4 mm ball)
    assert 0.3e-3 < m["lobe_rigid_penetration_m"] < 1e-3, m["lobe_rigid_penetration_m"]
    assert 0.1 < m["lobe_max_contact_force_N"] < 2.0 and m["lobe_max_strain"] > 0
    assert m["lobe_max_displacement_m"] > 2e-3, m["lobe_max_displacement_m"]  # the lift raised it
    assert m["recording_bytes"] > 0 and "lobe_tissue/surface" in record.read_text()
    assert m["max_penetration_m"] == m["lobe_rigid_penetration_m"]  # the scene's budget counts it


def test_the_guide_shows_the_example_scenario_as_it_is():
    import re

    page = (REPO / "docs" / "guide" / "own_soft_body.md").read_text()
    blocks = re.findall(r"```yaml\n(.*?)```", page, flags=re.S)
    assert blocks[0] == EXAMPLE.read_text()  # the second: the laparoscopy's organ written out (below)


def test_the_example_mesh_is_what_its_script_makes():
    """examples/own_soft_body/lobe.vtk is make_lobe.py's output, a real tetrahedral mesh."""
    from godobject_drake.config.meshes import check_tetrahedra, read_tet_vtk

    sys.path.insert(0, str(EXAMPLE.parent))
    try:
        import make_lobe
    finally:
        sys.path.pop(0)
    V, T = make_lobe.lobe()
    V2, T2 = read_tet_vtk(EXAMPLE.parent / "lobe.vtk", "lobe.vtk")
    assert np.array_equal(T, T2) and np.allclose(V, V2, rtol=0, atol=1e-15)
    assert (len(V), len(T)) == (180, 576)
    check_tetrahedra(V2, T2, "lobe.vtk")
    assert np.ptp(V2, axis=0) == pytest.approx([0.12, 0.04, 0.03])


# A soft pad where each tool kind's shipped path presses: the laparoscopy's articulated grasper (its
# capsules on a pad over the rigid uterus), the deformable probe (its FEM shell on a pad on the block).
PADS = {
    "articulated": ("laparoscopy", 3.0, "size_m: [0.04, 0.04, 0.01], resolution_m: 0.01, "
                    "xyz_m: [0.0, 0.0, 0.031], relaxation_time_s: 0.1, attach: [{to: world, "
                    "lower_m: [-0.03, -0.03, 0.0255], upper_m: [0.03, 0.03, 0.0265]}]"),
    "deformable": ("deformable_probe", 2.5, "size_m: [0.06, 0.06, 0.01], resolution_m: 0.015, "
                   "xyz_m: [-0.02, 0.0, 0.055], attach: [{to: world, lower_m: [-0.06, -0.04, 0.0495], "
                   "upper_m: [0.02, 0.04, 0.0505]}]"),
}  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("kind", sorted(PADS))
def test_every_tool_kind_presses_a_soft_body_through_contact(kind):
    """The grasper's capsules dent the pad 1.7 mm with 4.0 N, measured from the capsules' own
    shape 0.9 mm into it (Drake 1.51.1 and 1.58 alike); the deformable probe's FEM shell presses
    its pad with 6.2 N (deformable against deformable contact) and dents it 0.5 mm."""
    from godobject_drake.config.scenario import shipped_scenario_file
    from godobject_drake.simulation import simulate

    scene, duration, body = PADS[kind]
    scenario = load_scenario(shipped_scenario_file(scene), f"deformables: {{pad: {{shape: box, {body}}}}}")
    station = build(replace(scenario, **{"simulation.duration_s": duration}))
    assert station.scenario.kind == kind
    m = simulate(station, progress=False).metrics
    assert not m["diverged"] and m["pad_steps"] == round(duration / station.plant.time_step()) + 1
    assert m["pad_max_contact_force_N"] > 2.0 and m["pad_max_displacement_m"] > 3e-4
    assert m["pad_force_at_max_N"][2] < 0  # pressed down
    assert m["pad_rigid_inside_steps"] == 0
    if kind == "articulated":
        assert 3e-4 < m["pad_rigid_penetration_m"] < 2e-3  # the capsules' own shape, measured


@pytest.mark.slow
def test_the_hands_squeeze_the_sponge_lift_carry_and_set_it_down_by_friction_alone():
    """examples/own_soft_body/brick_sponge.yaml: the sponge rests free; squeezed between two
    bricks it rises 3 cm and moves 4 cm (its surface moves 5 cm at most: √(3² + 4²)), and ends
    set down 4 cm along x on the baseplate (measured: 39.5 mm, its centre 0.15 mm lower than it
    started, squeezed and settling)."""
    from godobject_drake.simulation import simulate

    station = build(load_scenario(EXAMPLE.parent / "brick_sponge.yaml"))
    result = simulate(station, progress=False)
    m = result.metrics
    assert not m["diverged"] and m["sponge_rigid_inside_steps"] == 0
    assert m["sponge_rigid_penetration_m"] < 2e-4 and m["sponge_max_contact_force_N"] > 0.2
    assert m["sponge_max_displacement_m"] > 0.045
    (observer,) = [s for s in station.diagram.GetSystems() if s.get_name() == "sponge_soft_body_observer"]
    body = station.soft_bodies["sponge"]
    moved = observer.positions(observer.GetMyContextFromRoot(result.context)).mean(axis=0) - body.rest_W.mean(
        axis=0
    )
    assert moved == pytest.approx([0.04, 0.0, 0.0], abs=2e-3)


def write_vtk_51(path: Path, V, T) -> Path:
    """A legacy-ASCII VTK file of version 5.1 (what meshio and VTK 9 write by default)."""
    lines = [
        "# vtk DataFile Version 5.1",
        "tets",
        "ASCII",
        "DATASET UNSTRUCTURED_GRID",
        f"POINTS {len(V)} double",
    ]
    lines += [" ".join(f"{x:.17g}" for x in v) for v in V]
    lines += [
        f"CELLS {len(T) + 1} {4 * len(T)}",
        "OFFSETS vtktypeint64",
        " ".join(str(4 * k) for k in range(len(T) + 1)),
    ]
    lines += [
        "CONNECTIVITY vtktypeint64",
        *(" ".join(map(str, t)) for t in T),
        f"CELL_TYPES {len(T)}",
        *["10"] * len(T),
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_vtk_51_mesh_as_meshio_writes_it_is_read_as_the_older_format_is(tmp_path):
    from godobject_drake.config.meshes import read_tet_vtk

    V, T = pad_mesh()
    V1, T1 = read_tet_vtk(write_vtk(tmp_path / "a.vtk", V, T), "a.vtk")
    V2, T2 = read_tet_vtk(write_vtk_51(tmp_path / "b.vtk", V, T), "b.vtk")
    assert np.array_equal(T1, T) and np.array_equal(T2, T) and np.array_equal(V1, V2)
    bad = tmp_path / "c.vtk"
    bad.write_text((tmp_path / "b.vtk").read_text().replace("vtktypeint64\n0 4 8", "vtktypeint64\n0 3 8"))
    with pytest.raises(ValueError, match="CELLS are not 4 points each"):
        read_tet_vtk(bad, "c.vtk")


def test_two_soft_bodies_in_one_scene_each_have_their_metrics_and_drawing(tmp_path):
    """A pad hung from the world and a ball resting free beside it: each its own observer, metrics
    (its name first) and deforming surface; in 0.1 s the free ball falls ½ g t² = 4.9 cm (nothing
    under it), the hung pad does not move a millimetre."""
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import make_meshcat

    V, T = pad_mesh()
    ball = "{shape: sphere, size_m: [0.02], resolution_m: 0.01, xyz_m: [0.1, -0.08, 0.1], free: true}"
    scenario = load_scenario(write_scene(tmp_path, V, T, body=PAD + "\n  ball: " + ball, duration=0.1))
    scenario = replace(scenario, **{"recording.file": str(tmp_path / "two.html")})
    station = build_station_with(scenario, make_meshcat(scenario))
    names = {s.get_name() for s in station.diagram.GetSystems()}
    assert {"pad_soft_body_visualizer", "ball_soft_body_visualizer"} <= names
    # the legend names each soft body (not "the FEM organ": the laparoscopy's uterus alone is one)
    from godobject_drake.systems.page import page_of

    lines = [text for _, text in page_of(station.meshcat).legend.values()]
    assert [line for line in lines if line.startswith("pink surface")] == [
        f"pink surface: {name}, a soft body (FEM), as the tools dent and move it" for name in ("pad", "ball")
    ]
    m = simulate(station, progress=False).metrics
    assert m["recording_bytes"] > 0
    assert m["pad_steps"] == m["ball_steps"] == 101
    assert m["pad_max_displacement_m"] < 1e-3
    assert m["ball_max_displacement_m"] == pytest.approx(0.5 * 9.81 * 0.1**2, rel=0.05)


def build_station_with(scenario, meshcat):
    from godobject_drake.station.build import build_station

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return build_station(scenario, meshcat)


def test_analyze_finds_where_the_articulated_grasper_presses_a_soft_pad_and_its_stiffness_there():
    """The laparoscopy's path pushes the closed grasper straight down the port's axis: analyze
    meets the pad on that axis at its top's centre, (0, 0, 0.036) m, the push 63 mm past it (the
    path's deepest, into the rigid uterus under the pad), and reads the pad's stiffness there from
    its own mesh: the same number as the FEM statics along that ray."""
    from godobject_drake.config.scenario import shipped_scenario_file
    from godobject_drake.studies.analyze import analyze

    scenario = load_scenario(
        shipped_scenario_file("laparoscopy"),
        f"deformables: {{pad: {{shape: box, {PADS['articulated'][2]}}}}}",
    )
    out = analyze(scenario, quick=True, verify=False)
    (row,) = [r for r in out["checks"] if r["section"] == "soft bodies"]
    press = out["soft_bodies"]["pad"]
    assert press["point_W"] == pytest.approx([0.0, 0.0, 0.036], abs=1e-6)
    assert press["push_m"] == pytest.approx(0.063, abs=2e-3)
    assert row["value"] == press["stiffness_n_m"] and 500 < row["value"] < 5000


def test_a_capsule_is_meshed_round_its_axis_to_its_radius_and_length():
    """The capsule's surface lies at its radius from its axis segment (the cylinder's length), its
    extent is 2r × 2r × (L + 2r), and its volume tends to π r² L + 4/3 π r³ as its cells shrink."""
    from godobject_drake.config.scene import SoftBody
    from godobject_drake.systems.soft_body import soft_body_mesh
    from godobject_drake.systems.tissue import surface_triangles, tet_volumes

    r, L = 0.01, 0.04
    volume = np.pi * r * r * L + 4.0 / 3.0 * np.pi * r**3
    errors = []
    for cells in (4, 8):
        spec = SoftBody(shape="capsule", size_m=[r, L], cells=cells, free=True, max_slowdown=np.inf)
        V, T = soft_body_mesh(spec, "deformables.c", 1e-3)
        assert np.all(tet_volumes(V, T) > 0)
        assert np.ptp(V, axis=0) == pytest.approx([2 * r, 2 * r, L + 2 * r])
        surface = np.unique(surface_triangles(T))
        z = np.clip(V[surface, 2], -L / 2, L / 2)  # the nearest point of the axis segment
        to_axis = np.linalg.norm(V[surface] - np.column_stack([0 * z, 0 * z, z]), axis=1)
        assert to_axis == pytest.approx(np.full(len(surface), r))
        errors.append(abs(tet_volumes(V, T).sum() - volume) / volume)
    assert errors[1] < errors[0] / 2 and errors[1] < 0.05  # the inscribed facets' shortfall halves and more
    with pytest.raises(ValueError, match=r"size_m: \[0\.01\]; a capsule takes 2 lengths"):
        SoftBody(shape="capsule", size_m=[0.01], free=True).check()


def test_a_body_held_below_its_top_keeps_those_vertices_in_place_and_only_to_the_world(tmp_path):
    """``below_top_m``: Drake's wall boundary condition, the vertices under the cut held exactly
    (their degrees of freedom gone), the rest hanging from them."""
    from godobject_drake.simulation import simulate

    V, T = pad_mesh()
    body = """    mesh: pad.vtk
    xyz_m: [0.0, -0.08, 0.1]
    attach: [{below_top_m: 0.02}]"""
    station = build(load_scenario(write_scene(tmp_path, V, T, body=body, duration=0.2)))
    (pad,) = [s._body for s in station.diagram.GetSystems() if s.get_name() == "pad_soft_body_observer"]
    assert pad.attached == 25  # the bottom layer of 5 x 5 (z = 0.085 m, under the cut at 0.095 m)
    assert np.all(pad.rest_W[pad.held, 2] == pytest.approx(0.085))
    result = simulate(station, progress=False)
    context = station.plant.GetMyContextFromRoot(result.context)
    p = station.plant.get_deformable_body_configuration_output_port().Eval(context).value(pad.geometry_id)
    moved = np.linalg.norm(np.asarray(p).reshape(-1, 3) - pad.rest_W, axis=1)
    assert moved[pad.held].max() == 0.0  # not a constraint's small slip: no motion at all
    assert 1e-7 < moved.max() < 2e-3  # the free part settles onto them
    bad = body.replace("{below_top_m: 0.02}", "{to: cube_post::cube, below_top_m: 0.02}")
    refused(
        write_scene(tmp_path, V, T, body=bad), "attach[0].to: 'cube_post::cube' with below_top_m", "to: world"
    )
    deep = body.replace("0.02", "0.05")
    refused(
        write_scene(tmp_path, V, T, body=deep), "attach[0]: 0.05 m reaches below the body's bottom", "30.0 mm"
    )


def test_the_laparoscopys_fem_organ_is_its_deformables_entry_written_out_step_for_step():
    """``organs: {model: fem, ...}`` stands for one ``deformables:`` entry (Organs.soft_body): the
    bimanual scene with that entry written out (and rigid organs) moves its plant bit for bit as
    the shipped scene does, its glued site lifted by the left grasper included."""

    from godobject_drake.config.scenario import shipped_scenario
    from godobject_drake.simulation import simulate

    shipped = replace(shipped_scenario("laparoscopy_bimanual"), **{"simulation.duration_s": 0.6})
    guide = (REPO / "docs" / "guide" / "own_soft_body.md").read_text()
    block = (
        guide.split("Written out, the bimanual scene's uterus reads:")[1]
        .split("```yaml\n")[1]
        .split("```")[0]
    )
    written = replace(shipped_scenario("laparoscopy_bimanual", block), **{"simulation.duration_s": 0.6})
    assert (
        written.deformables["uterus"] == shipped.organs.soft_body()
    )  # the guide's entry is the short form's
    states = []
    for scenario in (shipped, written):
        station = build(scenario)
        result = simulate(station, progress=False)
        plant = station.plant
        context = plant.GetMyContextFromRoot(result.context)
        body = station.soft_bodies.get("uterus") or station.tools["left"].tissue
        p = plant.get_deformable_body_configuration_output_port().Eval(context).value(body.geometry_id)
        states.append((plant.GetPositionsAndVelocities(context).copy(), np.asarray(p).copy()))
    (q_a, p_a), (q_b, p_b) = states
    assert np.array_equal(q_a, q_b) and np.array_equal(p_a, p_b)
    assert np.abs(p_a.reshape(-1, 3) - body.rest_W).max() > 1e-4  # the organ moved: the check is not of rest


def test_the_guides_own_vtk_writer_writes_what_the_reader_takes_back_exactly(tmp_path):
    """The guide's few lines for writing a mesh from numpy arrays (its python block): the points and
    tetrahedra read back bit for bit, and checked as a scenario's mesh is."""
    import re

    from godobject_drake.config.meshes import check_tetrahedra, read_tet_vtk

    page = (REPO / "docs" / "guide" / "own_soft_body.md").read_text()
    (code,) = re.findall(r"```python\n(.*?)```", page, flags=re.S)
    space: dict = {}
    exec(code, space)
    V, T = pad_mesh()
    space["write_tet_vtk"](tmp_path / "own.vtk", V * (1 + 1e-9), T)  # not round numbers
    V2, T2 = read_tet_vtk(tmp_path / "own.vtk", "own.vtk")
    check_tetrahedra(V2, T2, "own.vtk")
    assert np.array_equal(V2, V * (1 + 1e-9)) and np.array_equal(T2, T)
