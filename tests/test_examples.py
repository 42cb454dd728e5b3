"""Every file of examples/ runs and does what its comment says (these replace the tests that
parsed the README's headings: the README shows examples/cube_post.yaml, and a test checks it
still does)."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import EXAMPLES, REPO, own_scene_files

from godobject_drake.config.scenario import load_scenario
from godobject_drake.metrics import PenetrationBudgetWarning
from godobject_drake.station.build import build_station

GODOBJECT = Path(sys.executable).parent / "godobject"  # the console script of this environment


def run(argv: list, cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=cwd, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return proc


def test_every_example_has_a_test():
    tested = {"cube_post.yaml", "cube_post.sdf", "drake_table_block.yaml", "compose_diagram.py",
              "articulated_arm.py",
              "own_soft_body"}  # its scenes and mesh: tests/test_own_soft_body.py  # fmt: skip
    assert {p.name for p in EXAMPLES.iterdir()} == tested


@pytest.mark.slow
def test_the_own_scene_runs_from_its_folder(tmp_path):
    command = own_scene_files(tmp_path)
    proc = run([str(GODOBJECT), *command.split()[1:]], tmp_path)
    m = json.loads((tmp_path / "cube_post.json").read_text())
    assert not m["diverged"] and m["sim_time_s"] == pytest.approx(4.5)
    # The cube stops at the post: its box in the post's cylinder by at most the predicted static
    # penetration, the capped pull m ωn² · 0.2 m = 0.2 · 40² · 0.2 = 64 N over the pair's
    # stiffness (1e5 and 1e5 in series: 5e4 N/m), 1.28 mm, plus the impact's overshoot.
    assert m["predicted_static_penetration_m"] == pytest.approx(0.2 * 40.0**2 * 0.2 / 5e4)
    assert 0.0005 < m["max_penetration_m"] < 0.002
    assert m["recording_bytes"] == (tmp_path / "cube_post.html").stat().st_size
    assert "max_penetration_m" in proc.stdout  # the table


def test_a_soft_post_warns_at_build_time(tmp_path):
    """At 2e4 N/m the post lets the cube's capped pull (64 N) push it
    64 / (2e4 · 1e5 / 1.2e5) = 3.84 mm in, past the 2 mm budget: a warning naming the fix."""
    own_scene_files(tmp_path)
    sdf = tmp_path / "cube_post.sdf"
    text = sdf.read_text()
    post = text.index('<link name="post">')
    sdf.write_text(text[:post] + text[post:].replace("1e5", "2e4", 1))
    scenario = load_scenario(tmp_path / "cube_post.yaml")
    expected = r"cube's capped pull \(64 N\) can push it 3\.84 mm into cube_post::post .* budget 2 mm"
    with pytest.warns(PenetrationBudgetWarning, match=expected):
        station = build_station(scenario)
    assert station.predicted_penetration_m == pytest.approx(64.0 / (2e4 * 1e5 / 1.2e5))


@pytest.mark.slow
def test_drakes_own_table_and_block_welded_and_carried(tmp_path):
    """Models Drake's wheel ships (package://drake/...), the table welded with add_weld's X_PC.
    Neither file sets a stiffness: each geometry gets the default 2 m_max g / δ (m_max the
    heaviest body, the 53.5 kg table; δ the 1 mm penetration allowance), so the block's capped
    pull, 0.1 · 40² · 0.2 = 32 N, is predicted to press it 32 / (k/2) into the table."""
    proc = run([str(GODOBJECT), "run", str(EXAMPLES / "drake_table_block.yaml"), "--metrics", "m.json",
                "--no-progress"], tmp_path)  # fmt: skip
    m = json.loads((tmp_path / "m.json").read_text())
    assert not m["diverged"] and m["sim_time_s"] == pytest.approx(3.5)
    k = 2.0 * 53.5 * 9.81 / 1e-3
    assert m["predicted_static_penetration_m"] == pytest.approx(32.0 / (k / 2.0), rel=1e-3)
    assert m["max_penetration_m"] < 2 * m["predicted_static_penetration_m"]
    assert m["rms_tracking_error_m"] < 0.005  # carried: 5 mm at most, in free space
    assert "table" in proc.stdout or "max_penetration_m" in proc.stdout


@pytest.mark.slow
def test_the_block_is_set_down_where_the_device_put_it():
    from godobject_drake.simulation import simulate

    result = simulate(build_station(load_scenario(EXAMPLES / "drake_table_block.yaml")), progress=False)
    plant = result.station.plant
    block = plant.GetBodyByName("base_link", plant.GetModelInstanceByName("block"))
    p = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(result.context), block).translation()
    assert p[0] == pytest.approx(0.2, abs=0.005) and p[2] == pytest.approx(0.1, abs=0.002)  # standing


@pytest.mark.slow
def test_compose_your_own_diagram_example():
    out = run([sys.executable, str(EXAMPLES / "compose_diagram.py")], REPO).stdout
    z = float(out.split("z =")[1].split()[0])
    assert abs(z - 0.04) < 0.002  # lifted to the device's 4 cm
    # Pressed 1 cm into the baseplate: kd (20 N/m) × 1 cm = 0.2 N up, within the brick's sink into
    # the plate (the coupling's 0.037 N on four corner proxies: µm) and the damping term (at rest: 0).
    f_z = float(out.split("F_z =")[1].split()[0])
    assert f_z == pytest.approx(0.2, abs=0.002)


@pytest.mark.slow
def test_articulated_arm_example():
    out = run([sys.executable, str(EXAMPLES / "articulated_arm.py")], REPO).stdout
    elbow = float(out.split("elbow at")[1].split()[0])
    assert math.isclose(elbow, 0.6, abs_tol=0.02)  # the device's elbow angle
