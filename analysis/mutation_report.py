"""How strong are the core's unit tests? Mutation testing with mutmut, reported by unit.

mutmut changes the code one small step at a time (``<`` into ``<=``, ``+`` into ``-``, a
constant into another, an argument dropped) and runs the unit tests against each changed copy,
a *mutant*. A mutant the tests fail on is *killed*; one they pass is a *survivor*: a missing
test, an equivalent change (same behaviour, say why) or dead code. The configuration, which
modules are mutated and which tests run, is ``[tool.mutmut]`` in pyproject.toml; the last
run's numbers and the survivors' kinds are in docs/mutation.md.

Usage (from the repository root, with the Python that has the ``mutation`` extra; no activated
venv needed: mutmut runs as ``sys.executable -m mutmut``; 577 s measured on 2 cores for 3 014
mutants, 2 749 s for 4 848 with the local model on the machine loaded 2 to 5, docs/mutation.md;
CI runs it, .ci/run)::

    pip install -e '.[test,mutation]'
    python analysis/mutation_report.py --run          # mutate, test, report
    python analysis/mutation_report.py                # report the last run again
    python analysis/mutation_report.py --survivors    # ... with each survivor's diff

It exits 1 if a unit the goal covers kills fewer than ``--goal`` (default 85 %) of its mutants,
and with mutmut's own message (the end of reports/mutmut_run.log) if the run itself fails.

A whole run takes 11 to 15 minutes on 2 cores, so CI mutates only the goal units that have
changed since the last whole run: ``--run --record`` runs every goal unit and writes, beside
each unit's figures, a hash of its functions' source and of each test file whose tests reached
it (mutmut's own record of which tests reach which function) to ``analysis/mutation_baseline.json``;
``--run --changed`` runs only the units whose source or covering tests hash differently (every
unit when the goal's configuration changed) and reports the others from the record, marked
``recorded``. The goal holds for both::

    python analysis/mutation_report.py --run --record   # every goal unit; commit the record
    python analysis/mutation_report.py --run --changed  # what CI runs
"""

import argparse
import ast
import collections
import datetime
import hashlib
import importlib.metadata
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# The units that decide what a user feels (the goal applies to these), as (module or a tuple of
# modules, class, a tuple of classes or None, function names or None for all). A mutant is
# counted in the first unit it matches.
UNITS = {
    # GraspingCoupling: what the explicit and implicit couplings share (moved out of
    # GodObjectCoupling with no change of behaviour: its setup and caps, its grasp choice)
    "coupling: force law": ("systems.coupling", ("GodObjectCoupling", "GraspingCoupling"), {
        "__init__", "_setup_bodies", "_hot_body", "force_caps", "_calc_terms", "_calc_generalized_forces",
        "_calc_spatial_forces", "_slice_calc"}),
    "coupling: gains check": ("config.gains", "CouplingGains", None),
    "coupling: grasping": ("systems.coupling", ("GodObjectCoupling", "GraspingCoupling"), {
        "body_for_grasp", "validate_grasp_names", "nearest_body", "_update_grasp", "_grasp_change",
        "_body_state"}),
    "coupling: body lookup": ("systems.coupling", None, {"graspable_bodies", "fixed_bodies"}),
    "coupling: carried inertia": ("systems.coupling", None, {"with_carried_inertia"}),
    "feedback port": ("systems.feedback", "*", None),
    "spatial math": ("spatial", "*", None),
    "device sample guard": ("config.device_files", "SampleGuard", None),
    "device source (guard, timing)": ("devices.sources", "DeviceSource", None),
    "device aids (tether, ratio)": ("config.device_files", "RelativeAids", None),
    "device timing check": ("devices.sources", None, {"_check_timing"}),
    # what a haptic device renders: the driver's watchdog and stop, its rated limits
    # and buzz damping; what the link lets through: the key file, each datagram, each end's rules
    "driver: watchdog and stop": ("driver.safety", "FeedbackGate", None),
    "driver: rated limits and buzz": ("driver.safety", "ForceSafety", None),
    "link: key file": ("link.keys", None, {"key_path", "_check_folder", "_create_key", "load_key",
                                          "key_fingerprint"}),
    "link: datagrams and messages": ("link.transport", "_Tagger", None),
    "link: datagram checks": (("link.transport", "link.messages"), None, {
        "split", "data_fields", "decode", "parse_robot_state", "parse_url", "is_udp_url", "_derive"}),
    "link: each end's rules": ("link.transport", ("_End", "SceneEnd", "DriverEnd"), None),
    "link: transport": ("link.transport", "UdpLcm", None),
    # the local model: its payload on the link, and the driver's renderer
    # (driver/local_model.py): the proxy on the planes, the energy budget (the two accounts, the
    # controller, taking a model: everything of LocalRenderer but the validity), the validity (the
    # scene's period, the fade, the trips). heard and reserve are properties, which mutmut 3.8
    # leaves unmutated (it skips decorated functions); they are named for when it does not
    # GLM3 (an articulated tool's coupling as 3×3 matrices, docs/local_model.md
    # "An articulated tool"): the matrices' checks (_matrix) with the payload's, the proxy in
    # their metric with the scalar's
    "link: local model": ("link.messages", None, {"parse_local_model", "_finite", "_matrix", "alive_message",
                                                  "parse_alive"}),
    "link: local model payload": ("link.messages", "LocalModel", None),
    "driver: local model proxy": ("driver.local_model", None, {"project", "project_matrix", "spring_force",
                                                               "spring_energy", "explained"}),
    "driver: energy budget": ("driver.local_model", "LocalRenderer", {
        "__init__", "heard", "take", "proxy", "request", "_environment", "_account", "rendered", "reserve"}),
    "driver: local model validity": ("driver.local_model", "LocalRenderer", {"alive", "gap", "fade_end",
                                                                              "validity"}),
    # what no file, key or output may do (issue 55): the YAML bounds, the mesh indices before Drake
    # reads them (the surface meshes' checks: the tetrahedral reader beside them, a soft body's,
    # is tested by tests/test_own_soft_body.py, outside mutmut's selection), a key given as its
    # path or a missing named key file, the driver's outputs checked before the device is opened
    # and a log that can no longer grow
    "config: YAML bounds": ("config.yaml_guard", "*", None),
    "config: mesh indices": ("config.meshes", None, {"check_mesh", "_check_obj", "_obj_index", "_obj_refuse",
                                                     "_check_vtk", "_vtk_refuse"}),
    "link: key checks": ("link.keys", None, {"_not_a_key", "_missing"}),
    "driver: output checks": ("driver.process", (None, "Driver"), {"open_log_file", "check_summary", "_row",
                                                                   "_log_failed"}),
}  # fmt: skip
KILLED = {"killed", "timeout"}  # a mutant that hangs the tests is caught by the timeout
NAME = re.compile(r"godobject_drake\.([\w.]+?)\.x(?:ǁ(\w+)ǁ|_)(\w+?)__mutmut_\d+")
# mutmut of this Python, by module: no activated venv needed, and never another install's mutmut
MUTMUT = [sys.executable, "-m", "mutmut"]
BASELINE = ROOT / "analysis" / "mutation_baseline.json"
# mutmut's name of a mutated function: godobject_drake.MODULE.x_FUNCTION or .xǁCLASSǁMETHOD
FUNCTION = re.compile(r"godobject_drake\.([\w.]+?)\.x(?:ǁ(\w+)ǁ|_)(\w+)")


def unit_of(module: str, cls: str | None, function: str) -> str:
    for unit, (m, c, functions) in UNITS.items():
        if module not in (m if isinstance(m, tuple) else (m,)):
            continue
        if c == "*" or cls in (c if isinstance(c, tuple) else (c,)) or (c is None and cls is None):
            if functions is None or function in functions:
                return unit
    return f"{module}: other (tested elsewhere, not in the goal)"


def goal_globs(units=UNITS) -> list[str]:
    """mutmut name patterns (fnmatch) for the goal units' mutants (all of them, or ``units``):
    ``--run`` tests only these (the mutated modules' other functions are tested elsewhere;
    testing their mutants too took a fifth of the run)."""
    globs = []
    for modules, classes, functions in (UNITS[unit] for unit in units):
        for module in modules if isinstance(modules, tuple) else (modules,):
            prefix = f"godobject_drake.{module}."
            if classes == "*":
                globs.append(prefix + "x*")
                continue
            for cls in classes if isinstance(classes, tuple) else (classes,):
                head = prefix + ("x_" if cls is None else f"xǁ{cls}ǁ")
                names = ["*"] if functions is None else [f"{f}__mutmut_*" for f in sorted(functions)]
                globs += [head + name for name in names]
    return globs


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def unit_sources(root: Path = ROOT) -> dict[str, str]:
    """Each goal unit's hash: the source of every function of its module that :func:`unit_of`
    puts in it (decorators included), in file order. A change to the unit's code, and to nothing
    else, changes it."""
    parts = collections.defaultdict(list)
    for module in sorted(
        {m for ms, _, _ in UNITS.values() for m in (ms if isinstance(ms, tuple) else (ms,))}
    ):
        path = root / "godobject_drake" / (module.replace(".", "/") + ".py")
        source = path.read_text()
        lines = source.splitlines(keepends=True)
        for node in ast.parse(source).body:
            members = [(None, node)]
            if isinstance(node, ast.ClassDef):
                members = [(node.name, n) for n in node.body]
            for cls, fn in members:
                if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                    unit = unit_of(module, cls, fn.name)
                    if unit in UNITS:
                        first = min([fn.lineno, *(d.lineno for d in fn.decorator_list)])
                        parts[unit].append("".join(lines[first - 1 : fn.end_lineno]))
    return {unit: _sha("\n".join(parts[unit]).encode()) for unit in UNITS}


def configuration(root: Path = ROOT) -> str:
    """A hash of what decides the goal's mutants and tests: ``[tool.mutmut]``, the units, mutmut's
    version and the Python's. Another hash: the record says nothing of this configuration."""
    mutmut = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["mutmut"]
    try:
        version = importlib.metadata.version("mutmut")
    except importlib.metadata.PackageNotFoundError:  # the hash is still asked for: no run can match it
        version = "not installed"
    what = [mutmut, sorted((u, repr(m), repr(c), sorted(f or [])) for u, (m, c, f) in UNITS.items()),
            version, sys.version_info[:2]]  # fmt: skip
    return _sha(json.dumps(what, sort_keys=True, default=str).encode())


def covering_tests(root: Path = ROOT) -> dict[str, list[str]]:
    """Each goal unit's test files: those of the tests mutmut found reaching its functions in the
    last run (``mutants/mutmut-stats.json``)."""
    stats = json.loads((root / "mutants" / "mutmut-stats.json").read_text())
    files = collections.defaultdict(set)
    for name, tests in stats["tests_by_mangled_function_name"].items():
        m = FUNCTION.fullmatch(name)
        if m:
            files[unit_of(m.group(1), m.group(2), m.group(3))] |= {t.split("::")[0] for t in tests}
    return {unit: sorted(files[unit]) for unit in UNITS}


def file_hashes(paths, root: Path = ROOT) -> dict[str, str]:
    """Each file's hash, ``missing`` for one that is gone."""
    return {p: _sha((root / p).read_bytes()) if (root / p).is_file() else "missing" for p in paths}


def changed_units(baseline: dict | None, root: Path = ROOT) -> dict[str, str]:
    """The goal units a whole run must test again, each with why: all of them with no record or
    another configuration; else those whose source or covering tests hash otherwise."""
    if baseline is None:
        return dict.fromkeys(UNITS, f"no record ({BASELINE.relative_to(ROOT)})")
    if baseline.get("configuration") != configuration(root):
        why = "the goal's configuration changed ([tool.mutmut], the units, mutmut, Python)"
        return dict.fromkeys(UNITS, why)
    sources = unit_sources(root)
    changed = {}
    for unit in UNITS:
        record = baseline["units"].get(unit)
        if record is None:
            changed[unit] = "not in the record"
        elif record["source"] != sources[unit]:
            changed[unit] = "its source changed"
        else:
            tests = [p for p, h in record["tests"].items() if file_hashes([p], root)[p] != h]
            if tests:
                changed[unit] = "its tests changed: " + ", ".join(tests)
    return changed


def write_baseline(counts: dict[str, collections.Counter], root: Path = ROOT) -> None:
    """The record of a whole run (``--record``): each goal unit's figures and hashes."""
    covering, sources = covering_tests(root), unit_sources(root)
    units = {
        unit: {
            "source": sources[unit],
            "tests": file_hashes(["tests/conftest.py", *covering[unit]], root),
            "mutants": sum(counts[unit].values()),
            "killed": sum(counts[unit][s] for s in KILLED),
        }
        for unit in UNITS
    }
    record = {"recorded": datetime.date.today().isoformat(), "configuration": configuration(root),
              "python": sys.version.split()[0], "units": units}  # fmt: skip
    BASELINE.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    print(f"recorded {len(units)} units in {BASELINE.relative_to(ROOT)}")


def read_results() -> list[tuple[str, str, str]]:
    """``(mutant, unit, status)`` for every mutant of the last run."""
    out = subprocess.run(
        [*MUTMUT, "results", "--all", "true"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    rows = []
    for line in out.splitlines():
        name, _, status = line.strip().partition(": ")
        m = NAME.fullmatch(name)
        if m:
            rows.append((name, unit_of(m.group(1), m.group(2), m.group(3)), status.strip()))
    if not rows:
        sys.exit("mutmut has no results here: run with --run first")
    return rows


def run_mutmut(units: list[str], max_children: int) -> None:
    """mutmut on the units' mutants; exits with mutmut's own message (its log's end) if it fails."""
    log = ROOT / "reports" / "mutmut_run.log"
    log.parent.mkdir(exist_ok=True)
    with log.open("w") as f:  # mutmut's progress line is long; keep it out of the terminal
        run = subprocess.run([*MUTMUT, "run", "--max-children", str(max_children), *goal_globs(units)],
                             cwd=ROOT, stdout=f, stderr=subprocess.STDOUT)  # fmt: skip
    if run.returncode != 0:  # say why here (in CI the log is not kept): the log's end
        end = log.read_text(errors="replace")[-3000:]
        sys.exit(f"mutmut run failed (exit {run.returncode}); the end of {log}:\n{end}")


def select_units(args) -> tuple[list[str], dict | None]:
    """The goal units this call runs (all, or with ``--changed`` those :func:`changed_units`
    names, each said with why) and the record the others are reported from."""
    if not args.changed:
        return list(UNITS), None
    baseline = json.loads(BASELINE.read_text()) if BASELINE.is_file() else None
    changed = changed_units(baseline)
    for unit, why in changed.items():
        print(f"mutating {unit}: {why}")
    if baseline is not None and len(changed) < len(UNITS):
        same = len(UNITS) - len(changed)
        print(
            f"{same} goal units unchanged since the whole run of {baseline['recorded']} "
            f"({BASELINE.relative_to(ROOT)}): reported from it, marked 'recorded'"
        )
    return [u for u in UNITS if u in changed], baseline


def print_table(by_unit: dict, recorded: dict, goal: float) -> list[str]:
    """The per-unit table (a recorded unit from ``recorded``); returns the goal units below ``goal``."""
    print(f"{'unit':<52} {'mutants':>8} {'killed':>7} {'survived':>9} {'no tests':>9} {'killed %':>9}")
    failing = []
    for unit in [*UNITS, *sorted(u for u in by_unit if u not in UNITS)]:
        if unit in recorded:
            total, killed = recorded[unit]["mutants"], recorded[unit]["killed"]
            counts, mark = f"{total:>8} {killed:>7} {'':>9} {'':>9}", "  recorded"
        elif by_unit.get(unit):
            c = by_unit[unit]
            total, killed = sum(c.values()), sum(c[s] for s in KILLED)
            counts, mark = f"{total:>8} {killed:>7} {c['survived']:>9} {c['no tests']:>9}", ""
        else:
            continue
        share = killed / total
        if unit in UNITS and share < goal:
            failing.append(unit)
            mark += "  below goal"
        print(f"{unit:<52} {counts} {100 * share:>8.1f}%{mark}")
    return failing


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", action="store_true", help="run mutmut first (every unit: 11-15 min)")
    parser.add_argument(
        "--changed", action="store_true", help="with --run: only the goal units changed since the record (CI)"
    )
    parser.add_argument(
        "--record",
        action="store_true",
        help=f"with --run: every goal unit, then write {BASELINE.relative_to(ROOT)}",
    )
    parser.add_argument("--max-children", type=int, default=2, help="parallel test processes")
    parser.add_argument("--survivors", action="store_true", help="print each survivor's diff")
    parser.add_argument("--goal", type=float, default=0.85, help="share to kill in each goal unit")
    args = parser.parse_args(argv)
    if (args.changed or args.record) and not args.run:
        parser.error("--changed and --record go with --run")
    if args.changed and args.record:
        parser.error("--record needs every goal unit run: leave out --changed")
    units, baseline = select_units(args)
    if args.run and units:
        run_mutmut(units, args.max_children)
    recorded = {u: baseline["units"][u] for u in UNITS if u not in units} if baseline else {}
    rows = read_results() if units else []
    outside = sum(1 for _, unit, status in rows if unit not in UNITS and status == "not checked")
    rows = [row for row in rows if row[1] in units or (row[1] not in UNITS and row[2] != "not checked")]
    by_unit = collections.defaultdict(collections.Counter)
    for _, unit, status in rows:
        by_unit[unit][status] += 1
    failing = print_table(by_unit, recorded, args.goal)
    modules = collections.defaultdict(collections.Counter)
    for name, _, status in rows:
        modules[NAME.fullmatch(name).group(1)][status in KILLED] += 1
    shares = (f"{m} {c[True]}/{c[True] + c[False]}" for m, c in sorted(modules.items()))
    if modules:
        print("killed by module: " + ", ".join(shares))
    if outside:
        print(f"{outside} mutants outside the goal units were not run (--run tests the goal's: goal_globs())")
    if args.survivors:
        for name, unit, status in rows:
            if status == "survived" and unit in UNITS:
                show = [*MUTMUT, "show", name]
                diff = subprocess.run(show, cwd=ROOT, capture_output=True, text=True).stdout
                changed = [line for line in diff.splitlines() if line[:2] in ("- ", "+ ")]
                print(f"\n{name}  [{unit}]\n" + "\n".join(changed))
    if failing:
        print(f"below the {100 * args.goal:.0f} % goal: {', '.join(failing)}")
        return 1
    if args.record:
        write_baseline(by_unit)
    return 0


if __name__ == "__main__":
    sys.exit(main())
