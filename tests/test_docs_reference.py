"""docs/scenario.md, the scenario reference, is generated from the config dataclasses
(analysis/scenario_reference.py): it must be fresh, and each of its examples must load onto the
shipped scene it names."""

import dataclasses
import runpy

from conftest import REPO

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
