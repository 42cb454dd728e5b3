"""Record the trajectories of every shipped scene and variant, or compare them bit for bit.

A refactoring that should not change what a scene does is checked with this: record the
variants on the code before, record them again after, and compare. Each variant is a shipped
scenario with YAML overrides (the device kinds, haptic modes, couplings, shells, position
mode, sleeping, bricks, noise, the pseudo-haptic aids), run over its whole path with every
log kept; the plant's state at every step and every other logger's rows are stored, and two
recordings are equal only if every float has the same bits.

    python analysis/trajectory_check.py record /tmp/before          # on the old code
    python analysis/trajectory_check.py record /tmp/after           # on the new code
    python analysis/trajectory_check.py compare /tmp/before /tmp/after

``compare`` exits 1 if any variant differs, naming the variant, the log and the first step.
"""

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DIAGRAMS = ROOT / "diagrams"
MODELS = ROOT / "models"

# name: (shipped scene, YAML overrides, simulated seconds or None for the scene's whole path)
H1 = "plant: {time_step: 0.001}\n"
VARIANTS = {
    "lego": ("lego", "", None),
    "lego_sleep_off": ("lego", "sleep: {enabled: false}", None),
    "lego_bricks_16": ("lego", "bricks: 16", 3.0),
    "lego_position": ("lego", "simulation: {mode: position}", None),
    "lego_impedance": (
        "lego",
        "haptic: {mode: impedance, passivity_damping: 100.0}\nfeedback: {kd: 20.0, gamma_d: 0.2}",
        2.0,
    ),
    "lego_admittance": ("lego", "haptic: {mode: admittance}", None),
    "lego_noise_linear": ("lego", "random_seed: 7\ndevice: !Scripted {path: "
                          f"{MODELS}/lego/default_path.yaml, noise_m: 0.001, interpolation: linear}}", None),
    "lego_relative": ("lego", f"device: !Relative {{log: {MODELS}/lego/push_and_return.csv, "
                      "start_xyz: [-0.10, 0.0, 0.0048]}", None),
    "lego_relative_tether": ("lego", f"device: !Relative {{log: {MODELS}/lego/push_and_return.csv, "
                             "start_xyz: [-0.10, 0.0, 0.0048], tether_m: 0.002}", None),
    "lego_relative_cd": ("lego", f"device: !Relative {{log: {MODELS}/lego/push_and_return.csv, "
                         "start_xyz: [-0.10, 0.0, 0.0048], cd_ratio: 4.0}", None),
    "lego_h2ms": ("lego", "plant: {time_step: 0.002}", None),
    "lego_implicit": ("lego", "god_object: {coupling: implicit}", None),
    "lego_implicit_bricks_16": ("lego", "god_object: {coupling: implicit}\nbricks: 16", 3.0),
    # the laparoscopy at h = 1 ms (the step its baseline variants are recorded at), then as shipped
    "laparoscopy": ("laparoscopy", H1, None),
    "laparoscopy_position": ("laparoscopy", H1 + "simulation: {mode: position}", None),
    "laparoscopy_h10": ("laparoscopy", "", None),
    "laparoscopy_fem": ("laparoscopy", "organs: {model: fem}", None),
    "laparoscopy_bimanual": ("laparoscopy_bimanual", "", 3.0),  # its FEM uterus and glued grasp site
    # the first ring lifted by the left jaws (a pose hold) and handed to the right ones, the task scored
    "peg_transfer": ("peg_transfer", "", 6.0),
    "laparoscopy_joint_pd": ("laparoscopy", H1 + "god_object: !Articulated {model: grasper, device_joints: "
                             "[yaw, pitch, insertion, roll, jaw_upper, jaw_lower], coupling: joint_pd, "
                             "imposed_joints: [jaw_upper, jaw_lower], gains: {omega_n: 20.0, zeta: 1.0}, "
                             "tip_body: tube, pivot_body: port}", None),
    "laparoscopy_joint_pd_sap": ("laparoscopy", H1 + "god_object: !Articulated {model: grasper, "
                                 "device_joints: [yaw, pitch, insertion, roll, jaw_upper, jaw_lower], "
                                 "coupling: joint_pd_sap, imposed_joints: [jaw_upper, jaw_lower], gains: "
                                 "{omega_n: 20.0, zeta: 1.0}, tip_body: tube, pivot_body: port}", None),
    "probe_fem": ("deformable_probe", "", None),
    "probe_mass_spring": ("deformable_probe", "god_object: !Deformable {name: probe, shell: mass_spring, "
                          "spec: {youngs_modulus_pa: 5.0e4, nodes: 42, fem_resolution_m: 0.02}, "
                          "gains: {omega_n: 30.0, zeta: 1.0, omega_n_rot: 30.0}}", None),
    "probe_position": ("deformable_probe", "simulation: {mode: position}", None),
    # a soft body of one's own (deformables:): the probe presses the lobe, its summary rows kept
    "own_soft_body": ("examples/own_soft_body/own_soft_body.yaml", "", 2.5),
}  # fmt: skip

# Metrics that measure the machine, not the run.
WALL_CLOCK_KEYS = (
    "wall_time_s",
    "cpu_time_s",
    "real_time_factor",
    "step_cost_us",
    "build_time_s",
    "metrics_time_s",
)


def run_variant(name: str) -> dict[str, np.ndarray]:
    from godobject_drake.config.scenario import load_scenario, replace
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    scene, overrides, duration = VARIANTS[name]
    path = ROOT / scene if "/" in scene else DIAGRAMS / f"{scene}.yaml"  # a shipped scene, or a file
    scenario = load_scenario(path, overrides or None)
    if duration is not None:
        scenario = replace(scenario, **{"simulation.duration_s": duration})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        station = build_station(scenario)
    result = simulate(station, progress=False, keep_logs=True)
    out = {f"log_{key}": np.asarray(value) for key, value in result.data.items()}
    numbers = {
        k: v for k, v in result.metrics.items()
        if isinstance(v, int | float) and not isinstance(v, bool) and k not in WALL_CLOCK_KEYS
        and not k.endswith("_us") and not k.endswith("_wall_s")
    }  # fmt: skip
    out["metric_names"] = np.array(sorted(numbers))
    out["metric_values"] = np.array([float(numbers[k]) for k in sorted(numbers)])
    return out


def record(directory: Path, names: list[str]) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    for name in names:
        start = time.perf_counter()
        arrays = run_variant(name)
        np.savez(directory / f"{name}.npz", **arrays)
        steps = len(arrays["log_state"])
        print(f"{name:28s} {steps:6d} steps  {time.perf_counter() - start:6.1f} s", flush=True)


def compare(before: Path, after: Path, names: list[str]) -> int:
    failures = 0
    for name in names:
        a, b = np.load(before / f"{name}.npz"), np.load(after / f"{name}.npz")
        problems = []
        ma, mb = (
            {
                str(k): v
                for k, v in zip(z["metric_names"], z["metric_values"], strict=True)
                if k not in WALL_CLOCK_KEYS
            }
            for z in (a, b)
        )
        if set(ma) - set(mb):  # a metric lost; one added is said, and is no difference in the run
            problems.append(f"metric keys lost: {sorted(set(ma) - set(mb))}")
        added = sorted(set(mb) - set(ma))
        differ = [
            k
            for k in set(ma) & set(mb)
            if np.float64(ma[k]).view(np.uint64) != np.float64(mb[k]).view(np.uint64)
        ]
        if differ:
            problems.append(f"metrics differ: {', '.join(sorted(differ))}")
        for key in sorted((set(a.files) | set(b.files)) - {"metric_names", "metric_values"}):
            if key not in a.files or key not in b.files:
                problems.append(f"{key} only in {'before' if key in a.files else 'after'}")
                continue
            x, y = a[key], b[key]
            if x.shape != y.shape:
                problems.append(f"{key}: shape {x.shape} -> {y.shape}")
            elif x.dtype.kind == "f" and not np.array_equal(x.view(np.uint64), y.view(np.uint64)):
                rows = np.nonzero((x.view(np.uint64) != y.view(np.uint64)).reshape(len(x), -1).any(axis=1))[0]
                problems.append(
                    f"{key}: first differs at row {rows[0]} (max |diff| {np.nanmax(abs(x - y)):.3g})"
                )
            elif x.dtype.kind != "f" and not np.array_equal(x, y):
                problems.append(f"{key}: differs")
        failures += bool(problems)
        verdict = "bit-identical" if not problems else "DIFFERS: " + "; ".join(problems)
        if added:
            verdict += f" (metric keys added: {', '.join(added)})"
        print(f"{name:28s} {len(a['log_state']):6d} steps  {verdict}")
    print(f"{len(names) - failures} of {len(names)} variants bit-identical")
    return 1 if failures else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="run every variant and store its logs")
    rec.add_argument("directory", type=Path)
    cmp = sub.add_parser("compare", help="compare two recordings bit for bit")
    cmp.add_argument("before", type=Path)
    cmp.add_argument("after", type=Path)
    for p in (rec, cmp):
        p.add_argument("--only", nargs="*", choices=sorted(VARIANTS), help="these variants only")
    args = parser.parse_args(argv)
    names = args.only or list(VARIANTS)
    if args.command == "record":
        record(args.directory, names)
        return 0
    return compare(args.before, args.after, names)


if __name__ == "__main__":
    sys.exit(main())
