"""One build path: every entry point builds the scenario its flags say, through ``build_station``.

The command line's ``run`` and ``analyze``, each scene's script (``diagrams/NAME.py``), the
library (a scenario changed in Python) and the speed benchmark's cases are given the same two
changes, a coupling (``--coupling implicit`` on the brick scene, ``joint_pd_sap`` on the
laparoscopy scene) and a feedback stiffness (``--set feedback.kd=7``), and what reaches
``station.build.finish`` is caught there before anything runs: the scenario, and the tool as
built (its coupling system and its feedback port's gains). Each must have built both changes, and
``run``, the script, the library and the benchmark from the very same scenario. The
deformable probe has no coupling field: ``--coupling`` is refused alike everywhere, naming the
kinds that have it. (Once, ``python diagrams/lego.py --coupling implicit`` ran the explicit
coupling and ``diagrams/laparoscopy.py`` dropped the feedback gains.)
"""

import pytest
from conftest import REPO, load_script

from godobject_drake import cli
from godobject_drake.config.scenario import ScenarioError, replace, scenario_to_yaml, shipped_scenario
from godobject_drake.station import build
from godobject_drake.studies import benchmark
from godobject_drake.systems.implicit import ImplicitCoupling

COUPLING = {"lego": "implicit", "laparoscopy": "joint_pd_sap", "deformable_probe": None}


class Caught(BaseException):
    """Raised where the station is finished: past every ``except Exception`` of the entry points."""

    def __init__(self, scenario, god):
        super().__init__()
        self.scenario, self.god = scenario, god


@pytest.fixture
def catch(monkeypatch):
    def finish(builder, scenario, scene, tools, meshcat, records):
        (god,) = tools.values()  # a scene of one tool: its tool, by the name ""
        raise Caught(scenario, god)

    monkeypatch.setattr(build, "_finish", finish)


def caught(call):
    with pytest.raises(Caught) as got:
        call()
    return got.value


def entry_points(name: str, tmp_path, flags: list[str], library_changes: dict):
    """Each entry point, as a call that builds ``name`` with the changes."""
    script = load_script(f"diagrams/{name}.py")
    changed = replace(shipped_scenario(name), **library_changes)
    return {
        "run": lambda: cli.main(["run", name, "--no-progress", *flags]),
        "script": lambda: script.main(["--no-progress", *flags]),
        "analyze": lambda: cli.main(["analyze", name, "--out", str(tmp_path / "a"), "--quick", *flags]),
        "library": lambda: build.build_station(changed),
        "benchmark": lambda: benchmark.run_case(benchmark.make_case(changed, repeats=1)),
    }


@pytest.mark.parametrize("name", ["lego", "laparoscopy"])
def test_every_entry_point_honours_the_coupling_and_the_feedback_gain(name, tmp_path, catch):
    flags = ["--coupling", COUPLING[name], "--set", "feedback.kd=7"]
    changes = {"god_object.coupling": COUPLING[name], "feedback.kd": 7.0}
    built = {key: caught(call) for key, call in entry_points(name, tmp_path, flags, changes).items()}
    for key, got in built.items():
        s, god = got.scenario, got.god
        assert (s.god_object.coupling, s.feedback.kd) == (COUPLING[name], 7.0), key
        assert god.feedback.gains.kd == 7.0, key  # the built feedback port's own gain
        if name == "lego":  # the coupling as built: SAP's springs, no Python force per step
            assert isinstance(god.coupling, ImplicitCoupling), key
        else:
            assert god.coupling.coupling == "joint_pd_sap", key
    same = {key: scenario_to_yaml(built[key].scenario) for key in ("run", "script", "library", "benchmark")}
    assert len(set(same.values())) == 1, [k for k in same if same[k] != same["run"]]


def test_a_flag_the_tool_has_not_is_refused_alike_everywhere(tmp_path, capsys):
    """The deformable probe has no coupling field: run, the script and analyze refuse --coupling
    with the same words, exit status 2; nothing is built."""
    flags = ["--coupling", "implicit"]
    calls = entry_points("deformable_probe", tmp_path, flags, {})
    said = set()
    for key in ("run", "script", "analyze"):
        with pytest.raises(SystemExit) as exit_:
            calls[key]()
        assert exit_.value.code == 2, key
        said.add(capsys.readouterr().err.split("error: ", 1)[1].strip())
    assert said == {
        "--coupling: sets god_object.coupling, which the scenario's !Deformable god_object has not; it is "
        "for !Rigid, !Articulated"
    }
    with pytest.raises(ScenarioError):  # the library: the same refusal, as an exception
        cli.apply_arguments(shipped_scenario("deformable_probe"), _parse(flags))


def _parse(flags):
    import argparse

    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    return parser.parse_args(flags)


def test_the_scripts_are_the_command_lines_run():
    """A scene script holds no wiring of its own: it is ``run`` on its scenario file."""
    for name in ("lego", "laparoscopy", "deformable_probe"):
        text = (REPO / "diagrams" / f"{name}.py").read_text()
        assert "cli.scene_main(SCENARIO" in text and "DiagramBuilder" not in text, name
