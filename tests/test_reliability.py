"""Nothing lost and nothing left pushing (issue 30): outputs written whole, strict JSON, a full disk,
and a real device's feedback zeroed whatever stops the run."""

import dataclasses
import json
import math
import os
import re
import subprocess
import sys
import threading
import warnings

import numpy as np
import pytest
from conftest import REPO, assert_refused, build_scene, own_scene_files
from drake import lcmt_force_torque
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from godobject_drake import cli
from godobject_drake.config.scenario import ScenarioError, load_scenario
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.link.messages import FEEDBACK_CHANNEL
from godobject_drake.metrics import write_metrics
from godobject_drake.outputs import OutputError, dumps_metrics, write_atomically
from godobject_drake.safeguards import FallWatch, UnsupportedBodyWarning
from godobject_drake.simulation import _AllTools, simulate
from godobject_drake.station.build import build_station


@pytest.mark.slow
def test_a_reader_never_sees_half_a_metrics_file(tmp_path):
    """A reader polling the metrics while they are rewritten (as the checkpoints do) parses every
    read: a file is replaced whole, never truncated and refilled (the old write_text gave ~4 %
    unparseable reads)."""
    path = tmp_path / "m.json"
    big = {f"key_{i}": float(i) for i in range(20000)}  # ~0.5 MB, written 150 times
    write_metrics(path, big)
    done, bad, reads = threading.Event(), [], [0]

    def read():
        while not done.is_set():
            try:
                json.loads(path.read_text())
            except (json.JSONDecodeError, FileNotFoundError) as e:
                bad.append(type(e).__name__)
            reads[0] += 1

    reader = threading.Thread(target=read)
    reader.start()
    for k in range(150):
        write_metrics(path, {**big, "k": k})
    done.set()
    reader.join()
    assert reads[0] > 10 and bad == []
    assert json.loads(path.read_text())["k"] == 149
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]  # no temporary file left


def test_metrics_are_strict_json_with_the_non_finite_values_named(tmp_path):
    path = tmp_path / "m.json"
    write_metrics(path, {"a": 1.0, "b": math.nan, "c": {"d": [0.5, math.inf]}, "e": -math.inf, "f": None})

    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    m = json.loads(path.read_text(), parse_constant=refuse)  # what a strict reader (JavaScript) accepts
    assert m["a"] == 1.0 and m["b"] is None and m["c"]["d"] == [0.5, None] and m["e"] is None
    assert m["non_finite"] == {"b": "nan", "c.d[1]": "inf", "e": "-inf"}
    assert "non_finite" not in json.loads(dumps_metrics({"a": 1.0}))  # only when there is one


FULL_DISK = r"""
import resource, signal, sys
from pathlib import Path
from godobject_drake.outputs import OutputError, write_atomically
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))  # files past 100 kB cannot be written
path = Path(sys.argv[1])
write_atomically(path, "small and complete")
try:
    write_atomically(path, "x" * 300_000)
except OutputError as e:
    print(e)
"""


def test_a_full_disk_keeps_the_last_complete_file_and_says_so(tmp_path):
    """A write the file system refuses (here a file-size limit, as a full disk does: the kernel's
    EFBIG and ENOSPC are the same failure to ``write``) leaves the previous file whole, removes
    its temporary file, and names the file, its size, the cause and the fix."""
    path = tmp_path / "m.json"
    out = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(path)], capture_output=True, text=True, check=True
    )
    assert path.read_text() == "small and complete"
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]
    message = out.stdout
    assert f"could not write {path} (300000 bytes)" in message and "File too large" in message, message
    assert (
        "the previous version is kept" in message and "Free space on that disk or write elsewhere" in message
    )
    with pytest.raises(OutputError, match=r"could not write .*no_such_folder/m\.json .*nothing was written"):
        write_atomically(tmp_path / "no_such_folder" / "m.json", "{}")


def _lcm_scene(*flags):
    station = build_scene("lego", "--device", "lcm", "--lcm-url", "memq://", "--kd", "20", *flags)
    received = []
    station.device.lcm.Subscribe(FEEDBACK_CHANNEL, lambda raw: received.append(lcmt_force_torque.decode(raw)))
    return station, received


def test_a_real_device_gets_a_zero_wrench_when_the_run_ends():
    station, received = _lcm_scene("--duration", "0.2")
    start = station.device.samples(0.0)[0][1][0]
    lcm = station.device.lcm
    from test_lcm import POSE_CHANNEL, Q, pose_message  # the driver's messages, as test_lcm sends them

    lcm.Publish(POSE_CHANNEL, pose_message(1, start, Q, "*").encode())  # grasp the nearest brick

    def lift(metrics):  # after the first check period (50 ms): the driver lifts its target 1 cm
        if not lifted:
            lcm.Publish(POSE_CHANNEL, pose_message(2, start + np.array([0.0, 0.0, 0.01]), Q).encode())
            lifted.append(metrics["sim_time_s"])

    lifted = []
    m = simulate(station, progress=False, checkpoint=lift, checkpoint_period_s=0.0).metrics
    station.device.lcm.HandleSubscriptions(0)
    pushing = [msg for msg in received[:-1] if abs(msg.fz) > 1e-3]
    assert pushing, "the scene never pushed: the test would prove nothing"
    last = received[-1]
    assert (last.fx, last.fy, last.fz, last.tx, last.ty, last.tz) == (0.0,) * 6
    assert last.timestamp == round(0.2 * 1e6) and m["feedback_zeroed_at_s"] == pytest.approx(0.2)


def test_a_real_device_gets_a_zero_wrench_when_the_run_fails():
    """An exception in the middle of the run (here from the checkpoint callback) still zeroes it."""
    station, received = _lcm_scene("--duration", "0.5")

    def fail(metrics):
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        simulate(station, progress=False, checkpoint=fail, checkpoint_period_s=0.0)
    station.device.lcm.HandleSubscriptions(0)
    last = received[-1]
    assert (last.fx, last.fy, last.fz) == (0.0, 0.0, 0.0) and 0 < last.timestamp < 0.5e6


def test_devices_that_render_no_feedback_send_nothing():
    m = simulate(build_scene("lego", "--duration", "0.05"), progress=False).metrics
    assert "feedback_zeroed_at_s" not in m


LEGO = REPO / "diagrams" / "lego.yaml"


@pytest.mark.parametrize(
    ("overrides", "value", "limit", "fix"),
    [
        ("recording: {frames_per_second: 0.0}", r"second: 0\.0", r"in \(0, 1000\]", r"default 64"),
        ("recording: {frames_per_second: .nan}", r"second: nan", r"in \(0, 1000\]", r"default 64"),
        ("visualization: {publish_period_s: 0.0}", r"period_s: 0\.0 s", r"must be > 0", r"e\.g\. 0\.015625"),
        ("visualization: {publish_period_s: .nan}", r"period_s: nan s", r"must be > 0", r"64 frames"),
        ("plant: {time_step: 1.0e-12}", r"time_step: 1e-12 s", r"under 1e-05 s", r"Give h ≥ 1e-05"),
        ("simulation: {duration_s: 1.0e+300}", r"duration_s: 1e\+300 s", r"at most 1e\+06", r"several runs"),
        ("bricks: 100000", r"bricks: 100000", r"up to 512", r"or 0 for the directives' own"),
        (f"device: !Scripted {{path: {REPO}/models/lego/default_path.yaml, rate_hz: 1.0e+9}}",
         r"rate_hz: 1000000000\.0 Hz", r"at most 100000 Hz", r"1 to 10 kHz"),
    ],
)  # fmt: skip
def test_values_that_would_make_the_output_useless_or_the_run_endless_are_refused(
    overrides, value, limit, fix
):
    """Each was accepted before: a one-frame recording or frame −2147483648, a drawing every 0 s, a
    step of 1 ps, a run of 1e300 s, 100 000 bricks to build, a device sampled at 1 GHz."""
    assert_refused(lambda: load_scenario(LEGO, overrides), ScenarioError, value=value, limit=limit, fix=fix)


def test_a_free_body_without_mass_is_refused_naming_it(tmp_path):
    """Drake only logs a warning for it and gives the body 1 kg; the README's own scene with the
    cube's mass set to 0 is refused, Drake's message (file and line) inside ours."""
    own_scene_files(tmp_path)
    sdf = tmp_path / "cube_post.sdf"
    sdf.write_text(sdf.read_text().replace("<mass>0.2</mass>", "<mass>0</mass>"))
    assert_refused(
        lambda: build_station(load_scenario(tmp_path / "cube_post.yaml")), ScenarioError,
        value=r"cube_post\.sdf:26: .*'mass > 0' failed", limit=r"no positive mass",
        fix=r"<inertial><mass> > 0 in its model file, or weld it \(add_weld\)",
    )  # fmt: skip


class _CountingPath(ScriptedDevice):
    """The brick scene's path with its times written in µs as if they were s (× 1e6: 8.5e6 s), its
    sampler counted and stopped past a bound, so work that grows with the path's length fails fast."""

    BOUND = 10_000

    def __init__(self, *args, **kwargs):
        self.calls = 0
        super().__init__(*args, **kwargs)

    def _sample_path(self, t):
        self.calls += 1
        assert self.calls <= self.BOUND, "the device was sampled far past the run"
        return super()._sample_path(t)


def test_a_path_whose_times_run_far_costs_what_the_run_uses():
    """A path of 8.5e6 s: building the scene sampled it whole at 60 Hz (5e8 samples; RSS 160 → 786 MB
    in 40 s, still building). Now the grasp names are read off the waypoints, and a 0.2 s run
    samples the path 13 times, not more than a run without the stretch."""
    from pydrake.systems.framework import DiagramBuilder

    from godobject_drake.config.device_files import load_device_path
    from godobject_drake.station.build import finish
    from godobject_drake.station.plant import add_plant
    from godobject_drake.station.rigid_tool import add_god_object

    s = load_scenario(LEGO, "simulation: {duration_s: 0.2}")
    waypoints = load_device_path(REPO / "models" / "lego" / "default_path.yaml").waypoints
    far = [dataclasses.replace(w, t=w.t * 1e6) for w in waypoints]
    builder = DiagramBuilder()
    device = builder.AddNamedSystem("device", _CountingPath(far))
    assert device.grasp_names() == {"brick_0"} and device.calls <= 2
    scene = add_plant(builder, s)
    god = add_god_object(builder, scene.plant, device, s.god_object.gains, s.feedback)
    station = finish(builder, s, scene, god)
    result = simulate(station, progress=False)
    assert result.metrics["sim_time_s"] == pytest.approx(0.2) and device.calls < 100


def _log_with_junk_after(path, rows: int, bad_line_2: bool = False):
    """A device log of ``rows`` good rows (10 ms apart) followed by bytes no UTF-8 text holds."""
    lines = ["t,x,y,z,qw,qx,qy,qz,grasp"]
    lines += [f"{0.01 * k!r},-0.1,0.0,0.0048,1,0,0,0,brick_0" for k in range(rows)]
    if bad_line_2:
        lines[1] = "0.0,-0.1,fast,0.0048,1,0,0,0,brick_0"
    path.write_bytes(("\n".join(lines) + "\n").encode() + bytes([0xFF, 0xFE, 0xC0]) * 1000)
    return path


def test_a_log_is_read_as_far_as_the_run_reaches(tmp_path):
    """A 1 s run of a replayed log reads its first second: the junk after row 5 000 (50 s) is never
    read (the whole file was read first, and refused, before)."""
    log = _log_with_junk_after(tmp_path / "log.csv", rows=5_000)
    s = load_scenario(LEGO, f"device: !Replay {{log: {log}}}\nsimulation: {{duration_s: 1.0}}")
    station = build_station(s)
    assert len(station.device.log.t) == 102  # t = 0 .. 1.01 s: through the first row past the run
    assert not simulate(station, progress=False).metrics["diverged"]
    with pytest.raises(ValueError, match=r"duration_s=2\.0 s is past the scenario's .* build the station"):
        simulate(station, duration_s=2.0, progress=False)


def test_a_bad_row_is_found_without_reading_the_rest(tmp_path):
    """Bad at line 2 of a long log: said at once, naming line 2 (it took 70 s and 1.75 GB for a
    136 MB log, as the whole file was read before any check; here the junk after it would have
    been the complaint)."""
    log = _log_with_junk_after(tmp_path / "log.csv", rows=50_000, bad_line_2=True)
    with pytest.raises(ValueError, match=r"log\.csv:2: column 3 is not a number"):
        build_station(load_scenario(LEGO, f"device: !Replay {{log: {log}}}"))


DRAKE_REFUSALS = {  # overrides of the brick scene: what the user now reads (exit 2, no traceback)
    "a missing model file": (
        "- add_model: {name: thing, file: NOWHERE/nothing.sdf}",
        r"directives: Drake could not build the scene's plant: error: URI .*nothing\.sdf.* does not exist",
    ),
    "a file that is not a model": (
        f"- add_model: {{name: thing, file: {REPO}/README.md}}",
        r"README\.md' is not a recognized type\. Known types are",
    ),
    "the same model name twice": (
        "- add_directives: {file: package://godobject_models/lego/lego.dmd.yaml}",
        r"a model instance named 'lego_table'.*Check the directives' files, model names \(each once\)",
    ),
    "a weld to a frame that does not exist": (
        "- add_weld: {parent: world, child: no_such::frame}",
        r"There is no model instance named 'no_such'.*frame names \(model::frame\)",
    ),
}


@pytest.mark.parametrize("case", sorted(DRAKE_REFUSALS))
def test_drake_errors_while_building_are_bad_input_with_drakes_message_inside(tmp_path, capsys, case):
    """Each gave a traceback and exit 1."""
    directive, message = DRAKE_REFUSALS[case]
    text = LEGO.read_text().replace(
        "directives:\n- add_directives:\n    file: package://godobject_models/lego/lego.dmd.yaml\n",
        "directives:\n- add_directives: {file: package://godobject_models/lego/lego.dmd.yaml}\n"
        + directive.replace("NOWHERE", str(tmp_path))
        + "\n",
    )
    assert text.count("add_") >= 2
    (tmp_path / "s.yaml").write_text(text)
    with pytest.raises(SystemExit) as exit_:
        cli.main(["run", str(tmp_path / "s.yaml"), "--duration", "0.01", "--no-progress"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and re.search(message, err) and "Traceback" not in err, err


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ("plant: {sap_near_rigid_threshold: .nan}",
         r"plant\.sap_near_rigid_threshold: nan must be a finite number ≥ 0 \(Drake's default: 1\)"),
        ("simulation: [1, 2]", r"\[1, 2\] \(at simulation in the overrides\): give that key a value"),
        ("simulation: {duration_s: fast}", r"'fast' \(at simulation\.duration_s in the overrides\)"),
        ("simulation: {duration_s: 1", r"not valid YAML in the overrides: .*check the brackets"),
    ],
)  # fmt: skip
def test_scenario_mistakes_drake_reported_badly_name_the_key(overrides, message):
    with pytest.raises(ScenarioError, match=message):
        load_scenario(LEGO, overrides)


def test_an_increment_of_1e300_is_refused_naming_the_line(tmp_path):
    """It reached Drake as 'Axis is not normalized'."""
    log = tmp_path / "mouse.csv"
    rows = ["t,dx,dy,dz,drx,dry,drz,clutch,grasp", "0.0,0,0,0,0,0,0,0,brick_0", "0.1,0,0,0,1e300,0,0,0,"]
    log.write_text("\n".join(rows) + "\n")
    said = r"mouse\.csv:3: the increment drx,dry,drz = \[1e\+300, 0\.0, 0\.0\] is 1e\+300 rad long, over 1000"
    with pytest.raises(ValueError, match=said + r" rad in one row; .* metres and radians"):
        build_station(load_scenario(LEGO, f"device: !Relative {{log: {log}}}"))


def test_a_model_left_unwelded_that_falls_is_named(tmp_path):
    """The README's own scene with the floor's weld forgotten: the floor (and the cube on it) fell
    away and the run exited 0 in silence. Now the floor is named, with the fix; the cube, held, is not."""
    own_scene_files(tmp_path)
    sdf = tmp_path / "cube_post.sdf"
    weld = '<joint name="floor_weld" type="fixed"><parent>world</parent><child>floor</child></joint>'
    assert weld in sdf.read_text()
    sdf.write_text(sdf.read_text().replace(weld, ""))
    s = load_scenario(tmp_path / "cube_post.yaml", "simulation: {duration_s: 1.2}")
    said = r"^cube_post::floor fell more than 0\.1 m in the first 1 s without being held: .* needs a weld"
    with pytest.warns(UnsupportedBodyWarning, match=said):
        m = simulate(build_station(s), progress=False).metrics
    assert m["unsupported_bodies"] == ["cube_post::floor"]
    resting = simulate(build_scene("lego", "--duration", "1.2"), progress=False).metrics  # 8 bricks rest
    assert "unsupported_bodies" not in resting and resting["free_bodies"] == 8


def test_the_device_limit_at_build_is_python_controls_closed_loop_limit():
    """The build-time limit (plain numpy, limits.device_wall_limit) against a second method: the
    closed loop of python-control's exact ZOH device (studies.stability) on the virtual wall
    H(z) = kd + γd(1 − z⁻¹)/T, bisected on its poles; with no hand it is also near docs/theory.md
    §2's closed form 2(b + γd)/T (4400 N/m for 0.1 kg, 2 N·s/m, 1 kHz, γd = 0.2)."""
    import control as ct

    from godobject_drake.config.scene import Haptic
    from godobject_drake.limits import device_wall_limit
    from godobject_drake.station.haptic_chain import hand_on_handle
    from godobject_drake.studies.analyze.verify import _device_with_hand
    from godobject_drake.studies.stability import DeviceParams, bisect, wall_impedance

    haptic = Haptic(mode="impedance")
    m, b, T = haptic.device_mass_kg, haptic.device_damping, 1.0 / haptic.rate_hz
    hand = hand_on_handle(haptic)
    dev = DeviceParams(m, b, T, 0)
    for gamma_d in (0.0, 0.2, 5.0):
        for G, on_handle in ((_device_with_hand(dev, haptic), (hand.k, hand.b)), (None, ())):
            G = G if G is not None else ct.c2d(ct.ss([[0, 1], [0, -b / m]], [[0], [1 / m]], [[1, 0]], 0), T)

            def stable(kd, G=G, gamma_d=gamma_d):
                loop = ct.feedback(G, wall_impedance(kd, gamma_d, T), sign=-1)
                return float(np.max(np.abs(loop.poles()))) < 1.0

            second = bisect(stable, 1e-3, 1e6, 1e-7)
            ours = device_wall_limit(m, b, T, gamma_d, *on_handle)
            assert ours == pytest.approx(second, rel=1e-5), (gamma_d, on_handle)
            if not on_handle and gamma_d < b:  # the closed form is for light virtual damping
                assert ours == pytest.approx(2 * (b + gamma_d) / T, rel=0.01)


def test_an_unstable_haptic_gain_is_refused_at_build_naming_the_limit_and_the_fix():
    """``--haptic impedance --kd 1e6`` diverged with Drake's "cannot normalize" as the diagnosis; it
    is now refused before simulating (exit 2, no traceback): past the device's limit against a
    rigid obstacle with the simulated hand, 2.884e4 N/m at γd = 0 (the test above checks it)."""
    run = subprocess.run(
        [sys.executable, "-m", "godobject_drake", "run", "diagrams/lego.yaml", "--no-progress",
         "--haptic", "impedance", "--kd", "1e6", "--duration", "0.1"],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert re.search(r"feedback\.kd: 1e\+06 N/m is past the stability limit 2\.884e\+04 N/m", run.stderr)
    assert re.search(r"Use feedback\.kd < 2\.884e\+04 N/m \(--kd\), or raise haptic\.device_", run.stderr)
    # Within 20 % of the limit, or past the limit without a hand: built, with a warning.
    from godobject_drake.station.haptic_chain import HapticGainWarning

    with pytest.warns(HapticGainWarning, match=r"past the limit 4013 N/m of the same device with no hand"):
        build_scene("lego", "--haptic", "impedance", "--kd", "5000")
    with pytest.warns(HapticGainWarning, match=r"within 20% of the limit 2\.884e\+04 N/m"):
        build_scene("lego", "--haptic", "impedance", "--kd", "25000")


def test_a_diverging_haptic_device_is_named_with_the_likely_cause():
    """Built past the limit anyway (``check_gains=False``, as analyze does), the run stops at the
    first check with the simulated device named and its gain as the likely cause, not Drake's
    NaN message; the metrics stay strict JSON."""
    from conftest import scenario

    s = scenario("lego", "--haptic", "impedance", "--kd", "1e6", "--duration", "1")
    result = simulate(build_station(s, None, check_gains=False), progress=False)
    m = result.metrics
    assert m["diverged"] and m["sim_time_s"] < 0.2
    assert m["diagnosis"].startswith("the simulated haptic device diverged at t=")
    assert (
        "the likely cause: feedback.kd 1e+06 N/m is past the device's stability limit 2.884e+04 N/m"
        in (m["diagnosis"])
    )
    json.loads(dumps_metrics(m), parse_constant=lambda c: pytest.fail(f"{c} in the metrics"))


def test_an_output_gets_the_mode_a_plain_write_gives(tmp_path):
    """Outputs are written through a temporary file (mkstemp makes it 0600); the renamed file has
    the mode open() would give it under the process's umask, so others can read a recording."""
    import os

    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    write_atomically(tmp_path / "atomic.txt", "x")
    assert os.stat(tmp_path / "atomic.txt").st_mode & 0o777 == os.stat(plain).st_mode & 0o777


YCB_SCENE = """
name: ycb
directives:
- add_model:
    name: mustard
    file: package://drake_models/ycb/006_mustard_bottle.sdf
god_object: !Rigid {}
device: !Scripted {waypoints: [{t: 0.0, xyz: [0, 0, 0.1]}, {t: 1.0, xyz: [0, 0, 0.1]}]}
simulation: {duration_s: 0.1}
"""


def test_a_model_drake_must_download_without_network_names_the_package_and_the_ways_out(tmp_path):
    """A YCB object is in Drake's ``drake_models`` package, which the drake wheel does not ship:
    Drake downloads it. Without network (here: networking denied to Drake's PackageMap by
    DRAKE_ALLOW_NETWORK, and an empty download cache, so nothing leaves the machine) the run
    exits 2 naming the package, the wheel's own models and the cache to copy."""
    scene = tmp_path / "ycb.yaml"
    scene.write_text(YCB_SCENE)
    env = {**os.environ, "DRAKE_ALLOW_NETWORK": "meshcat:lcm", "XDG_CACHE_HOME": str(tmp_path / "cache")}
    done = subprocess.run([sys.executable, "-m", "godobject_drake", "run", str(scene), "--no-progress"],
                          env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2, done.stderr
    said = " ".join(done.stderr.split())
    assert (
        "a model of the package 'drake_models' (package://drake_models/...) is not in the drake wheel" in said
    )
    assert "package://drake/examples/kuka_iiwa_arm/models/objects/folding_table.urdf" in said
    assert f"{tmp_path / 'cache' / 'drake' / 'package_map'} (copy that folder" in said
    assert "Check the directives' files" not in said  # not the misleading hint


BOX_IN_TABLE = """
name: box_table
directives:
- add_model:
    name: table
    file: package://drake/examples/kuka_iiwa_arm/models/objects/folding_table.urdf
- add_weld: {parent: world, child: table::table_surface_center}
- add_model:
    name: box
    file: package://drake/examples/kuka_iiwa_arm/models/objects/open_top_box.urdf
- add_model:
    name: block
    file: package://drake/examples/kuka_iiwa_arm/models/objects/block_for_pick_and_place.urdf
    default_free_body_pose: {base_link: {translation: [0.0, 0.0, 0.2]}}
god_object: !Rigid {}
device: !Scripted
  waypoints: [{t: 0.0, xyz: [0, 0, 0.2], grasp: block}, {t: 1.0, xyz: [0, 0, 0.2], grasp: block}]
simulation: {duration_s: 0.5}
"""


def test_a_model_left_unwelded_inside_another_is_named_before_the_run(tmp_path):
    """Drake's open-top box with its weld left out starts at the world's origin, inside the folding
    table's top (whose surface is at z = 0): Drake's contact threw it out at 1.2 m/s and the run
    exited 0. Now the build refuses it, naming both, the depth (10 mm, as Drake's point-pair query
    gives it) and the two likely causes; welded 20 mm up, it builds."""
    scene = tmp_path / "box.yaml"
    scene.write_text(BOX_IN_TABLE)
    with pytest.raises(ScenarioError) as refused:
        build_station(load_scenario(scene))
    said = str(refused.value)
    assert said.startswith("table::table_top and box::bin start 10 mm inside each other")
    assert "missing weld (model 'box' has none" in said and "default_free_body_pose" in said
    weld = "- add_weld: {parent: world, child: box::bin, X_PC: {translation: [0, 0, 0.02]}}\n"
    welded = BOX_IN_TABLE.replace("- add_model:\n    name: block", weld + "- add_model:\n    name: block")
    scene.write_text(welded)  # the weld, 20 mm up: on the table
    build_station(load_scenario(scene))


def test_a_body_thrown_at_the_start_is_named_unless_a_tool_is_at_it():
    """The fall watch's second rule on the brick scene's start (the device holds brick_0): brick_1
    put 0.2 m sideways with nothing near it is named as thrown; put on the held brick, both 0.2 m
    away (a tool could have pushed it there), it is not; brick_0, held, never is."""
    station = build_scene("lego", "--duration", "0.5")
    plant = station.plant
    simulator = Simulator(station.diagram)
    simulator.AdvanceTo(0.01)  # the device's first sample taken: brick_0 held
    root = simulator.get_mutable_context()
    context = plant.GetMyMutableContextFromRoot(root)
    brick = plant.GetBodyByName("brick", plant.GetModelInstanceByName("brick_1"))
    held = plant.GetBodyByName("brick", plant.GetModelInstanceByName("brick_0"))
    tools = _AllTools(station)
    assert tools.held_bodies(root) == {int(held.index())}
    start, start_held = (plant.EvalBodyPoseInWorld(context, b) for b in (brick, held))
    away = np.array([0.1, 0.1, 0.05])
    for alone, named in ((True, ["brick_1::brick"]), (False, [])):
        watch = FallWatch(plant, context, tools, 1.0)
        plant.SetFreeBodyPose(context, brick, RigidTransform(start.rotation(), away))
        if not alone:  # the held brick just under it: touching (one brick height, 9.6 mm, apart)
            plant.SetFreeBodyPose(context, held, RigidTransform(start.rotation(), away - [0.0, 0.0, 0.0096]))
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            watch.check(context, root)
        assert watch.fallen == named
        assert [str(w.message).split(" moved")[0] for w in said] == named
        plant.SetFreeBodyPose(context, held, start_held)
        plant.SetFreeBodyPose(context, brick, start)
