"""Imports point one way: maths at the bottom, the CLI on top, no cycles."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "wavefront"

# Lowest first.  A module may import from its own layer or any layer below.
LAYERS = [
    {"vecmath", "sampling", "validation", "transform", "memory"},
    {"textures", "geometry", "camera", "materials", "background", "batch", "units", "output"},
    {"film", "shapes"},  # shapes: the subpackage counts as one module
    {"bvh", "accel", "lights", "media"},
    {"scene"},
    {"scenefile"},
    {"path", "whitted"},
    {"integrators"},
    {"render"},
    {"distributed"},
    {"cli", "__main__", "__init__"},
]
LAYER = {name: i for i, layer in enumerate(LAYERS) for name in layer}


def imports_of(path: Path, depth: int = 1) -> set[str]:
    """Top-level wavefront modules ``path`` imports; ``depth`` is how deep in
    the package the file sits (1 for ``wavefront/x.py``, 2 inside a subpackage)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == depth and node.module is None:
            found.update(alias.name for alias in node.names)  # from . import distributed
        elif isinstance(node, ast.ImportFrom) and node.level == depth:
            found.add(node.module.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("wavefront"):
            found.add(node.module.split(".")[1] if "." in node.module else "__init__")
    return found


def graph():
    g = {p.stem: imports_of(p) for p in PACKAGE.glob("*.py")}
    for sub in (d for d in PACKAGE.iterdir() if (d / "__init__.py").exists()):
        # a subpackage is one module: the union of its files' imports from outside it
        g[sub.name] = set().union(*(imports_of(p, 2) for p in sub.glob("*.py")))
    return g


def test_every_module_has_a_layer():
    assert set(graph()) <= set(LAYER), set(graph()) - set(LAYER)


def test_no_upward_imports():
    upward = [(m, d) for m, deps in graph().items() for d in deps if LAYER[d] > LAYER[m]]
    assert not upward, upward


def test_no_import_cycles():
    g = graph()
    state = {}

    def visit(m, stack):
        if state.get(m) == "done":
            return
        assert state.get(m) != "open", "cycle: " + " -> ".join(stack + [m])
        state[m] = "open"
        for d in g.get(m, ()):
            visit(d, stack + [m])
        state[m] = "done"

    for m in g:
        visit(m, [])
