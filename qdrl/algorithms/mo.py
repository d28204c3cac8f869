"""Multi-objective recipes: MOME, NSGA-II and SPEA2 on the one QD loop.

- `mome` (Pierrot et al. 2022): MAP-Elites whose cells hold Pareto fronts
  (`qdrl.qd.repertoires.mome`), with the emitters of `[emitter]` (QDax's example:
  polynomial mutation and crossover); sections `[task]`, `[repertoire]`,
  `[emitter]`, `[qd]`, `[mome]`.
- `nsga2` (Deb et al. 2002) and `spea2` (Zitzler et al. 2001): a population of
  `population.size` with its survival rule (`qdrl.qd.populations`), SBX and
  polynomial mutation; sections `[task]`, `[population]`, `[qd]`.

Each log point records the metrics of `qdrl.qd.mo_metrics` (exact hypervolumes: in
the compiled loop for two objectives, on the host with moocore for more); the end
writes `front.csv` (the global front), `repertoire.npz` / `repertoire.csv` (MOME)
or `population.npz` / `population.csv` (every stored solution), and plots of the
global front, the per-cell hypervolumes and a few cells' fronts.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Literal

import jax
import numpy as np

from qdrl import plotting
from qdrl.algorithms.base import (
    Algorithm,
    BuildContext,
    ExperimentConfig,
    Progress,
    QDParts,
    Recipe,
    Row,
    Sections,
    last_values,
)
from qdrl.algorithms.qd import (
    Container,
    parse_task_and_qd,
    qd_recipe,
    registry_source,
)
from qdrl.algorithms.task_spec import make_task_of
from qdrl.config import ConfigError, NonNegativeFloat, NonNegativeInt, PositiveInt, UnitFloat, build
from qdrl.placement import check_divisible
from qdrl.qd.emitters.ga import sbx_emitter
from qdrl.qd.map_elites import MapElites
from qdrl.qd.mo_metrics import exact_hypervolumes, global_front, mo_metrics
from qdrl.qd.populations import Survival, pareto_population
from qdrl.qd.repertoires.export import export_solutions, write_front
from qdrl.qd.repertoires.mome import mome_repertoire
from qdrl.tasks import TASKS, Task

__all__ = ["MOME", "NSGA2", "SPEA2", "MOMEConfig", "PopulationConfig"]


@dataclasses.dataclass(frozen=True)
class MOMEConfig:
    """The `[mome]` section: the Pareto front of each cell."""

    pareto_front_max_length: PositiveInt = 50  # most solutions a cell's front holds (QDax: 50)
    # Who leaves a front that overflows: the most crowded ("crowding", the paper's spread)
    # or the newest by index order ("index", what QDax does).
    overflow: Literal["crowding", "index"] = "crowding"


@dataclasses.dataclass(frozen=True)
class PopulationConfig:
    """The `[population]` section of NSGA-II and SPEA2: size and variation (Deb et al. 2002)."""

    size: PositiveInt = 100  # N: offspring per iteration, and survivors
    crossover_eta: NonNegativeFloat = 20.0  # SBX distribution index
    crossover_prob: UnitFloat = 0.9  # share of the pairs that cross
    mutation_eta: NonNegativeFloat = 20.0  # polynomial mutation distribution index
    # Each gene mutates with this probability; 0 means 1 / (number of genes), the usual choice.
    mutation_prob: UnitFloat = 0.0
    # A child equal to one of its parents is drawn again up to this many times (0: never), as
    # pymoo draws duplicates again; the draws are made at once.
    redraws: NonNegativeInt = 1
    # NSGA-II's cut of its last front: "distance", one cut by the crowding distance (Deb et al.
    # 2002), or "pruning", one member at a time with the distances computed again (Kukkonen &
    # Deb 2006; pymoo's crowding_func="pcd"). SPEA2 has its own truncation.
    crowding: Literal["distance", "pruning"] = "distance"


def check_mo_task(task: Mapping[str, Any], algorithm: str) -> None:
    """Refuses a resolved `[task]` of one objective, or a reference point of the wrong length
    (from the task registry's entry: nothing is built)."""
    m = TASKS[task["name"]].num_objectives(task)
    if m < 2:
        names = sorted(n for n, entry in TASKS.items() if entry.num_objectives({"name": n}) > 1)
        raise ConfigError(
            f"task.name: expected a multi-objective task for {algorithm} (one of {names}), "
            f"got {task['name']!r}"
        )
    ref = task.get("reference_point")
    if ref is not None and len(ref) != m:
        raise ConfigError(
            f"task.reference_point: expected {m} numbers (one per objective of {task['name']!r}), "
            f"got {list(ref)}"
        )


def _no_reevaluation(qd: Any) -> None:
    if qd.reevaluate_samples:
        raise ConfigError(f"qd.reevaluate_samples: expected 0 for a multi-objective run, got {qd.reevaluate_samples}")


def mo_log_row(state: Any, metrics: Any, task: Task) -> Row:
    """The row of a multi-objective chunk: counters, the last iteration's metrics (exact
    hypervolumes on the host when the loop has none: more than two objectives)."""
    m = jax.device_get(metrics)
    row: Row = {
        "iteration": int(state.iteration),
        "evaluations": int(state.evaluations),
        "env_steps": int(state.env_steps),
    }
    row.update(last_values(m, [k for k in m if k != "added"]))
    if "global_hypervolume" not in row:
        hv = exact_hypervolumes(jax.device_get(state.repertoire), _reference(task))
        row.update({k: v for k, v in hv.items() if k != "cell_hypervolumes"})
    row["added_per_iter"] = float(np.mean(m["added"]))
    return row


def _reference(task: Task) -> tuple[float, ...]:
    assert task.reference_point is not None, "multi-objective tasks have a reference point"
    return tuple(task.reference_point)


def _metrics(task: Task) -> Callable[[Any, float], dict[str, Any]]:
    reference = _reference(task)

    def metrics(container: Any, qd_offset: float) -> dict[str, Any]:
        del qd_offset
        return mo_metrics(container, reference)

    return metrics


def mo_plot(container: Any, out_dir: Path, task: Task, algorithm: str) -> None:
    """The global front against the true one where known; MOME: per-cell hypervolumes and fronts."""
    ref, title = _reference(task), f"{algorithm} on {task.name}"
    plotting.plot_pareto_front(
        {algorithm: global_front(container)}, out_dir / "plots" / "front.png", reference=ref,
        true_front=None if task.true_front is None else task.true_front(), title=title,
        minimised=task.minimised,
    )
    cells = exact_hypervolumes(container, ref).get("cell_hypervolumes")
    if cells is not None:
        plotting.plot_cell_hypervolumes(
            container.cells, cells, out_dir / "plots" / "cell_hypervolumes.png",
            task.descriptor_low, task.descriptor_high, title=title,
        )
        plotting.plot_cell_fronts(
            np.asarray(container.fitnesses), cells, out_dir / "plots" / "cell_fronts.png",
            reference=ref, title=title,
        )


def mo_finish(container: Any, out_dir: Path, task: Task, export_name: str) -> dict[str, Any]:
    """The global front (front.csv), the container's export, and the exact hypervolumes."""
    ref = _reference(task)
    front = global_front(container)
    hv = exact_hypervolumes(container, ref)
    hv.pop("cell_hypervolumes", None)
    write_front(front, out_dir / "front.csv")
    export_solutions(container, out_dir, export_name, task.descriptor_names)
    summary: dict[str, Any] = {
        "reference_point": list(ref),
        "global_front_size": len(front),
        **{f"exact_{k}": v for k, v in hv.items()},
    }
    if task.true_hypervolume is not None:
        summary["true_front_hypervolume"] = task.true_hypervolume
        summary["hypervolume_ratio"] = hv["global_hypervolume"] / task.true_hypervolume
    return summary


# -- MOME: MAP-Elites with a Pareto front per cell --


def _parse_mome(spec: Mapping[str, Any], sections: Sections, exp: ExperimentConfig) -> Sections:
    mome = build(MOMEConfig, spec.get("mome", {}), "mome")
    check_mo_task(sections["task"], exp.algorithm)
    _no_reevaluation(sections["qd"])
    return {"mome": mome}


def _wrap_mome(cells: Any, sections: Sections, task: Task, example: Any) -> Any:
    c: MOMEConfig = sections["mome"]
    return mome_repertoire(cells, example, task.num_objectives, c.pareto_front_max_length, c.overflow)


MOME_CONTAINER = Container(
    parse=_parse_mome,
    wrap=_wrap_mome,
    metrics=_metrics,
    log_row=mo_log_row,
    finish=lambda rep, out_dir, task, algorithm: mo_finish(rep, out_dir, task, "repertoire"),
    plot=mo_plot,
    progress_keys=("moqd_score", "global_hypervolume", "coverage", "evaluations_per_s"),
)
MOME = qd_recipe(
    registry_source(default_repertoire="cvt"), container=MOME_CONTAINER,
    description="MOME (Pierrot et al. 2022): a Pareto front per cell",
)


# -- NSGA-II and SPEA2: a population with its survival rule --


def _parse_population(spec: Mapping[str, Any], exp: ExperimentConfig, survival: Survival) -> Sections:
    """The checked sections of an NSGA-II or SPEA2 spec; `qd.init_batch_size` defaults to the
    population size."""
    population = build(PopulationConfig, spec.get("population", {}), "population")
    task, qd = parse_task_and_qd(
        spec, exp, population.size, "population.size", default_task="zdt1",
        qd_defaults={"init_batch_size": population.size},
    )
    check_divisible(population.size, exp.num_devices, "population.size")
    _no_reevaluation(qd)
    check_mo_task(task, exp.algorithm)
    if population.crowding != "distance" and survival != "nsga2":
        raise ConfigError(
            f"population.crowding: expected \"distance\" for {exp.algorithm} (pruning is NSGA-II's "
            f"cut of its last front), got {population.crowding!r}"
        )
    if TASKS[task["name"]].policy:  # policies: unbounded genotypes, which SBX cannot cross
        raise ConfigError(
            f"task.name: expected a task with bounded genotypes for {exp.algorithm} (SBX and "
            f"polynomial mutation need bounds), got the policy task {task['name']!r}"
        )
    return {"task": task, "population": population, "qd": qd}


def _build_population(sections: Sections, ctx: BuildContext, survival: Survival) -> Algorithm:
    task = make_task_of(sections["task"])
    c: PopulationConfig = sections["population"]
    qd = sections["qd"]
    mutation_prob = c.mutation_prob or 1.0 / task.genotype_size
    emitter = sbx_emitter(
        c.size, c.crossover_eta, c.mutation_eta, mutation_prob, task.genotype_low,
        task.genotype_high, crossover_prob=c.crossover_prob, redraws=c.redraws,
    )

    def empty(centroids: Any = None) -> Any:
        del centroids
        return pareto_population(
            task.example_genotype(), c.size, task.num_objectives, task.descriptor_size, survival, c.crowding
        )

    me = MapElites(task.scoring_fn, emitter, empty(), metrics_fn=_metrics(task), placement=ctx.placement)
    def init(key: jax.Array) -> Any:
        _, init_key, run_key = jax.random.split(key, 3)
        return me.init(task.init_genotypes(init_key, qd.init_batch_size), run_key)

    return Algorithm(
        task=task.name,
        sections=sections,
        num_chunks=qd.num_iterations // qd.log_every,
        progress=Progress(("global_hypervolume", "num_solutions", "evaluations_per_s"), "iteration", qd.num_iterations),
        init=init,
        chunk=lambda state: me.run(state, qd.log_every),
        log_row=lambda state, metrics: mo_log_row(state, metrics, task),
        finish=lambda state, rows, out_dir: mo_finish(jax.device_get(state.repertoire), out_dir, task, "population"),
        plot=lambda state, rows, out_dir: mo_plot(jax.device_get(state.repertoire), out_dir, task, ctx.algorithm),
        placement=ctx.placement,
        state_axes=me.state_axes,
        # no descriptor space: a population has no cells (its summary names no descriptor bounds)
        qd=QDParts(task, empty, task.scoring),
    )


_SURVIVALS: tuple[tuple[Survival, str], ...] = (
    ("nsga2", "NSGA-II (Deb et al. 2002)"), ("spea2", "SPEA2 (Zitzler et al. 2001)"),
)
NSGA2, SPEA2 = (
    Recipe(
        functools.partial(_parse_population, survival=survival),
        functools.partial(_build_population, survival=survival), "qd.num_iterations", description,
    )
    for survival, description in _SURVIVALS
)
