"""Multi-objective runs: MOME, NSGA-II and SPEA2 on the one QD loop, for the experiment driver.

- `mome` (Pierrot et al. 2022): MAP-Elites whose cells hold Pareto fronts
  (`qdrl.qd.repertoires.mome`), with the GA emitters of `[emitter]`
  (QDax's example: polynomial mutation and crossover); sections `[task]`,
  `[repertoire]`, `[mome]`, `[emitter]`, `[qd]`.
- `nsga2` (Deb et al. 2002) and `spea2` (Zitzler et al. 2001): a population of
  `population.size` with its survival rule (`qdrl.qd.populations`), SBX and
  polynomial mutation; sections `[task]`, `[population]`, `[qd]`.

The runs are `QDRun`s with another container and metrics: building, compiling,
checkpointing and resuming are QDRun's. Each log point records the metrics of
`qdrl.qd.mo_metrics` (exact hypervolumes: in the compiled loop for two objectives,
on the host with moocore for more); the end writes `front.csv` (the global front),
`repertoire.npz` / `repertoire.csv` (MOME) or `population.npz` / `population.csv`
(every stored solution; `qdrl.load_run(path).repertoire` gives the container back)
and plots of the global
front, the per-cell hypervolumes and a few cells' fronts.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import jax
import numpy as np

from qdrl.config import (
    ConfigError,
    NonNegativeFloat,
    NonNegativeInt,
    PositiveInt,
    UnitFloat,
    build,
    check_table,
)
from qdrl.experiment import ExperimentConfig, Sections, register, scalar
from qdrl.placement import check_divisible, make_placement
from qdrl.runners.qd import QDConfig, QDRun, parse_qd, parse_task

if TYPE_CHECKING:
    from qdrl.qd.map_elites import MapElites, QDState


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
    # pymoo draws duplicates again; the draws are made at once (one redraw: about +15% of
    # NSGA-II's loop on ZDT1, and +0.0004 of hypervolume at 25,000 evaluations).
    redraws: NonNegativeInt = 1
    # NSGA-II's cut of its last front: "distance", one cut by the crowding distance (Deb et al.
    # 2002), or "pruning", one member at a time with the distances computed again (Kukkonen &
    # Deb 2006; pymoo's crowding_func="pcd"). SPEA2 has its own truncation.
    crowding: Literal["distance", "pruning"] = "distance"


def _check_mo_task(task: Mapping[str, Any], algorithm: str) -> None:
    """Refuses a resolved `[task]` of one objective, or a reference point of the wrong length."""
    from qdrl.tasks.mo import MO_TASKS, num_objectives_of

    m = num_objectives_of(task)
    if m < 2:
        raise ConfigError(
            f"task.name: expected a multi-objective task for {algorithm} (one of "
            f"{sorted(MO_TASKS)}), got {task['name']!r}"
        )
    ref = task.get("reference_point")
    if ref is not None and len(ref) != m:
        raise ConfigError(
            f"task.reference_point: expected {m} numbers (one per objective of {task['name']!r}), "
            f"got {list(ref)}"
        )


def parse_mome(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    """The checked sections of a MOME spec: those of `parse_qd` (CVT by default) and `[mome]`."""
    mome = build(MOMEConfig, spec.get("mome", {}), "mome")
    sections = parse_qd(spec, exp, default_kind="cvt")
    _check_mo_task(sections["task"], "mome")
    if sections["qd"].reevaluate_samples:
        raise ConfigError("qd.reevaluate_samples: expected 0 for a multi-objective run, got "
                          f"{sections['qd'].reevaluate_samples}")
    sections["mome"] = mome
    return sections


def parse_population(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    """The checked sections of an NSGA-II or SPEA2 spec: `[task]`, `[population]` and `[qd]`.

    `qd.init_batch_size` defaults to the population size.
    """
    population = build(PopulationConfig, spec.get("population", {}), "population")
    qd_data = dict(check_table(spec.get("qd", {}), "qd"))
    qd_data.setdefault("init_batch_size", population.size)
    qd = build(QDConfig, qd_data, "qd")
    check_divisible(population.size, exp.num_devices, "population.size")
    check_divisible(qd.init_batch_size, exp.num_devices, "qd.init_batch_size")
    if qd.reevaluate_samples:
        raise ConfigError(f"qd.reevaluate_samples: expected 0 for a multi-objective run, got {qd.reevaluate_samples}")
    task = parse_task(spec.get("task", {"name": "zdt1"}), {"eval_batch": population.size})
    _check_mo_task(task, exp.algorithm)
    if population.crowding != "distance" and exp.algorithm != "nsga2":
        raise ConfigError(
            f"population.crowding: expected \"distance\" for {exp.algorithm} (pruning is NSGA-II's "
            f"cut of its last front), got {population.crowding!r}"
        )
    if "episode_length" in task:  # policies: unbounded genotypes, which SBX cannot cross
        raise ConfigError(
            f"task.name: expected a task with bounded genotypes for {exp.algorithm} (SBX and "
            f"polynomial mutation need bounds), got the policy task {task['name']!r}"
        )
    return {"task": task, "population": population, "qd": qd}


class _MOMixin:
    """What MOME and the populations share: metrics, log rows and the final artefacts."""

    progress_keys: tuple[str, ...] = ("global_hypervolume", "num_solutions", "evaluations_per_s")
    export_name = "population"  # the final container's files: <name>.npz, <name>.csv
    _task: Any
    algorithm: str
    task: str

    @property
    def reference_point(self) -> tuple[float, ...]:
        ref = self._task.reference_point
        assert ref is not None
        return tuple(ref)

    def metrics_fn(self) -> Any:
        from qdrl.qd.mo_metrics import mo_metrics

        ref = self.reference_point

        def metrics(container: Any, qd_offset: float) -> dict[str, Any]:
            del qd_offset
            return mo_metrics(container, ref)

        return metrics

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        from qdrl.qd.mo_metrics import exact_hypervolumes

        m = jax.device_get(chunk_metrics)
        row: dict[str, float] = {
            "iteration": int(state.iteration),
            "evaluations": int(state.evaluations),
            "env_steps": int(state.env_steps),
        }
        for key, values in m.items():
            if key != "added":
                row[key] = scalar(np.asarray(values)[-1])
        if "global_hypervolume" not in row:  # more than two objectives: exact, on the host
            hv = exact_hypervolumes(jax.device_get(state.repertoire), self.reference_point)
            row.update({k: v for k, v in hv.items() if k != "cell_hypervolumes"})
        row["added_per_iter"] = float(np.mean(m["added"]))
        return row

    def finish(self, state: QDState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        from qdrl import plotting
        from qdrl.qd.mo_metrics import exact_hypervolumes, global_front
        from qdrl.tasks.mo import TRUE_HYPERVOLUME, true_front

        container = jax.device_get(state.repertoire)
        ref = self.reference_point
        front = global_front(container)
        hv = exact_hypervolumes(container, ref)
        _write_front(front, out_dir / "front.csv")
        _export(container, out_dir, self.export_name)
        label = f"{self.algorithm} on {self.task}"
        known = None
        if self.task in ("zdt1", "zdt2", "zdt3") or (self.task == "dtlz2" and container.num_objectives == 3):
            known = true_front(self.task, 400 if self.task != "dtlz2" else 900)
        plotting.plot_pareto_front(
            {self.algorithm: front}, out_dir / "plots" / "front.png", reference=ref,
            true_front=known, title=label,
        )
        cells = hv.pop("cell_hypervolumes", None)
        if cells is not None:
            rep = container
            plotting.plot_cell_hypervolumes(
                rep.cells, cells, out_dir / "plots" / "cell_hypervolumes.png",
                self._task.descriptor_low, self._task.descriptor_high, title=label,
            )
            plotting.plot_cell_fronts(
                np.asarray(rep.fitnesses), cells, out_dir / "plots" / "cell_fronts.png",
                reference=ref, title=label,
            )
        summary: dict[str, Any] = {
            "reference_point": list(ref),
            "global_front_size": len(front),
            **{f"exact_{k}": v for k, v in hv.items()},
        }
        if self._task.name in TRUE_HYPERVOLUME and (self._task.name != "dtlz2" or container.num_objectives == 3):
            true = TRUE_HYPERVOLUME[self._task.name]
            summary["true_front_hypervolume"] = true
            summary["hypervolume_ratio"] = hv["global_hypervolume"] / true
        return summary


def _write_front(front: np.ndarray, path: Path) -> None:
    header = ",".join(f"objective_{k}" for k in range(front.shape[1]))
    np.savetxt(path, front, delimiter=",", header=header, comments="")


def _export(container: Any, out_dir: Path, name: str) -> None:
    """`<name>.npz` (as `export_npz`: fitnesses, descriptors, genotype leaves named `genotypes` +
    key path, centroids) and `<name>.csv`, one row per stored solution (cell and slot, or slot)."""
    fit = np.asarray(container.fitnesses)
    desc = np.asarray(container.descriptors)
    arrays: dict[str, np.ndarray] = {"fitnesses": fit, "descriptors": desc}
    for key_path, leaf in jax.tree_util.tree_flatten_with_path(container.genotypes)[0]:
        arrays["genotypes" + jax.tree_util.keystr(key_path)] = np.asarray(leaf)
    if hasattr(container, "centroids"):
        arrays["centroids"] = np.asarray(container.centroids)
    np.savez_compressed(out_dir / f"{name}.npz", **arrays)  # type: ignore[arg-type]
    m, d = fit.shape[-1], desc.shape[-1]
    flat_f, flat_d = fit.reshape(-1, m), desc.reshape(-1, d)
    keep = np.all(np.isfinite(flat_f), axis=1)
    slots = fit.shape[1] if fit.ndim == 3 else len(fit)
    index = np.arange(len(flat_f))
    cols = [index // slots, index % slots, *flat_f.T, *flat_d.T]
    names = ["cell", "slot", *(f"objective_{k}" for k in range(m)), *(f"descriptor_{k}" for k in range(d))]
    table = np.stack(cols, axis=1)[keep]
    fmt = ["%d", "%d", *(["%.9g"] * (m + d))]
    np.savetxt(out_dir / f"{name}.csv", table, delimiter=",", header=",".join(names), comments="", fmt=fmt)


class MOMERun(_MOMixin, QDRun):
    """MOME: a Pareto front per cell (`[mome]`), the GA of `[emitter]`, on a multi-objective task."""

    progress_keys: tuple[str, ...] = ("moqd_score", "global_hypervolume", "coverage", "evaluations_per_s")
    export_name = "repertoire"

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        super().__init__(sections, exp)
        self.mome_cfg: MOMEConfig = sections["mome"]

    def _build(self, key: jax.Array) -> MapElites:
        from qdrl.qd.map_elites import MapElites

        base = super()._build(key)  # the GA emitter of a QD run, on `empty_repertoire`
        return MapElites(
            base.scoring_fn, base.emitter, base.empty_repertoire, metrics_fn=self.metrics_fn(),
            placement=self.placement,
        )

    def empty_repertoire(self, key: jax.Array | None = None, centroids: Any = None) -> Any:
        """The empty MOME repertoire on the cells of `[repertoire]` (see `QDRun.empty_repertoire`)."""
        from qdrl.qd.repertoires.mome import mome_repertoire

        c = self.mome_cfg
        return mome_repertoire(
            super().empty_repertoire(key, centroids), self.example_genotype(),
            self._task.num_objectives, c.pareto_front_max_length, c.overflow,
        )


class PopulationRun(_MOMixin, QDRun):
    """NSGA-II or SPEA2: a population of `[population]` with its survival rule, SBX and mutation."""

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        from qdrl.runners.qd import make_task_of

        self.sections = dict(sections)
        self.pop_cfg: PopulationConfig = sections["population"]
        self.qd_cfg = sections["qd"]
        self.emitter_cfg = None
        self.pool_cfg = None
        self._lapack = contextlib.nullcontext  # no CMA-ES here
        self._task = make_task_of(sections["task"])
        self.algorithm = exp.algorithm
        self.task = str(sections["task"]["name"])
        self.num_chunks = self.qd_cfg.num_iterations // self.qd_cfg.log_every
        self.progress_unit, self.progress_total = "iteration", self.qd_cfg.num_iterations
        self.seed = exp.seed
        self.placement = make_placement(exp.devices)
        self._chunk: Any = None
        self.map_elites: MapElites | None = None

    @property
    def batch_size(self) -> int:
        """One offspring per member each generation."""
        return self.pop_cfg.size

    def _build(self, key: jax.Array) -> MapElites:
        from qdrl.qd.emitters.ga import sbx_emitter
        from qdrl.qd.map_elites import MapElites

        del key
        task, c = self._task, self.pop_cfg
        mutation_prob = c.mutation_prob or 1.0 / task.genotype_size
        emitter = sbx_emitter(
            c.size, c.crossover_eta, c.mutation_eta, mutation_prob, task.genotype_low,
            task.genotype_high, crossover_prob=c.crossover_prob, redraws=c.redraws,
        )
        return MapElites(
            self.scoring(), emitter, self.empty_repertoire(), metrics_fn=self.metrics_fn(), placement=self.placement
        )

    def empty_repertoire(self, key: jax.Array | None = None, centroids: Any = None) -> Any:
        """The empty population."""
        from qdrl.qd.populations import Survival, pareto_population

        del key, centroids
        survival: Survival = "nsga2" if self.algorithm == "nsga2" else "spea2"
        return pareto_population(
            self.example_genotype(), self.pop_cfg.size, self._task.num_objectives,
            self._task.descriptor_size, survival, self.pop_cfg.crowding,
        )


register("mome", parse_mome, MOMERun)
register("nsga2", parse_population, PopulationRun)
register("spea2", parse_population, PopulationRun)
