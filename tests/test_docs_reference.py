"""docs/scenario.md, the scenario reference, is generated from the config dataclasses
(analysis/scenario_reference.py), and docs/guide/flags.md's scenes and flags tables from the code
(analysis/flags_reference.py): each must be fresh, and each example of the reference must load
onto the shipped scene it names. References to a section name one that exists; the guides and
the help are in the present tense."""

import dataclasses
import re
import runpy
import subprocess
import sys
import unicodedata
from pathlib import Path

import pytest
from conftest import REPO, assert_refused, load_script

from godobject_drake.config.scene import Workspace

reference = runpy.run_path(str(REPO / "analysis" / "scenario_reference.py"))


def test_the_scenario_reference_is_fresh():
    assert (REPO / "docs" / "scenario.md").read_text() == reference["page"](), (
        "docs/scenario.md is stale: run python analysis/scenario_reference.py"
    )


def test_the_scenes_and_flags_tables_are_fresh():
    """docs/guide/flags.md's two tables are the code's: every shipped scenario file and every flag.
    Made in a process of its own: a device kind a test registers (tests/test_device_kinds.py) is
    offered by ``--device`` in the process that registered it, and is no shipped kind."""
    page = (REPO / "docs" / "guide" / "flags.md").read_text()
    made = subprocess.run(
        [sys.executable, "-c", "import runpy, sys; sys.stdout.write(runpy.run_path(sys.argv[1])['page']())",
         str(REPO / "analysis" / "flags_reference.py")],
        capture_output=True, text=True, check=True, cwd=REPO,
    )  # fmt: skip
    assert page == made.stdout, "docs/guide/flags.md is stale: run python analysis/flags_reference.py"
    scenes = {path.stem for path in (REPO / "diagrams").glob("*.yaml")}
    assert len(scenes) == 10 and all(f"| `{name}` |" in page for name in scenes)


def test_every_example_of_the_reference_loads():
    assert reference["check_examples"]() == []


def test_every_kind_has_its_section_with_every_field():
    """Each device and tool kind (the registries') has a section listing each of its fields."""
    text = (REPO / "docs" / "scenario.md").read_text()
    sections = {s.split("\n", 1)[0]: s for s in text.split("\n## ")[1:]}
    for cls in reference["classes"]():
        section = sections[cls.__name__]
        for field in dataclasses.fields(cls):
            if not field.name.startswith("_"):
                assert f"| `{field.name}` |" in section, (cls.__name__, field.name)
    assert "{t: 0.0, values: {yaw: 0.0" in sections["ScriptedJoints"]  # inline joint waypoints


def test_every_field_has_a_meaning():
    """Each field of every section has an Attributes entry in its class's docstring (or a base's):
    the reference's meaning column is never empty (issue 46 item 3)."""
    assert reference["undocumented"]() == []


def test_a_workspace_upside_down_is_refused():
    """The reference says upper_m is above lower_m in each coordinate: a box given the wrong way
    round (z swapped) is refused naming both corners, the axis and the fix."""
    assert_refused(
        Workspace(lower_m=[-0.1, -0.1, 0.1], upper_m=[0.1, 0.1, 0.0]).check,
        ValueError,
        value=r"upper_m: \[0\.1, 0\.1, 0\.0\]",
        limit=r"not above lower_m: \[-0\.1, -0\.1, 0\.1\] in z",
        fix="lowest corner as lower_m",
    )
    Workspace().check()  # the default box is the right way round


# --- References to a section (issue 56 item 3) -------------------------------------------------
# README.md "Title", README's "Title", PAGE.md "Title" (a heading's start) and PAGE.md#anchor, in
# the docs, the docstrings, the help strings, the scenarios' and the models' comments, each names a
# heading that exists: a section moved or renamed leaves no pointer to nowhere.

SOURCES = [
    REPO / "README.md",
    *(REPO / "docs").rglob("*.md"),
    *(
        p
        for folder in ("godobject_drake", "diagrams", "analysis", "examples", "tests")
        for p in (REPO / folder).rglob("*.py")
    ),
    *(
        p
        for folder in ("diagrams", "models", "examples")
        for ext in ("yaml", "sdf")
        for p in (REPO / folder).rglob(f"*.{ext}")
    ),
]
README_SECTION = re.compile(r"README(?:\.md)?(?:'s)?(?:\s+section)?\s+\"([^\"]+)\"")
ANCHOR = re.compile(r"([\w./-]+\.md)#([\w-]+)")
PAGE_SECTION = re.compile(r"([\w./-]+\.md)\)?,?\s+\"([^\"]+)\"")  # docs/design.md "Adding a tool kind"


def slug(heading: str) -> str:
    """A heading's anchor as MkDocs makes it (Python-Markdown's toc slugify)."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode()
    text = re.sub(r"[^\w\s-]", "", re.sub(r"\[([^]]*)\]\([^)]*\)", r"\1", text)).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def headings(page: Path) -> list[str]:
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)
    return [h.strip() for h in re.findall(r"^#{1,6} (.+)$", text, flags=re.M)]


def dangling_references() -> list[str]:
    readme = [" ".join(h.split()) for h in headings(REPO / "README.md")]
    found = []
    for source in SOURCES:
        if source == Path(__file__):  # this file's own examples
            continue
        if source == REPO / "analysis" / "flags_reference.py":  # its links are flags.md's, checked there
            continue
        text = source.read_text()
        where = source.relative_to(REPO)
        for title in README_SECTION.findall(text):
            if " ".join(title.split()) not in readme:
                found.append(f'{where}: README "{title}" is not a heading of README.md')
        for page, anchor in ANCHOR.findall(text):
            target = _page(source, page)
            if not target.exists():
                found.append(f"{where}: {page} does not exist")
            elif anchor not in {slug(h) for h in headings(target)}:
                found.append(f"{where}: {page}#{anchor} is not a heading of {page}")
        for page, title in PAGE_SECTION.findall(text):
            target, title = _page(source, page), " ".join(title.split())
            if page != "README.md" and not any(h.startswith(title) for h in _plain_headings(target)):
                found.append(f'{where}: {page} "{title}" does not start a heading of {page}')
    return found


def _page(source: Path, page: str) -> Path:
    """``page`` as ``source`` names it: beside a Markdown page, else from the clone's root."""
    near = source.parent / page
    return near if source.suffix == ".md" and near.exists() else REPO / page


def _plain_headings(page: Path) -> list[str]:
    return [" ".join(h.replace("`", "").split()) for h in headings(page)] if page.exists() else []


def test_every_reference_to_a_section_names_one_that_exists():
    assert dangling_references() == []


# --- The present tense (issue 56 item 6) ------------------------------------------------------
# The guides, the pages beside them and the help say what holds today; a measurement keeps its
# date and its command in docs/results.md, which alone may tell what came before.

PAST = re.compile(
    r"(?<!Drake )\bissue #?\d+|\bused to\b|\bthis round\b|\bwe changed\b|\bno longer\b"
    r"|\bbefore this\b|\bas before\b|\bnow\b",
    flags=re.I,
)


def narration(text: str) -> list[str]:
    """The lines of ``text`` (its code blocks and table rows aside) that tell of an earlier state."""
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return [line for line in prose.splitlines() if not line.lstrip().startswith("|") and PAST.search(line)]


def test_the_guides_say_what_holds_today():
    pages = [REPO / "README.md", *(REPO / "docs").rglob("*.md")]
    found = {
        str(page.relative_to(REPO)): narration(page.read_text())
        for page in pages
        if page.name != "results.md"
    }
    assert {page: lines for page, lines in found.items() if lines} == {}


def test_the_help_says_what_holds_today(capsys):
    """``godobject``'s, ``godobject-driver``'s and each scene script's ``--help``."""
    from godobject_drake import cli
    from godobject_drake.driver import process

    paths = [path for path in (REPO / "diagrams").glob("*.py") if path.stem != "__init__"]
    scripts = [load_script(f"diagrams/{path.name}").main for path in paths]
    for main, argv in (
        (cli.main, ["--help"]),
        (cli.main, ["run", "--help"]),
        (cli.main, ["analyze", "--help"]),
        (process.main, ["--help"]),
        (process.main, ["run", "--help"]),
        (process.main, ["calibrate", "--help"]),
        *((main, ["--help"]) for main in scripts),
    ):
        with pytest.raises(SystemExit):
            main(argv)
    assert narration(capsys.readouterr().out) == []
