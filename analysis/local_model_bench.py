"""The local model's benchmark (docs/local_model.md): the emulated device and its
simulated hand (0.1 kg handle, hand 400 N/m, 8 N·s/m) in a ``godobject-driver`` process of its
own, on loopback, pressing into a wall 2.5 cm past contact, holding, releasing; a table over
the scene's publication rate (Hz of wall time) and the feedback gain ``kd``.

    python analysis/local_model_bench.py                       # scripted wall scene, full table
    python analysis/local_model_bench.py --scene lego --rates 1000 30 --kds 200
    python analysis/local_model_bench.py --scene lego_haptic --rates 200 30   # the haptic recipe
    python analysis/local_model_bench.py --baseline            # also the held wrench (before)

Two scenes:

- ``scripted`` (the default, labelled so): a scene process that is *not* Drake: a god-object
  pulled toward the handle by a critically damped coupling (ω 40 rad/s, damping on the velocity
  relative to the handle's backward difference: the brick scene's law), with its free twin for
  the model's ``lag``,
  integrated at 1 ms of wall time, stopped by a rigid wall at x = 0 of the device's frame, which
  publishes the wrench and a local model (the wall as a plane) at the throttled rate;
- ``lego``: the brick scene (diagrams/lego.yaml, ``python -m godobject_drake run``, device
  ``!Lcm`` on ``udp://``) throttled by the test-only analysis/throttled_scene.py; the hand
  grasps brick_0, carries it into the wall and presses, holds, comes back (the contact found
  from the driver's own log); ``lego_haptic``: the same on the haptic recipe
  (diagrams/lego_haptic.yaml: h = 5 ms, the implicit coupling, the device at its 200 Hz).

For each run: the work the device did on the hand over press, hold and release (mJ, from the
driver's log: each period's rendered force times the handle's move over the period, the force
being held: what the hand received), the force's ripple while the hand holds still (peak to
peak of |f|, N), the watchdog trips, the drag in free space at 6 cm/s (mean |f|, N), the age of
the handle pose used by the spring term at p99 (ms, from the device read to the force command),
and on request (``--kill``) the time from a SIGKILL of the scene to zero force against its
bound, 3 scene periods + 50 ms (``bound``: the periods the scene was asked for; ``fade``: the
driver's, from the periods it measured). Prints nproc, the CPU model and the load beside the table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
HAND = {  # the device's frame (m): the wall at x = 0, free space x > 0; 6 cm/s in and out
    "waypoints": [
        {"t": 0.0, "xyz": [0.05, 0.0, 0.0]},
        {"t": 0.5, "xyz": [0.05, 0.0, 0.0]},
        {"t": 1.75, "xyz": [-0.025, 0.0, 0.0]},  # 7.5 cm in 1.25 s: 6 cm/s, contact at 1.33 s
        {"t": 2.75, "xyz": [-0.025, 0.0, 0.0]},
        {"t": 3.25, "xyz": [0.005, 0.0, 0.0]},
        {"t": 3.75, "xyz": [0.005, 0.0, 0.0]},
    ]
}
# hand time windows (s): free-space drag at 6 cm/s, the hold, and press/hold/release (from 2 mm
# before the contact to the end)
DRAG_S, HOLD_S, WORK_S = (0.7, 1.2), (2.05, 2.7), (1.3, 3.75)
RT_PRIORITY = 0  # --rt-priority: the driver's loop under SCHED_FIFO (0: the normal scheduler)
OMEGA = 40.0  # rad/s: the scripted god-object's coupling (the brick scene's omega_n)


def machine() -> str:
    model = next(
        (line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if "model name" in line), "?"
    )
    return f"nproc {os.cpu_count()}, CPU {model}, load {' '.join(open('/proc/loadavg').read().split()[:3])}"


# -- the scripted scene: a process of its own ---------------------------------------------------------


def serve(url: str, key_file: str, rate_hz: float, kd: float, seconds: float) -> None:
    """A wall scene that is not Drake (module docstring), publishing at ``rate_hz`` of wall time."""
    from drake import lcmt_force_torque

    from godobject_drake.link.messages import (
        FEEDBACK_CHANNEL,
        LOCAL_MODEL_CHANNEL,
        POSE_CHANNEL,
        POSE_NAMES,
        LocalModel,
        parse_robot_state,
    )
    from godobject_drake.link.transport import UdpLcm

    lcm = UdpLcm.listen(url, key_file)
    latest = {}

    def on_pose(raw):
        parsed = parse_robot_state(raw, POSE_NAMES)
        if parsed is not None:
            latest["utime"], latest["p"] = parsed[0], np.array(parsed[2][:3])

    lcm.Subscribe(POSE_CHANNEL, on_pose)
    h, dt = 1e-3, 1.0 / rate_hz
    G = v = None
    start = time.monotonic()
    next_step = next_publish = start
    while time.monotonic() - start < seconds:
        lcm.HandleSubscriptions(0)
        if "p" in latest:
            target = latest["p"]
            if G is None:
                G, v, before = target.copy(), np.zeros(3), target.copy()
                free_G, free_v = G.copy(), v.copy()  # the same god-object, no wall: the free lag
            v_T, before = (target - before) / h, target.copy()  # the coupling's: relative damping
            v = v + h * (OMEGA**2 * (target - G) + 2 * OMEGA * (v_T - v))  # semi-implicit Euler, ω h = 0.04
            G = G + h * v
            free_v = free_v + h * (OMEGA**2 * (target - free_G) + 2 * OMEGA * (v_T - free_v))
            free_G = free_G + h * free_v
            if G[0] < 0.0:  # the wall stops the god-object
                G[0], v[0] = 0.0, max(v[0], 0.0)
            now = time.monotonic()
            if now >= next_publish:
                next_publish = max(next_publish + dt, now - dt)
                f = kd * (G - target)
                msg = lcmt_force_torque()
                msg.timestamp = round((now - start) * 1e6)
                msg.fx, msg.fy, msg.fz = (float(c) for c in f)
                lcm.Publish(FEEDBACK_CHANNEL, msg.encode())
                planes = [((0.0, G[1], G[2]), (1.0, 0.0, 0.0), math.inf)] if G[0] < 0.005 else []
                model = LocalModel(
                    msg.timestamp, latest["utime"], dt, kd, 0.0, 0.0, 0.0, tuple(G), tuple(v),
                    (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), tuple(target), tuple(free_G - target),
                    tuple(planes),
                )  # fmt: skip
                lcm.Publish(LOCAL_MODEL_CHANNEL, model.encode())
        next_step += h
        wait = next_step - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        else:
            next_step = time.monotonic()


# -- one run -----------------------------------------------------------------------------------------------


def free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(scene: str, rate_hz: float, kd: float, local: bool, kill: bool, folder: Path) -> dict:
    from godobject_drake.driver import process as drv

    url = f"udp://127.0.0.1:{free_port()}"
    key = folder / "link.key"
    log, summary = folder / "driver.csv", folder / "driver.json"
    env = {**os.environ, "GODOBJECT_LINK_KEY": str(key)}
    seconds = 4.6
    if scene == "scripted":
        hand = HAND
        command = [sys.executable, __file__, "--serve", url, "--rate", str(rate_hz), "--kd", str(kd),
                   "--seconds", str(seconds + 3)]  # fmt: skip
    else:
        hand, command = lego_command(url, rate_hz, kd, folder, scene)
        seconds = hand["waypoints"][-1]["t"] + 0.5
    (folder / "hand.json").write_text(json.dumps(hand))
    scene_process = subprocess.Popen(command, cwd=folder, env=env, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True)  # fmt: skip
    driver_command = [sys.executable, "-m", "godobject_drake.driver.process", "run", "emulated",
                      "--scene", url, "--hand", str(folder / "hand.json"), "--log", str(log),
                      "--summary", str(summary), "--duration", str(seconds + 60)]  # fmt: skip
    driver_command += [] if local else ["--no-local-model"]
    driver_command += ["--rt-priority", str(RT_PRIORITY)] if RT_PRIORITY else []
    driver = subprocess.Popen(driver_command, cwd=folder, env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True)  # fmt: skip
    t_kill = None
    try:
        first = None
        while True:
            time.sleep(0.05)
            if log.exists():
                rows = drv.read_log(log)
                ok = np.flatnonzero(rows["state"] != "waiting") if len(rows["t"]) else []
                if len(ok) and first is None:
                    first = rows["t"][ok[0]]
                if first is not None and time.monotonic() - first > seconds:
                    break
            if scene_process.poll() is not None and scene != "scripted":
                break
            if first is None and scene_process.poll() is not None:
                raise RuntimeError(f"the scene ended: {scene_process.stderr.read()[-2000:]}")
        if kill:
            os.kill(scene_process.pid, signal.SIGKILL)
            t_kill = time.monotonic()
            time.sleep(0.6)
        elif scene != "scripted":  # the brick scene ends on SIGTERM, writing its metrics
            scene_process.send_signal(signal.SIGTERM)
            scene_process.wait(timeout=120)
        driver.send_signal(signal.SIGTERM)
        driver.wait(timeout=60)
    finally:
        for p in (scene_process, driver):
            if p.poll() is None:
                p.kill()
                p.wait()
    rows, info = drv.read_log(log), json.loads(summary.read_text())
    out = measure(rows, info, hand, t_kill, rate_hz)
    out["fade_end_ms"] = 1e3 * (info.get("local_model", {}).get("fade_end_s") or math.nan)
    if (folder / "metrics.json").exists():  # the brick scene's own figures
        m = json.loads((folder / "metrics.json").read_text())
        out["scene_model_ms"] = m.get("lcm_local_model_ms", math.nan)
        out["scene_models"] = m.get("lcm_local_models", 0)
        out["real_time_factor"] = m.get("real_time_factor", math.nan)
    return out


def hand_start(rows) -> float:
    """When the hand's path started: the first period after the scene was first heard."""
    return rows["t"][np.flatnonzero(rows["state"] != "waiting")[0]]


def _unit(v) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return np.asarray(v, float) / n if n > 0 else np.zeros(3)


def measure(rows, info, hand, t_kill, rate_hz) -> dict:
    t = rows["t"] - hand_start(rows)
    x = np.c_[rows["x"], rows["y"], rows["z"]]
    f = np.c_[rows["fx"], rows["fy"], rows["fz"]]
    keep = np.isfinite(x[:, 0])
    t_abs, state = rows["t"][keep], rows["state"][keep]
    t, x, f = t[keep], x[keep], f[keep]
    windows = hand.get("windows", {"work": WORK_S, "hold": HOLD_S, "drag": DRAG_S})
    w = (t >= windows["work"][0]) & (t <= windows["work"][1])
    k = np.flatnonzero(w)[:-1]
    work = float(np.sum(np.einsum("ij,ij->i", f[k], x[k + 1] - x[k])))
    held = (t >= windows["hold"][0]) & (t <= windows["hold"][1])
    norm = np.linalg.norm(f, axis=1)
    drag = (t >= windows["drag"][0]) & (t <= windows["drag"][1])
    running = t_abs < (math.inf if t_kill is None else t_kill)  # trips while the scene runs
    tripped = (state[1:] == "watchdog") & (state[:-1] != "watchdog") & running[1:]
    out = {
        "work_mJ": work * 1e3,
        "ripple_N": float(np.ptp(norm[held])) if held.any() else math.nan,
        "ripple98_N": float(np.subtract(*np.percentile(norm[held], [99, 1]))) if held.any() else math.nan,
        "hold_N": float(np.mean(norm[held])) if held.any() else math.nan,
        "trips": int(np.sum(tripped)),
        "drag_N": float(np.mean(norm[drag])) if drag.any() else math.nan,
        # its parts: against the hand's motion (the drag proper) and the mean force (a held
        # body's weight shows here, not in the drag proper)
        "drag_against_N": float(np.mean(-f[drag] @ _unit(x[drag][-1] - x[drag][0])))
        if drag.any()
        else math.nan,
        "drag_mean_N": np.mean(f[drag], axis=0).round(4).tolist() if drag.any() else [],
        "pose_age_p99_ms": (info.get("spring_pose_age", {}).get("p99_s") or math.nan) * 1e3,
        "models": info.get("local_model", {}).get("models", 0),
        "overruns": int(info["counts"]["overruns"]),
    }
    if t_kill is not None:
        after = rows["t"] > t_kill
        nonzero = after & (np.linalg.norm(np.c_[rows["fx"], rows["fy"], rows["fz"]], axis=1) > 0)
        last = rows["t"][nonzero][-1] - t_kill if nonzero.any() else 0.0
        out["kill_to_zero_ms"] = last * 1e3
        out["kill_bound_ms"] = (3.0 / rate_hz + 0.05) * 1e3
    return out


# -- the brick scene -----------------------------------------------------------------------------------------


def lego_command(url: str, rate_hz: float, kd: float, folder: Path, scene: str = "lego"):
    """The brick scene as a process (diagrams/lego.yaml, device !Lcm on ``url``; ``lego_haptic``:
    the haptic recipe, diagrams/lego_haptic.yaml, h = 5 ms and the implicit coupling, its device
    sampled at the recipe's 200 Hz) and a hand that grasps brick_0, carries it to the wall, presses
    2.5 cm past the contact, holds, comes back (tests/test_driver.py's frame: the device turned 90°
    about z, its −y the world's +x)."""
    sys.path.insert(0, str(REPO / "tests"))
    from godobject_drake.config import scenario as sc

    yaml = f"""
device: !Lcm
  url: {url}
{"  rate_hz: 1000.0" if scene == "lego" else ""}
  start_xyz: [-0.10, 0.0, 0.0048]
  device_to_world: {{xyz: [-0.05, 0.0, 0.02], rpy_deg: [0, 0, 90.0]}}
feedback: {{kd: {kd}}}
simulation: {{duration_s: 600}}
"""
    scenario = folder / "scene.yaml"
    scenario.write_text(sc.scenario_to_yaml(sc.load_scenario(REPO / "diagrams" / f"{scene}.yaml", yaml)))
    metrics = folder / "metrics.json"
    contact_y = -0.030  # where brick_0 meets the wall (device y, m), read from a driver log
    press, out = contact_y - 0.025, contact_y + 0.01
    reach = 0.8 + (0.05 - out) / 0.06  # 6 cm/s from over brick_0 to 1 cm before the wall
    pressed = reach + (out - press) / 0.06
    back = pressed + 1.0 + (out - press) / 0.06
    hand = {
        "waypoints": [
            {"t": 0.0, "xyz": [0.0, 0.05, -0.0152], "grasp": False},
            {"t": 0.3, "xyz": [0.0, 0.05, -0.0152], "grasp": True},
            {"t": 0.8, "xyz": [0.0, 0.05, 0.0], "grasp": True},
            {"t": reach, "xyz": [0.0, out, 0.0], "grasp": True},
            {"t": pressed, "xyz": [0.0, press, 0.0], "grasp": True},
            {"t": pressed + 1.0, "xyz": [0.0, press, 0.0], "grasp": True},
            {"t": back, "xyz": [0.0, out, 0.0], "grasp": True},
            {"t": back + 0.5, "xyz": [0.0, out, 0.0], "grasp": True},
        ],
        "windows": {
            "work": (reach, back + 0.5),
            "hold": (pressed + 0.3, pressed + 0.9),
            "drag": (1.0, reach - 0.1),
        },
    }
    command = [
        sys.executable,
        str(REPO / "analysis" / "throttled_scene.py"),  # its link at rate_hz of wall time
        str(rate_hz),
        "run",
        str(scenario),
        "--no-progress",
        "--metrics",
        str(metrics),
    ]
    return hand, command


# -- the table -----------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", choices=("scripted", "lego", "lego_haptic"), default="scripted")
    p.add_argument("--rates", type=float, nargs="+", default=[1000, 200, 100, 30])
    p.add_argument("--kds", type=float, nargs="+", default=[50, 200, 1000])
    p.add_argument("--baseline", action="store_true", help="also run the driver on the held wrench")
    p.add_argument("--kill", action="store_true", help="SIGKILL the scene at the end of each run")
    p.add_argument("--json", default="", help="write the rows to this file")
    p.add_argument("--rt-priority", type=int, default=0, help="the driver's --rt-priority (0: none)")
    p.add_argument("--serve", default="", help=argparse.SUPPRESS)
    p.add_argument("--rate", type=float, default=1000.0, help=argparse.SUPPRESS)
    p.add_argument("--kd", type=float, default=200.0, help=argparse.SUPPRESS)
    p.add_argument("--seconds", type=float, default=10.0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    global RT_PRIORITY
    RT_PRIORITY = args.rt_priority
    if args.serve:
        serve(args.serve, os.environ["GODOBJECT_LINK_KEY"], args.rate, args.kd, args.seconds)
        return 0
    label = f"the brick scene (diagrams/{args.scene}.yaml, Drake)"
    if args.scene == "scripted":
        label = "SCRIPTED wall scene (not Drake: a god-object at ω 40 rad/s against a rigid wall)"
    rt = f"driver --rt-priority {args.rt_priority}" if args.rt_priority else "driver on the normal scheduler"
    print(f"local model benchmark: {label}; {rt}; {machine()}")
    header = (f"{'driver':13s} {'scene Hz':>8s} {'kd':>6s} {'work mJ':>8s} {'ripple N':>9s} {'p1-p99':>7s} "
              f"{'hold N':>7s} "
              f"{'trips':>5s} {'drag N':>7s} {'age p99 ms':>10s} {'overruns':>8s} {'models':>6s}"
              + (f" {'kill→0 ms':>9s} {'bound':>6s} {'fade':>6s}" if args.kill else ""))  # fmt: skip
    print(header)
    results = []
    modes = [True, False] if args.baseline else [True]
    for rate in args.rates:
        for kd in args.kds:
            for local in modes:
                with tempfile.TemporaryDirectory() as folder:
                    r = run(args.scene, rate, kd, local, args.kill, Path(folder))
                r.update(
                    scene=args.scene, rate_hz=rate, kd=kd, driver="local model" if local else "held wrench"
                )
                results.append(r)
                line = (f"{r['driver']:13s} {rate:8g} {kd:6g} {r['work_mJ']:+8.3f} {r['ripple_N']:9.4f} "
                        f"{r['ripple98_N']:7.4f} "
                        f"{r['hold_N']:7.3f} {r['trips']:5d} {r['drag_N']:7.4f} {r['pose_age_p99_ms']:10.3f} "
                        f"{r['overruns']:8d} {r['models']:6d}")  # fmt: skip
                if args.kill:
                    line += f" {r['kill_to_zero_ms']:9.1f} {r['kill_bound_ms']:6.0f} {r['fade_end_ms']:6.0f}"
                print(line, flush=True)
    for r in results:
        if "scene_model_ms" in r:
            print(f"{r['driver']}, {r['rate_hz']:g} Hz, kd {r['kd']:g}: the scene published "
                  f"{r['scene_models']} local models, {r['scene_model_ms']:.3f} ms each; real-time factor "
                  f"{r['real_time_factor']:.2f}")  # fmt: skip
    print(f"after: {machine()}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
