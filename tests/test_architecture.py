"""The project's own modules import each other without circles, and JAX stays in `env/`.

The graph is read from the source with `ast`, so it sees every import: module level, inside
functions (a lazy import must not hide a circle) and under `TYPE_CHECKING`.
"""

from __future__ import annotations

import ast
from collections.abc import Collection, Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("env", "textualizer", "prompts", "llm_agents")


def module_files() -> dict[str, Path]:
    """Dotted module name -> source file, for every module of the four packages."""
    modules: dict[str, Path] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def imported_modules(
    tree: ast.Module, module: str, is_package: bool, known: Collection[str]
) -> Iterator[str]:
    """The module each import statement anywhere in the module loads: for `from a import b`,
    `a.b` when that is a module in `known`, else `a` (the parent packages Python runs first are
    left out: every submodule has them)."""
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                anchor = parts[: len(parts) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                yield submodule if submodule in known else base


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (a `from a import b` of submodule `b` counts as
    importing `a.b`; a parent package's `__init__` is not counted unless named itself)."""
    files = module_files()
    graph: dict[str, set[str]] = {}
    for module, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = imported_modules(tree, module, path.name == "__init__.py", files)
        graph[module] = {name for name in names if name in files and name != module}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component: list[str] = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_graph_sees_lazy_relative_and_type_checking_imports() -> None:
    source = """
from typing import TYPE_CHECKING
from . import sibling, CONSTANT
from ..other import thing
if TYPE_CHECKING:
    from pkg.typed import Name
def later():
    import pkg.lazy
"""
    known = {"pkg", "pkg.sub", "pkg.sub.sibling", "pkg.other", "pkg.typed", "pkg.lazy"}
    found = set(imported_modules(ast.parse(source), "pkg.sub.here", False, known))
    assert found & known == {"pkg.sub.sibling", "pkg.sub", "pkg.other", "pkg.typed", "pkg.lazy"}


def test_no_import_circles() -> None:
    assert cycles(import_graph()) == []


def test_packages_import_only_downwards() -> None:
    # env <- textualizer <- prompts <- llm_agents: a package uses only those before it.
    layer = {package: rank for rank, package in enumerate(PACKAGES)}
    upward = [
        f"{module} -> {target}"
        for module, targets in import_graph().items()
        for target in targets
        if layer[target.split(".")[0]] > layer[module.split(".")[0]]
    ]
    assert upward == []


def test_the_cycle_finder_finds_a_circle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_only_env_imports_jax() -> None:
    heavy = {"jax", "flax", "craftax"}
    for module, path in module_files().items():
        if module.split(".")[0] == "env":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = imported_modules(tree, module, path.name == "__init__.py", ())
        roots = {name.split(".")[0] for name in names}
        assert not roots & heavy, f"{module} imports {sorted(roots & heavy)}"


#: llm_agents' rooms, top to bottom: a room imports only rooms below it (see docs/architecture.md).
ROOMS = (
    "cli",
    "cli_flags",
    "viewer",
    "planning",
    "evaluation",
    "agents",
    "run_data",
    "backends",
)


def test_llm_agents_rooms_import_only_downwards() -> None:
    def room(module: str) -> str | None:
        parts = module.split(".")
        return parts[1] if parts[0] == "llm_agents" and len(parts) > 1 else None

    rank = {name: index for index, name in enumerate(ROOMS)}
    graph = import_graph()
    rooms = {room(module) for module in graph} - {None}
    assert rooms == set(ROOMS), f"rooms not in ROOMS: {sorted(rooms - set(ROOMS))}"
    upward = [
        f"{module} -> {target}"
        for module, targets in graph.items()
        for target in targets
        if (a := room(module)) and (b := room(target)) and a != b and rank[b] < rank[a]
    ]
    assert upward == []
