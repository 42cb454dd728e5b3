"""The package's structure, as docs/design.md draws it: layers that point one way, no import cycle,
our own imports inside functions only where a comment says why, no function over 100 lines,
config types that load no Drake system of ours, a driver that loads no ``pydrake.systems``.

Read from the code's own imports (``ast``), so a change that breaks a rule fails here, naming the
module, the line and the rule.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

PACKAGE = REPO / "godobject_drake"

# Each module's layer; an import may point to its own layer or a lower one (docs/design.md).
LAYERS = (
    ("godobject_drake.spatial", 0),
    ("godobject_drake.limits", 0),
    ("godobject_drake.quantiles", 0),
    ("godobject_drake.outputs", 0),  # the standard library only: the scene's outputs and the driver's
    ("godobject_drake.config", 1),
    # the link: what a scene and a driver share; its scene half (a Drake system) is the scene's
    ("godobject_drake.link.scene_model", 2),
    ("godobject_drake.link", 1),
    ("godobject_drake.systems", 2),
    ("godobject_drake.devices", 2),
    ("godobject_drake.metrics", 2),
    ("godobject_drake.task_score", 2),  # a task's score, beside the metrics
    ("godobject_drake.task_metrics", 2),
    ("godobject_drake.safeguards", 2),
    ("godobject_drake.realtime", 2),
    ("godobject_drake.sleeping", 2),
    ("godobject_drake.station", 3),
    ("godobject_drake.simulation", 4),
    ("godobject_drake.cli", 5),
    ("godobject_drake.studies", 5),
    ("godobject_drake.__main__", 5),
)
# The driver's process stands beside the layers: it may use the link, the plain config and the
# outputs' guards only.
DRIVER = "godobject_drake.driver"
# (the link but its scene half: godobject_drake.link.scene_model loads pydrake.systems)
DRIVER_MAY_IMPORT = (
    "godobject_drake.driver",
    "godobject_drake.link.messages",
    "godobject_drake.link.keys",
    "godobject_drake.link.transport",
    "godobject_drake.link.logs",
    "godobject_drake.config",
    "godobject_drake.quantiles",
    "godobject_drake.outputs",
)
MAX_INNER_IMPORTS = 5
MAX_FUNCTION_LINES = 100


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def layer(module: str):
    for prefix, n in LAYERS:
        if module == prefix or module.startswith(prefix + "."):
            return n
    return None


def resolve(target: str) -> str | None:
    """The module ``target`` names (``a.b.name`` → ``a.b`` when ``name`` is not a module)."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


class Imports(ast.NodeVisitor):
    """Our own imports of one module: ``(line, target module, inside a function)``."""

    def __init__(self, module: str):
        self.module, self.found, self._depth = module, [], 0

    def visit_If(self, node):
        if ast.unparse(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING"):
            return  # for annotations only: nothing runs
        self.generic_visit(node)

    def visit_FunctionDef(self, node):
        self._depth += 1
        self.generic_visit(node)
        self._depth -= 1

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_Import(self, node):
        for alias in node.names:
            if alias.name.startswith("godobject_drake"):
                self.found.append((node.lineno, resolve(alias.name), self._depth > 0))

    def visit_ImportFrom(self, node):
        base = node.module or ""
        if base.startswith("godobject_drake"):
            for alias in node.names:
                target = (
                    resolve(f"{base}.{alias.name}") if f"{base}.{alias.name}" in MODULES else resolve(base)
                )
                self.found.append((node.lineno, target, self._depth > 0))


def imports(module: str):
    visitor = Imports(module)
    visitor.visit(ast.parse(MODULES[module].read_text()))
    return visitor.found


def graph() -> dict[str, set[str]]:
    """Module → the modules it imports at its top level; importing ``a.b.c`` runs ``a.b`` first."""
    edges = {m: set() for m in MODULES}
    for m in MODULES:
        for _, target, inner in imports(m):
            if inner or target is None or target == m:
                continue
            edges[m].add(target)
            parent = target.rpartition(".")[0]
            while parent and parent != "godobject_drake":
                if parent != m and not m.startswith(parent + "."):
                    edges[m].add(parent)
                parent = parent.rpartition(".")[0]
    return edges


def test_every_module_has_a_layer():
    missing = [m for m in MODULES if m != "godobject_drake" and layer(m) is None and not m.startswith(DRIVER)]
    assert not missing, f"give these modules a layer in LAYERS (and in docs/design.md): {missing}"


def test_imports_point_down():
    wrong = []
    for m in MODULES:
        if m == "godobject_drake":
            continue
        for line, target, _ in imports(m):
            if target is None or target == "godobject_drake":
                continue
            if m.startswith(DRIVER):
                if not target.startswith(DRIVER_MAY_IMPORT):
                    wrong.append(f"{m}:{line} imports {target}: the driver shares only the link and config")
            elif target.startswith(DRIVER):
                wrong.append(f"{m}:{line} imports the driver {target}")
            elif layer(target) > layer(m):
                wrong.append(f"{m}:{line} (layer {layer(m)}) imports {target} (layer {layer(target)})")
    assert not wrong, "\n".join(wrong)


def test_no_import_cycle():
    edges, index, low, stack, on, cycles = graph(), {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in edges:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_imports_inside_functions_are_few_and_say_why():
    """At most a handful, each with a comment on its line or the line above saying why it is not
    at the top (an optional dependency, a heavy one a command does not need, a subcommand)."""
    inner = [(m, line) for m in MODULES for line, target, inside in imports(m) if inside and target]
    assert len(inner) <= MAX_INNER_IMPORTS, inner
    for m, line in inner:
        lines = MODULES[m].read_text().splitlines()
        said = "#" in lines[line - 1] or lines[line - 2].strip().startswith("#")
        assert said, f"{m}:{line}: an import inside a function needs a comment saying why"


def test_no_function_over_a_hundred_lines():
    long = []
    for m, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{m}.{node.name}: {n} lines")
    assert not long, long


def loaded_after(statement: str) -> list[str]:
    """The modules a fresh interpreter has loaded after ``statement``."""
    code = f"{statement}\nimport sys\nprint('\\n'.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    return out.stdout.split()


@pytest.mark.parametrize(
    ("statement", "forbidden"),
    [
        # the config types: no Drake system of ours (pydrake's own config types are fine)
        ("import godobject_drake.config.scenario", ("godobject_drake.systems", "godobject_drake.devices",
                                                    "godobject_drake.station", "godobject_drake.simulation")),
        # the driver's process: the link only, no Drake systems at all (it runs the device's loop)
        ("import godobject_drake.driver.process", ("pydrake.systems", "godobject_drake.systems",
                                                   "godobject_drake.devices", "godobject_drake.config")),
    ],
    ids=["config", "driver"],
)  # fmt: skip
def test_what_a_part_loads(statement, forbidden):
    loaded = [m for m in loaded_after(statement) if m.startswith(forbidden)]
    assert not loaded, f"{statement} loads {loaded[:8]}"


# Each tool is resolved once (config.scenario.tool_records, returned by check_scenario and carried
# by the station as ``records``): its scenario view and its device's kind are asked for nowhere
# else. kind_of stays where a kind is looked up by its config: the registry itself and the
# device factory.
RESOLVED_IN = {
    "per_tool": {"godobject_drake.config.scenario"},
    "kind_of": {
        "godobject_drake.config.scenario",
        "godobject_drake.config.devices",
        "godobject_drake.devices.factory",
    },
}


@pytest.mark.parametrize("function", sorted(RESOLVED_IN))
def test_each_tool_is_resolved_in_one_place(function):
    found = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                f = node.func
                name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
                if name == function and module not in RESOLVED_IN[function]:
                    found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert found == [], f"{function}() called outside {sorted(RESOLVED_IN[function])}: read the tool's record"


ANALYSIS = REPO / "analysis"


def test_no_function_over_a_hundred_lines_in_analysis():
    """The scripts under analysis/ keep the package's rule: a function longer than 100 lines is
    split into named steps (each failure names the file, the function and its length)."""
    long = []
    for path in sorted(ANALYSIS.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(REPO)}: {node.name} (line {node.lineno}) is {n} lines")
    assert not long, long


def test_every_analysis_script_is_in_the_index():
    """analysis/README.md names every script of analysis/ (as ``NAME.py`` in backticks), so the
    index says what each one is for."""
    index = (ANALYSIS / "README.md").read_text()
    missing = [p.name for p in sorted(ANALYSIS.glob("*.py")) if f"`{p.name}`" not in index]
    assert not missing, f"analysis/README.md does not list {missing}: add each with its question and command"


def test_no_module_reads_a_test_only_environment_variable():
    """A test or a benchmark injects what it needs (analysis/throttled_scene.py: the scene's
    publication rate); the package reads no ``GODOBJECT_TEST_*`` setting, so nothing a user's
    environment holds can switch on a test's behaviour."""
    found = [
        f"{m}:{n}"
        for m, path in MODULES.items()
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if "GODOBJECT_TEST_" in line
    ]
    assert not found, f"the package names a GODOBJECT_TEST_ variable: {found}"


REGISTRIES = {
    "DEVICE_KINDS": "godobject_drake.config.devices",
    "TOOL_CONFIGS": "godobject_drake.config.tools",
    "TOOL_BUILDERS": "godobject_drake.config.tools",
}


REGISTERING = ("device_kind", "tool_kind", "device_factory")


def test_each_kind_is_registered_in_one_place():
    """A device kind is its config's ``@device_kind(..., factory=...)`` and a tool kind its config's
    ``@tool_kind(builder)``: each registry is written by its decorator alone, in its own module, and
    no other module registers a kind's second half (a factory or a builder) anywhere."""
    found = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            target = None
            if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Store):
                target = node.value
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                if node.func.attr in ("append", "update", "setdefault", "__setitem__"):
                    target = node.func.value
            name = getattr(target, "id", getattr(target, "attr", None))
            if name in REGISTRIES and module != REGISTRIES[name]:
                found.append(f"{path.relative_to(REPO)}:{node.lineno} writes {name}")
            if isinstance(node, ast.FunctionDef | ast.ClassDef) and module not in REGISTRIES.values():
                for d in node.decorator_list:
                    called = d.func if isinstance(d, ast.Call) else d
                    if getattr(called, "id", getattr(called, "attr", None)) in REGISTERING:
                        found.append(f"{path.relative_to(REPO)}:{node.lineno} registers {node.name}")
    assert found == [], found
