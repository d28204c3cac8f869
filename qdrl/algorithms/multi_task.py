"""Multi-task MAP-Elites (Mouret & Maguire 2020): a row of the QD family on a multi-task family.

The QD loop as every QD recipe runs it (`qd_recipe`), with the emitter of
`qdrl.qd.emitters.multi_task` (`[mt_me]`) and a CVT repertoire whose cells are the
family's tasks: the recipe sets `[repertoire]` from `[task]` (kind "cvt",
num_centroids = task.num_tasks, cvt_samples, kmeans_iters, cvt_seed = task.task_seed),
so that cell i is task i, and refuses a `[repertoire]` key that says otherwise.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Annotated, Any

from qdrl.algorithms.base import ExperimentConfig, Recipe, Sections
from qdrl.algorithms.qd import EmitterSource, RepertoireConfig, qd_recipe
from qdrl.algorithms.task_spec import parse_task
from qdrl.config import ConfigError, OneOf, check_keys, check_table, coerce
from qdrl.qd.emitters.multi_task import MTMEConfig, MultiTaskEmitter, make_multi_task_emitter
from qdrl.tasks import Task
from qdrl.tasks.multi_task import MULTI_TASK_TASKS

__all__ = ["MT_ME", "MT_ME_SOURCE", "task_repertoire"]

FamilyName = Annotated[str, OneOf(lambda: MULTI_TASK_TASKS)]


def _make(task: Task, config: MTMEConfig) -> MultiTaskEmitter:
    return make_multi_task_emitter(config, task.genotype_low, task.genotype_high)


MT_ME_SOURCE = EmitterSource.of_section("mt_me", MTMEConfig, _make, default_repertoire="cvt")
_QD = qd_recipe(MT_ME_SOURCE, description="Multi-task MAP-Elites (Mouret & Maguire 2020)")

# [repertoire] key <- [task] key: the repertoire's cells are the family's tasks.
_LAYOUT = {"num_centroids": "num_tasks", "cvt_samples": "cvt_samples", "kmeans_iters": "kmeans_iters",
           "cvt_seed": "task_seed"}


def task_repertoire(task: Mapping[str, Any]) -> dict[str, Any]:
    """The `[repertoire]` keys of a resolved multi-task `[task]` table: a CVT whose cells are its tasks."""
    return {"kind": "cvt", **{key: task[source] for key, source in _LAYOUT.items()}}


def _parse(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    task_data = {"name": "multi_task_arm", **check_table(spec.get("task", {}), "task")}
    name = task_data["name"]
    if not isinstance(name, str) or name not in MULTI_TASK_TASKS:
        # An unknown name gets the message of every QD algorithm; a known task that is not of a
        # multi-task family is read (so that the spec schema, `qdrl.spec_recording`, knows every
        # task's keys for mt_me too), then refused.
        parse_task({"name": name})
        coerce(name, FamilyName, "task.name")
    task = parse_task(task_data)
    if task["cvt_samples"] < task["num_tasks"]:
        raise ConfigError(
            f"task.cvt_samples: expected at least task.num_tasks={task['num_tasks']}, got {task['cvt_samples']}"
        )
    raw = check_table(spec.get("repertoire", {}), "repertoire")
    given = check_keys(RepertoireConfig, raw, "repertoire")  # each key's type first, as everywhere
    layout = task_repertoire(task)
    for key, value in layout.items():
        if key in given and given[key] != value:
            source = f"task.{_LAYOUT[key]}" if key in _LAYOUT else "mt_me"
            raise ConfigError(
                f"repertoire.{key}: expected {value!r} (set by {source}: mt_me keeps one elite per task, "
                f"the cells are the tasks), got {raw[key]!r}"
            )
    sections = _QD.parse({**spec, "task": task_data, "repertoire": {**raw, **layout}}, exp)
    config: MTMEConfig = sections["mt_me"]
    if config.variation == "sbx" and MULTI_TASK_TASKS[task["name"]].policy:
        raise ConfigError(
            f"mt_me.variation: expected 'isoline' for task {task['name']!r}, whose genotypes are unbounded "
            "policy parameters (SBX crosses genes within finite bounds), got 'sbx'"
        )
    return sections


MT_ME: Recipe = dataclasses.replace(_QD, parse=_parse)
