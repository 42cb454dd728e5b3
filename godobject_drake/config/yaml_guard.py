"""A YAML file's shape bounded before a typed loader reads it.

Drake's ``yaml_load_typed`` reads a YAML file whole with PyYAML and then merges it into the
schema, expanding every alias as it goes: a 1.6 kB file of nested aliases (a "billion laughs")
ran 145 s to 4.2 GB before a ``MemoryError``, and 5,000 nested brackets ended in a
``RecursionError`` traceback. PyYAML composes a file into a graph of nodes in which an alias is a
second reference to the node it names, not a copy, so the graph of even the worst bomb is small:
:func:`check_yaml` composes the text once (a composer that counts its depth as it goes), then
counts what the graph would expand to, before anything expands it. It refuses, naming the limit
and the fix:

- a text past :data:`MAX_YAML_BYTES`;
- nesting deeper than :data:`MAX_YAML_DEPTH` (as written, or through aliases);
- aliases that add more than :data:`MAX_ALIAS_NODES` nodes to those written, or an alias inside
  the node it names (a cycle);
- a key given twice in one mapping (PyYAML and Drake keep the last one silently: a tool named
  twice in ``tools:`` was dropped), naming the key and both lines.

Its messages name lines and keys, never a value of the file.
"""

import os

import yaml

# The shipped scenarios are 1-3 kB; a device path of 100,000 waypoints is about 5 MB.
MAX_YAML_BYTES = 16 * 2**20
# The shipped scenarios nest 6 deep; Python's recursion limit (1,000) is what a deeper file meets.
MAX_YAML_DEPTH = 64
# Templates (``_base: &base {...}`` then ``<<: *base``) add a few hundred nodes in a real file.
MAX_ALIAS_NODES = 100_000


class YamlShapeError(ValueError):
    """A YAML text past a bound or with a key given twice; the message names the line and the fix."""


def shown(text) -> str:
    """``text`` with its control characters escaped (``\\x1b``, ``\\n``), for a message: a name or
    a path from a file or a command line must not reach the terminal raw."""
    text = str(text)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class _BoundedComposer(yaml.SafeLoader):
    """SafeLoader's parser and composer (pure Python: its nodes are inspected), with a depth count
    and a duplicate-key check; it constructs nothing."""

    def __init__(self, stream, where: str):
        super().__init__(stream)
        self.where, self.depth = where, 0

    def compose_node(self, parent, index):
        self.depth += 1
        try:
            if self.depth > MAX_YAML_DEPTH:
                line = self.peek_event().start_mark.line + 1
                raise YamlShapeError(
                    f"{self.where}: line {line}: nested more than {MAX_YAML_DEPTH} deep (the limit, "
                    "godobject_drake.config.yaml_guard.MAX_YAML_DEPTH); a scenario nests a few levels: "
                    "check the brackets and indentation"
                )
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def compose_mapping_node(self, anchor):
        node = super().compose_mapping_node(anchor)
        first: dict = {}
        for key, _ in node.value:
            if not isinstance(key, yaml.ScalarNode):
                continue
            seen = first.setdefault((key.tag, key.value), key)
            if seen is not key:
                raise YamlShapeError(
                    f"{self.where}: line {key.start_mark.line + 1}: the key {shown(key.value)!r} is given "
                    f"twice in one mapping (first at line {seen.start_mark.line + 1}); a mapping takes "
                    "each key once (the loader would keep only the last): remove or rename one"
                )
        return node


def _expanded(root, where: str) -> int:
    """How many nodes ``root`` stands for once every alias is expanded, refusing a cycle or a depth
    past the limit; each node is walked once (an alias adds its node's count, remembered)."""
    size: dict[int, int] = {}
    height: dict[int, int] = {}
    open_: set[int] = set()
    budget = [0]  # nodes counted so far, expanded

    def walk(node, depth):
        key = id(node)
        if key in size:
            budget[0] += size[key]
            depth += height[key] - 1  # its deepest node, where this alias puts it
        elif key in open_:
            raise YamlShapeError(
                f"{where}: line {node.start_mark.line + 1}: an alias inside the node its anchor names "
                "(a cycle: it expands without end); name a node outside it"
            )
        else:
            open_.add(key)
            start, deepest = budget[0], depth
            budget[0] += 1
            children = node.value if isinstance(node, yaml.SequenceNode) else []
            if isinstance(node, yaml.MappingNode):
                children = [x for pair in node.value for x in pair]
            for child in children:
                deepest = max(deepest, walk(child, depth + 1))
            open_.discard(key)
            size[key], height[key] = budget[0] - start, deepest - depth + 1
            depth = deepest
        if depth > MAX_YAML_DEPTH:
            raise YamlShapeError(
                f"{where}: line {node.start_mark.line + 1}: nested more than {MAX_YAML_DEPTH} deep once "
                "its aliases are expanded (the limit, godobject_drake.config.yaml_guard.MAX_YAML_DEPTH); "
                "alias a smaller node"
            )
        return depth

    walk(root, 1)
    return budget[0]


def _written(root) -> int:
    """How many nodes the text writes (each aliased node once)."""
    seen: set[int] = set()
    stack = [root]
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)
        elif isinstance(node, yaml.MappingNode):
            stack.extend(x for pair in node.value for x in pair)
    return len(seen)


def check_yaml_file(path, where: str) -> None:
    """:func:`check_yaml` of the file at ``path``, its size refused before it is read."""
    size = os.stat(path).st_size
    if size > MAX_YAML_BYTES:
        _too_large(size, where)
    with open(path, encoding="utf-8", errors="replace") as f:
        check_yaml(f.read(), where)


def _too_large(size: int, where: str):
    raise YamlShapeError(
        f"{shown(where)}: {size / 2**20:.1f} MiB of YAML, past the {MAX_YAML_BYTES // 2**20} MiB limit "
        "(godobject_drake.config.yaml_guard.MAX_YAML_BYTES); write long paths or logs as a CSV log"
    )


def check_yaml(text: str, where: str) -> None:
    """Refuse ``text`` (YAML; ``where`` names it) past the module's bounds, with a
    :class:`YamlShapeError`. Not valid YAML is left to the loader, which says where."""
    if len(text) > MAX_YAML_BYTES:
        _too_large(len(text), where)
    try:
        loader = _BoundedComposer(text, shown(where))  # its reader refuses a control character at once
    except yaml.YAMLError:
        return  # the loader names the error
    try:
        roots = []
        while loader.check_node():
            roots.append(loader.get_node())
    except yaml.YAMLError:
        return  # the loader names the error
    finally:
        loader.dispose()
    for root in roots:
        written = _written(root)
        expanded = _expanded(root, shown(where))
        if expanded - written > MAX_ALIAS_NODES:
            raise YamlShapeError(
                f"{shown(where)}: its aliases expand to {expanded:.3g} nodes from the {written} written, "
                f"past the limit of {MAX_ALIAS_NODES:,} added (godobject_drake.config.yaml_guard."
                "MAX_ALIAS_NODES): aliases of aliases multiply; write the values out, or alias less"
            )
