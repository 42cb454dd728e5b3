#!/usr/bin/env python3
"""What a second tool costs: a two-tool scene against the same scene with its first tool alone,
interleaved round by round in one process.

    python analysis/second_tool_cost.py [--rounds 3] [--scenes lego_two_hands laparoscopy_bimanual]
                                        [--set organs.model=rigid]

Each round builds and runs both variants of each scene, alternating which goes first, and takes
the CPU time of the simulation loop per simulated second (``cpu_time_s / sim_time_s`` from the
run's metrics: the loop alone, not the build, and less moved by other work on the machine than
the wall clock). The one-tool variant keeps the scene's first tool and drops the others' loops;
their models leave the directives too when they are articulated (a grasper no loop drives would
still be simulated), so the comparison is "this scene as one tool" against "as two". A free body
the dropped tool would have held stays in the scene. Prints each round's ratio, the median, the
machine and the load.
"""

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

import yaml

from godobject_drake.config import scenario as sc
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"


def one_tool(s: sc.Scenario, folder: Path) -> sc.Scenario:
    """``s`` with its first tool alone; the other tools' articulated models out of its directives."""
    first, *others = s.tools
    out = sc.replace(s)
    dropped = [
        out.tools[n].god_object.model for n in others if isinstance(out.tools[n].god_object, sc.Articulated)
    ]
    out.tools = {first: out.tools[first]}
    if dropped:
        out.directives = _directives_without(out, dropped, folder)
    return out


def _directives_without(s: sc.Scenario, models: list[str], folder: Path):
    """The scene's directives, its ``add_directives`` files read, with every directive naming one
    of ``models`` (an add_model, its weld, its frame) left out: a new file in ``folder``."""
    entries = []
    for directive in s.directives:
        file = directive.add_directives.file if directive.add_directives else None
        if file:
            path = sc.MODELS_DIR / file.removeprefix("package://godobject_models/")
            entries += yaml.safe_load(path.read_text())["directives"]
    names = set(models)
    frames = {
        e["add_weld"]["parent"]
        for e in entries
        if "add_weld" in e and e["add_weld"]["child"].split("::")[0] in names
    }
    kept = [
        e for e in entries
        if not (
            ("add_model" in e and e["add_model"]["name"] in names)
            or ("add_weld" in e and e["add_weld"]["child"].split("::")[0] in names)
            or ("add_frame" in e and e["add_frame"]["name"] in frames)
        )
    ]  # fmt: skip
    out = folder / "one_tool.dmd.yaml"
    out.write_text(yaml.safe_dump({"directives": kept}))
    return sc.scenario_from_yaml(f"directives:\n- add_directives:\n    file: {out}\n").directives


def cost(s: sc.Scenario) -> float:
    """CPU seconds per simulated second of one run."""
    m = simulate(build_station(s, meshcat=None), progress=False).metrics
    if m["diverged"] or m["partial"]:
        sys.exit(f"{s.name}: the run did not finish ({m.get('diagnosis')})")
    return m["cpu_time_s"] / m["sim_time_s"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--scenes", nargs="+", default=["lego_two_hands", "laparoscopy_bimanual"])
    parser.add_argument("--set", action="append", default=[], dest="sets", metavar="KEY=VALUE")
    args = parser.parse_args(argv)
    ratios: dict[str, list[float]] = {}
    costs: dict[str, dict[str, list[float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        variants = {}
        for scene in args.scenes:
            s = sc.shipped_scenario(scene)
            if args.sets:
                s = sc.replace(s, **dict(item.split("=", 1) for item in args.sets))
            s = sc.replace(s, **{"recording.file": "", "visualization.serve": False})
            folder = Path(tmp) / scene
            folder.mkdir()
            variants[scene] = {"one": one_tool(s, folder), "two": s}
            ratios[scene], costs[scene] = [], {"one": [], "two": []}
        for k in range(args.rounds):
            for scene, pair in variants.items():
                order = ("one", "two") if k % 2 == 0 else ("two", "one")
                got = {which: cost(pair[which]) for which in order}
                for which in order:
                    costs[scene][which].append(got[which])
                ratios[scene].append(got["two"] / got["one"])
                print(f"round {k + 1} {scene:22s} one tool {got['one']:6.3f} CPU s per simulated s, two "
                      f"{got['two']:6.3f}: {got['two'] / got['one']:.3f}", flush=True)  # fmt: skip
    print(f"\nmachine: nproc {os.cpu_count()}, {cpu_model()}; load {os.getloadavg()[0]:.1f} at the end")
    for scene, r in ratios.items():
        one, two = (statistics.median(costs[scene][w]) for w in ("one", "two"))
        print(f"{scene:22s} two tools / one: median {statistics.median(r):.3f} (rounds {min(r):.3f} to "
              f"{max(r):.3f}); median CPU s per simulated s one {one:.3f}, two {two:.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
