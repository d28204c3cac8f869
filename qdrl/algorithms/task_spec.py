"""The `[task]` section of QD specs: resolved against the task registry, then built."""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Annotated, Any

from qdrl.config import ConfigError, OneOf, check_params, check_table, coerce
from qdrl.tasks import TASKS, Task

TaskName = Annotated[str, OneOf(lambda: TASKS)]

__all__ = ["make_task_of", "parse_task"]


def parse_task(data: Any, defaults: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The `[task]` table resolved: its name and every parameter of the task's builder.

    Each key is checked against the annotation of the builder's parameter (type,
    finiteness, declared range) without building the task. `defaults` fill the
    keys that the builder takes and `data` does not give (e.g. a policy task's
    `eval_batch`, from the run's batch size).
    """
    data = check_table(data, "task")
    name = data.get("name")
    if name is None:
        raise ConfigError(f"task.name: missing; expected one of {sorted(TASKS)}")
    name = coerce(name, TaskName, "task.name")
    builder: Callable[..., Any] = TASKS[name].build
    given = {k: v for k, v in data.items() if k != "name"}
    kwargs = check_params(builder, given, "task", owner=f"task {name!r}", selector=("name", name))
    params = inspect.signature(builder).parameters
    for key, value in (defaults or {}).items():
        if key in params and key not in kwargs:
            kwargs[key] = value
    resolved: dict[str, Any] = {"name": name}
    for key, p in params.items():
        value = kwargs.get(key, p.default)
        if value is inspect.Parameter.empty:
            raise ConfigError(f"task.{key}: missing; task {name!r} needs it")
        resolved[key] = list(value) if isinstance(value, tuple) else value
    return resolved


def make_task_of(table: Mapping[str, Any]) -> Task:
    """The task of a resolved `[task]` table (`parse_task`): builds its environment, if any."""
    params = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items() if k != "name"}
    try:
        return TASKS[table["name"]](**params)
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith("task.") else f"task: {msg}") from e
