"""Per-step cost of two source trees of this package, measured as interleaved pairs.

A refactoring that should not change speed is checked with this: a checkout of the code before
(``git worktree add /tmp/before <commit>``) against this one. Each pair runs the same scene once
with each tree, in fresh processes, A then B, so a machine whose speed drifts slows both alike;
the figure is the per-pair ratio B/A of the run's CPU time per plant step (the process's CPU time
over ``simulate``: the stepping loop and the metrics' folding, not the build), and its median over
the pairs. Pairs alternate their order (A B, then B A) so a drift within a pair cancels.

    python analysis/step_cost_pairs.py /tmp/before . --pairs 5

Absolute costs depend on the machine: the script prints ``nproc`` and the CPU model beside them.
"""

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

from godobject_drake.studies.benchmark import cpu_model

SCENES = {  # scene: (overrides, simulated seconds)
    "lego": ("", 4.0),
    "laparoscopy": ("", 4.0),
    "deformable_probe": ("", 1.0),
}

RUN = """
import json, sys, time, warnings
from godobject_drake.station.build import build_station
from godobject_drake.config.scenario import load_scenario, replace
from godobject_drake.simulation import simulate
scene, overrides, duration = sys.argv[1], sys.argv[2], float(sys.argv[3])
s = load_scenario(f"{sys.argv[4]}/diagrams/{scene}.yaml", overrides or None)
s = replace(s, **{"simulation.duration_s": duration})
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    station = build_station(s)
    cpu = time.process_time()
    m = simulate(station, progress=False, keep_logs=False).metrics
    cpu = time.process_time() - cpu
steps = round(m["sim_time_s"] / m["time_step_s"])
print(json.dumps({"step_cost_us": m["step_cost_us"], "cpu_us": 1e6 * cpu / steps, "diverged": m["diverged"]}))
"""


def step_cost(tree: Path, scene: str) -> float:
    overrides, duration = SCENES[scene]
    env = {**os.environ, "PYTHONPATH": str(tree.resolve())}
    out = subprocess.run(
        [sys.executable, "-c", RUN, scene, overrides, str(duration), str(tree.resolve())],
        env=env, capture_output=True, text=True, check=True, cwd=tree,
    ).stdout  # fmt: skip
    result = json.loads(out.strip().splitlines()[-1])
    if result["diverged"]:
        raise RuntimeError(f"{scene} diverged with the tree {tree}")
    return result["cpu_us"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path, help="the source tree measured first in each pair (A)")
    parser.add_argument("after", type=Path, help="the source tree measured second (B)")
    parser.add_argument("--pairs", type=int, default=5, help="pairs per scene")
    parser.add_argument("--scenes", nargs="*", choices=sorted(SCENES), default=list(SCENES))
    args = parser.parse_args(argv)
    print(f"{os.cpu_count()} CPUs (nproc), {cpu_model()}; Python {platform.python_version()}")
    header = ("scene", "A CPU µs/step", "B CPU µs/step", "B/A per pair: median [min, max]")
    print(f"{header[0]:18s} {header[1]:>19s} {header[2]:>19s} {header[3]:>34s}")
    for scene in args.scenes:
        a, b = [], []
        for k in range(args.pairs):
            if k % 2 == 0:
                a.append(step_cost(args.before, scene))
                b.append(step_cost(args.after, scene))
            else:
                b.append(step_cost(args.after, scene))
                a.append(step_cost(args.before, scene))
        ratios = [y / x for x, y in zip(a, b, strict=True)]
        print(
            f"{scene:18s} {statistics.median(a):19.1f} {statistics.median(b):19.1f} "
            f"{statistics.median(ratios):>17.3f} [{min(ratios):.3f}, {max(ratios):.3f}]",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
