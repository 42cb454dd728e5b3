"""Model files read safely (issue 45): a FIFO, a device, a file past the size limit or a symlink loop
named anywhere a scenario reaches (a directive's file, a nested directives file, a model's mesh, a
device's path or log) is refused with exit 2 naming the file, before Drake or the device reads it."""

import os
import stat
import subprocess
import sys
import time

import pytest
from conftest import REPO

from godobject_drake.config.inputs import MAX_INPUT_FILE_BYTES
from godobject_drake.config.scenario import ScenarioError, load_scenario

SCENE = """name: own
directives:
- add_model:
    name: thing
    file: {model}
device: !Scripted
  path: {path}
simulation:
  duration_s: 0.01
"""
BRICK = (REPO / "models" / "lego" / "brick_2x4.sdf").read_text()
LEGO_PATH = "package://godobject_models/lego/default_path.yaml"


def scene(tmp_path, model="brick.sdf", path=LEGO_PATH, name="scene.yaml"):
    (tmp_path / "brick.sdf").write_text(BRICK)
    file = tmp_path / name
    file.write_text(SCENE.format(model=model, path=path))
    return file


def test_the_own_scene_with_regular_files_loads(tmp_path):
    assert load_scenario(scene(tmp_path)).directives[0].add_model.file.endswith("brick.sdf")


def test_a_fifo_as_a_model_file_exits_2_naming_it_instead_of_hanging(tmp_path):
    """It hung until killed: Drake's parser waited on the FIFO for a writer."""
    os.mkfifo(tmp_path / "model.sdf")
    file = scene(tmp_path, model="model.sdf")
    t0 = time.perf_counter()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "godobject_drake", "run", str(file), "--no-progress"],
            capture_output=True, text=True, timeout=120, cwd=tmp_path,
        )  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.fail(f"the run hung on the FIFO for {time.perf_counter() - t0:.0f} s")
    assert done.returncode == 2, done.stderr
    assert (
        f"directives[0].add_model.file: {tmp_path}/model.sdf is a FIFO (named pipe), not a regular file: "
        "reading it waits for a writer" in done.stderr
    )
    assert "Traceback" not in done.stderr


def test_a_model_file_past_the_size_limit_is_refused_before_it_is_read(tmp_path):
    """A 2 GB file was read whole (2.26 GB of memory) before Drake called it empty. A sparse file:
    2 GiB long, no disk used."""
    with open(tmp_path / "big.sdf", "wb") as f:
        f.truncate(2 * 2**30)
    with pytest.raises(ScenarioError) as refused:
        load_scenario(scene(tmp_path, model="big.sdf"))
    message = str(refused.value)
    assert f"{tmp_path}/big.sdf is 2048 MiB, past the {MAX_INPUT_FILE_BYTES // 2**20} MiB limit" in message
    assert "decimate the mesh or split the model" in message


def test_a_symlink_loop_as_a_model_file_is_refused_not_a_traceback(tmp_path):
    (tmp_path / "a.sdf").symlink_to(tmp_path / "b.sdf")
    (tmp_path / "b.sdf").symlink_to(tmp_path / "a.sdf")
    with pytest.raises(ScenarioError, match=r"directives\[0\]\.add_model\.file: .*/a\.sdf: a symlink loop"):
        load_scenario(scene(tmp_path, model="a.sdf"))


def test_a_fifo_in_a_nested_directives_file_is_refused(tmp_path):
    os.mkfifo(tmp_path / "deep.sdf")
    (tmp_path / "inner.dmd.yaml").write_text(
        f"directives:\n- add_model:\n    name: deep\n    file: file://{tmp_path}/deep.sdf\n"
    )
    (tmp_path / "outer.dmd.yaml").write_text(
        f"directives:\n- add_directives:\n    file: file://{tmp_path}/inner.dmd.yaml\n"
    )
    file = tmp_path / "scene.yaml"
    file.write_text(
        "name: own\ndirectives:\n- add_directives:\n    file: outer.dmd.yaml\n"
        f"device: !Scripted\n  path: {LEGO_PATH}\n"
    )
    with pytest.raises(ScenarioError) as refused:
        load_scenario(file)
    message = str(refused.value)
    assert "directives[0].add_directives.file → outer.dmd.yaml: directives[0].add_directives.file" in message
    assert f"inner.dmd.yaml: directives[0].add_model.file: {tmp_path}/deep.sdf is a FIFO" in message


def test_a_mesh_a_model_names_is_checked_too(tmp_path):
    os.mkfifo(tmp_path / "hull.obj")
    hull = '<visual name="hull"><geometry><mesh><uri>hull.obj</uri></mesh></geometry></visual>'
    (tmp_path / "meshy.sdf").write_text(
        BRICK.replace('<collision name="box">', hull + '<collision name="box">')
    )
    with pytest.raises(ScenarioError, match=r"meshy\.sdf: <uri> hull\.obj: .*/hull\.obj is a FIFO"):
        load_scenario(scene(tmp_path, model="meshy.sdf"))


def test_a_device_path_that_is_a_fifo_is_refused(tmp_path):
    os.mkfifo(tmp_path / "path.yaml")
    with pytest.raises(ScenarioError, match=r"device\.path: .*/path\.yaml is a FIFO"):
        load_scenario(scene(tmp_path, path="path.yaml"))


def test_a_device_log_that_is_a_device_is_refused_by_the_flag(tmp_path, capsys):
    """``--device replay --device-log /dev/zero``: said 'does not exist'; a symlink loop given to the
    flag ended in a RuntimeError traceback."""
    from godobject_drake import cli

    node = tmp_path / "zero"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 5))
    except PermissionError:
        pytest.skip("making a device node needs root")
    with pytest.raises(SystemExit) as ended:
        cli.main(["run", "lego", "--device", "replay", "--device-log", str(node), "--no-progress"])
    assert ended.value.code == 2
    assert f"device.log: {node} is a character device, not a regular file" in capsys.readouterr().err
    (tmp_path / "a.csv").symlink_to(tmp_path / "b.csv")
    (tmp_path / "b.csv").symlink_to(tmp_path / "a.csv")
    with pytest.raises(SystemExit) as ended:
        cli.main(["run", "lego", "--device", "replay", "--device-log", str(tmp_path / "a.csv")])
    assert ended.value.code == 2
    assert f"device.log: {tmp_path}/a.csv: a symlink loop" in capsys.readouterr().err


def test_a_fifo_as_the_scenario_file_is_named_as_one(tmp_path):
    os.mkfifo(tmp_path / "scene.yaml")
    with pytest.raises(ScenarioError, match=r"scenario file: .*/scene\.yaml is a FIFO"):
        load_scenario(tmp_path / "scene.yaml")
