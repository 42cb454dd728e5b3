"""The README: at most 250 lines, opening with the two commands CI runs (.ci/run reads the first
line of its first two ```bash blocks); its example is examples/cube_post.yaml, run by
tests/test_examples.py; its links point at files that exist. Every command of the README and
the docs parses (fast tier) and runs, shortened (slow tier), or says why not."""

import argparse
import importlib
import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from conftest import EXAMPLES, REPO, load_script

from godobject_drake import cli

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


# --- Every command in README.md and docs/ (issue 56 item 1) -----------------------------------
#
# Each line of a shell block (```bash, ```sh, ```console or a bare ```) that starts with a program,
# and each inline `godobject …`, `godobject-driver …`, `python -m godobject_drake …`,
# `python diagrams/…`, `python analysis/…` or `pip install …` span, split at `&&`. Each is parsed by
# its program's own argument parser (a run's or analyze's scenario loaded with its flags too), and
# the cheap ones run (slow tier), shortened to 0.2 s, in a temporary folder, against this clone's
# code. What cannot be parsed or run is listed below with why; a listed command that no page shows
# any more fails, so the lists stay honest.

PAGES = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
PROGRAMS = ("godobject", "python", "pip", "mkdocs", "ssh", "cd", "jupyter-execute")
INLINE = re.compile(
    r"(godobject(-driver)? |python -m godobject_drake|python (diagrams|analysis)/|(python -m )?pip install )"
)

# A synopsis (placeholders in capitals, [optional] parts, a|b) and the command that stands for it.
SYNOPSES = {
    "godobject run SCENARIO [flags]": "godobject run lego",
    "godobject analyze SCENARIO [--out DIR] [--quick] [--verify/--no-verify] [flags]": (
        "godobject analyze lego --out DIR --quick --no-verify"
    ),
    "godobject run NAME.yaml": "godobject run cube_post.yaml",
    "godobject run lego FLAGS": "godobject run lego --duration 1",
    "godobject run diagrams/lego.yaml FLAGS": "godobject run diagrams/lego.yaml --duration 1",
    "python diagrams/lego.py FLAGS": "python diagrams/lego.py --duration 1",
    "python diagrams/laparoscopy.py --coupling C": "python diagrams/laparoscopy.py --coupling joint_pd_sap",
    "godobject analyze SCENARIO --out DIR": "godobject analyze lego --out DIR",
    "godobject analyze SCENE --coupling implicit": "godobject analyze lego --coupling implicit",
    "godobject-driver run FAMILY": "godobject-driver run emulated",
    "godobject-driver run emulated|haply|forcedimension|openhaptics": "godobject-driver run emulated",
    "python -m godobject_drake.driver.process run FAMILY": (
        "python -m godobject_drake.driver.process run emulated"
    ),
    "godobject-driver calibrate FAMILY --scenario S.yaml --out CALIBRATED.yaml [--seconds 20]": (
        "godobject-driver calibrate emulated --scenario "
        "diagrams/lego_driver.yaml --out calibrated.yaml --seconds 20"
    ),
    "python -m godobject_drake.driver.replay LOG.csv --lcm-url URL": (
        "python -m godobject_drake.driver.replay models/lego/push_and_return.csv --lcm-url memq://"
    ),
    "python analysis/driver_memory.py [--scene]": "python analysis/driver_memory.py --scene",
    "python analysis/driver_lag.py --duration 3 [--rt-priority 50]": (
        "python analysis/driver_lag.py --duration 3 --rt-priority 50"
    ),
    "godobject run laparoscopy_bimanual --set tools.right.device.path=my_press.yaml": (
        "godobject run laparoscopy_bimanual --set "
        "tools.right.device.path=models/laparoscopy/deep_press_path.yaml"
    ),
}

# Commands not parsed here, each with why (a key names every command that starts with it).
NOT_PARSED = {
    "pip install HaplyHardwareAPI": "a device maker's SDK, from PyPI",
    "pip install forcedimension-core": "a device maker's SDK, from PyPI",
    "pip install pyopenhaptics": "a device maker's SDK, from PyPI",
    "python -m pip install -e '.[docs]' jupyterlab": (
        "JupyterLab, from PyPI (the docs extra is checked alone)"
    ),
    "python -m ruff": "the lint CI runs (.ci/run)",
    "python -m build": (
        "builds the sdist and the wheel; CI installs each in a fresh venv and runs it (.ci/run)"
    ),
    "python -m pytest": "the test suite itself",
    "mkdocs serve": "serves the site until Ctrl-C; CI builds it (mkdocs build --strict)",
    "ssh -N -L": "a tunnel from another machine",
    "cd notebooks": "tests/test_notebooks.py executes the notebooks",
    "jupyter-execute": "tests/test_notebooks.py executes the notebooks",
    "python cenic_trial.py": "a script of the project's history (git show 6795d06:analysis/cenic_trial.py)",
    "python analysis/throttled_scene.py": "patches the link's publishers for the whole process it runs in",
    "godobject analyze --verify": "a flag named in prose, not a command",
}

# Commands parsed but not run here, each with why (a key names every command that starts with it).
NOT_RUN = {
    "python -m pip install": "installs (the test runs in the environment it would install into)",
    "pip install": "installs (the test runs in the environment it would install into)",
    "python analysis/": "an analysis script: minutes of measuring (its page gives the time)",
    "python -m godobject_drake.studies.indentation": "minutes of FEM indentations",
    "godobject-driver": "a device's loop: runs until its scene stops (tests/test_driver.py pairs one)",
    "python -m godobject_drake.driver.": "a device's loop: runs until its scene stops (tests/test_driver.py)",
    "godobject run lego_driver": "waits for its driver, in another terminal (tests/test_pairing.py)",
    "godobject run laparoscopy_bimanual_drivers": (
        "waits for its two drivers, in two other terminals (tests/test_bimanual_drivers.py)"
    ),
    "godobject run peg_transfer_drivers": (
        "waits for its two drivers, in two other terminals (tests/test_peg_drivers.py)"
    ),
    "python -m godobject_drake run diagrams/lego_haptic.yaml": "waits for its driver (tests/test_pairing.py)",
    "godobject run diagrams/lego_haptic.yaml": "waits for its driver (tests/test_pairing.py)",
    "godobject run lego --device lcm": "waits for a device on LCM (tests/test_lcm.py)",
    "godobject analyze laparoscopy --set organs.model=fem --verify": (
        "checks the FEM tissue in Drake: minutes"
    ),
    "godobject analyze laparoscopy --set organs.model=fem --set organs.cells=8": (
        "checks the reference's FEM tissue in Drake: minutes"
    ),
}


def _shell_lines(text: str) -> list[str]:
    lines = []
    for lang, body in re.findall(r"^```(\w*)\n(.*?)^```", text, flags=re.S | re.M):
        if lang in ("bash", "sh", "console", "shell", ""):
            for line in re.sub(r"\\\n\s*", " ", body).splitlines():
                if line.strip().split(" ")[0] in PROGRAMS:
                    lines.append(line.strip())
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    for span in re.findall(r"`([^`]+)`", prose):
        span = " ".join(span.split())
        if INLINE.match(span) and not re.fullmatch(
            r"(godobject(-driver)?|python -m godobject_drake)( \w+)?", span
        ):
            lines.append(span)
    return lines


def doc_commands() -> dict[str, list[str]]:
    """Each documented command (its words joined by one space, shell quotes and comments gone),
    with the pages that show it; a synopsis stands as its stand-in."""
    found: dict[str, list[str]] = {}
    for page in PAGES:
        for line in _shell_lines(page.read_text()):
            words = shlex.split(line, comments=True)
            while words:
                end = words.index("&&") if "&&" in words else len(words)
                said = " ".join(words[:end])
                command = SYNOPSES.get(said, shlex.join(words[:end]))
                found.setdefault(command, []).append(str(page.relative_to(REPO)))
                words = words[end + 1 :]
    return found


def listed(command: str, table: dict) -> str | None:
    """Why ``command`` is in ``table`` (a key it starts with), or None."""
    return next((why for key, why in table.items() if command.startswith(key)), None)


def test_every_listed_exception_is_still_documented():
    """A synopsis or an exception no page shows any more is dropped from its list."""
    shown = []
    for page in PAGES:
        for line in _shell_lines(page.read_text()):
            words = shlex.split(line, comments=True)
            shown += [" ".join(words)] + [" ".join(words[i + 1 :]) for i, w in enumerate(words) if w == "&&"]
    commands = set(doc_commands())
    assert [s for s in SYNOPSES if not any(line.startswith(s) for line in shown)] == []
    for table in (NOT_PARSED, NOT_RUN):
        assert [key for key in table if not any(c.startswith(key) for c in commands)] == []


class Parsed(BaseException):
    """Raised by a parser once it has parsed: the command goes no further."""

    def __init__(self, namespace):
        super().__init__()
        self.namespace = namespace


def _entry(words: list[str]):
    """The documented command's ``main`` and its arguments (None: not a program of ours)."""
    from godobject_drake.driver import process

    if words[0] == "godobject":
        return cli.main, words[1:]
    if words[0] == "godobject-driver":
        return process.main, words[1:]
    if words[:3] == ["python", "-m", "godobject_drake"]:
        return cli.main, words[3:]
    if words[:2] == ["python", "-m"] and words[2].startswith("godobject_drake."):
        return importlib.import_module(words[2]).main, words[3:]
    if words[0] == "python" and words[1].startswith(("diagrams/", "analysis/")):
        return load_script(words[1]).main, words[2:]
    if words[0] == "python" and words[1].startswith("examples/") and words[1].endswith(".py"):
        return _example(words[1]), words[2:]
    return None


def _example(path: str):
    """An example script (no parser: it runs as written): it must exist and be given nothing."""

    def main(argv):
        if not (REPO / path).is_file() or argv:
            print(f"{path} {' '.join(argv)}: no such example, or arguments it does not take", file=sys.stderr)
            raise SystemExit(2)
        raise SystemExit(0)

    return main


def _pip_failure(words: list[str]) -> str | None:
    """A ``pip install`` of this clone (``.``, ``-e .``, ``.[extras]``, ``dist/*.whl``): the extras
    must be pyproject's."""
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    targets = [w for w in words[words.index("install") + 1 :] if not w.startswith("-")]
    for target in targets:
        if target.startswith("dist/") and target.endswith(".whl"):
            continue
        if not target.startswith("."):
            return f"{target}: not this clone (PyPI has no {target}); install from the clone or a wheel"
        unknown = set(re.findall(r"\[(.*)\]", target)[0].split(",") if "[" in target else []) - set(extras)
        if unknown:
            return f"extras {sorted(unknown)} are not pyproject.toml's ({sorted(extras)})"
    return None


def parse_failure(command: str, capsys) -> str | None:
    """Why ``command`` does not parse (its program's own parser, a scene's flags applied to its
    scenario), or None. Run in the documents' folder (:func:`docs_folder`)."""
    words = shlex.split(command)
    if "install" in words and "pip" in words:
        return _pip_failure(words)
    entry = _entry(words)
    if entry is None:
        return "not a program of this project: parse it, or list it in NOT_PARSED with why"
    main, argv = entry
    original = argparse.ArgumentParser.parse_args

    def parse_args(self, args=None, namespace=None):
        raise Parsed(original(self, args, namespace))

    argparse.ArgumentParser.parse_args = parse_args
    try:
        main(argv)
    except Parsed as parsed:
        args = parsed.namespace
    except SystemExit as e:
        return None if e.code == 0 else capsys.readouterr().err.strip().splitlines()[-1]
    finally:
        argparse.ArgumentParser.parse_args = original
    if words[0] == "python" and words[1].startswith("diagrams/"):  # a scene script: its own scenario
        args.scenario = REPO / words[1].replace(".py", ".yaml")
    if isinstance(getattr(args, "scenario", None), Path) and hasattr(args, "set_fields"):
        try:
            cli.scenario_of(args.scenario, args)
        except Exception as e:
            return f"{type(e).__name__}: {e}"
    return None


@pytest.fixture(scope="module")
def docs_folder(tmp_path_factory) -> Path:
    """A folder as the docs' commands expect: the clone's diagrams/, models/, analysis/ and
    examples/, and the own-scene example's files beside them (README: "run it from its folder")."""
    folder = tmp_path_factory.mktemp("docs_commands")
    for name in ("diagrams", "models", "analysis", "examples"):
        (folder / name).symlink_to(REPO / name)
    for name in ("cube_post.yaml", "cube_post.sdf"):
        shutil.copy(EXAMPLES / name, folder / name)
    # the device logs the pages' --replay-devices commands read: a short session of the peg
    # transfer recorded here, under each name the pages give it
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    subprocess.run([sys.executable, "-m", "godobject_drake", "run", "peg_transfer", "--duration", "0.2",
                    "--no-progress", "--record-devices", "session.csv"], cwd=folder, env=env, check=True,
                   capture_output=True, timeout=300)  # fmt: skip
    for side in ("left", "right"):
        shutil.copy(folder / f"session.{side}.csv", folder / f"s01_haptic.{side}.csv")
    return folder


def test_every_documented_command_parses(docs_folder, monkeypatch, capsys):
    """Each command of README.md and docs/ is accepted by its program's own parser; a scene's
    command loads its scenario with its flags (`--set organs.model=fem` on a scene without organs
    fails here)."""
    monkeypatch.chdir(docs_folder)
    failures = {}
    for command, pages in doc_commands().items():
        if listed(command, NOT_PARSED) is None:
            failure = parse_failure(command, capsys)
            monkeypatch.chdir(docs_folder)
            if failure:
                failures[command] = f"{command}\n    ({', '.join(sorted(set(pages)))}): {failure}"
    assert not failures, "\n".join(failures.values())


def _runs() -> list[str]:
    return [c for c in doc_commands() if listed(c, NOT_PARSED) is None and listed(c, NOT_RUN) is None]


def shortened(command: str) -> list[str]:
    """The command's words as ``python -m`` runs them from this clone, shortened: a run to 0.2 s of
    simulated time, an analysis to its quick models (no Drake check)."""
    words = shlex.split(command)
    if words[0] == "godobject":
        words = [sys.executable, "-m", "godobject_drake", *words[1:]]
    elif words[0] == "python":
        words[0] = sys.executable
    if "run" in words[:4] or words[1].startswith("diagrams/"):
        return [*words, "--duration", "0.2", "--no-progress"]
    if "analyze" in words[:4]:
        return [*words, "--quick", "--no-verify"]
    return words


@pytest.mark.slow(seconds=5)
@pytest.mark.parametrize("command", _runs())
def test_every_documented_command_runs(command, docs_folder):
    """The command runs to its end, exit status 0, shortened (:func:`shortened`), from the
    documents' folder, on this clone's code."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}  # this clone's code, whatever is installed
    done = subprocess.run(shortened(command), cwd=docs_folder, env=env, capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]


def test_the_driver_commands_the_code_prints_parse(capsys):
    """The ``godobject-driver`` commands the package and the scenario files tell a user to type
    (the scene's hint while it waits for its driver, the driver's own docstring) parse by the
    driver's parser: a hint once named --lcm-url, which the driver does not have."""
    sources = [*(REPO / "godobject_drake").rglob("*.py"), *(REPO / "diagrams").glob("*.yaml")]
    commands = []
    for source in sources:
        for found in re.findall(r"godobject-driver (?:run|calibrate) [^\n,()\"`#]*", source.read_text()):
            if "{args" in found:  # the calibrated file's comment, not a command to type
                continue
            command = re.sub(r"\{url\}|%s", "udp://127.0.0.1:7667", found.replace("[", "").replace("]", ""))
            commands.append(re.sub(r"\b(FAMILY|KIND)\b", "emulated", command).strip())
    assert len(commands) >= 4
    assert {c: f for c in commands if (f := parse_failure(c, capsys))} == {}


def test_each_kind_of_user_has_a_way_in():
    """Issue 56 item 5: the docs' index and navigation open a way in for a haptics lab, a
    surgical-simulation team and a Drake user, each section's first page the one that takes them
    from the install to a first result; "where to go next" names the haptic devices and the
    laparoscopy."""
    import yaml

    nav = yaml.safe_load((REPO / "mkdocs.yml").read_text())["nav"]
    sections = {name: pages for entry in nav for name, pages in entry.items()}
    first = {name: next(iter(sections[name][0].values())) for name in
             ("Haptics lab", "Surgical simulation", "Drake diagrams")}  # fmt: skip
    assert first == {"Haptics lab": "guide/start_haptics.md",
                     "Surgical simulation": "guide/start_surgical.md",
                     "Drake diagrams": "guide/start_drake.md"}  # fmt: skip
    index = (REPO / "docs" / "index.md").read_text()
    start, after = index.split("## Where to start")[1].split("## Where to go next")
    assert all(f"]({page})" in start for page in first.values())
    assert "](haptic_devices.md)" in after and "](guide/laparoscopy.md)" in after
    for page in first.values():  # from the install to a first result: each opens with the install
        text = (REPO / "docs" / page).read_text()
        assert text.index("python -m pip install -e .") < text.index("## Next")


def guarded_table_tests() -> list[tuple[str, str]]:
    """Each (test, file) the "What is guarded" table of docs/haptic_devices.md names: a row's last
    cell names its tests in backticks, in ``tests/test_pairing.py`` unless a file follows them."""
    text = (REPO / "docs" / "haptic_devices.md").read_text()
    start = text.index("**What is guarded**")
    table = text[start : text.index("**What is not guarded**", start)]
    named = []
    for row in table.splitlines():
        if not row.startswith("| ") or row.startswith("|---"):
            continue
        cell = row.rstrip(" |").rsplit(" | ", 1)[-1]
        # "`a`, `b` (`tests/x.py`); `c`": a and b in x, c in tests/test_pairing.py
        pending = []
        for token in re.findall(r"`(test_\w+|tests/[\w/]+\.py)`|(;)", cell):
            name, stop = token
            if name.startswith("tests/"):
                named += [(test, name) for test in pending]
                pending = []
            elif name:
                pending.append(name)
            elif stop:
                named += [(test, "tests/test_pairing.py") for test in pending]
                pending = []
        named += [(test, "tests/test_pairing.py") for test in pending]
    return named


def test_every_test_the_guarded_table_names_is_in_the_file_it_names():
    named = guarded_table_tests()
    assert len(named) >= 40  # the table's rows, each naming at least one
    missing = [
        f"{name} ({file})"
        for name, file in named
        if not re.search(rf"^def {name}\(", (REPO / file).read_text(), flags=re.M)
    ]
    assert not missing, f"the table names tests that are not there: {missing}"
