"""The package's import graph, read from the source with ``ast`` (nothing is imported).

Every ``import`` and ``from ... import`` counts, at module level or inside a function,
relative or absolute: a deferred import still ties two modules together, and a circle of
them is a layering error (``rstrace_engine/__init__.py`` writes the order down). And the
core never imports Blender or the add-on.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = "rstrace_engine"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE

#: The import order written in ``rstrace_engine/__init__.py``: a module imports only from
#: its own layer or lower ones (by its first name below the package).
LAYERS = {
    "tolerances": 1, "errors": 1, "frame": 1, "image": 1, "cancel": 1, "kernel_cache": 1,
    "shipped_kernels": 1, "views": 1, "heap": 1, "stripes": 1, "numba_inline": 1,
    "numba_overloads_cached": 1, "linalg": 1, "beside": 1, "child_python": 1,
    "geometry": 2,
    "accel": 3,
    "tracing": 4,
    "interpolants": 5, "ri_tree": 5, "interactive": 5,
    "session": 6,
    "scenes": 7, "warm_kernels": 7, "warm_first": 7, "bench": 7, "__main__": 7,
}


def _module_names() -> dict[str, Path]:
    """Dotted name -> file of every module of the package (packages by their __init__)."""
    names = {}
    for path in ROOT.rglob("*.py"):
        parts = (PACKAGE,) + path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def _imported(tree: ast.Module, name: str, is_package: bool, modules) -> set[str]:
    """Absolute names of the modules ``tree`` imports (outside packages: their names as
    written). ``from p import x`` names ``p.x`` when that is a module, else ``p``."""
    package = name if is_package else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module
            for alias in node.names:
                sub = f"{prefix}.{alias.name}"
                out.add(sub if sub in modules else prefix)
    return out


def _all_imports() -> dict[str, set[str]]:
    modules = _module_names()
    out = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        out[name] = _imported(tree, name, path.name == "__init__.py", modules)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of the package it imports."""
    return {name: {t for t in targets if t.split(".")[0] == PACKAGE and t != name}
            for name, targets in _all_imports().items()}


def external_imports() -> dict[str, set[str]]:
    """Module -> top-level names of the packages it imports from outside the package."""
    return {name: {t.split(".")[0] for t in targets if t.split(".")[0] != PACKAGE}
            for name, targets in _all_imports().items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One circle of imports (its modules, the first repeated at the end), or None."""
    state = dict.fromkeys(graph, 0)  # 0 unseen, 1 on the current path, 2 done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state[nxt] == 1:
                return path[path.index(nxt):] + [nxt]
            if state[nxt] == 0:
                found = visit(nxt)
                if found:
                    return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if state[node] == 0:
            found = visit(node)
            if found:
                return found
    return None


def test_reader_sees_every_kind_of_import():
    src = (
        "import numpy as np\n"
        "from .. import tolerances as tol\n"
        "from ..frame import CLASS_TRACED\n"
        "from . import bvh\n"
        "def f():\n"
        "    import bpy\n"
        "    from .visibility_field import VisibilityField\n"
        "    from addon.engine import X\n"
    )
    modules = {f"{PACKAGE}.{m}" for m in ("tolerances", "frame", "accel.bvh",
                                          "accel.visibility_field", "accel.accelerators")}
    got = _imported(ast.parse(src), f"{PACKAGE}.accel.accelerators", False, modules)
    assert got == {"numpy", f"{PACKAGE}.tolerances", f"{PACKAGE}.frame", f"{PACKAGE}.accel.bvh",
                   "bpy", f"{PACKAGE}.accel.visibility_field", "addon.engine"}
    graph = import_graph()
    assert f"{PACKAGE}.tolerances" in graph[f"{PACKAGE}.tracing.shader"]
    assert graph[PACKAGE] == {f"{PACKAGE}.kernel_cache", f"{PACKAGE}.numba_overloads_cached"}


def test_finder_finds_a_circle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_no_import_circle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def _layer(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1:
        return 0  # the package itself: its __init__ runs before anything else
    if parts[1] not in LAYERS:
        raise AssertionError(f"{module}: not in the import order; add it to LAYERS here and "
                             f"to the order in {PACKAGE}/__init__.py")
    return LAYERS[parts[1]]


def test_layer_order():
    graph = import_graph()
    upward = sorted(f"{a} -> {b}" for a, targets in graph.items() if a != PACKAGE
                    for b in targets if _layer(b) > _layer(a))
    assert not upward, "imports against the order in __init__.py: " + "; ".join(upward)


def test_no_blender_imports():
    bad = {m: sorted(names & {"bpy", "addon", "bmesh", "mathutils", "gpu"})
           for m, names in external_imports().items()}
    bad = {m: names for m, names in bad.items() if names}
    assert not bad, f"the core imports Blender or the add-on: {bad}"
