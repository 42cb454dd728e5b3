"""docs/scenario.md, the scenario reference, is generated from the config dataclasses
(analysis/scenario_reference.py): it must be fresh, and each of its examples must load onto the
shipped scene it names."""

import dataclasses
import runpy

from conftest import REPO, assert_refused

from godobject_drake.config.scene import Workspace

reference = runpy.run_path(str(REPO / "analysis" / "scenario_reference.py"))


def test_the_scenario_reference_is_fresh():
    assert (REPO / "docs" / "scenario.md").read_text() == reference["page"](), (
        "docs/scenario.md is stale: run python analysis/scenario_reference.py"
    )


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
