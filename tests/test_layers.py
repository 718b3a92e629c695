"""The package's shape, checked: imports only go down the layers of docs/ARCHITECTURE.md,
imports form no cycle (module-level and function-level alike: an import moved into a
function hides a circle from the interpreter, not from the design), and no module reads
another object's underscore attributes. Pure source analysis (ast), no import of the package."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "plmarl_sitl"
CORE = {"config", "mission", "mission_reference", "errors", "proc", "machine", "cmdline"}

# What each layer may import (besides itself). The deployable side loads the exported
# policy (learning.nn) but nothing of training; the SITL rig stands on the deployable side.
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "model": {"core"},
    "twin": {"core", "model"},
    "learning.nn": {"core", "model"},
    "learning.train": {"core", "model", "twin", "learning.nn"},
    "learning.eval": {"core", "model", "twin", "learning.nn", "learning.train"},
    "learning.pipeline": {"core", "model", "twin", "learning.nn", "learning.train", "learning.eval"},
    "deploy": {"core", "model", "learning.nn"},
    "sitl": {"core", "model", "twin", "learning.nn", "deploy"},
}
ALLOWED["bench"] = set(ALLOWED) - {"bench"}
ALLOWED["cli"] = set(ALLOWED) - {"cli"}

# Underscore names that are public API by convention (namedtuple methods), and the
# few library types that have no public name.
PUBLIC_UNDERSCORE = {"_asdict", "_replace", "_fields", "_make", "_exit"}  # _exit: os._exit, a forked child's end
LIBRARY_TYPES = {
    "_SubParsersAction",  # argparse: the type of add_subparsers()
    "_C",  # torch._C.Graph: the frozen TorchScript graph nn/fused.py inspects
}
# aiomqtt's and pymavlink's internals are each read in exactly one module, which checks
# the library's version first.
LIBRARY_FAST_PATHS = {"plmarl_sitl.deploy.mqtt.aiomqtt_fastpath", "plmarl_sitl.deploy.mavlink.pymavlink_fastpath"}


def module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer(module: str) -> str:
    parts = module.split(".")[1:]
    if not parts or parts[0] in CORE:
        return "core"
    if parts[0] == "learning":
        return "learning." + parts[1] if len(parts) > 1 and parts[1] in {"nn", "train", "eval", "pipeline"} else "learning.nn"
    return parts[0]


def sources() -> dict[str, ast.Module]:
    return {module_name(p): ast.parse(p.read_text(), str(p)) for p in sorted(PKG.rglob("*.py"))}


def imports(tree: ast.Module) -> set[str]:
    """The package modules (and names) a module imports anywhere in it: at module level,
    under `if TYPE_CHECKING` (a type-only dependency is still a dependency) and inside
    functions and methods."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("plmarl_sitl")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("plmarl_sitl"):
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}  # `from pkg import module`
    return out


def test_imports_only_go_down_the_layers() -> None:
    mods = sources()
    bad = []
    for mod, tree in mods.items():
        for target in imports(tree):
            if target not in mods:
                continue  # a name imported from a module, not a module
            src, dst = layer(mod), layer(target)
            if dst != src and dst not in ALLOWED[src]:
                bad.append(f"{mod} ({src}) imports {target} ({dst})")
    assert not bad, "\n".join(bad)


def import_cycles(mods: dict[str, ast.Module]) -> list[list[str]]:
    """Cycles of the import graph, every import counted wherever it stands in the module."""
    graph = {m: {t for t in imports(tree) if t in mods and t != m} for m, tree in mods.items()}
    # A package's __init__ importing its own modules is how packages work, not a cycle.
    for m in graph:
        graph[m] = {t for t in graph[m] if not m.startswith(t + ".")}
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    return cycles


def test_imports_have_no_cycle() -> None:
    cycles = import_cycles(sources())
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)


def test_a_cycle_through_a_function_level_import_is_seen() -> None:
    """The check is not blind to the way the nn/deploy.py <-> nn/io.py circle was hidden."""
    a = ast.parse("from plmarl_sitl.b import g\n")
    b = ast.parse("def g():\n    from plmarl_sitl.a import f\n    return f\n")
    assert import_cycles({"plmarl_sitl.a": a, "plmarl_sitl.b": b}) == [["plmarl_sitl.a", "plmarl_sitl.b", "plmarl_sitl.a"]]


def test_no_module_reads_another_objects_underscore_attributes() -> None:
    bad = []
    for mod, tree in sources().items():
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")):
                continue
            if node.attr in PUBLIC_UNDERSCORE or node.attr in LIBRARY_TYPES or mod in LIBRARY_FAST_PATHS:
                continue
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in {"self", "cls"}:
                continue
            bad.append(f"{mod}:{node.lineno} .{node.attr}")
    assert not bad, "\n".join(bad)
