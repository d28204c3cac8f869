"""The Uncertain-QD rows that change what a candidate's evaluation is or what a cell keeps.

Each is MAP-Elites (`qd_recipe`) with the registry's emitters (`registry_source`):

- `me_sampling`: every candidate evaluated `sampling.num_samples` times, the plain repertoire
  storing the means (`qdrl.qd.sampling`; the naive baseline of Flageat & Cully 2023);
- `me_ls`: the same samples, kept by MAP-Elites Low-Spread's rule on a repertoire of spreads
  (`qdrl.qd.repertoires.mels`; GECCO 2023, QDax `MELS`);
- `deep_grid`: `deep_grid.depth` solutions per cell (`qdrl.qd.repertoires.deep_grid`; Flageat &
  Cully 2020), each candidate evaluated once unless `sampling.num_samples` says otherwise.

Sections beside the QD ones:

    [sampling]
    num_samples = 8   # evaluations of each candidate (me_sampling, me_ls: 8; deep_grid: 1)

    [deep_grid]       # deep_grid only
    depth = 50        # solutions a cell keeps (the paper's depth)

An iteration evaluates `emitter.batch_size x sampling.num_samples` times, and the logged
`evaluations` count every one of them (the summary's `num_samples` says how many per candidate).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from qdrl.algorithms.base import BuildContext, ExperimentConfig, Recipe
from qdrl.algorithms.qd import EmitterSource, parse_repertoire, qd_recipe, registry_source
from qdrl.config import ConfigError, PositiveInt, build, check_table
from qdrl.qd.emitters.qd_rl import QDRLParts
from qdrl.qd.repertoires.cells import CellRepertoire
from qdrl.qd.repertoires.deep_grid import DeepGrid, deep_grid
from qdrl.qd.repertoires.mels import MELSRepertoire, mels_repertoire
from qdrl.qd.sampling import sampled_scoring
from qdrl.tasks import Task

__all__ = ["DEEP_GRID", "ME_LS", "ME_SAMPLING", "DeepGridConfig", "SamplingConfig", "Uncertain", "uncertain_source"]


@dataclasses.dataclass(frozen=True)
class SamplingConfig:
    """The `[sampling]` section: how many times each candidate is evaluated."""

    # evaluations of each candidate, each with its own key; the repertoire sees their means
    # (ME-LS also their spread); 1: one evaluation, the task's own scoring
    num_samples: PositiveInt = 8


@dataclasses.dataclass(frozen=True)
class DeepGridConfig:
    """The `[deep_grid]` section: Deep-Grid's population per cell."""

    depth: PositiveInt = 50  # solutions each cell keeps (Flageat & Cully 2020 use 50)


@dataclasses.dataclass(frozen=True)
class Uncertain:
    """An Uncertain-QD row's emitter config: the registry's, `[sampling]`, and `[deep_grid]`
    for Deep-Grid (None otherwise)."""

    emitter: Any
    sampling: SamplingConfig
    deep_grid: DeepGridConfig | None = None

    @property
    def offspring(self) -> int:
        """Candidates per iteration (each evaluated `sampling.num_samples` times)."""
        return int(self.emitter.offspring)


def _parse(spec: Mapping[str, Any], exp: ExperimentConfig, algorithm: str, samples: int, deep: bool) -> Uncertain:
    inner = registry_source()
    if "search_archive" in spec:
        raise ConfigError(f"search_archive: {algorithm} keeps its own container; remove [search_archive]")
    if algorithm != "me_sampling":
        rep = parse_repertoire(spec, inner.default_repertoire, {})
        if rep.kind not in ("grid", "cvt"):
            raise ConfigError(f"repertoire.kind: {algorithm} keeps its cells on a grid or cvt repertoire, got {rep.kind!r}")
        if rep.annealed:
            key = "learning_rate" if rep.learning_rate < 1.0 else "threshold_min"
            raise ConfigError(
                f"repertoire.{key}: {algorithm} keeps no CMA-MAE thresholds; expected the defaults "
                f"(learning_rate 1, threshold_min -inf), got {getattr(rep, key)}"
            )
    if not deep and "deep_grid" in spec:
        raise ConfigError(f"deep_grid: only the deep_grid algorithm reads it, not {algorithm}")
    sampling: SamplingConfig = build(
        SamplingConfig, {"num_samples": samples, **check_table(spec.get("sampling", {}), "sampling")}, "sampling"
    )
    cells: DeepGridConfig | None = build(DeepGridConfig, spec.get("deep_grid", {}), "deep_grid") if deep else None
    return Uncertain(inner.parse(spec, exp), sampling, cells)


def _build(config: Uncertain, task: Task, ctx: BuildContext) -> QDRLParts:
    parts = registry_source().build(config.emitter, task, ctx)
    return parts._replace(scoring_fn=sampled_scoring(parts.scoring_fn, config.sampling.num_samples))


def uncertain_source(algorithm: str, samples: int, deep: bool = False) -> EmitterSource:
    """The registry's emitters (`registry_source`) whose candidates are evaluated `[sampling]
    num_samples` times (default `samples`), with `[deep_grid]` when `deep`."""
    inner = registry_source()

    def tables(c: Uncertain) -> dict[str, Any]:
        return {**inner.tables(c.emitter), "sampling": c.sampling, **({"deep_grid": c.deep_grid} if deep else {})}

    return dataclasses.replace(
        inner,
        parse=lambda spec, exp: _parse(spec, exp, algorithm, samples, deep),
        tables=tables,
        config_of=lambda s: Uncertain(inner.config_of(s), s["sampling"], s.get("deep_grid")),
        build=_build,
        uses_cma_es=lambda c: inner.uses_cma_es(c.emitter),
        summary=lambda c: {"num_samples": c.sampling.num_samples},
    )


def _mels_cells(cells: CellRepertoire, config: Uncertain) -> MELSRepertoire:
    del config
    return mels_repertoire(cells)


def _deep_cells(seed: int) -> Callable[[CellRepertoire, Uncertain], DeepGrid]:
    def cells_as(cells: CellRepertoire, config: Uncertain) -> DeepGrid:
        assert config.deep_grid is not None
        return deep_grid(cells, config.deep_grid.depth, seed)

    return cells_as


ME_SAMPLING = qd_recipe(
    uncertain_source("me_sampling", 8),
    description="MAP-Elites-sampling (Flageat & Cully 2023's baseline): each candidate's mean of N evaluations",
)
ME_LS = qd_recipe(
    uncertain_source("me_ls", 8),
    cells_as=_mels_cells,
    description="MAP-Elites Low-Spread (QDax MELS, GECCO 2023): elites of high mean fitness and low spread",
)
_DEEP_SOURCE = uncertain_source("deep_grid", 1, deep=True)
_DEEP_GRID = qd_recipe(_DEEP_SOURCE)
# Built per run, so the deep grid's random replacements draw from the run's seed.
DEEP_GRID: Recipe = dataclasses.replace(
    _DEEP_GRID,
    build=lambda sections, ctx: qd_recipe(_DEEP_SOURCE, cells_as=_deep_cells(ctx.seed)).build(sections, ctx),
    description="Deep-Grid MAP-Elites (Flageat & Cully 2020): a population of solutions per cell",
)
