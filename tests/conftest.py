"""Shared fixtures and helpers: the shipped scenes by name, a guarded run, a one-body plant.

The shipped scenes are run as a user runs them: their scenario file, the command line's
flags applied to it (``godobject_drake.cli.apply_arguments``), built and simulated by the
library. The scripts under ``diagrams/`` and ``analysis/`` are not installed; a test that
needs one imports it by path with :func:`load_script` (the package itself never does).
"""

import argparse
import base64
import dataclasses
import gc
import importlib.util
import logging
import os
import re
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import RotationalInertia, SpatialInertia, UnitInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake import cli
from godobject_drake.config.scenario import Scenario, load_scenario, scenario_to_yaml
from godobject_drake.safeguards import DivergenceError, Safeguards, install_safeguards
from godobject_drake.simulation import RunResult, simulate
from godobject_drake.station.build import build_station, make_meshcat

REPO = Path(__file__).resolve().parent.parent

# The processes the tests start get SIGHUP's default disposition, as a process started from a
# terminal does: a suite run under ``nohup`` (SIGHUP ignored, inherited by every child) would
# otherwise make each scene and driver outlive its SIGHUP, as they rightly do for a user who
# asked for nohup, and the tests that send SIGHUP to see them end would fail for that alone
# (seen: three of them, in a CI run started with nohup). The nohup test sets SIG_IGN itself.
signal.signal(signal.SIGHUP, signal.SIG_DFL)


@pytest.fixture(autouse=True)
def _collect_on_the_main_thread():
    """Each test's garbage collected after it, on the main thread. Once in a fast-tier run the
    garbage collector ran inside a thread a test had just started (test_pairing's driver thread)
    and the process aborted there ("Fatal Python error: Aborted ... Garbage-collecting", the
    pytest-xdist worker lost): a Drake object an earlier test left in a reference cycle (Meshcat
    is one that must be used on the thread that made it) destroyed off its thread."""
    yield
    gc.collect()


EXAMPLES = REPO / "examples"
SCENES = ("lego", "laparoscopy", "deformable_probe")


def load_script(relative: str):
    """Import a script of the clone (``diagrams/lego.py``, ``analysis/...``) by path, as python runs it."""
    path = REPO / relative
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def scenario(name: str, *flags: str) -> Scenario:
    """A shipped scene's scenario (``diagrams/NAME.yaml``) with command-line ``flags`` applied."""
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    return cli.apply_arguments(
        load_scenario(REPO / "diagrams" / f"{name}.yaml"), parser.parse_args(list(flags))
    )


def build_scene(name: str, *flags: str):
    """:func:`scenario`, built (with the Meshcat it asks for)."""
    s = scenario(name, *flags)
    return build_station(s, make_meshcat(s))


def run_scene(name: str, *flags: str) -> RunResult:
    """A shipped scene run as ``python diagrams/NAME.py FLAGS`` runs it, without the progress bar."""
    return simulate(build_scene(name, *flags), progress=False)


def lego_run(*flags: str) -> RunResult:
    return run_scene("lego", *flags)


_SHARED_RUNS: dict[str, RunResult] = {}


def shared_run(name: str, *flags: str) -> RunResult:
    """:func:`run_scene`, run once a session (once a pytest-xdist worker) for each scenario the
    flags make, however they spell it: the tests that read the same run (a scene's default path,
    say, in test_lego, test_long_runs and test_sleeping) share it instead of each simulating it
    again. What it returns is shared: read it, never change it."""
    s = scenario(name, *flags)
    key = scenario_to_yaml(s)
    if key not in _SHARED_RUNS:
        _SHARED_RUNS[key] = simulate(build_station(s, make_meshcat(s)), progress=False)
    return _SHARED_RUNS[key]


@dataclasses.dataclass
class Guarded:
    """A plain ``Simulator`` run with the safeguards installed: where it stopped and why."""

    simulator: Simulator
    safeguards: Safeguards
    diagnosis: str | None

    @property
    def context(self):
        return self.simulator.get_context()

    @property
    def sim_time_s(self) -> float:
        return self.context.get_time()


def run_guarded(diagram, duration: float, **safeguards) -> Guarded:
    """``Simulator(diagram)`` with :func:`install_safeguards`, advanced ``duration`` s; a divergence
    ends the run with its diagnosis instead of raising."""
    simulator = Simulator(diagram)
    guard = install_safeguards(simulator, **safeguards)
    try:
        simulator.AdvanceTo(duration)
        guard.check()
    except DivergenceError:
        pass
    return Guarded(simulator, guard, guard.diagnosis)


def add_free_boxes(
    builder: DiagramBuilder, time_step: float, masses=(0.5,), inertia_diag=(1e-3, 2e-3, 3e-3), gravity=True
):
    """A plant with free bodies (no geometry), finalized. Returns (plant, bodies)."""
    plant = MultibodyPlant(time_step)
    if not gravity:
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    scene_graph = builder.AddSystem(SceneGraph())
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    builder.AddSystem(plant)
    builder.Connect(
        plant.get_geometry_pose_output_port(), scene_graph.get_source_pose_port(plant.get_source_id())
    )
    builder.Connect(scene_graph.get_query_output_port(), plant.get_geometry_query_input_port())
    bodies = []
    for i, m in enumerate(masses):
        M = SpatialInertia(m, np.zeros(3), UnitInertia(*(np.array(inertia_diag) / m)))
        expected = RotationalInertia(*inertia_diag).CopyToFullMatrix3()
        assert np.allclose(M.CalcRotationalInertia().CopyToFullMatrix3(), expected)
        bodies.append(plant.AddRigidBody(f"body_{i}", M))
    plant.Finalize()
    return plant, bodies


def meshcat_commands(html: str) -> list[bytes]:
    """The msgpack commands a Meshcat static HTML replays (as raw bytes)."""
    payloads = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [base64.b64decode(p) for p in payloads]


class _DrakeDeprecations(logging.Handler):
    """Collects what Drake's C++ side logs about deprecations (pydrake forwards it to ``drake``)."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []

    def emit(self, record):
        message = record.getMessage()
        if "deprecat" in message.lower():
            self.messages.append(message)


DRAKE_DEPRECATIONS = _DrakeDeprecations()
logging.getLogger("drake").addHandler(DRAKE_DEPRECATIONS)


@pytest.fixture(autouse=True)
def no_drake_deprecation_logged():
    """Fail a test during which Drake logged a deprecation (the Python ones are errors already:
    pyproject.toml's filterwarnings)."""
    seen = len(DRAKE_DEPRECATIONS.messages)
    yield
    new = DRAKE_DEPRECATIONS.messages[seen:]
    assert not new, f"Drake logged a deprecation: {new}"


@pytest.fixture(autouse=True, scope="session")
def link_key(tmp_path_factory):
    """The tests' own link key (``udp://`` links pair with it, godobject_drake.link.keys): a file
    of this session (in a folder of mode 0700), never the user's ~/.config/godobject/link.key.
    Processes the tests start inherit it through ``$GODOBJECT_LINK_KEY``."""
    path = tmp_path_factory.mktemp("link", numbered=True) / "link.key"
    previous = os.environ.get("GODOBJECT_LINK_KEY")
    os.environ["GODOBJECT_LINK_KEY"] = str(path)
    yield path
    if previous is None:
        os.environ.pop("GODOBJECT_LINK_KEY", None)
    else:
        os.environ["GODOBJECT_LINK_KEY"] = previous


def assert_refused(call, error, *, value: str, limit: str, fix: str) -> str:
    """``call()`` raises ``error`` whose message names the bad value, the limit it breaks and the
    fix (each a regular expression); returns the message. One check for every refusal test."""
    with pytest.raises(error) as raised:
        call()
    message = str(raised.value)
    for what, pattern in (("value", value), ("limit", limit), ("fix", fix)):
        assert re.search(pattern, message), f"the refusal does not name the {what} ({pattern!r}): {message}"
    return message


def own_scene_files(tmp_path) -> str:
    """The README's own scene (``examples/cube_post.yaml`` and ``cube_post.sdf``), copied to
    ``tmp_path`` as a user copies them; returns the command that runs it (the example's own)."""
    for name in ("cube_post.yaml", "cube_post.sdf"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    return "godobject run cube_post.yaml --record cube_post.html --metrics cube_post.json"


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist (``-n``), the tests whose ``slow`` mark gives their ``seconds`` start
    first, longest first; the rest keep their order. xdist's ``worksteal`` gives each worker half
    of the list and lets an idle one take the back half of another's queue, but cannot split a
    running test: the 10-minute random-motion run (340 s, a third of the suite on one core)
    begun last would end the run 340 s after everything else. A plain ``pytest`` keeps the file
    order."""
    if not hasattr(config, "workerinput"):  # not an xdist worker
        return

    def seconds(item):
        mark = item.get_closest_marker("slow")
        return mark.kwargs.get("seconds", 0) if mark else 0

    items.sort(key=seconds, reverse=True)  # stable: equal keys keep their order
