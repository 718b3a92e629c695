"""No import circles inside plmarl_sitl: module-level imports, `if TYPE_CHECKING:` ones included.

Read from the source with `ast` (nothing is imported). An import inside a function is not
counted: a few are there on purpose, to keep start-up light. Importing a submodule also runs
its package's __init__, which is not counted either: a package re-exporting its modules is
not a circle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import plmarl_sitl

ROOT = Path(plmarl_sitl.__file__).parent


def _modules() -> dict[str, Path]:
    out = {}
    for f in ROOT.rglob("*.py"):
        parts = ("plmarl_sitl", *f.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _module_level_imports(tree: ast.Module) -> list[str]:
    """Dotted names imported by statements at module level (inside if/try blocks too)."""
    names: list[str] = []

    def visit(stmts: list[ast.stmt]) -> None:
        for s in stmts:
            if isinstance(s, ast.Import):
                names.extend(a.name for a in s.names)
            elif isinstance(s, ast.ImportFrom) and s.module and s.level == 0:
                names.extend(f"{s.module}.{a.name}" for a in s.names)
            elif isinstance(s, ast.If):
                visit(s.body)
                visit(s.orelse)
            elif isinstance(s, ast.Try):
                visit(s.body)
                for h in s.handlers:
                    visit(h.body)
                visit(s.orelse)
                visit(s.finalbody)

    visit(tree.body)
    return names


def import_graph() -> dict[str, set[str]]:
    mods = _modules()

    def resolve(name: str) -> str | None:  # `from a.b import c`: module a.b.c, else a.b
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        targets = {resolve(n) for n in _module_level_imports(ast.parse(path.read_text()))}
        graph[name] = {t for t in targets if t is not None and t != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def strongconnect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    return found


def test_the_checker_sees_a_circle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from x.y import Z\ndef f():\n    import w\n")
    assert _module_level_imports(tree) == ["typing.TYPE_CHECKING", "x.y.Z"]


def test_no_import_cycle_in_plmarl_sitl() -> None:
    graph = import_graph()
    assert "plmarl_sitl.sitl.autopilot.vehicle" in graph  # the walk found the package
    assert cycles(graph) == []
