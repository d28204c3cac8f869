"""Cells whose elites keep every sample they were given: the Uncertain-QD methods that re-evaluate.

In a noisy task one evaluation of a solution is one draw of its fitness and descriptor;
an elite kept for a lucky draw holds its cell against better solutions. The repertoire
here stores, beside each elite, its samples' count, fitness sum and descriptor sum: its
stored fitness and descriptor are their means. Three methods grow these samples:

- Archive-Sampling (Flageat & Cully 2023, "Uncertain Quality-Diversity", IEEE TEVC):
  each iteration the elites are re-evaluated once more, their means updated, and the
  archive rebuilt from the elites at their new means and the offspring (one sample each):
  an elite whose mean descriptor moved competes in its new cell, by mean fitness.
- Parallel-Adaptive-Sampling (same paper): Archive-Sampling whose offspring are each
  evaluated m times, m the median (or max, min, mean) number of samples of the elites,
  so that an offspring is compared on as many samples as the elites it meets; the
  offspring per iteration shrink to what the rows left after re-evaluations allow.
- Adaptive-Sampling (Justesen, Risi & Mouret 2019, "MAP-Elites for noisy domains by
  adaptive sampling", GECCO companion): an offspring that beats the mean of an occupied
  cell's elite becomes that cell's challenger; the elite is re-evaluated once (it is
  challenged), then the challenger once per round while its mean stays above the
  elite's and in the elite's cell; it replaces the elite when it has as many samples as
  the elite (at most `max_samples`) and is dropped as soon as it falls behind or leaves
  the cell. An offspring reaching an empty cell fills it at once.

A batch of n rows is planned by the repertoire itself (`plan`, a function of its state,
so the emitter that builds the batch and the `add_evaluation` that reads it agree): up
to `reevaluations` rows re-evaluate stored solutions (jobs: the least-sampled elites,
or the challengers and the challenged elites), the others are offspring, each taking
`offspring_samples(state)` consecutive rows (1 but for Parallel-Adaptive-Sampling); rows
of an incomplete last group are evaluated and unused. Jobs that do not fit wait for the
next iteration; when there are fewer, their rows are offspring. Every row is one
evaluation, so a run evaluates exactly the emitter's batch per iteration.

Typical use (with `qdrl.qd.emitters.resampling.ResamplingEmitter`)::

    rep = accumulating_repertoire(grid_repertoire(example, (32, 32), 0.0, 1.0),
                                  "archive_sampling", reevaluations=256)
    batch = rep.batch(offspring)  # n rows: re-evaluations, then offspring
    rep, result = rep.add_evaluation(batch, scoring_fn(batch, key))
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.repertoires.cells import (
    CellRepertoire,
    check_batch,
    init_storage,
    valid_candidates,
    write_rows,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype

__all__ = [
    "METHODS",
    "STATISTICS",
    "AccumulatingRepertoire",
    "Method",
    "Plan",
    "Statistic",
    "accumulating_repertoire",
]

Method = Literal["archive_sampling", "adaptive_sampling", "parallel_adaptive_sampling"]
METHODS: tuple[str, ...] = ("archive_sampling", "adaptive_sampling", "parallel_adaptive_sampling")
# Which statistic of the elites' sample counts sets Parallel-Adaptive-Sampling's m (the paper's
# `use_evals`; its runs use the median).
Statistic = Literal["median", "max", "min", "mean"]
STATISTICS: tuple[str, ...] = ("median", "max", "min", "mean")

_NEVER = jnp.iinfo(jnp.int32).max  # sort key of a job nobody wants


class Plan(NamedTuple):
    """What each of a batch's n rows evaluates."""

    job: Array  # (n,) int32: stored solution re-evaluated (cell c: its elite, C + c: its challenger), -1 if none
    group: Array  # (n,) int32: the offspring this row samples, -1 for job rows and unused rows
    samples: Array  # () int32: rows per offspring (m)


@dataclasses.dataclass(frozen=True, eq=False)
class AccumulatingRepertoire(CellRepertoire):
    """A `CellRepertoire` whose elites keep their samples; see the module docstring.

    `fitnesses` and `descriptors` are the elites' sample means; the cells are the
    repertoire's own (grid or CVT), so metrics, plots, exports and the corrected
    re-evaluation read it as any cell repertoire.

    Attributes (beyond `CellRepertoire`'s):
      counts: (C,) int32 samples of each elite (0 where empty).
      fitness_sums, descriptor_sums: (C,) and (C, D) float32 sums of its samples.
      challenger_genotypes, challenger_counts, challenger_fitness_sums,
        challenger_descriptor_sums: Adaptive-Sampling's challenger of each cell (count 0:
        none); None for the other methods.
      elite_due: (C,) bool, the elite owes the re-evaluation of its current challenge
        (Adaptive-Sampling); None otherwise.
      method: which method's rules `add_evaluation` applies (static).
      reevaluations: at most this many rows of a batch re-evaluate stored solutions (static).
      max_samples: 0 for no cap; else Archive- and Parallel-Adaptive-Sampling stop
        re-evaluating an elite with that many samples, Parallel-Adaptive-Sampling's m is at
        most it, and an Adaptive-Sampling challenger wins with that many (static).
      statistic: the count statistic that sets Parallel-Adaptive-Sampling's m (static).
    """

    counts: Array | None = None
    fitness_sums: Array | None = None
    descriptor_sums: Array | None = None
    challenger_genotypes: Genotype = None
    challenger_counts: Array | None = None
    challenger_fitness_sums: Array | None = None
    challenger_descriptor_sums: Array | None = None
    elite_due: Array | None = None
    method: str = "archive_sampling"
    reevaluations: int = 0
    max_samples: int = 0
    statistic: str = "median"

    # -- the plan of a batch --

    @property
    def _adaptive(self) -> bool:
        return self.method == "adaptive_sampling"

    def _counts(self) -> Array:
        assert self.counts is not None, "built by accumulating_repertoire"
        return self.counts

    def offspring_samples(self) -> Array:
        """() int32 rows each offspring gets: Parallel-Adaptive-Sampling's m, the chosen statistic
        of the elites' sample counts (floored, at least 1, at most `max_samples`); 1 otherwise."""
        if self.method != "parallel_adaptive_sampling":
            return jnp.ones((), jnp.int32)
        counts = self._counts().astype(jnp.float32)
        kept = jnp.where(self.filled, counts, jnp.nan)
        stat: dict[str, Callable[[Array], Array]] = {
            "median": jnp.nanmedian, "max": jnp.nanmax, "min": jnp.nanmin, "mean": jnp.nanmean,
        }
        m = stat[self.statistic](kept)
        m = jnp.where(self.is_empty, 1.0, jnp.floor(m))
        if self.max_samples:
            m = jnp.minimum(m, float(self.max_samples))
        return jnp.maximum(m, 1.0).astype(jnp.int32)

    def _jobs(self) -> tuple[Array, Array]:
        """(wanted, key) of every job: sorted by key, then index, the wanted ones are done first."""
        counts = self._counts()
        if not self._adaptive:
            wanted = self.filled
            if self.max_samples:
                wanted = wanted & (counts < self.max_samples)
            return wanted, jnp.where(wanted, counts, _NEVER)
        assert self.challenger_counts is not None and self.elite_due is not None
        active = self.challenger_counts > 0
        # A challenged elite's one re-evaluation first, then the least-sampled challengers.
        wanted = jnp.concatenate([self.elite_due, active])
        key = jnp.concatenate([jnp.zeros_like(counts), self.challenger_counts])
        return wanted, jnp.where(wanted, key, _NEVER)

    def plan(self, n: int) -> Plan:
        """The plan of a batch of n rows (a function of the state; jittable)."""
        wanted, key = self._jobs()
        k = min(self.reevaluations, n, int(key.shape[0]))
        order = jnp.argsort(key, stable=True)[:k].astype(jnp.int32)
        num_jobs = jnp.minimum(jnp.sum(wanted, dtype=jnp.int32), k)
        row = jnp.arange(n, dtype=jnp.int32)
        is_job = row < num_jobs
        job = jnp.where(is_job, jnp.pad(order, (0, n - k)), -1)
        m = self.offspring_samples()
        position = row - num_jobs
        group = position // m
        complete = (group + 1) * m <= n - num_jobs
        group = jnp.where(~is_job & complete, group, -1)
        return Plan(job.astype(jnp.int32), group.astype(jnp.int32), m)

    def batch(self, offspring: Genotype) -> Genotype:
        """The n rows to evaluate: the planned re-evaluations, then the offspring (each offspring
        repeated over its m rows); `offspring` (leaves (n, ...)) come from the emitter."""
        n = int(jax.tree.leaves(offspring)[0].shape[0])
        plan = self.plan(n)
        num_cells = self.num_cells
        from_offspring = jnp.maximum(plan.group, 0)
        elite = jnp.clip(plan.job, 0, num_cells - 1)

        def rows(offspring_leaf: Array, elite_leaf: Array, challenger_leaf: Array | None) -> Array:
            stored = elite_leaf[elite]
            if challenger_leaf is not None:
                challenger = challenger_leaf[jnp.clip(plan.job - num_cells, 0, num_cells - 1)]
                stored = jnp.where(_rows(plan.job >= num_cells, stored), challenger, stored)
            return jnp.where(_rows(plan.job >= 0, stored), stored, offspring_leaf[from_offspring])

        if self._adaptive:
            return jax.tree.map(rows, offspring, self.genotypes, self.challenger_genotypes)
        return jax.tree.map(lambda o, e: rows(o, e, None), offspring, self.genotypes)

    # -- adding --

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[AccumulatingRepertoire, AddResult]:
        """MAP-Elites insertion of candidates evaluated once (`CellRepertoire.add`); a new elite
        starts with its one sample."""
        added, result = CellRepertoire.add(self, genotypes, descriptors, fitnesses)
        new = _own(added)
        target = jnp.where(result.added, result.cell, self.num_cells)
        d, f = check_batch(self.genotypes, self.descriptor_dim, genotypes, descriptors, fitnesses, "add")
        return dataclasses.replace(
            new,
            counts=self._counts().at[target].set(1, mode="drop"),
            fitness_sums=_sums(self.fitness_sums).at[target].set(f, mode="drop"),
            descriptor_sums=_sums(self.descriptor_sums).at[target].set(d, mode="drop"),
        ), result

    def add_evaluation(
        self, genotypes: Genotype, evaluation: Evaluation
    ) -> tuple[AccumulatingRepertoire, AddResult]:
        """Reads a batch built by `batch` (n rows, planned from this same state): samples of the
        re-evaluated solutions are accumulated, the offspring (m rows each) averaged, then the
        method's rules applied (module docstring). A non-finite sample is not accumulated; an
        offspring with one is rejected.

        Returns the new repertoire and an `AddResult` over the n rows: an offspring's outcome on
        the first row of its group (`added`: it is now an elite), nothing on the others."""
        descriptors, fitnesses = check_batch(
            self.genotypes, self.descriptor_dim, genotypes, evaluation.descriptors, evaluation.fitnesses,
            "add_evaluation",
        )
        n = fitnesses.shape[0]
        plan = self.plan(n)
        valid = valid_candidates(descriptors, fitnesses)
        f = jnp.where(valid, fitnesses, 0.0)
        d = jnp.where(valid[:, None], descriptors, 0.0)

        # Samples of the jobs, one segment per stored solution (cells, then challengers).
        num_jobs = self.num_cells * (2 if self._adaptive else 1)
        job = jnp.where((plan.job >= 0) & valid, plan.job, num_jobs)
        job_count = jax.ops.segment_sum(jnp.ones_like(job), job, num_jobs + 1)[:num_jobs]
        job_f = jax.ops.segment_sum(f, job, num_jobs + 1)[:num_jobs]
        job_d = jax.ops.segment_sum(d, job, num_jobs + 1)[:num_jobs]

        # The offspring, averaged over their rows; rejected unless every sample is finite.
        group = jnp.where(plan.group >= 0, plan.group, n)
        rows_in = jax.ops.segment_sum(jnp.ones((n,), jnp.int32), group, n + 1)[:n]
        count = jax.ops.segment_sum(valid.astype(jnp.int32), group, n + 1)[:n]
        first = jax.ops.segment_min(jnp.arange(n, dtype=jnp.int32), group, n + 1)[:n]
        candidate = (rows_in > 0) & (count == rows_in)
        safe = jnp.maximum(count, 1)
        cand_fsum = jax.ops.segment_sum(f, group, n + 1)[:n]
        cand_dsum = jax.ops.segment_sum(d, group, n + 1)[:n]
        cand_f = jnp.where(candidate, cand_fsum / safe, jnp.nan)
        cand_d = jnp.where(candidate[:, None], cand_dsum / safe[:, None], jnp.nan)
        cand_genotypes = jax.tree.map(lambda x: x[jnp.clip(first, 0, n - 1)], genotypes)
        samples = _Samples(jnp.where(candidate, count, 0), cand_fsum, cand_dsum)

        if self._adaptive:
            new, result = self._adaptive_rules(job_count, job_f, job_d, cand_genotypes, cand_f, cand_d, samples)
        else:
            new, result = self._rebuild(job_count, job_f, job_d, cand_genotypes, cand_f, cand_d, samples)
        # Each offspring's outcome on the first row of its group.
        on_row = (plan.group >= 0) & (jnp.arange(n) == first[jnp.maximum(plan.group, 0)])
        at = jnp.maximum(plan.group, 0)
        return new, AddResult(
            added=on_row & result.added[at],
            new_cell=on_row & result.new_cell[at],
            improvement=jnp.where(on_row, result.improvement[at], -jnp.inf).astype(jnp.float32),
            cell=jnp.where(on_row, result.cell[at], -1).astype(jnp.int32),
        )

    def _rebuild(
        self, job_count: Array, job_f: Array, job_d: Array, genotypes: Genotype, cand_f: Array, cand_d: Array,
        samples: _Samples,
    ) -> tuple[AccumulatingRepertoire, AddResult]:
        """Archive- and Parallel-Adaptive-Sampling: the elites' samples grow, then the archive is
        emptied and refilled with the elites at their means and the offspring, best mean per cell."""
        counts = self._counts() + job_count
        fsum = _sums(self.fitness_sums) + job_f
        dsum = _sums(self.descriptor_sums) + job_d
        filled = self.filled
        safe = jnp.maximum(counts, 1)
        elite_f = jnp.where(filled, fsum / safe, jnp.nan)
        elite_d = jnp.where(filled[:, None], dsum / safe[:, None], jnp.nan)
        all_f = jnp.concatenate([elite_f, cand_f])
        all_d = jnp.concatenate([elite_d, cand_d])
        rows = jax.tree.map(lambda e, c: jnp.concatenate([e, c]), self.genotypes, genotypes)
        ok = valid_candidates(all_d, all_f)
        cell = jnp.where(ok, self.cell_index(jnp.where(ok[:, None], all_d, 0.0)), -1)
        # Elites come first: of equal means, the elite keeps its cell (MAP-Elites' tie rule).
        emptied = dataclasses.replace(self, fitnesses=jnp.full_like(self.fitnesses, -jnp.inf))
        inserted_into, inserted = CellRepertoire._insert(emptied, rows, all_d, all_f, cell)
        new = _own(inserted_into)
        target = jnp.where(inserted.added, inserted.cell, self.num_cells)
        zeros = jnp.zeros_like(counts)
        new = dataclasses.replace(
            new,
            counts=zeros.at[target].set(jnp.concatenate([counts, samples.number]), mode="drop"),
            fitness_sums=jnp.zeros_like(fsum).at[target].set(jnp.concatenate([fsum, samples.fitness]), mode="drop"),
            descriptor_sums=jnp.zeros_like(dsum).at[target].set(
                jnp.concatenate([dsum, samples.descriptor]), mode="drop"
            ),
        )
        # The offspring's outcome, against the cells as they were before the batch.
        c = self.num_cells
        cand_cell = cell[c:]
        old = jnp.where(cand_cell >= 0, self.fitnesses[jnp.maximum(cand_cell, 0)], -jnp.inf)
        added = inserted.added[c:]
        return new, AddResult(
            added=added,
            new_cell=added & (old == -jnp.inf),
            improvement=jnp.where(cand_cell >= 0, jnp.where(old > -jnp.inf, cand_f - old, cand_f), -jnp.inf),
            cell=cand_cell,
        )

    def _adaptive_rules(
        self, job_count: Array, job_f: Array, job_d: Array, genotypes: Genotype, cand_f: Array, cand_d: Array,
        samples: _Samples,
    ) -> tuple[AccumulatingRepertoire, AddResult]:
        """Adaptive-Sampling: challenged elites and challengers take their samples, pending
        challenges are decided, then offspring fill empty cells or challenge occupied ones."""
        assert self.challenger_counts is not None and self.elite_due is not None
        c = self.num_cells
        counts = self._counts() + job_count[:c]
        fsum = _sums(self.fitness_sums) + job_f[:c]
        dsum = _sums(self.descriptor_sums) + job_d[:c]
        ch_counts = self.challenger_counts + job_count[c:]
        ch_fsum = _sums(self.challenger_fitness_sums) + job_f[c:]
        ch_dsum = _sums(self.challenger_descriptor_sums) + job_d[c:]
        due = self.elite_due & (job_count[:c] == 0)
        filled = self.filled

        # Decide the challenges whose elite has taken its sample.
        safe = jnp.maximum(counts, 1)
        ch_safe = jnp.maximum(ch_counts, 1)
        elite_f = fsum / safe
        ch_f = ch_fsum / ch_safe
        ch_d = ch_dsum / ch_safe[:, None]
        cells = jnp.arange(c, dtype=jnp.int32)
        deciding = (ch_counts > 0) & ~due
        stays = self.cell_index(ch_d) == cells
        needed = counts if not self.max_samples else jnp.minimum(counts, self.max_samples)
        lost = deciding & ((ch_f <= elite_f) | ~stays)
        won = deciding & ~lost & (ch_counts >= needed)
        genotypes_now = jax.tree.map(
            lambda e, ch: jnp.where(_rows(won, e), ch, e), self.genotypes, self.challenger_genotypes
        )
        counts = jnp.where(won, ch_counts, counts)
        fsum = jnp.where(won, ch_fsum, fsum)
        dsum = jnp.where(won[:, None], ch_dsum, dsum)
        ended = lost | won
        ch_counts = jnp.where(ended, 0, ch_counts)

        # Offspring: into empty cells as MAP-Elites does; into an occupied cell without a pending
        # challenge, the best that beats the elite's mean becomes its challenger.
        safe = jnp.maximum(counts, 1)
        elite_f = jnp.where(filled, fsum / safe, -jnp.inf)
        elite_d = dsum / safe[:, None]
        ok = valid_candidates(cand_d, cand_f)
        cell = jnp.where(ok, self.cell_index(jnp.where(ok[:, None], cand_d, 0.0)), -1)
        at = jnp.maximum(cell, 0)
        into_empty = ok & ~filled[at]
        current = dataclasses.replace(
            self, genotypes=genotypes_now, fitnesses=elite_f, descriptors=jnp.where(filled[:, None], elite_d, 0.0)
        )
        inserted_into, inserted = CellRepertoire._insert(
            current, genotypes, cand_d, cand_f, jnp.where(into_empty, cell, -1)
        )
        new = _own(inserted_into)
        target = jnp.where(inserted.added, inserted.cell, c)
        counts = counts.at[target].set(samples.number, mode="drop")
        fsum = fsum.at[target].set(samples.fitness, mode="drop")
        dsum = dsum.at[target].set(samples.descriptor, mode="drop")

        n = cand_f.shape[0]
        eligible = ok & filled[at] & (ch_counts[at] == 0) & (cand_f > elite_f[at])
        segment = jnp.where(eligible, cell, c)
        best = jax.ops.segment_max(jnp.where(eligible, cand_f, -jnp.inf), segment, c + 1)
        index = jnp.arange(n, dtype=jnp.int32)
        first = jax.ops.segment_min(jnp.where(eligible & (cand_f == best[segment]), index, n), segment, c + 1)
        challenger = eligible & (first[segment] == index)
        slot = jnp.where(challenger, cell, c)
        new = dataclasses.replace(
            new,
            counts=counts,
            fitness_sums=fsum,
            descriptor_sums=dsum,
            challenger_genotypes=write_rows(self.challenger_genotypes, slot, genotypes),
            challenger_counts=ch_counts.at[slot].set(samples.number, mode="drop"),
            challenger_fitness_sums=ch_fsum.at[slot].set(samples.fitness, mode="drop"),
            challenger_descriptor_sums=ch_dsum.at[slot].set(samples.descriptor, mode="drop"),
            elite_due=due.at[slot].set(True, mode="drop"),
        )
        old = jnp.where(cell >= 0, self.fitnesses[at], -jnp.inf)
        return new, AddResult(
            added=inserted.added,
            new_cell=inserted.new_cell,
            improvement=jnp.where(cell >= 0, jnp.where(old > -jnp.inf, cand_f - old, cand_f), -jnp.inf),
            cell=cell,
        )


class _Samples(NamedTuple):
    """The offspring's samples: their number (0: rejected), fitness sum, descriptor sum."""

    number: Array
    fitness: Array
    descriptor: Array


def _own(repertoire: CellRepertoire) -> AccumulatingRepertoire:
    """`CellRepertoire`'s insertion, which keeps the subclass, typed as it is."""
    assert isinstance(repertoire, AccumulatingRepertoire)
    return repertoire


def _sums(x: Array | None) -> Array:
    assert x is not None, "built by accumulating_repertoire"
    return x


def _rows(mask: Array, leaf: Array) -> Array:
    """`mask` (n,) broadcast against a leaf (n, ...)."""
    return mask.reshape(mask.shape + (1,) * (leaf.ndim - 1))


jax.tree_util.register_dataclass(
    AccumulatingRepertoire,
    data_fields=[
        "genotypes", "fitnesses", "descriptors", "centroids", "lookup_table", "lookup_hull", "thresholds",
        "counts", "fitness_sums", "descriptor_sums", "challenger_genotypes", "challenger_counts",
        "challenger_fitness_sums", "challenger_descriptor_sums", "elite_due",
    ],
    meta_fields=[
        "grid_shape", "low", "high", "lookup_grid", "learning_rate", "threshold_min",
        "method", "reevaluations", "max_samples", "statistic",
    ],
)


def accumulating_repertoire(
    cells: CellRepertoire,
    method: Method,
    reevaluations: int,
    max_samples: int = 0,
    statistic: Statistic = "median",
) -> AccumulatingRepertoire:
    """The empty cells of `cells` (a grid or CVT `CellRepertoire` without thresholds) as an
    `AccumulatingRepertoire` applying `method`'s rules (module docstring).

    Args:
      cells: the cells; its elites are dropped.
      method: "archive_sampling", "adaptive_sampling" or "parallel_adaptive_sampling".
      reevaluations: at most this many rows of each batch re-evaluate stored solutions (>= 1).
      max_samples: 0, or the cap on samples (see `AccumulatingRepertoire`).
      statistic: Parallel-Adaptive-Sampling's statistic of the elites' counts.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if statistic not in STATISTICS:
        raise ValueError(f"statistic: expected one of {STATISTICS}, got {statistic!r}")
    if not (isinstance(reevaluations, int) and reevaluations >= 1):
        raise ValueError(f"reevaluations: expected a positive integer, got {reevaluations!r}")
    if not (isinstance(max_samples, int) and max_samples >= 0):
        raise ValueError(f"max_samples: expected a non-negative integer, got {max_samples!r}")
    if cells.thresholds is not None:
        raise ValueError("cells: expected an elitist repertoire (learning_rate 1), got CMA-MAE's thresholds")
    if cells.genotypes is None:
        raise ValueError("cells: expected a repertoire that stores genotypes (re-evaluation needs them)")
    c, dim = cells.num_cells, cells.descriptor_dim
    example = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), cells.genotypes)
    adaptive = method == "adaptive_sampling"
    fields = {f.name: getattr(cells, f.name) for f in dataclasses.fields(CellRepertoire)}
    fields.update(
        genotypes=init_storage(example, c),
        fitnesses=jnp.full((c,), -jnp.inf, jnp.float32),
        descriptors=jnp.zeros((c, dim), jnp.float32),
    )
    return AccumulatingRepertoire(
        **fields,
        counts=jnp.zeros((c,), jnp.int32),
        fitness_sums=jnp.zeros((c,), jnp.float32),
        descriptor_sums=jnp.zeros((c, dim), jnp.float32),
        challenger_genotypes=init_storage(example, c) if adaptive else None,
        challenger_counts=jnp.zeros((c,), jnp.int32) if adaptive else None,
        challenger_fitness_sums=jnp.zeros((c,), jnp.float32) if adaptive else None,
        challenger_descriptor_sums=jnp.zeros((c, dim), jnp.float32) if adaptive else None,
        elite_due=jnp.zeros((c,), bool) if adaptive else None,
        method=method,
        reevaluations=reevaluations,
        max_samples=max_samples,
        statistic=statistic,
    )
