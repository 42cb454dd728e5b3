#!/usr/bin/env python3
"""Two checkouts' cost per plant step, interleaved: did a change that should not cost anything cost
something? The companion of trajectory_check.py (which checks the same change keeps every bit).

    python analysis/cost_pairs.py OLD_CHECKOUT NEW_CHECKOUT [--rounds 5] [--scenes lego laparoscopy]

Each round runs every scene once with each checkout (``python -m godobject_drake run`` with the
checkout first on ``PYTHONPATH``, its own ``diagrams/NAME.yaml``), old and new back to back in an
order that alternates from round to round, and takes the CPU time of the simulation loop per
plant step from the run's metrics (``cpu_time_s``: the loop alone, not the build; less moved by
other work on the machine than the wall clock). It prints each scene's per-round ratio new/old,
their median and range, and the machine. ``--set KEY=VALUE`` is passed to every run (e.g.
``--set god_object.coupling=implicit``).
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def cost_per_step(checkout: Path, scene: str, sets: list[str]) -> float:
    """CPU seconds per plant step of one run of ``scene`` with ``checkout``'s code."""
    with tempfile.TemporaryDirectory() as tmp:
        metrics = Path(tmp) / "m.json"
        scenario = checkout / "diagrams" / f"{scene}.yaml"
        command = [sys.executable, "-m", "godobject_drake", "run", str(scenario), "--no-progress",
                   "--metrics", str(metrics), *[a for s in sets for a in ("--set", s)]]  # fmt: skip
        env = {**os.environ, "PYTHONPATH": str(checkout)}
        done = subprocess.run(command, env=env, cwd=tmp, capture_output=True, text=True)
        if done.returncode != 0:
            sys.exit(f"{checkout} {scene}: exit {done.returncode}\n{done.stderr[-2000:]}")
        m = json.loads(metrics.read_text())
    return m["cpu_time_s"] / round(m["sim_time_s"] / m["time_step_s"])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--scenes", nargs="+", default=["lego", "laparoscopy", "deformable_probe"])
    parser.add_argument("--set", action="append", default=[], dest="sets")
    args = parser.parse_args(argv)
    ratios = {scene: [] for scene in args.scenes}
    costs = {scene: {"old": [], "new": []} for scene in args.scenes}
    for k in range(args.rounds):
        for scene in args.scenes:
            order = ("old", "new") if k % 2 == 0 else ("new", "old")
            got = {which: cost_per_step(getattr(args, which).resolve(), scene, args.sets) for which in order}
            for which in ("old", "new"):
                costs[scene][which].append(got[which])
            ratios[scene].append(got["new"] / got["old"])
            old, new = got["old"] * 1e6, got["new"] * 1e6
            print(f"round {k + 1} {scene:17s} old {old:7.1f} µs/step, new {new:7.1f}: {new / old:.3f}",
                  flush=True)  # fmt: skip
    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")), "unknown CPU")  # fmt: skip
    print(f"\nmachine: nproc {os.cpu_count()}, {cpu}; load {os.getloadavg()[0]:.1f} at the end")
    for scene, r in ratios.items():
        old, new = (statistics.median(costs[scene][w]) * 1e6 for w in ("old", "new"))
        print(f"{scene:17s} new/old median {statistics.median(r):.3f} (rounds {min(r):.3f} to {max(r):.3f}); "
              f"median µs/step old {old:.1f}, new {new:.1f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
