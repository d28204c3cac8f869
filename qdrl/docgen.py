"""Markdown tables generated from the code, for the documentation site (docs/hooks.py).

The spec keys of a section come from its config dataclass: the key, its default,
what it accepts (`qdrl.config.describe`, the words of the spec errors) and the
comment written beside the field, so the documentation cannot drift from the code.
The task catalogue comes from the task registry, each task built with its
defaults; the spec list from the packaged specs' first comment lines.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
from collections.abc import Sequence
from typing import Any

from qdrl import specs
from qdrl.config import _toml_value, describe, field_default, table_keys
from qdrl.tasks import TASKS

__all__ = ["field_comments", "keys_table", "specs_table", "tasks_table"]


def _class_comments(cls: type) -> dict[str, str]:
    """field -> the comment on its line, or the comment lines just above it, in `cls` itself."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    (node,) = ast.parse(source).body
    out = {}
    assert isinstance(node, ast.ClassDef)
    for stmt in node.body:
        if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
            continue
        line = lines[stmt.end_lineno - 1] if stmt.end_lineno else ""
        comment = line.split("  # ", 1)[1].strip() if "  # " in line else ""
        if not comment:  # the comment block right above the field
            above: list[str] = []
            i = stmt.lineno - 2
            while i >= 0 and lines[i].strip().startswith("#"):
                above.insert(0, lines[i].strip().lstrip("#").strip())
                i -= 1
            comment = " ".join(above)
        out[stmt.target.id] = comment
    return out


def field_comments(cls: type) -> dict[str, str]:
    """The comment of each field of dataclass `cls`, from its own class or the base that
    declares it (a subclass's comment wins)."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            out.update({k: v for k, v in _class_comments(klass).items() if v or k not in out})
    return out


def _default(cls: type, path: tuple[str, ...]) -> str:
    """The default of the key at `path` (its field's default, then the nested configs' values)."""
    f = {f.name: f for f in dataclasses.fields(cls)}[path[0]]
    value = field_default(f)
    if value is dataclasses.MISSING:
        return "(required)"
    for name in path[1:]:
        value = getattr(value, name)
    try:
        return f"`{_toml_value(value)}`"
    except TypeError:
        return "(none)" if value is None else f"`{value!r}`"


def _comment(cls: type, path: tuple[str, ...]) -> str:
    """The comment of the field at `path`, in the class that holds it (a nested config's own)."""
    owner: Any = cls
    for name in path[:-1]:
        owner = type(field_default({f.name: f for f in dataclasses.fields(owner)}[name]))
    return field_comments(owner).get(path[-1], "")


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def keys_table(cls: type, section: str) -> str:
    """A Markdown table of the keys of spec section `[section]`, parsed into dataclass `cls`
    (the keys of its nested configs included, under their spec names)."""
    rows = [
        f"| `{section}.{key}` | {_default(cls, path)} | {_cell(describe(tp))} | {_cell(_comment(cls, path))} |"
        for key, (path, tp) in table_keys(cls).items()
    ]
    return "\n".join(["| key | default | accepts | meaning |", "|---|---|---|---|", *rows])


def _first_line(obj: Any) -> str:
    doc = inspect.getdoc(obj) or ""
    return doc.split("\n\n", 1)[0].replace("\n", " ")


def _bounds(low: Sequence[float], high: Sequence[float]) -> str:
    def num(x: float) -> str:
        return f"{x:.4g}"

    return " × ".join(f"[{num(lo)}, {num(hi)}]" for lo, hi in zip(low, high, strict=True))


def tasks_table(names: Sequence[str] | None = None) -> str:
    """A Markdown table of the QD tasks (`qdrl.tasks.TASKS`), each built with its defaults:
    parameters, descriptor names and bounds, QD offset, and the builder's first docstring line."""

    rows = []
    for name in names or sorted(TASKS):
        builder = TASKS[name].build
        task = builder()
        params = ", ".join(
            f"`{p.name}={_toml_value(p.default)}`" if p.default is not None else f"`{p.name}`"
            for p in inspect.signature(builder).parameters.values()
            if p.default is not inspect.Parameter.empty
        )
        descriptor = ", ".join(task.descriptor_names) + " in " + _bounds(task.descriptor_low, task.descriptor_high)
        rows.append(
            f"| `{name}` | {_cell(_first_line(builder))} | {_cell(descriptor)} | {task.qd_offset:.6g} | {params} |"
        )
    return "\n".join([
        "| task | what it is | descriptor (default parameters) | QD offset (default parameters) | parameters |",
        "|---|---|---|---|---|",
        *rows,
    ])


def specs_table(prefixes: Sequence[str]) -> str:
    """A Markdown table of the packaged specs whose name starts with one of `prefixes`."""

    directory = specs.spec_dir()
    names = [n for n in specs.spec_names() if any(n.startswith(p) for p in prefixes)]
    rows = [f"| `{n}` | {_cell(specs.describe(directory / f'{n}.toml'))} |" for n in names] if directory else []
    return "\n".join(["| spec (`qdrl run NAME`) | its first comment line |", "|---|---|", *rows])
