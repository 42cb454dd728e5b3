"""The README: at most 250 lines, opening with the two commands CI runs (.ci/run reads the first
line of its first two ```bash blocks); its example is examples/cube_post.yaml, run by
tests/test_examples.py; its links point at files that exist."""

import re

from conftest import EXAMPLES, REPO

README = (REPO / "README.md").read_text()


def test_readme_opens_with_the_two_commands():
    blocks = re.findall(r"```bash\n(.*?)\n```", README, flags=re.S)
    assert (
        blocks[0]
        == "python -m pip install -e . && godobject run lego --metrics metrics.json --record lego.html"
    )
    tests = (
        'python -m pip install -e ".[test]" && python -m ruff check . && python -m ruff format --check . && '
    )
    # the suite on every core (pytest-xdist), then the wall-clock tests alone, serial, after it
    assert blocks[1] == tests + (
        'python -m pytest -n auto --dist worksteal -m "not realtime" && python -m pytest -m realtime'
    )
    assert README.index("```bash") < README.index("```yaml")  # the two commands come first


def test_readme_is_short_and_its_links_resolve():
    assert len(README.splitlines()) <= 250
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README)
    local = [link for link in links if "://" not in link]
    assert local and [link for link in local if not (REPO / link).exists()] == []


def test_the_own_scene_example_is_the_file_wherever_it_is_shown():
    for page in (REPO / "README.md", REPO / "docs" / "guide" / "own_scene.md"):
        blocks = re.findall(r"```yaml\n(# Push a 0.2 kg cube.*?)```", page.read_text(), flags=re.S)
        assert blocks == [(EXAMPLES / "cube_post.yaml").read_text()], page
    sdf = re.findall(r"```xml\n(.*?)```", (REPO / "docs" / "guide" / "own_scene.md").read_text(), flags=re.S)
    assert sdf == [(EXAMPLES / "cube_post.sdf").read_text()]


def test_the_composed_diagram_is_the_example_file():
    """docs/guide/own_scene.md's "Compose your own diagram" block is examples/compose_diagram.py's
    code (its docstring aside), which tests/test_examples.py runs."""
    page = (REPO / "docs" / "guide" / "own_scene.md").read_text()
    (block,) = re.findall(r"```python\n(from pydrake.systems.analysis.*?)```", page, flags=re.S)
    code = (EXAMPLES / "compose_diagram.py").read_text()
    assert block == code[code.index("from pydrake.systems.analysis") :]
