"""The brick scene as a user runs it: the issue's acceptance numbers, replay, recording, CLI."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, build_scene, lego_run, meshcat_commands, shared_run

from godobject_drake.config.device_files import write_device_log
from godobject_drake.metrics import METRIC_KEYS


def default_run(mode: str) -> dict:
    """The default 8.5 s path in one mode (about 7 s of wall time), once a session (shared with
    test_long_runs and test_sleeping): the fast tier runs only the position baseline."""
    return shared_run("lego", "--mode", mode).metrics


@pytest.mark.slow
def test_god_object_respects_the_obstacles():
    m = default_run("god_object")
    assert not m["diverged"], m["diagnosis"]
    assert m["max_penetration_m"] <= 0.0015
    assert m["max_other_body_speed_mps"] < 0.05  # nothing else is knocked over
    assert m["rms_tracking_error_m"] is not None and m["free_space_samples"] > 1000


def test_position_baseline_goes_through_the_wall():
    m = default_run("position")
    assert m["max_penetration_m"] >= 0.005  # the brick is imposed inside the 8 mm wall
    assert m["rms_tracking_error_m"] < m["max_penetration_m"]  # it does follow the device


def test_replayed_csv_equals_the_scripted_path(tmp_path):
    scripted = lego_run("--duration", "1.0")
    log = tmp_path / "path.csv"
    write_device_log(log, build_scene("lego").device.samples(1.0))
    replayed = lego_run("--duration", "1.0", "--device", "replay", "--device-log", str(log))
    np.testing.assert_array_equal(replayed.states, scripted.states)
    assert scripted.metrics["max_penetration_m"] == replayed.metrics["max_penetration_m"]


@pytest.mark.slow
def test_same_seed_same_run():
    a = lego_run("--duration", "0.3", "--device-noise", "0.001", "--seed", "7")
    b = lego_run("--duration", "0.3", "--device-noise", "0.001", "--seed", "7")
    c = lego_run("--duration", "0.3", "--device-noise", "0.001", "--seed", "8")
    np.testing.assert_array_equal(a.states, b.states)
    assert not np.array_equal(a.states, c.states)


def test_recording_has_the_animation_and_the_ghost(tmp_path):
    html_path = tmp_path / "r.html"
    result = lego_run("--duration", "0.6", "--record", str(html_path))
    commands = meshcat_commands(html_path.read_text())
    (animation,) = [c for c in commands if b"set_animation" in c]
    # Both the plant's bodies and our ghost and spring are animated.
    for path in (b"/drake/visualizer/brick_0/brick", b"/godobject/ghost/brick_0/brick", b"/godobject/spring"):
        assert path in animation, path
    ghost_objects = [c for c in commands if b"set_object" in c and b"/godobject/ghost/brick_0/brick" in c]
    assert ghost_objects and all(b"transparent" in c for c in ghost_objects)
    assert result.metrics["recording_bytes"] == html_path.stat().st_size


def run_cli(*argv):
    return subprocess.run(
        [sys.executable, str(REPO / "diagrams" / "lego.py"), *argv, "--no-progress"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )


def test_command_line_writes_metrics_and_table(tmp_path):
    out = tmp_path / "m.json"
    proc = run_cli("--duration", "0.2", "--metrics", str(out))
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads(out.read_text())
    assert set(METRIC_KEYS) <= set(metrics)
    assert metrics["sim_time_s"] == pytest.approx(0.2)
    assert "max_penetration_m" in proc.stdout and "god_object" in proc.stdout


def test_command_line_refuses_unstable_gains():
    proc = run_cli("--duration", "0.1", "--time-step", "0.01", "--omega-n", "100")
    assert proc.returncode != 0
    assert "past the explicit (symplectic Euler) stability limit" in proc.stderr
    assert "Use omega_n < 82.84 rad/s" in proc.stderr
