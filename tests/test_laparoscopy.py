"""The laparoscopy scene as a user runs it: penetration, trocar, tracking against its prediction."""

import json
import re

import numpy as np
import pytest
from conftest import (
    assert_refused,
    build_scene,
    load_script,
    meshcat_commands,
    run_scene,
    scenario,
    shared_run,
)

from godobject_drake.config.device_files import write_joint_log
from godobject_drake.config.gains import CouplingGainError
from godobject_drake.studies.joint_space import device_targets, linear_response
from godobject_drake.systems.articulated import joint_space_loop


def run(*flags):
    """(station, metrics, states, q_device) of the scene run with these flags."""
    result = run_scene("laparoscopy", *flags)
    return result.station, result.metrics, result.states, result.data["q_device"]


@pytest.fixture(scope="module")
def default_runs():
    """The default path (10 s), god-object (Cartesian coupling) and the position baseline."""
    return {mode: shared_run("laparoscopy", "--mode", mode).metrics for mode in ("god_object", "position")}


@pytest.mark.slow
def test_god_object_stays_out_of_the_organ_where_the_baseline_goes_in(default_runs):
    god, pos = default_runs["god_object"], default_runs["position"]
    assert not god["diverged"] and not pos["diverged"]
    assert pos["max_penetration_m"] > 0.020  # the interface drives 35 mm into the uterus
    assert god["max_penetration_m"] <= 0.005
    assert god["max_penetration_m"] <= pos["max_penetration_m"] / 5
    for m in (god, pos):
        assert m["max_trocar_offset_m"] <= 1e-6  # reduced coordinates: the pivot holds exactly


def test_default_path_pushes_the_device_tip_3_cm_into_the_organ():
    """The scripted interface's tip (kinematic copy) reaches ≥ 30 mm inside the uterus (Fig. 7)."""
    station = build_scene("laparoscopy")
    plant, tool, device = station.plant, station.god_object.tool, station.device
    uterus_top = 0.025  # m, models/laparoscopy/organs.sdf
    tip = plant.GetBodyByName("tube", tool.model)
    depths = [uterus_top - plant.EvalBodyPoseInWorld(tool.set_device_state(q), tip).translation()[2]
              for q in device.samples(station.scenario.simulation.duration_s)]  # fmt: skip
    assert max(depths) >= 0.030


FREE_LOG_CHANNELS = scenario("laparoscopy").device.channels


@pytest.fixture(scope="module")
def free_space_log(tmp_path_factory):
    """2 s of sinusoids on every channel, the tip 45 mm or more above the organ."""
    t = np.arange(0.0, 2.0 + 1e-9, 1.0 / 120.0)
    u = np.column_stack([
        0.08 * np.sin(2 * np.pi * 0.5 * t), 0.1 * np.sin(2 * np.pi * 0.7 * t),
        0.035 + 0.008 * np.sin(2 * np.pi * 0.6 * t), 0.5 * np.sin(2 * np.pi * 0.4 * t), 0.3 + 0.0 * t,
    ])  # fmt: skip
    path = tmp_path_factory.mktemp("laparoscopy") / "free.csv"
    write_joint_log(path, FREE_LOG_CHANNELS, t, u)
    return path


@pytest.mark.parametrize("coupling", ["cartesian", "joint_pd", "joint_pd_sap"])
def test_free_space_tip_tracking_matches_its_gains(coupling, free_space_log):
    """Drake's tip error equals the linearized joint-space loop's (same gains, same samples) within 10 %."""
    station, metrics, states, q_device = run(
        "--device", "replay", "--device-log", str(free_space_log), "--duration", "2.0", "--coupling", coupling
    )
    assert metrics["free_space_samples"] == len(states)  # never near the organ
    system, plant, device = station.coupling, station.plant, station.device
    tool, h = system.tool, plant.time_step()
    c = [0, 1, 2, 3]  # yaw, pitch, insertion, roll; the jaws are imposed
    q_T, v_T = device_targets(device, h, len(states) - 1)
    loop = joint_space_loop(tool, coupling.replace("_sap", ""), system.gains, device.sample(0.0), h)
    q_pred = linear_response(
        loop, device.sample(0.0)[c], q_T[:, c], v_T[:, c], implicit=coupling == "joint_pd_sap"
    )
    tip = plant.GetBodyByName("tube", tool.model)

    def tip_at(q):
        return plant.EvalBodyPoseInWorld(tool.set_device_state(q), tip).translation()

    errors = []
    for qp, qd in zip(q_pred, q_device, strict=True):
        q = qd.copy()
        q[c] = qp
        errors.append(tip_at(q) - tip_at(qd))
    predicted = float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1))))
    assert 2e-4 < predicted < 1e-3  # sub-millimetre, and not trivially zero
    assert metrics["tip_tracking_rms_m"] == pytest.approx(predicted, rel=0.10)


def test_recording_draws_the_device_tool_as_a_wireframe(tmp_path):
    html = tmp_path / "lap.html"
    metrics_path = tmp_path / "m.json"
    script = load_script("diagrams/laparoscopy.py")
    assert script.main(["--no-progress", "--duration", "0.2", "--record", str(html),
                        "--metrics", str(metrics_path)]) == 0  # fmt: skip
    commands = meshcat_commands(html.read_text())
    (animation,) = [c for c in commands if b"set_animation" in c]
    # The god-object tool is the plant's solid drawing; the device's tool is a wireframe ghost.
    for path in (b"/drake/visualizer/grasper/tube", b"/godobject/device_tool/tube"):
        assert path in animation, path
    ghosts = [c for c in commands if b"set_object" in c and b"/godobject/device_tool/tube" in c]
    assert ghosts and all(b"wireframe" in c for c in ghosts)
    m = json.loads(metrics_path.read_text())
    keys = ("scene", "mode", "time_step_s", "real_time_factor", "max_penetration_m", "rms_tracking_error_m",
            "tip_tracking_rms_m", "max_trocar_offset_m", "coupling", "imposed_joints",
            "step_cost_us")  # fmt: skip
    for key in keys:
        assert key in m
    assert m["recording_bytes"] == len(html.read_bytes())


def test_bad_device_logs_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,yaw,pitch,insertion,roll\n0,0,0,0.04,0\n")
    with pytest.raises(ValueError, match=r"bad\.csv:1: header must be t,yaw,pitch,insertion,roll,jaw"):
        run("--device", "replay", "--device-log", str(bad), "--duration", "0.1")
    bad.write_text("t,yaw,pitch,insertion,roll,jaw\n0,0,0,0.04,0,0\n0.1,0,0,0.04,0,0\n0.05,0,0,0.04,0,0\n")
    with pytest.raises(ValueError, match=r"bad\.csv:4: time 0\.05 is not after"):
        run("--device", "replay", "--device-log", str(bad), "--duration", "0.1")
    bad.write_text("t,yaw,pitch,insertion,roll,jaw\n0,0,nan,0.04,0,0\n")
    with pytest.raises(ValueError, match=r"bad\.csv:2: non-finite"):
        run("--device", "replay", "--device-log", str(bad), "--duration", "0.1")


def test_explicit_gains_past_the_limit_are_refused_with_the_fix(capsys):
    flags = ("--duration", "0.1", "--coupling", "joint_pd", "--omega-n", "2000")
    refusal = dict(
        value=r"coupling='joint_pd' with omega_n=2000",
        limit=r"spectral radius \d+\.\d+ ≥ 1",
        fix=r"Lower the bandwidths or time_step, or use coupling='joint_pd_sap'",
    )
    assert_refused(lambda: build_scene("laparoscopy", *flags), CouplingGainError, **refusal)
    # On the command line: the same message, and the exit status of bad input (2).
    script = load_script("diagrams/laparoscopy.py")
    with pytest.raises(SystemExit) as exit_:
        script.main(["--no-progress", *flags])
    assert exit_.value.code == 2
    stderr = capsys.readouterr().err
    for pattern in refusal.values():
        assert re.search(pattern, stderr), (pattern, stderr)
    _, metrics, _, _ = run("--duration", "0.2", "--coupling", "joint_pd_sap", "--omega-n", "2000")
    assert not metrics["diverged"]


def test_figure_script_draws_the_run(tmp_path):
    figure = load_script("analysis/laparoscopy_figure.py")
    out = tmp_path / "lap.png"
    figure.main(["--out", str(out), "--duration", "0.3"])
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
