"""The README's example and commands stay true."""

import json
import re
import subprocess
import sys

import pytest
from conftest import REPO, own_scene_files

from godobject_drake.building import PenetrationBudgetWarning, build_station
from godobject_drake.scenario import load_scenario

README = (REPO / "README.md").read_text()


def run_example(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_compose_your_own_diagram_example_runs():
    out = run_example(re.findall(r"```python\n(.*?)```", README, flags=re.S)[0])
    z = float(out.split("z =")[1].split()[0])
    assert abs(z - 0.04) < 0.002  # lifted to the device's 4 cm
    # Pressed 1 cm into the baseplate: kd (20 N/m) × 1 cm = 0.2 N up, within the brick's sink into
    # the plate (the coupling's 0.037 N on four corner proxies: µm) and the damping term (at rest: 0).
    f_z = float(out.split("F_z =")[1].split()[0])
    assert f_z == pytest.approx(0.2, abs=0.002)


def test_describe_your_own_scene_runs_as_written(tmp_path):
    command = own_scene_files(tmp_path)
    proc = subprocess.run(command.replace("python", sys.executable, 1), shell=True, capture_output=True,
                          text=True, cwd=tmp_path, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    m = json.loads((tmp_path / "cube_post.json").read_text())
    assert not m["diverged"] and m["sim_time_s"] == pytest.approx(4.5)
    # The cube stops at the post (its box in the post's cylinder by at most the predicted static
    # penetration, 64 N / 5e4 N/m = 1.28 mm, plus the impact's overshoot) and goes around it.
    assert m["predicted_static_penetration_m"] == pytest.approx(0.2 * 40.0**2 * 0.2 / 5e4)
    assert 0.0005 < m["max_penetration_m"] < 0.002
    assert m["recording_bytes"] == (tmp_path / "cube_post.html").stat().st_size
    assert "max_penetration_m" in proc.stdout  # the table


def test_a_soft_post_warns_at_build_time(tmp_path):
    """The README's claim: at 2e4 N/m the post lets the cube's capped pull (64 N) push it
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


def test_articulated_example_runs():
    out = run_example(re.findall(r"```python\n(.*?)```", README, flags=re.S)[1])
    assert abs(float(out.split("elbow at")[1].split()[0]) - 0.6) < 0.02  # the device's elbow angle


def test_readme_opens_with_the_two_commands():
    blocks = re.findall(r"```bash\n(.*?)\n```", README, flags=re.S)
    assert blocks[0].startswith("python -m pip install -e . && python diagrams/lego.py")
    assert "--metrics" in blocks[0] and "--record" in blocks[0]
    assert blocks[1].startswith('python -m pip install -e ".[test]"') and "pytest" in blocks[1]
