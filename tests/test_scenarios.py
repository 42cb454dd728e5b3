"""Contract tests over every shipped scenario (in the style of dm_control's suite tests), and the
scenario file itself: loading, errors that name the file and key, paths, round trips.

Each shipped scene (``diagrams/NAME.yaml``) is run for a short time: the same scenario gives the
same trajectory, every vector output of every system is finite, every common metric key is
there, the YAML round-trips; and every entry point (the command line's ``run`` and ``analyze``,
the scene scripts, the library, the benchmark) builds the scenario its flags say, through
``build_station`` alone.
"""

import dataclasses
import json
import math
import subprocess
import sys
import typing

import numpy as np
import pytest
from conftest import REPO, SCENES, scenario
from pydrake.common.yaml import yaml_load_typed

from godobject_drake.config.scenario import (
    Scenario,
    ScenarioError,
    load_scenario,
    replace,
    scenario_from_yaml,
    scenario_to_yaml,
    shipped_scenario,
)
from godobject_drake.metrics import METRIC_KEYS
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station, make_meshcat
from godobject_drake.station.loop import make_device

# Keys every run's metrics have, whatever the scene (docs/metrics.md).
COMMON_KEYS = (
    *METRIC_KEYS, "diagnosis", "step_cost_us", "free_space_samples", "predicted_static_penetration_m",
    "contact", "contact_approximation", "device", "device_rate_hz", "omega_n_rad_s", "omega_n_rot_rad_s",
    "zeta", "seed",
)  # fmt: skip
SHORT = ("--duration", "0.3")


def short_run(name, *flags):
    s = scenario(name, *SHORT, *flags)
    return simulate(build_station(s, make_meshcat(s)), progress=False)


@pytest.fixture(scope="module", params=SCENES)
def runs(request):
    """Two runs of each shipped scene with the same scenario."""
    name = request.param
    return name, short_run(name), short_run(name)


@pytest.mark.slow
def test_same_scenario_same_trajectory(runs):
    name, a, b = runs
    # 0.3 s at h = 1 ms (the laparoscopy's and the probe's h = 10 ms), one row per plant step, t = 0 included
    assert len(a.states) == {"lego": 301, "laparoscopy": 31, "deformable_probe": 31}[name]
    np.testing.assert_array_equal(a.states, b.states)
    for key in a.data:
        np.testing.assert_array_equal(a.data[key], b.data[key])


def test_every_output_is_finite(runs):
    _, result, _ = runs
    context = result.context
    checked = 0
    for system in result.station.diagram.GetSystems():
        sub = system.GetMyContextFromRoot(context)
        for i in range(system.num_output_ports()):
            port = system.get_output_port(i)
            if port.get_data_type() != port.get_data_type().kVectorValued:
                continue
            value = port.Eval(sub)
            assert np.all(np.isfinite(value)), f"{system.get_name()}.{port.get_name()} = {value}"
            checked += 1
    assert checked >= 5  # plant state, device, coupling, feedback, ... : the check saw them


def test_every_common_metric_key_is_there(runs):
    name, result, _ = runs
    m = result.metrics
    assert "metrics_error" not in m, m.get("metrics_error")
    missing = [k for k in COMMON_KEYS if k not in m]
    assert not missing, missing
    assert m["scene"] == name and not m["diverged"] and m["sim_time_s"] == pytest.approx(0.3)
    json.dumps(m)  # JSON-ready


def _leaves(node, path=""):
    """``(dotted path, value)`` of every plain field of a scenario's dataclasses (Drake's own config
    types, the plant config and the directives, are Drake's to round-trip)."""
    hints = typing.get_type_hints(type(node))
    for field in dataclasses.fields(node):
        value, at = getattr(node, field.name), f"{path}{field.name}"
        if dataclasses.is_dataclass(value):
            yield from _leaves(value, at + ".")
        elif isinstance(value, bool | int | float | str):
            yield at, value
        elif value is None:  # an optional field: a value of its type
            kind = next(a for a in typing.get_args(hints[field.name]) if a is not type(None))
            yield at, {int: 7, float: 0.125, str: "x"}[kind]


def _changed(value):
    """A value of the same type that differs from ``value``."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return 0.5 if math.isinf(value) else value * 1.5 + 0.25
    return value + "_x"


@pytest.mark.parametrize("name", SCENES)
def test_yaml_round_trips_every_field(name):
    """Each plain field of each shipped scenario, changed alone, is written by scenario_to_yaml and
    read back by the typed loader with its new value: no field is lost on the way out or in (a
    field lost both ways would leave the text unchanged, and the shared runs' cache, keyed by this
    text, would mix two scenarios)."""
    s = shipped_scenario(name)
    text = scenario_to_yaml(s)
    again = yaml_load_typed(schema=Scenario, data=text)
    assert type(again.device) is type(s.device) and type(again.god_object) is type(s.god_object)
    leaves = list(_leaves(s))
    assert len(leaves) > 60  # the walk sees the scenario's fields (tool, device, haptic, ...)
    for path, value in leaves:
        changed = replace(s, **{path: _changed(value)})
        written = scenario_to_yaml(changed)
        assert written != text, f"{path} is not written"
        back = yaml_load_typed(schema=Scenario, data=written)
        target = back
        for part in path.split("."):
            target = getattr(target, part)
        assert target == _changed(value), f"{path}: wrote {_changed(value)!r}, read {target!r}"


@pytest.mark.slow
def test_the_command_and_the_script_agree(tmp_path):
    """``python -m godobject_drake run diagrams/lego.yaml`` and ``python diagrams/lego.py``: same run."""
    out = {}
    for key, command in (
        ("module", [sys.executable, "-m", "godobject_drake", "run", "diagrams/lego.yaml"]),
        ("script", [sys.executable, "diagrams/lego.py"]),
    ):
        path = tmp_path / f"{key}.json"
        proc = subprocess.run(
            [*command, "--duration", "0.4", "--no-progress", "--metrics", str(path)],
            capture_output=True, text=True, cwd=REPO, timeout=300,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        out[key] = json.loads(path.read_text())
    timing = {"wall_time_s", "cpu_time_s", "real_time_factor", "step_cost_us", "metrics_time_s"}
    assert {k: v for k, v in out["module"].items() if k not in timing} == {
        k: v for k, v in out["script"].items() if k not in timing
    }


# -- the scenario file ----------------------------------------------------------------------------


def write(tmp_path, text, name="s.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_unknown_key_names_the_key_and_the_file(tmp_path):
    path = write(tmp_path, "name: x\nsimulation: {duration_s: 1.0, duraton: 2.0}\n")
    with pytest.raises(ScenarioError, match=r"s\.yaml: .*\['duraton'\] were unknown") as e:
        load_scenario(path)
    assert "check its spelling" in str(e.value)


def test_a_device_tag_that_does_not_exist_lists_the_kinds(tmp_path):
    path = write(tmp_path, "device: !Mouse {rate_hz: 60}\n")
    with pytest.raises(ScenarioError, match=r"s\.yaml: .*'Mouse'.*give the YAML tag"):
        load_scenario(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("simulation: {duration_s: -1.0}", r"simulation\.duration_s: -1\.0 s must be > 0"),
        (
            "plant: {time_step: 0.0}",
            r"plant\.time_step: 0\.0 s; SAP is discrete.* cenic integrator\) is not offered.*CENIC "
            r"against SAP",
        ),
        ("contact: {geometry: hydroelastic}", r"contact\.geometry: hydroelastic needs plant\.contact_model"),
        ("haptic: {mode: impedence}", r"haptic\.mode: 'impedence'; choose one of"),
        ("device: !Scripted {rate_hz: 0.0}", r"device\.rate_hz: 0\.0 Hz must be > 0"),
        (
            "god_object: !Articulated {model: arm, device_joints: [elbow]}",
            r"device: an articulated .* joint-space",
        ),
        ("haptic: {passivity_damping: 50.0}", r"haptic\.passivity_damping: 50\.0 N·s/m acts on an impedance"),
    ],
)
def test_bad_values_name_the_field_the_value_and_the_fix(tmp_path, text, message):
    with pytest.raises(ScenarioError, match=message):
        load_scenario(write(tmp_path, text + "\n"))


def test_input_paths_are_relative_to_the_scenario_file(tmp_path):
    (tmp_path / "paths").mkdir()
    (tmp_path / "paths" / "here.yaml").write_text(
        "waypoints:\n- {t: 0.0, xyz: [0, 0, 0]}\n- {t: 1.0, xyz: [0, 0, 0.1]}\n"
    )
    s = load_scenario(write(tmp_path, "device: !Scripted {path: paths/here.yaml}\n"
                              "directives:\n- add_model: {name: m, file: models/m.sdf}\n"))  # fmt: skip
    assert s.device.path == str(tmp_path / "paths" / "here.yaml")
    assert s.directives[0].add_model.file == "file://" + str(tmp_path / "models" / "m.sdf")
    lego = shipped_scenario("lego")  # package:// URLs: model files stay URLs, device paths become files
    assert lego.directives[0].add_directives.file.startswith("package://godobject_models/")
    assert lego.device.path == str(REPO / "models" / "lego" / "default_path.yaml")


def test_a_scenario_from_text_runs_like_the_file(tmp_path):
    text = (REPO / "diagrams" / "lego.yaml").read_text()
    a = scenario_from_yaml(text, base_dir=REPO / "diagrams")
    assert scenario_to_yaml(a) == scenario_to_yaml(shipped_scenario("lego"))


def test_flags_override_fields_and_keep_the_rotation_ratio():
    log = REPO / "models" / "lego" / "push_and_return.csv"  # a real increment log (the paper's mouse)
    s = scenario("lego", "--omega-n", "20", "--time-step", "0.002", "--device", "relative",
                 "--device-log", str(log))  # fmt: skip
    assert (s.god_object.gains.omega_n, s.god_object.gains.omega_n_rot) == (20.0, 60.0)  # 3x, as 40/120
    assert s.plant.time_step == 0.002 and type(s.device).__name__ == "Relative"
    np.testing.assert_allclose(s.device.start_xyz, [-0.10, 0.0, 0.0048])  # where the path starts
    assert s.device.rate_hz == 60.0 and s.device.log == str(log)
    device = make_device(s.device)  # the switched device reads the log: its first sample is the start
    p0, _, _ = device.samples(0.0)[0][1]
    np.testing.assert_allclose(p0, [-0.10, 0.0, 0.0048], atol=1e-12)
    # --coupling takes both kinds' couplings; each kind's check refuses the other's
    with pytest.raises(
        ScenarioError, match=r"god_object.coupling: 'joint_pd'; choose one of \('explicit', 'implicit'\)"
    ):
        scenario("lego", "--coupling", "joint_pd")
    with pytest.raises(ScenarioError, match=r"god_object.coupling: 'implicit'; choose one of \('cartesian'"):
        scenario("laparoscopy", "--coupling", "implicit")
    with pytest.raises(
        ScenarioError,
        match=r"--device-noise: sets device.noise_m, which the scenario's "
        r"!ScriptedJoints device has not; it is for !Scripted, !Replay",
    ):
        scenario("laparoscopy", "--device-noise", "0.001")


ROCK_SDF = """<?xml version="1.0"?>
<sdf version="1.9">
  <model name="quarry">
    <joint name="weld" type="fixed"><parent>world</parent><child>ground</child></joint>
    <link name="ground">
      <collision name="ground">
        <geometry><plane><normal>0 0 1</normal><size>1 1</size></plane></geometry>
      </collision>
    </link>
    <link name="rock">
      <pose>0 0 0.05 0 0 0</pose>
      <inertial><mass>0.1</mass>
        <inertia><ixx>1e-5</ixx><iyy>1e-5</iyy><izz>1e-5</izz><ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia>
      </inertial>
      <collision name="rock"><geometry><mesh><uri>rock.obj</uri></mesh></geometry></collision>
      <visual name="rock"><geometry><mesh><uri>rock.obj</uri></mesh></geometry></visual>
    </link>
  </model>
</sdf>
"""
ROCK_OBJ = "v 0.02 0 0\nv -0.02 0.02 0\nv -0.02 -0.02 0\nv 0 0 0.03\nf 1 2 3\nf 1 2 4\nf 2 3 4\nf 3 1 4\n"
ROCK_YAML = """name: quarry
directives:
- add_model: {name: quarry, file: rock.sdf}
device: !Scripted
  waypoints:
  - {t: 0.0, xyz: [0.0, 0.0, 0.05], grasp: rock}
  - {t: 0.3, xyz: [0.0, 0.0, 0.10], grasp: rock}
simulation: {duration_s: 0.3}
"""


def test_a_metric_that_fails_leaves_the_recording_and_the_other_metrics(tmp_path):
    """A mesh rock over a half-space ground: no penetration measure exists for that pair (Drake's
    signed distance takes only spheres against a half space; a mesh has no support function here).
    The run still writes its recording, reports the common metrics, names what failed, and the
    command exits 1."""
    for name, text in (("rock.sdf", ROCK_SDF), ("rock.obj", ROCK_OBJ), ("quarry.yaml", ROCK_YAML)):
        (tmp_path / name).write_text(text)
    html, metrics = tmp_path / "quarry.html", tmp_path / "quarry.json"
    proc = subprocess.run(
        [sys.executable, "-m", "godobject_drake", "run", str(tmp_path / "quarry.yaml"), "--no-progress",
         "--record", str(html), "--metrics", str(metrics)],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    m = json.loads(metrics.read_text())
    assert "penetration of quarry::rock into the half space quarry::ground" in m["metrics_error"]
    assert m["recording_bytes"] == html.stat().st_size > 100_000
    assert m["sim_time_s"] == pytest.approx(0.3) and not m["diverged"]


def test_a_package_path_set_on_a_device_after_loading_is_taken_as_loading_takes_it():
    """A ``package://godobject_models/`` path set from Python after the scenario was loaded (a
    device's ``path``) is the models' file, as in a scenario file: before, the check passed it on
    and the path's reader raised a bare FileNotFoundError."""
    from godobject_drake.config.scenario import MODELS_DIR, check_scenario, shipped_scenario

    s = shipped_scenario("peg_transfer")
    s.tools["left"].device.path = "package://godobject_models/peg_transfer/clumsy_left_path.yaml"
    check_scenario(s)
    assert s.tools["left"].device.path == str(MODELS_DIR / "peg_transfer" / "clumsy_left_path.yaml")
    assert s.tools["left"].device.joint_path().waypoints[-1].t > 50.0  # the clumsy one's 50.77 s
