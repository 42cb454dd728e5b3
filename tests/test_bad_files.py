"""Hostile files refused fast and quietly: a YAML alias bomb, a nest thousands deep and a key given
twice are refused before Drake's loader expands them, with exit 2 naming the limit; no message
repeats a device file's lines or sends a control character in a name to the terminal raw."""

import os
import subprocess
import sys
import time

import pytest
from conftest import REPO

from godobject_drake.config.device_files import load_device_path, read_device_log
from godobject_drake.config.scenario import ScenarioError, load_scenario, scenario_from_yaml
from godobject_drake.config.yaml_guard import MAX_ALIAS_NODES, MAX_YAML_DEPTH, YamlShapeError, check_yaml

SECRET = "PASSWORD-h55b"


def alias_bomb(levels=7, width=9) -> str:
    """Private root keys (Drake's loader drops them) holding aliases of aliases: width**levels nodes."""
    lines = [f"_a0: &a0 [{', '.join(['1'] * width)}]"]
    for i in range(1, levels):
        lines.append(f"_a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]")
    return "\n".join(lines) + f"\ndirectives: *a{levels - 1}\n"


def run(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "godobject_drake", *args], capture_output=True, text=True, timeout=120,
        cwd=cwd or REPO,
    )  # fmt: skip


def test_an_alias_bomb_is_refused_in_well_under_a_second_naming_the_limit(tmp_path):
    """Before: the loader expanded 4.8 million nodes and quoted them all in its message."""
    file = tmp_path / "bomb.yaml"
    file.write_text(alias_bomb())
    start = time.perf_counter()
    with pytest.raises(ScenarioError, match="MAX_ALIAS_NODES") as e:
        load_scenario(file)
    assert time.perf_counter() - start < 0.5
    assert "[1, 1" not in str(e.value) and len(str(e.value)) < 400


def test_a_cycle_of_aliases_is_refused():
    with pytest.raises(YamlShapeError, match="cycle"):
        check_yaml("a: &a [1, *a]\n", "text")


def test_a_nest_thousands_deep_exits_2_naming_the_limit_not_a_traceback(tmp_path):
    """Before: a RecursionError traceback from PyYAML's composer."""
    file = tmp_path / "deep.yaml"
    file.write_text("simulation: " + "[" * 5000 + "]" * 5000 + "\n")
    done = run("run", str(file))
    assert done.returncode == 2, done.stderr[-500:]
    assert "MAX_YAML_DEPTH" in done.stderr and "Traceback" not in done.stderr


def test_aliases_that_nest_past_the_limit_are_refused():
    lines = ["_a0: &a0 [1]"] + [f"_a{i}: &a{i} [[[[[[[[[[*a{i - 1}]]]]]]]]]]" for i in range(1, 10)]
    with pytest.raises(YamlShapeError, match="once its aliases are expanded"):
        check_yaml("\n".join(lines) + "\n", "text")


def test_a_key_twice_in_a_mapping_is_refused_naming_the_key_and_both_lines(tmp_path):
    """Before: the second ``left`` replaced the first, silently (a tool dropped)."""
    text = "tools:\n  left:\n    device: !Scripted {}\n  left:\n    device: !Scripted {}\n"
    with pytest.raises(ScenarioError, match=r"line 4: the key 'left' is given twice .*first at line 2"):
        scenario_from_yaml(text)
    with pytest.raises(ScenarioError, match="given twice"):
        scenario_from_yaml("simulation: {duration_s: 1, duration_s: 2}\n")


def test_the_same_key_in_two_mappings_and_templates_are_kept(tmp_path):
    check_yaml("a: {x: 1}\nb: {x: 2}\n_t: &t {x: 1}\nc: {<<: *t, y: 2}\n", "text")
    for scene in (REPO / "diagrams").glob("*.yaml"):
        check_yaml(scene.read_text(), str(scene))


def test_the_bounds_hold_the_overrides_and_device_path_files(tmp_path):
    with pytest.raises(ScenarioError, match=r"the overrides: .*given twice"):
        load_scenario(REPO / "diagrams" / "lego.yaml", "simulation: {duration_s: 1, duration_s: 2}")
    path = tmp_path / "path.yaml"
    path.write_text(alias_bomb().replace("directives", "waypoints"))
    with pytest.raises(ValueError, match=r"device path file .*MAX_ALIAS_NODES"):
        load_device_path(path)


def test_a_bomb_in_a_directives_file_is_refused_before_drake_reads_it(tmp_path):
    (tmp_path / "bomb.dmd.yaml").write_text(alias_bomb())
    text = "directives:\n- add_directives: {file: bomb.dmd.yaml}\ndevice: !Scripted {}\n"
    (tmp_path / "scene.yaml").write_text(text)
    with pytest.raises(ScenarioError, match=r"bomb.dmd.yaml.*MAX_ALIAS_NODES"):
        load_scenario(tmp_path / "scene.yaml")


@pytest.mark.parametrize(
    "content",
    [
        f"waypoints:\n- {{t: 0, {SECRET}: 1}}\n",  # a key the schema does not know
        f"waypoints: [{{t: {SECRET}}}]\n",  # a value of the wrong type
        f"{SECRET} line one\nline two\n",  # not a mapping
        f"waypoints: [1, 2\n{SECRET}: x\n",  # not YAML
    ],
)
def test_an_error_about_a_device_path_file_does_not_print_its_content(tmp_path, content):
    """Before: the file's key, value or line reached the terminal (or a traceback did)."""
    (tmp_path / "private.yaml").write_text(content)
    (tmp_path / "scene.yaml").write_text(
        "device: !Scripted\n  path: private.yaml\nsimulation: {duration_s: 0.01}\n"
    )
    done = run("run", str(tmp_path / "scene.yaml"), "--no-progress")
    assert done.returncode == 2, done.stderr[-800:]
    assert "device path file" in done.stderr and "private.yaml" in done.stderr
    assert SECRET not in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize("row", [f"{SECRET},1,2,3,4,5,6,7", f"{SECRET}\n0,0,0,0,1,0,0,0"])
def test_an_error_about_a_device_log_does_not_print_its_lines(tmp_path, row):
    log = tmp_path / "log.csv"
    header = "t,x,y,z,qw,qx,qy,qz,grasp\n" if row.startswith(SECRET + ",") else ""
    log.write_text(header + row + "\n")
    with pytest.raises(ValueError) as e:
        read_device_log(log)
    assert SECRET not in str(e.value) and "log.csv:" in str(e.value)


def test_a_control_character_in_a_name_is_escaped_in_the_message(tmp_path):
    """Before: an ESC in a file name reached the terminal raw (a terminal obeys it)."""
    (tmp_path / "scene.yaml").write_text(
        'directives:\n- add_model: {name: m, file: "evil\\e[2Jname\\t#.sdf"}\n'
        "device: !Scripted\n  path: package://godobject_models/lego/default_path.yaml\n"
    )
    os.mkfifo(tmp_path / "evil\x1b[2Jname\t#.sdf")
    done = run("run", str(tmp_path / "scene.yaml"))
    assert done.returncode == 2
    assert "FIFO" in done.stderr, done.stderr  # found under its name as written (a tab, a #)
    assert "\x1b" not in done.stderr and "\t" not in done.stderr and "evil\\x1b[2Jname\\t#.sdf" in done.stderr


def test_the_limits_are_what_the_docs_say():
    assert MAX_YAML_DEPTH == 64 and MAX_ALIAS_NODES == 100_000


# -- model files: meshes and inertia --------------------------------------------------------------------

TETRA = "v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0 0 0.01\nf 1 2 3\nf 1 3 4\nf 2 3 4\nf 1 4 2\n"
INERTIAL = (
    "<inertial><mass>{mass}</mass><inertia><ixx>{ixx}</ixx><iyy>1e-5</iyy><izz>1e-5</izz>"
    "<ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia></inertial>"
)
MODEL = """<?xml version="1.0"?>
<sdf version="1.7" xmlns:drake="http://drake.mit.edu">
  <model name="thing">
    <link name="body">
      {inertial}
      <collision name="c"><geometry><mesh><uri>{mesh}</uri></mesh></geometry>
        <drake:proximity_properties><drake:rigid_hydroelastic/></drake:proximity_properties></collision>
    </link>
  </model>
</sdf>
"""
MESH_SCENE = """directives:
- add_model: {name: thing, file: thing.sdf}
device: !Scripted
  waypoints: [{t: 0, xyz: [0, 0, 0.3]}, {t: 1, xyz: [0, 0, 0.3]}]
simulation: {duration_s: 0.01}
"""


def mesh_scene(tmp_path, mesh=TETRA, mass="0.1", ixx="1e-5", suffix=".obj"):
    (tmp_path / f"mesh{suffix}").write_text(mesh)
    inertial = INERTIAL.format(mass=mass, ixx=ixx)
    (tmp_path / "thing.sdf").write_text(MODEL.format(inertial=inertial, mesh=f"mesh{suffix}"))
    (tmp_path / "scene.yaml").write_text(MESH_SCENE)
    return tmp_path / "scene.yaml"


def test_an_obj_whose_face_names_a_vertex_it_does_not_have_exits_2_instead_of_crashing(tmp_path):
    """Before: exit 139, a segmentation fault inside Drake (a rigid hydroelastic mesh built from
    the face tinyobjloader only warned about)."""
    scene = mesh_scene(tmp_path, TETRA.replace("f 1 3 4", "f 1 3 400000000"))
    done = run("run", str(scene), "--no-progress", "--contact", "hydroelastic")
    assert done.returncode == 2, (done.returncode, done.stderr[-800:])
    assert "mesh.obj: line 6: a face names vertex 400000000, but the mesh has 4" in done.stderr


@pytest.mark.parametrize(
    "face, said",
    [("f 1 2 0", "vertex 0"), ("f -1 -2 -9", "vertex -9"), ("f 1/5 2/5 3/5", "texture coordinate 5"),
     ("f 1//2 2//2 3//2", "normal 2")],
    ids=["zero", "negative", "texcoord", "normal"],
)  # fmt: skip
def test_each_kind_of_obj_index_is_checked(tmp_path, face, said):
    from godobject_drake.config.meshes import MeshFileError, check_mesh

    (tmp_path / "m.obj").write_text(TETRA + "vt 0 0\nvn 0 0 1\n" + face + "\n")
    with pytest.raises(MeshFileError, match=said):
        check_mesh(tmp_path / "m.obj", "m.obj")


def test_a_well_formed_obj_with_forward_references_and_negative_indices_passes(tmp_path):
    from godobject_drake.config.meshes import check_mesh

    (tmp_path / "m.obj").write_text(
        "f 1 2 3\n" + TETRA + "f -1 -2 -3\nf 1/1/1 2/1/1 3/1/1\nvt 0 0\nvn 0 0 1\n"
    )
    check_mesh(tmp_path / "m.obj", "m.obj")


def test_a_vtk_cell_past_its_points_is_refused_and_a_good_one_passes(tmp_path):
    from godobject_drake.config.meshes import MeshFileError, check_mesh
    from godobject_drake.systems.tissue import write_vtk

    good = write_vtk(tmp_path / "t.vtk", [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 1, 2, 3]])
    check_mesh(good, "t.vtk")
    (tmp_path / "bad.vtk").write_text(good.read_text().replace("4 0 1 2 3", "4 0 1 2 4"))
    with pytest.raises(MeshFileError, match="a cell names point 4, but the mesh has 4"):
        check_mesh(tmp_path / "bad.vtk", "bad.vtk")


@pytest.mark.parametrize("ixx", ["nan", "-1", "1"], ids=["nan", "negative", "triangle"])
def test_an_inertia_drake_replaces_is_refused_not_warned(tmp_path, ixx):
    """Before: Drake warned ("invalid inertia"), replaced it, and the scene ran (exit 0)."""
    done = run("run", str(mesh_scene(tmp_path, ixx=ixx)), "--no-progress")
    assert done.returncode == 2, done.stderr[-800:]
    assert "rotational inertia is not physically valid" in done.stderr and "thing.sdf:4" in done.stderr


@pytest.mark.parametrize("mass", ["nan", "-1"])
def test_a_nan_or_negative_mass_is_refused(tmp_path, mass):
    done = run("run", str(mesh_scene(tmp_path, mass=mass)), "--no-progress")
    assert done.returncode == 2 and "no positive mass" in done.stderr, done.stderr[-800:]


def test_a_scenario_file_past_the_yaml_size_limit_is_refused_before_it_is_parsed(tmp_path):
    from godobject_drake.config.yaml_guard import MAX_YAML_BYTES

    file = tmp_path / "huge.yaml"
    with file.open("w") as f:
        f.truncate(MAX_YAML_BYTES + 1)  # sparse: nothing written, nothing to read
    start = time.perf_counter()
    with pytest.raises(ScenarioError, match=r"huge\.yaml: 16\.0 MiB of YAML, past the 16 MiB limit"):
        load_scenario(file)
    assert time.perf_counter() - start < 0.5
