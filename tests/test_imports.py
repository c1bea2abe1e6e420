"""mscap's import graph has no cycle: no module imports, at import time, a module that
imports it back (read from the source with ast; nothing is imported)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mscap"


def _modules() -> dict[str, Path]:
    """Dotted name → file of every module of the package (a package is its ``__init__``)."""
    modules = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


def _import_time_imports(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """Imports that run when the module is imported: at top level, in class bodies and in
    if/try/with blocks; not inside functions, nor under ``if TYPE_CHECKING:``."""
    found = []

    def walk(nodes):
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                walk(node.orelse)
                continue
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                found.append(node)
            for name in ("body", "orelse", "finalbody", "handlers"):
                block = getattr(node, name, None)
                if isinstance(block, list):
                    walk(block)

    walk(tree.body)
    return found


def import_graph() -> dict[str, set[str]]:
    """Module → the mscap modules it imports at import time. ``from a.b import c`` names
    the module ``a.b.c`` when there is one, else ``a.b``."""
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = set()
        for node in _import_time_imports(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names if alias.name in modules)
                continue
            base = node.module or ""
            if node.level:  # relative: up level − 1 packages from this one
                parents = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(parents + ([base] if base else []))
            for alias in node.names:
                target = f"{base}.{alias.name}"
                if target in modules:
                    targets.add(target)
                elif base in modules:
                    targets.add(base)
        graph[name] = targets - {name}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle ``[a, b, ..., a]`` of the graph, or ``None`` (iterative depth-first search)."""
    state = dict.fromkeys(graph, 0)  # 0 new, 1 on the current path, 2 done
    for root in sorted(graph):
        if state[root]:
            continue
        path, stack = [root], [iter(sorted(graph[root]))]
        state[root] = 1
        while stack:
            child = next(stack[-1], None)
            if child is None:
                state[path.pop()] = 2
                stack.pop()
            elif state[child] == 1:
                return path[path.index(child):] + [child]
            elif state[child] == 0:
                state[child] = 1
                path.append(child)
                stack.append(iter(sorted(graph[child])))
    return None


def test_the_graph_is_read():
    graph = import_graph()
    assert "mscap.bodies.registry" in graph and "mscap.fem.transfer" in graph
    assert "mscap.bodies.basic" in graph["mscap.bodies.registry"]
    assert "mscap.errors" in graph["mscap"]


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_in_mscap():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


#: The package order, bottom floor first (docs/architecture.md draws it): a package may
#: import the floors below it and its own, never one above; the first floor is the
#: top-level modules (``mscap``, ``errors``, ``profile``, ``outfile``, ``farm``, ...).
FLOORS = (("", "errors", "_lazy", "profile", "testing", "outputs", "outfile", "infile", "farm"), ("geometry",), ("bodies",),
          ("scene",), ("mesh",), ("fem",), ("readout",), ("fabrication",), ("design",), ("calibration",),
          ("service",), ("viz",), ("cli",))

#: The imports that still point up, each named: none. The list stays so that one added
#: on purpose is named here, and the test says when it is gone.
UPWARD: set[tuple[str, str]] = set()


def every_import(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """Every import of a module, inside functions too; not those under ``if TYPE_CHECKING:``."""
    typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                   and "TYPE_CHECKING" in ast.unparse(node.test) for n in ast.walk(node)}
    return [node for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
            and id(node) not in typing_only]


def upward_imports() -> set[tuple[str, str]]:
    """``(module, imported module)`` pairs whose target sits on a higher floor."""
    floor = {package: i for i, packages in enumerate(FLOORS) for package in packages}

    def package(module: str) -> str:
        parts = module.split(".")
        return parts[1] if len(parts) > 1 else ""

    found = set()
    for name, path in _modules().items():
        for node in every_import(ast.parse(path.read_text(encoding="utf-8"))):
            targets = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            for target in targets:
                if target.startswith("mscap") and floor[package(target)] > floor[package(name)]:
                    found.add((name, target))
    return found


def test_every_package_has_a_floor():
    packages = {name.split(".")[1] if name.count(".") else "" for name in _modules()}
    placed = {package for packages in FLOORS for package in packages}
    assert packages <= placed, f"no floor for {sorted(packages - placed)}"


def test_no_package_imports_one_above_it_inside_functions_or_not():
    found = upward_imports()
    assert not found - UPWARD, f"new imports up the floors: {sorted(found - UPWARD)}"
    assert not UPWARD - found, f"gone, remove from UPWARD: {sorted(UPWARD - found)}"


def test_the_floor_check_sees_an_import_inside_a_function():
    tree = ast.parse("def f():\n    from mscap.fem import simulate\nif TYPE_CHECKING:\n    import mscap.cli\n")
    assert [node.module for node in every_import(tree) if isinstance(node, ast.ImportFrom)] == ["mscap.fem"]
    assert not [node for node in every_import(tree) if isinstance(node, ast.Import)]


#: The scene's tables a stage takes as its own input (a run's layout and its mesh sizes are
#: a :class:`~mscap.scene.settings.Sheet`; a finer check's sizes, a skinning choice are
#: arguments): no code rebuilds a scene around them.
STAGE_TABLES = {"layout", "mesh", "elastic", "optimizer", "sheet_outline_mm", "layers"}


def scene_rebuilds(tree: ast.Module) -> list[str]:
    """``replace(<...scene>, <stage table>=...)`` calls: a scene made to carry a stage's input."""
    found = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and ast.unparse(node.func).split(".")[-1] == "replace" and node.args
                and ast.unparse(node.args[0]).split(".")[-1].lower().endswith("scene")
                and STAGE_TABLES & {k.arg for k in node.keywords}):
            found.append(f"line {node.lineno}: {ast.unparse(node)[:80]}")
    return found


def test_no_scene_is_rebuilt_around_a_runs_layout_or_settings():
    found = {name: hits for name, path in _modules().items()
             if (hits := scene_rebuilds(ast.parse(path.read_text(encoding="utf-8"))))}
    assert not found, f"a scene rebuilt to carry a stage's input (pass a Sheet or the settings): {found}"


def test_the_rebuild_check_sees_one():
    tree = ast.parse("s = replace(self.scene, layout=x)\nt = dataclasses.replace(scene, poses=p)\n"
                     "u = replace(scene.sheet, layout=x)\n")
    assert scene_rebuilds(tree) == ["line 1: replace(self.scene, layout=x)"]
