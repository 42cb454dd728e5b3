"""Long sessions in bounded memory: streamed metrics, flat memory, a capped recording, nothing lost.

A run folds its logs into running metrics every simulated second (``simulate(keep_logs=False)``,
what the command line does), so its memory does not grow with its length; the metrics equal the
ones computed from the whole logs at the end; a recording covers a stated span; and a run that
is interrupted or killed still leaves its metrics, marked partial.
"""

import json
import math
import resource
import signal
import subprocess
import sys
import textwrap
import time

import msgpack
import pytest
import theory
from conftest import REPO, build_scene, meshcat_commands, run_scene, shared_run

from godobject_drake.simulation import simulate

# One 2x4 brick on the brick scene's baseplate, lifted and held: a cheap scene (one free body)
# whose logs would grow by (13 state + 34 coupling terms) × 8 bytes × 1000 steps = 376 KB per
# simulated second if they were kept.
ONE_BRICK = """
name: one_brick
directives:
- add_model: {name: table, file: package://godobject_models/lego/table.sdf}
- add_weld: {parent: world, child: table::baseplate}
- add_model:
    name: brick
    file: package://godobject_models/lego/brick_2x4.sdf
    default_free_body_pose: {brick: {translation: [-0.1, 0.0, 0.0048]}}
god_object: !Rigid {gains: {omega_n: 40.0, zeta: 1.0, omega_n_rot: 120.0}}
device: !Scripted
  waypoints:
  - {t: 0.0, xyz: [-0.1, 0.0, 0.0048], grasp: brick}
  - {t: 1.0, xyz: [-0.1, 0.0, 0.03], grasp: brick}
"""


@pytest.mark.slow
@pytest.mark.parametrize("name", ["lego", "laparoscopy", "deformable_probe"])
def test_streamed_metrics_equal_the_whole_log_ones(name):
    """The default path, folded every simulated second, against the same logs measured at once
    (the run test_lego, test_laparoscopy, test_deformable and test_sleeping read too)."""
    result = shared_run(name)
    streamed, whole = result.metrics, theory.scene_metrics(result.station, result.data)
    for key, value in whole.items():
        if isinstance(value, float):
            assert streamed[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key  # sums, chunk by chunk
        else:
            assert streamed[key] == value, key  # maxima, counts, steps: exactly
    assert streamed["partial"] is False and streamed["metrics_time_s"] > 0


def peak_rss_mb(tmp_path, duration_s: float) -> float:
    """A fresh process's peak resident memory (its own accounting, MB) after running the scene."""
    (tmp_path / "one_brick.yaml").write_text(ONE_BRICK)
    code = textwrap.dedent(f"""
        import resource
        from godobject_drake.station.build import build_station
        from godobject_drake.config.scenario import load_scenario
        from godobject_drake.simulation import simulate
        station = build_station(load_scenario("{tmp_path / "one_brick.yaml"}"))
        result = simulate(station, duration_s={duration_s}, keep_logs=False, progress=False)
        assert abs(result.metrics["sim_time_s"] - {duration_s}) < 1e-6 and not result.metrics["diverged"]
        print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return float(proc.stdout.split()[-1])


@pytest.mark.slow
def test_memory_stays_flat_however_long_the_run(tmp_path):
    """120 s against 5 s of simulation: kept logs would add 115 s × 376 KB/s = 43 MB; folded,
    the peak grows by less than 4 MB (allocator noise: the logs hold at most 1 s, 0.4 MB)."""
    short, long = peak_rss_mb(tmp_path, 5.0), peak_rss_mb(tmp_path, 120.0)
    assert long - short < 4.0, (short, long)


@pytest.mark.slow
def test_a_recording_covers_its_stated_span(tmp_path):
    """``recording.max_duration_s`` caps what is recorded: at 0.5 s of a 1 s run the last
    recorded frame is at most 0.5 s × 64 fps = frame 32, and the file says how long it covers."""
    capped, full = tmp_path / "capped.html", tmp_path / "full.html"
    station = build_scene("lego", "--duration", "1.0", "--record", str(capped))
    station.scenario.recording.max_duration_s = 0.5
    m = simulate(station, progress=False, keep_logs=False).metrics
    assert m["recording_s"] == 0.5 and m["sim_time_s"] == pytest.approx(1.0)
    last = max(_frames(capped))
    assert 30 <= last <= 32
    run_scene("lego", "--duration", "1.0", "--record", str(full))
    assert 62 <= max(_frames(full)) <= 64
    assert capped.stat().st_size < full.stat().st_size


def _frames(html_path) -> list[int]:
    """The frame numbers of every key of the recording's animation."""
    (animation,) = [c for c in meshcat_commands(html_path.read_text()) if b"set_animation" in c]
    message = msgpack.unpackb(animation, raw=False)
    return [key["time"] for a in message["animations"] for t in a["clip"]["tracks"] for key in t["keys"]]


def cli(tmp_path, *flags):
    """The brick scene on the command line for 60 s, metrics checkpointed every 0.3 s of wall time."""
    scenario = (REPO / "diagrams" / "lego.yaml").read_text()
    assert "\nmetrics:\n" in scenario
    (tmp_path / "lego.yaml").write_text(
        scenario.replace("\nmetrics:\n", "\nmetrics:\n  checkpoint_period_s: 0.3\n")
    )
    command = [sys.executable, "-m", "godobject_drake", "run", str(tmp_path / "lego.yaml"), "--no-progress",
               "--duration", "60", "--metrics", str(tmp_path / "m.json"), *flags]  # fmt: skip

    # A terminal's Ctrl-C, even when the tests themselves run in the background: a job started
    # with `&` by a non-interactive shell inherits SIGINT ignored, and Python then keeps it
    # ignored (no KeyboardInterrupt), so the child gets SIGINT's default disposition back.
    # No core file either: SIGQUIT's default action, once the run has put its handlers back, dumps one.
    def child():
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))

    return subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=child)  # fmt: skip


def wait_for(path, timeout_s=60.0):
    start = time.monotonic()
    while not path.exists():
        assert time.monotonic() - start < timeout_s, f"{path} never appeared"
        time.sleep(0.1)


@pytest.mark.slow
def test_ctrl_c_leaves_the_metrics_so_far_marked_partial(tmp_path):
    proc = cli(tmp_path)
    # Into the run, whatever start-up costs on this machine: the first checkpoint is written
    # from inside the simulation loop.
    wait_for(tmp_path / "m.json", timeout_s=60.0)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (out, err)
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["partial"] is True and m["interrupted"] is True
    assert 0.0 < m["sim_time_s"] < 60.0 and not m["diverged"]
    assert m["max_penetration_m"] is not None and m["device_samples"] >= 1  # measured, not empty
    assert "the metrics above are partial" in err and "max_penetration_m" in out


@pytest.mark.slow
def test_sigterm_ends_the_run_as_ctrl_c_does(tmp_path):
    """SIGTERM (a scheduler's or a service manager's stop) gives exit 143, the metrics so far marked
    partial and a whole recording, where it used to lose the run."""
    proc = cli(tmp_path, "--record", "r.html")
    wait_for(tmp_path / "m.json", timeout_s=60.0)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, (out, err)
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["partial"] is True and m["interrupted"] is True and 0.0 < m["sim_time_s"] < 60.0
    assert "interrupted (SIGTERM)" in err and "recording written to" in err  # logged: stderr
    html = (tmp_path / "r.html").read_text()
    assert html.rstrip().endswith("</html>")
    frames = _frames(tmp_path / "r.html")  # the recording covers the run up to the signal, to a frame
    # (64 a second: a run stopped early, 0.107 s on a loaded machine, ends at frame 6, 0.094 s)
    assert max(frames) / 64 >= m["sim_time_s"] - 1 / 64 and m["recording_s"] == m["sim_time_s"]


@pytest.mark.slow
def test_a_killed_run_leaves_its_last_checkpoint(tmp_path):
    """Even SIGKILL, which nothing can catch, leaves the metrics of the last checkpoint (every
    ``metrics.checkpoint_period_s`` of wall time: 10 s by default, 0.3 s here)."""
    proc = cli(tmp_path)
    wait_for(tmp_path / "m.json", timeout_s=60.0)
    proc.kill()
    proc.communicate(timeout=60)
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["partial"] is True and 0.0 < m["sim_time_s"] < 60.0
    assert math.isfinite(m["max_penetration_m"])


def _litter(tmp_path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir() if p.name not in ("lego.yaml", "m.json", "r.html"))


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT],
                         ids=lambda s: signal.Signals(s).name)  # fmt: skip
def test_a_signal_at_any_moment_of_the_end_leaves_whole_outputs_and_says_what_was_written(tmp_path, signum):
    """The signal every 10 ms from inside the run to the process's end: the first ends the run,
    the rest land while the recording is saved, the metrics made and written, the locks removed.
    Before, a second Ctrl-C while the recording was saved said "interrupted before the run started"
    and wrote neither output (a .tmp left); SIGTERM while the metrics were written left .tmp and
    .lock files; SIGHUP ended the scene with no metrics and no STOP, SIGQUIT likewise with a core
    dump. Now: no temporary or lock file, the metrics and the recording whole, and stderr says each
    was written and that the run was interrupted; the exit is the signal's (128 + N; or the signal
    itself, after the last word)."""
    proc = cli(tmp_path, "--record", "r.html")
    wait_for(tmp_path / "m.json", timeout_s=60.0)
    sent = 0
    while proc.poll() is None and sent < 3000:
        proc.send_signal(signum)
        sent += 1
        time.sleep(0.01)
    err = proc.communicate(timeout=120)[1]
    name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
    assert proc.returncode in (128 + signum, -signum), (proc.returncode, err[-3000:])
    assert _litter(tmp_path) == [], _litter(tmp_path)
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["partial"] is True and m["interrupted"] is True, err[-3000:]
    assert (tmp_path / "r.html").read_text().rstrip().endswith("</html>")
    assert "recording written to" in err and f"metrics written to {tmp_path / 'm.json'}" in err
    assert f"interrupted ({name}) at t = " in err and "before the run started" not in err
    print(f"{sent} signals sent; rc {proc.returncode}")
