"""The package's structural rules, checked statically: no module over 800 lines, no cycle
among the imports that run when a module is imported (those at module level, outside
``if TYPE_CHECKING:``; an import inside a function runs only when it is called), and no import
at all, even inside a function, from a higher layer of :data:`LAYERS`."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "jaxflex"
MAX_LINES = 800


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("foundations", ("_arguments", "_host", "_io", "_lazy", "_linalg", "_progress", "registry",
                     "parallel", "metrics", "signals", "units", "records", "noise", "testbed",
                     "parameters", "stations")),
    ("physics", ("fem", "modal", "effects", "drives", "sensors", "model", "friction_solve",
                 "simulation", "fused", "frequency_response")),
    ("numerics", ("evolve", "least_squares")),
    ("data", ("record_files", "data", "preprocess", "rest", "synthetic", "datasets", "arm",
              "rigs", "diagnosis")),
    ("estimation", ("initial", "objective", "intervals", "refine", "fit", "rigid", "kalman",
                    "prediction_error", "identification", "comparison_table", "comparison",
                    "measured", "design", "prediction_report", "missing_torque",
                    "torque_regression")),
    ("analysis", ("discovery", "study")),
    ("interface", ("plots", "demo", "cli", "distributed", "jaxflex", "__main__")),
)
"""The package's layers, lowest first, by top-level module or subpackage: a module imports
only from its own layer and those below (``jaxflex`` is the package's ``__init__``)."""


def _import_time_imports(node: ast.AST):
    """The import statements under ``node`` that run when its module is imported: not those in
    a function (or lambda) and not those under ``if TYPE_CHECKING:``."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child
        elif isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
            for orelse in child.orelse:
                yield from _import_time_imports(ast.Module(body=[orelse], type_ignores=[]))
        else:
            yield from _import_time_imports(child)


def _imported_modules(name: str, path: Path) -> set[str]:
    """The jaxflex modules that importing ``name`` imports by name (a ``from a import b`` of a
    submodule ``a.b`` counts as importing ``a.b``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in _import_time_imports(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                found.add(sub if sub in MODULES else module)
    return {m for m in found if m in MODULES and m != name}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` as a path that ends where it starts, or None."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_module_is_longer_than_the_limit(name):
    lines = MODULES[name].read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_LINES, f"{MODULES[name]} has {lines} lines; split it by concept"


def test_the_package_imports_without_cycles():
    graph = {name: _imported_modules(name, path) for name, path in MODULES.items()}
    assert {"jaxflex.records", "jaxflex.units"} <= graph["jaxflex.record_files"]
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_check_finds_a_cycle():
    """The checker itself: a three-module cycle is found, a diamond is not a cycle."""
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b", "c"}, "b": {"d"}, "c": {"d"}, "d": set()}) is None


def _part(module: str) -> str:
    """The layer entry of a module: its top-level module or subpackage (``jaxflex``: the
    package itself)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def test_no_module_imports_from_a_higher_layer():
    rank = {part: i for i, (_, parts) in enumerate(LAYERS) for part in parts}
    unplaced = sorted({_part(m) for m in MODULES} - set(rank))
    assert not unplaced, f"modules in no layer of LAYERS: {unplaced}"
    upward = []
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = ([f"jaxflex.{a.name}" if f"jaxflex.{a.name}" in MODULES else "jaxflex"
                            for a in node.names] if node.module == "jaxflex" else [node.module])
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for target in targets:
                if target.split(".")[0] == "jaxflex" and rank[_part(target)] > rank[_part(name)]:
                    upward.append(f"{name} imports {target} (line {node.lineno})")
    assert not upward, "imports from a higher layer: " + "; ".join(upward)

