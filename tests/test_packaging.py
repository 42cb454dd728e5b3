"""The installed package carries what it runs: the models, the shipped scenarios, package.xml,
py.typed, and the ``godobject`` console script (CI builds the wheel and the sdist and runs them
from a folder outside the clone: .ci/run)."""

import fnmatch
import importlib.metadata
import importlib.resources
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from conftest import REPO

import godobject_drake
from godobject_drake import cli
from godobject_drake.config import scenario as sc
from godobject_drake.config.scenario import load_scenario
from godobject_drake.station import plant as scenes
from godobject_drake.station.build import build_station

PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]


def tracked(folder: str) -> list[str]:
    out = subprocess.run(["git", "ls-files", folder], cwd=REPO, capture_output=True, text=True)
    if out.returncode != 0:
        pytest.skip("not a git clone (an unpacked sdist)")
    return out.stdout.split()


@pytest.mark.parametrize("package", ["godobject_models", "godobject_scenarios"])
def test_every_data_file_of_a_data_package_is_in_the_wheel(package):
    """Each tracked file of models/ and diagrams/ is a module or matches the package's
    package-data globs: a new model file type cannot be left out of the wheel unnoticed."""
    folder = SETUPTOOLS["package-dir"][package]
    globs = SETUPTOOLS["package-data"][package]
    files = [Path(f).relative_to(folder).as_posix() for f in tracked(folder)]
    missing = [f for f in files if not f.endswith(".py") and not any(fnmatch.fnmatch(f, g) for g in globs)]
    assert files and not missing, f"not package data of {package}: {missing}"


def test_the_data_packages_are_found_with_importlib_resources():
    assert scenes.MODELS_DIR == Path(str(importlib.resources.files("godobject_models")))
    assert (scenes.MODELS_DIR / "package.xml").is_file()
    scenarios = Path(str(importlib.resources.files("godobject_scenarios")))
    for name in sc.SHIPPED:
        assert sc.shipped_scenario_file(name).parent == scenarios
        for view in sc.shipped_scenario(name).per_tool().values():  # each tool's device path
            if not hasattr(view.device, "path"):
                continue  # a driver's device (lego_driver): its samples come over the link
            assert Path(view.device.path).is_relative_to(scenes.MODELS_DIR)  # inside the installed models
            assert Path(view.device.path).is_file()
    with pytest.raises(sc.ScenarioError, match="no shipped scene 'cube'; the shipped scenes are lego, "):
        sc.shipped_scenario_file("cube")


def test_a_shipped_scene_by_name_unless_a_file_of_that_name_is_here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.scenario_path("lego") == sc.shipped_scenario_file("lego")
    (tmp_path / "lego").write_text("")
    assert cli.scenario_path("lego") == Path("lego")
    assert cli.scenario_path("my.yaml") == Path("my.yaml")


def test_an_own_scene_needs_no_package_xml_of_ours(monkeypatch):
    """examples/cube_post.yaml has no package:// URL: it builds with the models folder gone."""
    monkeypatch.setattr(scenes, "MODELS_DIR", Path("/nonexistent"))
    station = build_station(load_scenario(REPO / "examples" / "cube_post.yaml"))
    assert station.plant.GetBodyByName("cube").default_mass() == pytest.approx(0.2)


def test_version_is_the_installed_distributions():
    assert godobject_drake.__version__ == importlib.metadata.version("godobject_drake")
    assert PYPROJECT["project"]["scripts"]["godobject"] == "godobject_drake.cli:console_main"
    out = subprocess.run([sys.executable, "-m", "godobject_drake", "--version"], capture_output=True,
                         text=True, check=True).stdout  # fmt: skip
    assert out.startswith(f"godobject_drake {godobject_drake.__version__} (drake ")
    assert importlib.metadata.version("drake") in out


def test_py_typed_and_license_ship():
    assert (Path(godobject_drake.__file__).parent / "py.typed").is_file()
    assert "py.typed" in SETUPTOOLS["package-data"]["godobject_drake"]
    assert (REPO / "LICENSE").read_text().startswith("BSD 3-Clause License")
    assert PYPROJECT["project"]["license"] == "BSD-3-Clause" and PYPROJECT["project"]["license-files"] == [
        "LICENSE"
    ]


def test_every_model_folder_is_a_listed_package():
    """setuptools ships models/'s folders as package data of godobject_models only when they are
    listed packages (otherwise it warns that this is deprecated)."""
    folders = {p.name for p in (REPO / "models").iterdir() if p.is_dir() and p.name != "__pycache__"}
    listed = {
        name.split(".", 1)[1] for name in SETUPTOOLS["packages"] if name.startswith("godobject_models.")
    }
    assert folders == listed


def test_every_code_package_is_listed_and_every_listed_one_exists():
    """setuptools ships the listed packages only, and stops the install (editable too) at a listed
    one whose folder is gone: each folder of godobject_drake/ with an __init__.py is listed, and
    nothing listed under godobject_drake is missing."""
    root = REPO / "godobject_drake"
    inits = [p for p in root.rglob("__init__.py") if "__pycache__" not in p.parts]
    folders = {".".join(p.parent.relative_to(REPO).parts) for p in inits}
    listed = {name for name in SETUPTOOLS["packages"] if name.startswith("godobject_drake")}
    assert folders == listed, f"listed, no package: {listed - folders}; not listed: {folders - listed}"
