"""The README's example and commands stay true."""

import re
import subprocess
import sys

from conftest import REPO

README = (REPO / "README.md").read_text()


def run_example(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_compose_your_own_diagram_example_runs():
    out = run_example(re.findall(r"```python\n(.*?)```", README, flags=re.S)[0])
    z = float(out.split("z =")[1])
    assert abs(z - 0.04) < 0.002  # lifted to the device's 4 cm


def test_articulated_example_runs():
    out = run_example(re.findall(r"```python\n(.*?)```", README, flags=re.S)[1])
    assert abs(float(out.split("elbow at")[1].split()[0]) - 0.6) < 0.02  # the device's elbow angle


def test_readme_opens_with_the_two_commands():
    blocks = re.findall(r"```bash\n(.*?)\n```", README, flags=re.S)
    assert blocks[0].startswith("python -m pip install -e . && python diagrams/lego.py")
    assert "--metrics" in blocks[0] and "--record" in blocks[0]
    assert blocks[1].startswith('python -m pip install -e ".[test]"') and "pytest" in blocks[1]
