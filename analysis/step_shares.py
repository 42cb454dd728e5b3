"""Where a step of the brick scene goes: py-spy's samples inside the simulation loop, by part.

``run`` is what to profile (the brick scene, ``simulate`` as ``godobject run`` calls it);
``shares`` reads py-spy's raw output (``-f raw``: one collapsed stack and its count a line) and
splits the samples taken inside the simulation loop's ``AdvanceTo`` call into Drake's C++ (SAP, the
SceneGraph pose update of every geometry, the geometry query's point pairs, the rest of the
plant, the framework) and the Python callbacks (the coupling's port reads and its arithmetic,
the sleep check, the safeguards, the device); what the loop does outside ``AdvanceTo`` (the
metrics fold) is given on top.

    py-spy record --native -r 50 -f raw -o /tmp/p8.txt -- python analysis/step_shares.py run
    py-spy record --native -r 50 -f raw -o /tmp/p64.txt -- \\
        python analysis/step_shares.py run --bricks 64 --seconds 3
    python analysis/step_shares.py shares /tmp/p8.txt /tmp/p64.txt

py-spy stops the process for each sample: on a small machine it runs the scene 10–20× slower
than real time, and a system call (the loop's CPU clock) can collect more samples than it costs.
The shares are of samples, not of time measured otherwise.
"""

import argparse
import ast
import collections
import sys
from pathlib import Path

LOOP_FILE = "godobject_drake/simulation.py"


def loop_lines() -> tuple[str, int, int]:
    """Where ``godobject_drake.simulation`` runs its loop: the qualified name of the function that
    calls ``AdvanceTo`` (as py-spy names its frames), that call's line, and the line of the metrics
    fold in the same function (−1 if none). Read from the source, so a restructured loop is found."""
    from godobject_drake import simulation

    tree = ast.parse(Path(simulation.__file__).read_text())

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                yield from visit(child, prefix + child.name + ".")
            elif isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                yield prefix + child.name, child
                yield from visit(child, prefix + child.name + ".<locals>.")

    def calls(function, name):
        return sorted(
            n.lineno
            for n in ast.walk(function)
            if isinstance(n, ast.Call)
            and (getattr(n.func, "attr", None) == name or getattr(n.func, "id", None) == name)
        )

    for qualname, function in visit(tree, ""):
        advance = calls(function, "AdvanceTo")
        if advance:
            fold = [line for line in calls(function, "fold") if line > advance[0]]
            return qualname, advance[0], fold[0] if fold else -1
    raise RuntimeError(f"no function of {LOOP_FILE} calls AdvanceTo: update step_shares.loop_lines")


def part(below: list[str]) -> str:
    """The part a sample below ``AdvanceTo`` belongs to (``below``: its frames, outermost first)."""
    ours = [k for k, f in enumerate(below) if "(godobject_drake/" in f]
    if ours:
        text = ";".join(below[k] for k in ours)
        after = ";".join(below[ours[-1] + 1 :])
        drake_call = "pydrake" in after or "libdrake" in after
        if "sleeping.py" in text:
            return "Python: sleep check"
        if "systems/coupling.py" in text or "systems/implicit.py" in text:
            return "Python: coupling, " + ("port reads and Drake calls" if drake_call else "its arithmetic")
        if "devices/" in text:
            return "Python: device"
        if "safeguards.py" in text:
            return "Python: safeguards (monitor, checks)"
        return "Python: other (" + below[ours[0]].split("(")[1].split(":")[0] + ")"
    if any(".py:" in f for f in below):
        return "Python: other"
    text = ";".join(below)
    if "CalcPoseUpdate" in text:
        return "C++: SceneGraph pose update (every geometry)"
    if "drake::geometry" in text or "fcl::" in text:
        return "C++: geometry query (point pairs)"
    if "Sap" in text:
        return "C++: SAP (contact problem and solve)"
    if "drake::multibody" in text:
        return "C++: rest of the plant"
    return "C++: framework (simulator, diagram, loggers)"


def shares(path: Path, loop: tuple[str, int, int]) -> dict:
    """Samples by part inside the loop's ``AdvanceTo`` call, and outside it in the loop's function
    (all; the fold); ``loop``: :func:`loop_lines`."""
    function, advance, fold = loop
    frame = f"{function} ({LOOP_FILE}:"
    inside: collections.Counter = collections.Counter()
    outside = folding = 0
    for line in path.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        frames = stack.split(";")
        at = next((k for k, f in enumerate(frames) if f.startswith(frame)), None)
        if at is None:
            continue
        where = int(frames[at][len(frame) :].rstrip(")"))
        if where == advance:
            inside[part(frames[at + 1 :])] += int(n)
        else:
            outside += int(n)
            folding += int(n) if where == fold else 0
    return {"inside": dict(inside), "outside": outside, "fold": folding}


def report(path: Path, s: dict) -> list[str]:
    total = sum(s["inside"].values())
    if not total:
        return [f"{path}: no sample inside the simulation loop's AdvanceTo"]
    cpp = sum(v for k, v in s["inside"].items() if k.startswith("C++"))
    out = [
        f"{path}: {total} samples inside AdvanceTo: C++ {100 * cpp / total:.1f} %, Python "
        f"{100 * (total - cpp) / total:.1f} %; outside it, in the loop, {100 * s['outside'] / total:.1f} % "
        f"on top (the metrics fold {100 * s['fold'] / total:.1f} %)"
    ]
    for k, v in sorted(s["inside"].items(), key=lambda kv: -kv[1]):
        out.append(f"  {k:46s} {100 * v / total:5.1f} %")
    return out


def run(bricks: int, seconds: float | None, repeats: int, deactivate: bool) -> None:
    from godobject_drake.config.scenario import replace, shipped_scenario
    from godobject_drake.simulation import simulate
    from godobject_drake.station.build import build_station

    changes: dict = {"sleep.deactivate": deactivate}
    if seconds is not None:
        changes["simulation.duration_s"] = seconds
    if bricks != 8:
        changes["bricks"] = bricks
    scenario = replace(shipped_scenario("lego"), **changes)
    for _ in range(repeats):
        metrics = simulate(build_station(scenario), progress=False).metrics
        print(f"{bricks} bricks: {metrics['cpu_time_s']:.2f} CPU s in the loop", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run the brick scene (the process to profile)")
    r.add_argument("--bricks", type=int, default=8)
    r.add_argument("--seconds", type=float, help="simulated s (default: the whole path)")
    r.add_argument("--repeats", type=int, default=1)
    r.add_argument("--deactivate", choices=("on", "off"), default="on", help="sleep.deactivate")
    s = sub.add_parser("shares", help="py-spy raw outputs to shares of a step")
    s.add_argument("raw", nargs="+", type=Path)
    args = parser.parse_args(argv)
    if args.command == "run":
        run(args.bricks, args.seconds, args.repeats, args.deactivate == "on")
        return 0
    loop = loop_lines()
    for path in args.raw:
        print("\n".join(report(path, shares(path, loop))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
