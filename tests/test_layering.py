"""Imports point one way: maths at the bottom, the CLI on top, no cycles."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "wavefront"

# Lowest first.  A module may import from its own layer or any layer below.
LAYERS = [
    {"vecmath", "sampling", "validation"},
    {"geometry", "camera", "materials", "background", "batch", "units", "output"},
    {"film"},
    {"bvh", "accel"},
    {"scene"},
    {"scenefile"},
    {"path", "whitted"},
    {"render"},
    {"distributed"},
    {"cli", "__main__", "__init__"},
]
LAYER = {name: i for i, layer in enumerate(LAYERS) for name in layer}


def imports_of(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module is None:
            found.update(alias.name for alias in node.names)  # from . import distributed
        elif isinstance(node, ast.ImportFrom) and node.level == 1:
            found.add(node.module.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("wavefront"):
            found.add(node.module.split(".")[1] if "." in node.module else "__init__")
    return found


def graph():
    return {p.stem: imports_of(p) for p in PACKAGE.glob("*.py")}


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
