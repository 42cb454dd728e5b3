"""The command line's conventions (issue 29, item 2): plain help, errors without the usage block,
``--set`` for any field, a logger with -v/-q, and nothing on stderr that a log file should not hold."""

import io
import json
import logging
import pydoc
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO, load_script

import godobject_drake
from godobject_drake import cli
from godobject_drake.config import scenario as sc
from godobject_drake.link.logs import StderrHandler

MARKUP = ("``", ":func:", ":mod:", ":class:")


def help_text(capsys, argv, main=cli.main) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["analyze", "--help"]])
def test_help_is_plain_text(capsys, argv):
    text = help_text(capsys, argv)
    assert not [m for m in MARKUP if m in text], text


def test_a_scene_scripts_help_is_plain_text(capsys):
    script = load_script("diagrams/laparoscopy.py")  # its docstring has ``--coupling`` markup
    text = help_text(capsys, ["--help"], script.main)
    assert "--coupling picks" in text and not [m for m in MARKUP if m in text]


def test_analyze_takes_only_the_flags_it_uses(capsys):
    analyze, run = help_text(capsys, ["analyze", "--help"]), help_text(capsys, ["run", "--help"])
    for flag in cli.RUN_ONLY_FLAGS:
        assert f"{flag} " in run and f"{flag} " not in analyze, flag
    for flag in ("--omega-n", "--time-step", "--kd", "--set", "--quick"):
        assert flag in analyze
    with pytest.raises(SystemExit) as exit_:
        cli.main(["analyze", "lego", "--out", "x", "--record", "r.html"])
    assert exit_.value.code == 2 and "unrecognized arguments: --record" in capsys.readouterr().err


def test_bad_input_is_one_line_and_exit_2_without_the_usage(capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["run", "lego", "--set", "simulation.duration_s=-1"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "usage:" not in err, err
    assert err.startswith("python -m godobject_drake run: error: --set simulation.duration_s=-1: ")
    assert "simulation.duration_s: -1.0 s must be > 0" in err and err.count("\n") == 1


def test_set_overrides_any_field_before_the_checks():
    sets = ["simulation.duration_s=2", "feedback.kd=50", "god_object.gains.zeta=0.7"]
    s = cli.load_with_sets(sc.shipped_scenario_file("lego"), sets)
    lego = sc.shipped_scenario("lego")
    assert s.simulation.duration_s == 2.0 and s.feedback.kd == 50.0 and s.god_object.gains.zeta == 0.7
    assert s.simulation.mode == lego.simulation.mode and s.god_object.gains.omega_n == 40.0  # the rest kept
    assert cli.set_overrides(["a.b=1", "a.c=[1, 2]", "d="]) == 'a:\n  b: 1\n  c: [1, 2]\nd: ""\n'
    for items, named in (
        (
            ["simulation.duration_s=2", "simulation.durration_s=2"],
            "--set simulation.durration_s=2: .*unknown",
        ),
        (["plant.time_step=fast"], "--set plant.time_step=fast: "),
        (["simulation"], "--set simulation: give KEY=VALUE"),
    ):
        with pytest.raises(sc.ScenarioError, match=named):
            cli.load_with_sets(sc.shipped_scenario_file("lego"), items)


def test_set_one_device_field_keeps_the_device_kind_and_reads_the_path_from_here(tmp_path, monkeypatch):
    """``--set device.path=my_path.yaml`` on the laparoscopy scene (a ``!ScriptedJoints`` device):
    Drake's loader would read the untagged mapping as the first kind, ``!Scripted``, and the
    articulated scene then refused "a joint-space device ... got !Scripted"; and the relative path
    was taken from the scenario's folder (inside the installed package). Now the device keeps its
    kind and its other fields, and the path is the user's, from the working folder."""
    path = sc.shipped_scenario("laparoscopy").device.path
    (tmp_path / "mine.yaml").write_text(Path(path).read_text())
    monkeypatch.chdir(tmp_path)
    s = cli.load_with_sets(sc.shipped_scenario_file("laparoscopy"), ["device.path=mine.yaml"])
    shipped = sc.shipped_scenario("laparoscopy").device
    assert type(s.device) is type(shipped) and s.device.path == str(tmp_path / "mine.yaml")
    assert s.device.channels == shipped.channels and s.device.mix == shipped.mix  # the rest kept
    # A tag the user gives is kept as given (their choice of kind), not replaced by the file's.
    s = cli.load_with_sets(sc.shipped_scenario_file("lego"), ["device=!Scripted {rate_hz: 30}"])
    assert type(s.device).__name__ == "Scripted" and s.device.rate_hz == 30


@pytest.mark.slow
def test_a_recording_run_logs_to_stderr_without_meshcat_or_progress_frames(tmp_path):
    """A run writing a recording, stderr not a terminal: no "Meshcat listening" (nobody is to open
    it), no tqdm \\r frames, what sleeping bodies do on this Drake and the outputs named by the
    logger; -q keeps only warnings."""
    argv = [sys.executable, "-m", "godobject_drake", "run", "lego", "--duration", "0.05",
            "--record", "r.html", "--metrics", "m.json"]  # fmt: skip
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()  # what sleeping does on this Drake (issue 47), then the outputs
    assert lines[0].startswith("sleeping bodies: locked") and len(lines) == 3, lines
    assert lines[1:] == ["metrics written to m.json", "recording written to r.html"]
    assert (
        "max_penetration_m" in proc.stdout
        and json.loads((tmp_path / "m.json").read_text())["sim_time_s"] == 0.05
    )
    quiet = subprocess.run([*argv, "-q"], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr


def test_the_package_shows_its_public_names():
    public = set(godobject_drake.__all__)
    assert {"load_scenario", "build_station", "simulate", "Scenario"} <= public <= set(dir(godobject_drake))
    text = pydoc.render_doc(godobject_drake, renderer=pydoc.plaintext)
    # (Python 3.13's pydoc puts a long signature's parameters one a line)
    assert re.search(r"load_scenario\(\s*filename", text) and re.search(r"simulate\(\s*station", text)


def test_the_console_script_and_python_m_are_one_command():
    proc = subprocess.run([sys.executable, "-m", "godobject_drake", "--version"], capture_output=True,
                          text=True, cwd=REPO)  # fmt: skip
    assert proc.returncode == 0 and proc.stdout.startswith("godobject_drake ")


def test_a_log_line_goes_to_the_stderr_of_the_moment(capsys, monkeypatch):
    """A driver's handler left on the package logger from an earlier in-process run held the stderr
    of its time: once that stream was closed, each later line printed "--- Logging error ---" with
    a traceback (seen in the whole suite, from the scenario fuzz test). Each handler now writes to
    sys.stderr as it is when the line is written."""
    old = io.StringIO()
    monkeypatch.setattr(sys, "stderr", old)
    handler = StderrHandler()
    log = logging.getLogger("godobject_drake.test_stderr")
    log.addHandler(handler)
    monkeypatch.setattr(log, "propagate", False)  # this handler alone, not the package's
    try:
        old.close()  # the earlier capture is gone
        monkeypatch.setattr(sys, "stderr", new := io.StringIO())
        log.warning("to the stderr of now")
    finally:
        log.removeHandler(handler)
    assert new.getvalue() == "to the stderr of now\n"


def test_a_run_checks_its_scenario_once(monkeypatch, tmp_path):
    """The file, its --set items and the flags are checked together once, and the build takes the
    records of that check: one call of check_scenario for one ``godobject run``."""
    calls = []
    check = sc.check_scenario

    def counted(s, where="scenario"):
        calls.append(where)
        return check(s, where)

    monkeypatch.setattr(sc, "check_scenario", counted)
    metrics = tmp_path / "m.json"
    argv = ["run", "lego", "--duration", "0.01", "--no-progress", "--set", "god_object.gains.zeta=0.9",
            "--metrics", str(metrics)]  # fmt: skip
    assert cli.main(argv) == 0
    assert calls == [str(sc.shipped_scenario_file("lego"))]
    assert json.loads(metrics.read_text())["sim_time_s"] == pytest.approx(0.01)


@pytest.mark.parametrize(
    "argv, named",
    [
        (["--time-step", "-1"], r"^--time-step: plant\.time_step: -1\.0 s"),
        (["--set", "plant.time_step=-1"], r"^--set plant\.time_step=-1: .*mine\.yaml: plant\.time_step"),
        (
            ["--set", "god_object.gains.zeta=0.9"],
            r"^\S*mine\.yaml: simulation\.duration_s: -1\.0 s must be > 0",
        ),
    ],
)
def test_the_one_check_names_the_flag_the_set_item_or_the_file(tmp_path, argv, named):
    """Its error is about the field a flag set (the flag), a --set item set (the item and the file),
    or the file itself (the file, not an unrelated --set item given beside it)."""
    bad = "simulation: {duration_s: -1}\n" if "god_object.gains.zeta=0.9" in argv else ""
    mine = tmp_path / "mine.yaml"
    shipped = sc.shipped_scenario_file("lego").read_text()
    if bad:  # the file's own simulation section, given once (a key twice is refused)
        shipped = shipped.replace("\nsimulation:", "\n_simulation:", 1)  # a private key: dropped
    mine.write_text(shipped + bad)
    parser = cli.argparse.ArgumentParser()
    cli.add_arguments(parser)
    args = parser.parse_args(argv)
    with pytest.raises(sc.ScenarioError, match=named):
        cli.scenario_of(mine, args)


def test_an_error_of_the_file_itself_is_the_files_not_a_set_items(tmp_path):
    """A key twice in the file, an unrelated --set beside it: the file is named, not the item."""
    mine = tmp_path / "mine.yaml"
    mine.write_text(sc.shipped_scenario_file("lego").read_text() + "simulation: {duration_s: 1}\n")
    with pytest.raises(
        sc.ScenarioError, match=r"^\S*mine\.yaml: line \d+: the key 'simulation' is given twice"
    ):
        cli.load_with_sets(mine, ["god_object.gains.zeta=0.9"])
