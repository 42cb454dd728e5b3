"""Both hands from two drivers: the figures per hand of ``laparoscopy_bimanual_drivers`` run
as three processes on loopback, the scene (``godobject run``) and two ``godobject-driver run
emulated`` processes, one per hand (``--hand bimanual_left``, ``--hand bimanual_right``).

Each round runs the scene's 8 s (at real time: the hands move on the wall clock) on free ports,
with a key file of its own in a temporary folder, and prints per hand:

- the force the driver rendered: its peak ``|f|`` over the run, and its mean ``|f|`` and mean
  z in contact: the left while its grasper holds the edge (the scene's ``grasp_events``) and the
  hand has lifted (the handle above −15 mm), the right while its handle is within 5 mm of the
  press's depth (below −30 mm; the tissue stops the tool there);
- the driver's watchdog trips, overruns (periods that started late), force and rate clamps and
  buzz events; the feedback's gaps at the driver (p50, p99, max);
- the scene's side of the link: samples with no new pose (``lcm_silent_samples``), samples the
  grasper's target did not take (``pose_to_joints_held_samples``: missing, the driver silent past
  ``timeout_periods``, or invalid, or a jump, of which ``pose_to_joints_rejected_jumps``), the
  pairings and refused drivers;

and the scene's real-time factor, how far behind it ended, its CPU time per simulated second,
with the machine's cores, CPU model and load average before and after.

``--scene peg_transfer_drivers``: the same for the peg transfer from two drivers (its hands
``--hand peg_left`` and ``peg_right``, each taking a ring on a left peg and pressing it onto the
board around its peg); the contact is each hand's hold, pressed (5 to 7 s on its clock), with the
rendered force's ripple (peak to peak of its norm) there and the work the device did on the
handle over the run (Σ f · Δx: at most what the damping spent, if the rendering is passive).

    python analysis/bimanual_drivers.py [--scene NAME] [--rounds 1] [--set tools.left.feedback.kd=60 ...]
        [--out FILE.json]

Two figures behind the scene's choices, without drivers:

- ``--rates 1000 200 100``: what the device's rate costs. Each rate, the scene with both devices
  on ``memq://`` (nothing sends: the tools hold their start) runs ``--seconds`` (2), beside the
  scripted ``laparoscopy_bimanual`` before each, in one process: CPU time per simulated second
  (an LCM device keeps the run on the wall clock, so a rate it cannot hold also warns).
- ``--stiffness``: the feedback's stiffness at each device per N/m of ``feedback.kd``, along the
  tube and across it, at each waypoint of the shipped hands: the eigenvalues of
  ``J⁻ᵀ (Σ Jᵢᵀ Jᵢ) J⁻¹`` (``J`` the trocar's Jacobian of the tip, ``Jᵢ`` Drake's Jacobians of the
  coupled bodies' centres of mass on yaw, pitch and insertion: Eq. 8's translational spring).

Not a test: figures depend on the machine's load. All traffic stays on 127.0.0.1.
"""

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HANDS = ("left", "right")
DRIVER_COUNTS = ("loops", "overruns", "watchdog_trips", "force_clamps", "rate_clamps", "buzz_events")
SCENE_COUNTS = (
    "lcm_silent_samples", "pose_to_joints_held_samples", "pose_to_joints_rejected_jumps", "lcm_udp_pairings",
    "lcm_udp_refused_drivers", "grasp_events", "max_tissue_contact_force_N", "max_feedback_force_N",
)  # fmt: skip


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def machine() -> str:
    cpu = next(
        (ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "?"
    )
    return f"nproc {os.cpu_count()}, {cpu}, load average {' '.join(f'{v:.2f}' for v in os.getloadavg())}"


# the scenes of two drivers: each scene's hands (models/haptic/PREFIX_left.json, ..._right.json)
SCENES = {"laparoscopy_bimanual_drivers": "bimanual", "peg_transfer_drivers": "peg"}
PEG_PRESSED_S = (5.0, 7.0)  # the peg hands' hold, pressed (s on their clock)


def run_round(work: Path, sets: list[str], scene_name: str = "laparoscopy_bimanual_drivers") -> dict:
    """The scene and its two drivers once; the metrics, each driver's summary and log."""
    env = {**os.environ, "GODOBJECT_LINK_KEY": str(work / "link.key")}  # made on first use
    urls = {name: f"udp://127.0.0.1:{free_port()}" for name in HANDS}
    flags = [f"--set=tools.{name}.device.url={urls[name]}" for name in HANDS]
    flags += [f"--set={s}" for s in sets]
    scene = subprocess.Popen(
        [sys.executable, "-m", "godobject_drake", "run", scene_name, "--no-progress",
         "--metrics", str(work / "metrics.json"), *flags],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    drivers = {
        name: subprocess.Popen(
            [
                sys.executable,
                "-m",
                "godobject_drake.driver.process",
                "run",
                "emulated",
                "--scene",
                urls[name],
                "--hand",
                f"{SCENES[scene_name]}_{name}",
                "--exit-on-stop",
                "--log",
                str(work / f"{name}.csv"),
                "--summary",
                str(work / f"{name}.json"),
            ],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for name in HANDS
    }
    try:
        _, err = scene.communicate(timeout=600)
        if scene.returncode != 0:
            raise RuntimeError(f"the scene failed ({scene.returncode}): {err[-2000:]}")
        for driver in drivers.values():
            driver.wait(timeout=60)
    finally:
        for p in (scene, *drivers.values()):
            p.kill()
    from godobject_drake.driver.process import read_log

    return {
        "scene": scene_name,
        "metrics": json.loads((work / "metrics.json").read_text()),
        "summaries": {name: json.loads((work / f"{name}.json").read_text()) for name in HANDS},
        "logs": {name: read_log(work / f"{name}.csv") for name in HANDS},
    }


def contact(name: str, log, tool: dict, scene_name: str = "laparoscopy_bimanual_drivers") -> np.ndarray:
    """The driver's periods in contact (module docstring): its own rows, ``state`` ok."""
    ok = log["state"] == "ok"
    if scene_name == "peg_transfer_drivers":  # the hand's hold, pressed, on its clock
        t_hand = log["t"] - log["t"][np.argmax(ok)]
        return ok & (t_hand >= PEG_PRESSED_S[0]) & (t_hand <= PEG_PRESSED_S[1])
    if name == "right":
        return ok & (log["z"] < -0.030)
    events = [float(e.split()[0]) for e in tool.get("grasp_events", [])]
    if len(events) < 2:
        return np.zeros_like(ok)
    return ok & (log["t_scene"] > events[0]) & (log["t_scene"] < events[1]) & (log["z"] > -0.015)


def work_on_handle(log) -> float:
    """The work the device's rendered force did on the handle over the run (J): Σ f · Δx."""
    x, f = np.c_[log["x"], log["y"], log["z"]], np.c_[log["fx"], log["fy"], log["fz"]]
    moved = np.isfinite(x[1:, 0]) & np.isfinite(x[:-1, 0])  # the exit row has no pose
    return float(np.sum(np.einsum("ij,ij->i", f[:-1][moved], (x[1:] - x[:-1])[moved])))


def hand_figures(name: str, r: dict) -> dict:
    m, log, summary = r["metrics"], r["logs"][name], r["summaries"][name]
    tool = m["tools"][name]
    f = np.c_[log["fx"], log["fy"], log["fz"]]
    norm = np.linalg.norm(f, axis=1)
    touching = contact(name, log, tool, r["scene"])
    gap = summary["feedback_gap"]
    return {
        "peak_N": float(norm.max()),
        "contact_periods": int(touching.sum()),
        "contact_mean_N": float(norm[touching].mean()) if touching.any() else float("nan"),
        "contact_mean_fz_N": float(f[touching, 2].mean()) if touching.any() else float("nan"),
        "contact_ripple_N": float(np.ptp(norm[touching])) if touching.any() else float("nan"),
        "work_on_handle_mJ": 1e3 * work_on_handle(log),
        **{k: summary["counts"][k] for k in DRIVER_COUNTS},
        "gap_ms": [1e3 * gap[k] for k in ("p50_s", "p99_s", "max_s")],
        **{k: tool.get(k) for k in SCENE_COUNTS},
    }


def report(k: int, r: dict, before: str, after: str) -> dict:
    m = r["metrics"]
    duration = m["duration_s"] if "duration_s" in m else m["sim_time_s"]
    scene = {
        "real_time_factor": m["real_time_factor"],
        "behind_at_end_s": m.get("realtime_lag_end_s"),
        "cpu_per_simulated_s": m["cpu_time_s"] / duration,
        "diverged": m["diverged"],
    }
    hands = {name: hand_figures(name, r) for name in HANDS}
    print(f"\nround {k}: before: {before}\n         after:  {after}")
    print(
        f"  scene: real-time factor {scene['real_time_factor']:.2f}, ended {scene['behind_at_end_s']:.2f} s "
        f"behind, {scene['cpu_per_simulated_s']:.2f} s CPU per simulated s, diverged {scene['diverged']}"
    )
    for name, h in hands.items():
        print(
            f"  {name:5s}: rendered peak {h['peak_N']:.2f} N; in contact ({h['contact_periods']} periods) "
            f"mean |f| {h['contact_mean_N']:.2f} N, mean fz {h['contact_mean_fz_N']:+.2f} N, ripple "
            f"{h['contact_ripple_N']:.3f} N; work on the handle {h['work_on_handle_mJ']:+.2f} mJ; "
            f"{h['watchdog_trips']} watchdog trips, {h['overruns']} overruns of {h['loops']} periods, "
            f"{h['force_clamps']} force / {h['rate_clamps']} rate clamps, {h['buzz_events']} buzz; "
            f"feedback gap p50/p99/max {'/'.join(f'{v:.1f}' for v in h['gap_ms'])} ms"
        )
        print(
            f"         scene side: {h['lcm_silent_samples']} silent samples, "
            f"{h['pose_to_joints_held_samples']} held ({h['pose_to_joints_rejected_jumps']} jumps), "
            f"{h['lcm_udp_pairings']} pairing(s), {h['lcm_udp_refused_drivers']} refused; tissue force "
            f"peak {h['max_tissue_contact_force_N'] or 0.0:.2f} N, feedback peak "
            f"{h['max_feedback_force_N']:.2f} N; "
            f"grasps {h['grasp_events']}"
        )
    return {"before": before, "after": after, "scene": scene, "hands": hands}


def rates(values: list[float], seconds: float) -> None:
    """CPU per simulated second of the scene at each device rate, the scripted scene beside it."""
    from godobject_drake.config import scenario as sc
    from godobject_drake.config.scenario import replace
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    def cost(s) -> float:
        station = build_station(s)
        start = time.process_time()
        simulate(station, progress=False, realtime_rate=0.0, keep_logs=False)
        return (time.process_time() - start) / seconds

    scripted = replace(sc.shipped_scenario("laparoscopy_bimanual"), **{"simulation.duration_s": seconds})
    print(f"\n{machine()}")
    for rate in values:
        s = replace(sc.shipped_scenario("laparoscopy_bimanual_drivers"), **{"simulation.duration_s": seconds})
        for name in HANDS:
            device = s.tools[name].device
            device.url, device.rate_hz = "memq://", rate
            device.channel, device.feedback_channel = f"POSE_{name}", f"FEEDBACK_{name}"
        print(
            f"  scripted {cost(scripted):.2f} s CPU per simulated s; devices at {rate:g} Hz {cost(s):.2f} s"
        )
    print(machine())


def stiffness(scene_name: str = "laparoscopy_bimanual_drivers") -> None:
    """The feedback's stiffness at each device per N/m of kd along each shipped hand's path."""
    from godobject_drake.config import scenario as sc
    from godobject_drake.config.scenario import MODELS_DIR, replace
    from godobject_drake.devices.trocar import TrocarKinematics
    from godobject_drake.station.build import build_station

    scripted = scene_name.removesuffix("_drivers")  # the same plant, its scripted devices
    s = replace(sc.shipped_scenario(scripted), **{"organs.model": "rigid"})
    station, drivers = build_station(s), sc.shipped_scenario(scene_name)
    plant = station.plant
    for name in HANDS:
        tool, model = station.tools[name].coupling.tool, plant.GetModelInstanceByName(f"grasper_{name}")
        kin = TrocarKinematics.from_plant(plant, model, "port", "tube", ("yaw", "pitch", "insertion", "roll"))
        v = [plant.GetJointByName(j, model).velocity_start() for j in ("yaw", "pitch", "insertion")]
        origin = np.asarray(drivers.tools[name].device.device_to_world.xyz, float)
        hand = json.loads((MODELS_DIR / "haptic" / f"{SCENES[scene_name]}_{name}.json").read_text())
        hand = hand["waypoints"]
        for w in hand:
            q4 = kin.inverse(origin + w["xyz"], np.eye(3))
            K = sum(J[3:, v].T @ J[3:, v] for J in tool.com_jacobians(np.r_[q4, 0.0, 0.0]))
            Jinv = np.linalg.inv(kin.jacobian(q4))
            K_device = Jinv.T @ K @ Jinv
            u = kin.forward(q4)[1][:, 2]  # the tube's axis
            across = np.linalg.eigvalsh(K_device)[-2:]
            print(
                f"  {name:5s} t {w['t']:6.1f} s, insertion {q4[2] * 1e3:5.1f} mm: per N/m of kd, "
                f"{u @ K_device @ u:.2f} N/m along the tube, {across[0]:.2f} and {across[1]:.2f} across"
            )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rounds", type=int, default=1, help="runs of the three processes (default 1)")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE",
        help="a scenario override passed to the scene (e.g. tools.left.feedback.kd=60)",
    )  # fmt: skip
    parser.add_argument(
        "--scene",
        choices=tuple(SCENES),
        default="laparoscopy_bimanual_drivers",
        help="the scene of two drivers (default laparoscopy_bimanual_drivers)",
    )
    parser.add_argument("--out", default="", help="write every round's figures to FILE.json")
    parser.add_argument("--rates", type=float, nargs="+", metavar="HZ", help="the device rates' cost instead")
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated s per --rates run (default 2)")
    parser.add_argument("--stiffness", action="store_true", help="the feedback's stiffness at each device")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error(f"--rounds {args.rounds} must be ≥ 1")
    if args.rates or args.stiffness:
        if args.rates and not (args.seconds > 0 and all(r > 0 for r in args.rates)):
            parser.error(f"--rates {args.rates} and --seconds {args.seconds} must be > 0")
        if args.stiffness:
            stiffness(args.scene)
        if args.rates:
            rates(args.rates, args.seconds)
        return 0
    rounds = []
    for k in range(1, args.rounds + 1):
        before = machine()
        with tempfile.TemporaryDirectory() as work:  # mode 0700: the key file's folder
            r = run_round(Path(work), args.set, args.scene)
        rounds.append(report(k, r, before, machine()))
        time.sleep(1.0)
    if args.out:
        out = {"scene": args.scene, "sets": args.set, "rounds": rounds}
        Path(args.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
