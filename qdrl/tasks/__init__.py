"""QD tasks: scoring functions with their bounds, and a registry of them by name.

`TASKS[name](**params)` builds a `Task` (`TASKS[name]` is a `TaskEntry`: its builder
and what a spec can know of the task before building it); `make_task(name, **params)`
does the same with a helpful error for unknown names.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qdrl.tasks.arm import arm, noisy_arm
from qdrl.tasks.base import Task, TaskEntry
from qdrl.tasks.brax_features import FEATURE_TASKS
from qdrl.tasks.brax_qd import BRAX_TASKS
from qdrl.tasks.deceptive import archimedean_spiral, deceptive_evolvability, ssf
from qdrl.tasks.functions import rastrigin, rastrigin_proj, sphere, sphere_proj
from qdrl.tasks.jumanji_qd import snake
from qdrl.tasks.lp import lp_plateau, lp_rastrigin, lp_sphere
from qdrl.tasks.mo import MO_TASKS
from qdrl.tasks.multi_task import MULTI_TASK_TASKS
from qdrl.tasks.point_maze import point_maze

_FUNCTIONS: dict[str, Callable[..., Task]] = {
    "sphere": sphere,
    "rastrigin": rastrigin,
    "sphere_proj": sphere_proj,
    "rastrigin_proj": rastrigin_proj,
    "lp_sphere": lp_sphere,
    "lp_rastrigin": lp_rastrigin,
    "lp_plateau": lp_plateau,
    "arm": arm,
    "noisy_arm": noisy_arm,
    "archimedean_spiral": archimedean_spiral,
    "deceptive_evolvability": deceptive_evolvability,
    "ssf": ssf,
}
_POLICIES: dict[str, Callable[..., Task]] = {
    "point_maze": point_maze,
    "snake": snake,
    **BRAX_TASKS,
    **FEATURE_TASKS,
}
TASKS: dict[str, TaskEntry] = {
    **{name: TaskEntry(build) for name, build in _FUNCTIONS.items()},
    **{name: TaskEntry(build, policy=True) for name, build in _POLICIES.items()},
    **MO_TASKS,
    **MULTI_TASK_TASKS,
}


def make_task(name: str, **params: Any) -> Task:
    """The task registered as `name`, built with keyword `params`."""
    try:
        builder = TASKS[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; known: {', '.join(sorted(TASKS))}") from None
    return builder(**params)


__all__ = [
    "TASKS",
    "Task",
    "TaskEntry",
    "archimedean_spiral",
    "arm",
    "deceptive_evolvability",
    "lp_plateau",
    "lp_rastrigin",
    "lp_sphere",
    "make_task",
    "noisy_arm",
    "rastrigin",
    "rastrigin_proj",
    "sphere",
    "sphere_proj",
    "ssf",
]
