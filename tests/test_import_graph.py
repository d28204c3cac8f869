"""The package's import graph: no cycle anywhere in qdrl/ (imports inside functions counted),
and imports inside functions only where they pay (optional dependencies, start-up cost)."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "qdrl"
# Imports inside functions: optional dependencies and a measured start-up cost (the CLI's,
# `import qdrl`'s, `qdrl adapt`'s checks before jax, the environments' registry, matplotlib), at most
# this many in the package.
MAX_LOCAL_IMPORTS = 22


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def _imports(path: Path) -> Iterator[tuple[str, bool, int]]:
    """(imported qdrl module, inside a function, line) of every import of the file."""
    tree = ast.parse(path.read_text())
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    local: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            local.update(id(n) for n in ast.walk(node) if isinstance(n, ast.Import | ast.ImportFrom))
    typing_only: set[int] = set()
    for node in ast.walk(tree):  # `if TYPE_CHECKING:` blocks are never executed
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            typing_only.update(id(n) for n in ast.walk(node) if isinstance(n, ast.Import | ast.ImportFrom))
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "qdrl":
                    yield alias.name, id(node) in local, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            if base.split(".")[0] != "qdrl":
                continue
            for alias in node.names:  # `from qdrl import checkpoint` imports the module qdrl.checkpoint
                target = f"{base}.{alias.name}"
                yield (target if target in MODULES else base), id(node) in local, node.lineno


def _graph() -> dict[str, set[str]]:
    return {name: {t for t, _, _ in _imports(path) if t in MODULES and t != name} for name, path in MODULES.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        colour[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if colour.get(nxt) == 1:
                return [*stack[stack.index(nxt):], nxt]
            if nxt not in colour and (found := visit(nxt)) is not None:
                return found
        stack.pop()
        colour[node] = 2
        return None

    for node in sorted(graph):
        if node not in colour and (found := visit(node)) is not None:
            return found
    return None


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle_in_the_package() -> None:
    graph = _graph()
    assert "qdrl.algorithms" in graph and "qdrl.experiment" in graph["qdrl.runs"]
    assert _cycle(graph) is None, " -> ".join(_cycle(graph) or [])


def _local_imports(path: Path) -> list[str]:
    """Every import statement inside a function of the file (any module), as "file:line module"."""
    tree = ast.parse(path.read_text())
    found = {}
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            for n in ast.walk(fn):
                if isinstance(n, ast.Import | ast.ImportFrom):
                    module = n.module if isinstance(n, ast.ImportFrom) else n.names[0].name
                    found[n.lineno] = f"{path.relative_to(PACKAGE.parent)}:{n.lineno} {module}"
    return list(found.values())


def test_imports_inside_functions_are_few() -> None:
    local = [entry for path in sorted(MODULES.values()) for entry in _local_imports(path)]
    assert len(local) <= MAX_LOCAL_IMPORTS, "\n".join(local)
