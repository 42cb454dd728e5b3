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
