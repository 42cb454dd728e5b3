"""CI mutates only the goal units changed since the last whole run (analysis/mutation_report.py):
what counts as a change is checked here on a copy of the package, one edit at a time."""

import importlib.util
import json
import shutil

import pytest
from conftest import REPO

spec = importlib.util.spec_from_file_location("mutation_report", REPO / "analysis" / "mutation_report.py")
report = importlib.util.module_from_spec(spec)
spec.loader.exec_module(report)


@pytest.fixture
def root(tmp_path):
    """A copy of what the record hashes: the package, pyproject.toml and two test files."""
    shutil.copytree(REPO / "godobject_drake", tmp_path / "godobject_drake")
    shutil.copy(REPO / "pyproject.toml", tmp_path)
    (tmp_path / "tests").mkdir()
    for name in ("conftest.py", "test_spatial.py"):
        shutil.copy(REPO / "tests" / name, tmp_path / "tests")
    return tmp_path


def record_of(root) -> dict:
    """A record as ``--record`` writes it, every unit covered by tests/test_spatial.py."""
    tests = report.file_hashes(["tests/conftest.py", "tests/test_spatial.py"], root)
    units = {
        u: {"source": h, "tests": tests, "mutants": 10, "killed": 9}
        for u, h in report.unit_sources(root).items()
    }
    return {"recorded": "2026-12-04", "configuration": report.configuration(root), "units": units}


def edit(path, old, new):
    text = path.read_text()
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new))


def test_every_goal_unit_has_code_and_a_distinct_hash():
    sources = report.unit_sources()
    assert set(sources) == set(report.UNITS)
    empty = report._sha(b"")
    assert [u for u, h in sources.items() if h == empty] == []  # each unit names functions that exist
    assert len(set(sources.values())) == len(sources)


def test_an_unchanged_tree_runs_nothing(root):
    assert report.changed_units(record_of(root), root) == {}


def test_a_changed_function_runs_its_unit_only(root):
    baseline = record_of(root)
    edit(
        root / "godobject_drake" / "spatial.py", "def quat_conjugate(", "def quat_conjugate(  # edited\n    "
    )
    assert report.changed_units(baseline, root) == {"spatial math": "its source changed"}


def test_a_method_of_one_class_runs_the_unit_that_owns_it(root):
    baseline = record_of(root)
    edit(
        root / "godobject_drake" / "driver" / "safety.py",
        "class FeedbackGate",
        "# a comment\nclass FeedbackGate",
    )
    assert report.changed_units(baseline, root) == {}  # a comment outside every function
    source = (root / "godobject_drake" / "driver" / "safety.py").read_text()
    assert "class FeedbackGate" in source and "    def __init__(" in source
    head = source.index("class FeedbackGate")
    init = source.index("    def __init__(", head)
    source = source[:init] + "    def __init__(  # edited\n" + source[init + len("    def __init__(") :]
    (root / "godobject_drake" / "driver" / "safety.py").write_text(source)
    assert report.changed_units(baseline, root) == {"driver: watchdog and stop": "its source changed"}


def test_a_changed_or_missing_test_file_runs_the_units_it_covers(root):
    baseline = record_of(root)
    baseline["units"]["feedback port"]["tests"] = report.file_hashes(["tests/conftest.py"], root)
    (root / "tests" / "test_spatial.py").write_text("# emptied\n")
    changed = report.changed_units(baseline, root)
    assert "feedback port" not in changed  # its tests are conftest.py alone
    assert changed["spatial math"] == "its tests changed: tests/test_spatial.py"
    (root / "tests" / "test_spatial.py").unlink()
    assert report.file_hashes(["tests/test_spatial.py"], root) == {"tests/test_spatial.py": "missing"}


def test_another_configuration_or_no_record_runs_every_unit(root):
    baseline = record_of(root)
    edit(
        root / "pyproject.toml", '"tests/test_spatial.py",', '"tests/test_spatial.py", "tests/test_link.py",'
    )
    changed = report.changed_units(baseline, root)
    assert set(changed) == set(report.UNITS) and "configuration" in changed["spatial math"]
    assert set(report.changed_units(None, root)) == set(report.UNITS)


def test_the_shipped_record_covers_every_unit_at_the_goal():
    record = json.loads(report.BASELINE.read_text())
    assert set(record["units"]) == set(report.UNITS)
    for unit, r in record["units"].items():
        assert r["killed"] >= 0.85 * r["mutants"] > 0, unit
        assert "tests/conftest.py" in r["tests"], unit
