#!/usr/bin/env python3
"""CPU time per plant step of the implicit coupling on the brick scene: this tree's springs
against another implicit.py (the former seven vertical springs), interleaved in one process.

    python analysis/implicit_cost.py OLD_IMPLICIT_PY [--rounds 5] [--duration 8.5]
                                     [--time-step 1e-3] [--explicit]

OLD_IMPLICIT_PY is another version of godobject_drake/implicit.py, e.g. from
``git show 3a320c7:godobject_drake/implicit.py > /tmp/implicit_old.py``. The rest of the package
is this tree's: only ``godobject_drake.systems.implicit`` is swapped in ``sys.modules`` (the god-object
imports it when it builds and runs). Each round runs the shipped brick scene with
``god_object.coupling: implicit`` once with each version, the order alternating, and takes the
simulation loop's process CPU time (``metrics["cpu_time_s"]``, which a loaded machine inflates
less than the wall time) per plant step; printed: every run and the median ratio new/old (with
``--explicit`` the explicit coupling runs in each round too, and both against it).
"""

import argparse
import importlib.util
import statistics
import sys
import warnings

import godobject_drake.systems.implicit as new_implicit
from godobject_drake.config import scenario as sc
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station


def load(path: str):
    spec = importlib.util.spec_from_file_location("godobject_drake.systems.implicit", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def cost(module, duration: float, h: float, coupling: str = "implicit") -> tuple[float, dict]:
    sys.modules["godobject_drake.systems.implicit"] = module
    try:
        s = sc.replace(sc.shipped_scenario("lego"), **{"god_object.coupling": coupling,
                       "simulation.duration_s": duration, "plant.time_step": h})  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            station = build_station(s)
        m = simulate(station, progress=False).metrics
    finally:
        sys.modules["godobject_drake.systems.implicit"] = new_implicit
    steps = round(m["sim_time_s"] / m["time_step_s"])
    return 1e6 * m["cpu_time_s"] / steps, m


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--duration", type=float, default=8.5)
    parser.add_argument("--time-step", type=float, default=1e-3)
    parser.add_argument("--explicit", action="store_true", help="also run the explicit coupling each round")
    args = parser.parse_args(argv)
    versions = {"old": load(args.old), "new": new_implicit}
    print(f"springs: old {versions['old'].N_SPRINGS}, new {new_implicit.N_SPRINGS}; h = {args.time_step} s")
    runs = {"old": [], "new": []} | ({"explicit": []} if args.explicit else {})
    order = list(runs)
    for r in range(args.rounds):
        for name in order[r % len(order) :] + order[: r % len(order)]:
            coupling = "explicit" if name == "explicit" else "implicit"
            us, m = cost(versions.get(name, new_implicit), args.duration, args.time_step, coupling)
            runs[name].append(us)
            print(
                f"round {r} {name}: {us:.1f} µs CPU per step, penetration "
                f"{1e3 * m.get('max_penetration_m', float('nan')):.3f} mm",
                flush=True,
            )
    ratios = [n / o for n, o in zip(runs["new"], runs["old"], strict=True)]
    print("median µs/step: " + ", ".join(f"{k} {statistics.median(v):.1f}" for k, v in runs.items()))

    def line(label, r):
        print(
            f"ratio {label} per round {', '.join(f'{x:.3f}' for x in r)}; median {statistics.median(r):.3f}"
        )

    line("new/old", ratios)
    if args.explicit:
        for name in ("old", "new"):
            line(f"{name}/explicit", [a / b for a, b in zip(runs[name], runs["explicit"], strict=True)])


if __name__ == "__main__":
    main()
