"""The QD family's recipes: MAP-Elites with any emitter, on a grid or CVT repertoire.

MAP-Elites, CVT-MAP-Elites, CMA-ME, CMA-MAE, OMG-MEGA, CMA-MEGA, CMA-MAEGA and the
bandit pools are one recipe with different `[emitter]` kinds and repertoire
options; PGA-ME, QD-PG, DCRL-ME, ME-ES and ME-PBT are the same recipe with the
emitter of `qdrl.qd.emitters.qd_rl`. What differs between them is an
`EmitterSource`: how the emitter's config is read from the spec, how many
offspring it makes, and how the emitter is built for the task. A new QD
algorithm is an emitter module plus one row of the table:

    ALGORITHMS["my_me"] = qd_recipe(EmitterSource.of_section("my", MyConfig, make_my_emitter))

Sections: `[task]`, `[repertoire]`, the emitter's (`[emitter]`, `[[emitters]]` and
`[scheduler]`, `[pg]`, ...), `[qd]`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from qdrl import plotting
from qdrl.agents import AGENTS
from qdrl.algorithms.base import (
    Algorithm,
    BuildContext,
    DescriptorSpace,
    ExperimentConfig,
    Progress,
    QDParts,
    Recipe,
    Row,
    Sections,
    last_values,
    scalar,
)
from qdrl.algorithms.search_archives import (
    check_aurora,
    check_capacity,
    check_rankers,
    make_search_archive,
    parse_search_archive,
)
from qdrl.algorithms.task_spec import make_task_of, parse_task
from qdrl.config import (
    ConfigError,
    NonNegativeInt,
    PositiveInt,
    Range,
    UnitFloat,
    build,
    check_table,
)
from qdrl.envs.skills import SkillSpace
from qdrl.lapack_threads import single_threaded_lapack
from qdrl.pbt import search_space
from qdrl.placement import check_divisible
from qdrl.qd.base import Emitter, emitter_metrics
from qdrl.qd.emitters.es import ESConfig
from qdrl.qd.emitters.ga import GAConfig
from qdrl.qd.emitters.me_pbt import MEPBTConfig
from qdrl.qd.emitters.pg import PGConfig
from qdrl.qd.emitters.qd_rl import (
    DCRLMEConfig,
    PGAMEConfig,
    QDPGConfig,
    QDRLParts,
    make_dcrl_me,
    make_me_es,
    make_me_pbt,
    make_pga_me,
    make_qdpg,
    with_task_reward_offset,
)
from qdrl.qd.emitters.registry import (
    CMA_KINDS,
    GA_KINDS,
    EmitterContext,
    EmitterFamily,
    EmitterPool,
    build_emitters,
    configs_of,
    parse_emitter,
    parse_emitters,
    reads_gradients,
    uses_cma_es,
)
from qdrl.qd.map_elites import MapElites, qd_state_axes
from qdrl.qd.metrics import cqd_score, cqd_target_points, qd_metrics, range_qd_score
from qdrl.qd.reevaluate import reevaluation_report, write_reevaluation
from qdrl.qd.repertoires import cvt_repertoire, export_npz, grid_repertoire, write_csv
from qdrl.qd.repertoires.categorical import categorical_archive
from qdrl.qd.repertoires.cvt import cvt_cells
from qdrl.qd.repertoires.result import (
    ResultArchived,
    result_archive,
    search_archive_metrics,
)
from qdrl.qd.repertoires.sliding import sliding_boundaries_archive
from qdrl.skill_metrics import archive_skill_metrics
from qdrl.tasks import TASKS, Task
from qdrl.tasks.brax_features import feature_space
from qdrl.types import Array

__all__ = [
    "QD_PROGRESS",
    "Container",
    "EmitterSource",
    "QDConfig",
    "RepertoireConfig",
    "qd_recipe",
]

# The start value of CMA-MAE's thresholds: any number, or -inf (a cell's threshold is then its elite's fitness).
ThresholdMin = Annotated[float, Range(high=math.inf, high_open=True, finite=False)]


@dataclasses.dataclass(frozen=True)
class RepertoireConfig:
    """The `[repertoire]` section: the container of elites."""

    # regular grid (direct indexing), CVT, a grid whose bin edges follow the recent descriptors'
    # percentiles (sliding boundaries, Fontaine et al. 2019), or one cell per combination of
    # categories (descriptors are category indices, as pyribs' CategoricalArchive)
    kind: Literal["grid", "cvt", "sliding", "categorical"] = "grid"
    grid_shape: tuple[PositiveInt, ...] = (32, 32)  # grid, sliding: cells per descriptor dimension
    remap_frequency: PositiveInt = 100  # sliding: candidates between two re-placings of the edges
    buffer_capacity: PositiveInt = 1000  # sliding: recent solutions kept, re-inserted at each re-placing
    # categorical: the category names of each descriptor dimension, e.g. [["a", "b"], ["x", "y", "z"]]
    categories: tuple[tuple[str, ...], ...] = ()
    num_centroids: PositiveInt = 1024  # cvt: number of cells
    cvt_samples: PositiveInt = 50_000  # cvt: uniform samples clustered by k-means into centroids
    kmeans_iters: PositiveInt = 50  # cvt: at most this many Lloyd iterations (after k-means++ seeding)
    # cvt: the k-means seed; default the experiment's, so each seed of a sweep has cells of its own
    # (as in QDax). Give one to share the cells across a sweep's seeds: computed once per process.
    cvt_seed: NonNegativeInt | None = None
    # CMA-MAE's archive learning rate alpha (Fontaine & Nikolaidis 2023): thresholds apart
    # from the elites move towards accepted fitnesses; 1 with threshold_min = -inf: plain MAP-Elites.
    learning_rate: UnitFloat = 1.0
    threshold_min: ThresholdMin = -math.inf  # the thresholds' start value (CMA-MAE: the lowest fitness)
    # [min, max] fitness: the repertoire plots' colour scale, and the metrics `range_qd_score`
    # (`qdrl.qd.metrics.range_qd_score`: fitnesses clipped to the range, scaled to [0, 1], per cell)
    # and `cqd_score` (`range_cqd_score`, at each log point)
    fitness_range: tuple[float, float] | None = None

    def check(self) -> None:
        if not self.grid_shape:
            raise ValueError("repertoire.grid_shape: expected a list of positive integers, got []")
        if self.fitness_range is not None and not self.fitness_range[0] < self.fitness_range[1]:
            raise ValueError(
                f"repertoire.fitness_range: expected [min, max] with min < max, got {list(self.fitness_range)}"
            )
        if self.kind == "cvt" and self.cvt_samples < self.num_centroids:
            raise ValueError(
                f"repertoire.cvt_samples: expected at least repertoire.num_centroids="
                f"{self.num_centroids}, got {self.cvt_samples}"
            )
        if self.kind == "categorical" and not (self.categories and all(self.categories)):
            raise ValueError(
                "repertoire.categories: expected a list of category names per descriptor dimension, "
                f"got {[list(c) for c in self.categories]}"
            )
        if self.kind in ("sliding", "categorical") and self.annealed:
            raise ValueError(f"repertoire.learning_rate: a {self.kind} repertoire keeps no thresholds; expected 1")
        if self.threshold_min == -math.inf and self.learning_rate < 1.0:
            raise ValueError(
                "repertoire.threshold_min: expected a finite number when repertoire.learning_rate "
                f"< 1 (CMA-MAE), got {self.threshold_min}"
            )

    @property
    def annealed(self) -> bool:
        """Whether the repertoire keeps CMA-MAE's thresholds (not plain MAP-Elites)."""
        return self.learning_rate < 1.0 or self.threshold_min > -math.inf


@dataclasses.dataclass(frozen=True)
class QDConfig:
    """The `[qd]` section: length of the run and logging."""

    num_iterations: PositiveInt = 1000  # emitter batches evaluated after the initial population
    log_every: PositiveInt = 50  # iterations between log points (one compiled chunk)
    init_batch_size: PositiveInt = 1024  # random genotypes evaluated to seed the repertoire
    # "task": the task's random genotypes; "zeros": genotypes of zeros (x0 = 0 of the
    # CMA-ME, CMA-MAE and DQD papers' CMA runs: every search starts at the origin).
    initial_genotypes: Literal["task", "zeros"] = "task"
    # At the end, re-score every elite this many times from random start states and
    # report corrected metrics (Flageat & Cully 2023; `qdrl reevaluate`); 0: off.
    reevaluate_samples: NonNegativeInt = 0

    def check(self) -> None:
        if self.num_iterations % self.log_every:
            raise ValueError(
                f"qd.num_iterations: expected a multiple of qd.log_every={self.log_every}, "
                f"got {self.num_iterations}"
            )


QD_PROGRESS = ("qd_score", "normalised_qd_score", "coverage", "max_fitness", "evaluations_per_s")
# The QD metrics of every log row, as the last iteration of a chunk left them.
QD_METRICS = ("qd_score", "normalised_qd_score", "coverage", "max_fitness", "mean_fitness", "num_elites")


# -- where a QD algorithm's emitter comes from --


def _same(config: Any, task: Task) -> Any:
    del task
    return config


def _no_check(config: Any, task: Mapping[str, Any], qd: QDConfig) -> None:
    del config, task, qd


def _no_cma_es(config: Any) -> bool:
    del config
    return False


@dataclasses.dataclass(frozen=True)
class EmitterSource:
    """How a QD algorithm's emitter comes from its spec: one row of the QD family.

    `parse(spec, experiment)` reads the emitter's sections into its checked config (errors name
    `section.key`); the config's `offspring` is the batch evaluated each iteration
    (set by the spec key `where`; each device rolls out its share, a policy task's
    `eval_batch`). `tables(config)` are the sections the resolved spec writes, and
    `config_of(sections)` reads the config back from them.
    `check(config, task, qd)` refuses what the emitter cannot do with the resolved
    `[task]` table and `[qd]` (a replay buffer too small for a batch of episodes);
    `resolve(config, task)` completes it from the built task (DCRL-ME's reward offset);
    `build(config, task, context)` makes the emitter and what the loop scores.
    """

    parse: Callable[[Mapping[str, Any], ExperimentConfig], Any]
    where: str
    tables: Callable[[Any], Sections]
    config_of: Callable[[Sections], Any]
    build: Callable[[Any, Task, BuildContext], QDRLParts]
    resolve: Callable[[Any, Task], Any] = _same
    check: Callable[[Any, Mapping[str, Any], QDConfig], None] = _no_check
    uses_cma_es: Callable[[Any], bool] = _no_cma_es
    progress_keys: tuple[str, ...] = QD_PROGRESS
    # The row after the QD loop's (ME-PBT counts its training steps as environment steps).
    adjust_row: Callable[[Row], Row] | None = None
    summary: Callable[[Any], dict[str, Any]] | None = None  # extra summary fields
    default_repertoire: Literal["grid", "cvt"] = "cvt"

    @classmethod
    def of_section(
        cls, section: str, config: type[Any], make: Callable[[Task, Any], Emitter], **options: Any
    ) -> EmitterSource:
        """The source of an emitter whose config is one spec section (`[section]`, parsed into
        dataclass `config`, whose `offspring` the emitter makes each iteration) and which
        `make(task, config)` builds for the task's own genotypes and scoring."""
        def build_parts(cfg: Any, task: Task, ctx: BuildContext) -> QDRLParts:
            del ctx
            emitter = make(task, cfg)
            return QDRLParts(emitter, task.init_genotypes, task.scoring_fn, task.example_genotype())

        return cls(
            parse=lambda spec, exp: build(config, spec.get(section, {}), section),
            where=f"{section}.batch_size",
            tables=lambda cfg: {section: cfg},
            config_of=lambda sections: sections[section],
            build=build_parts,
            **options,
        )


def _build_registry(config: Any, task: Task, ctx: BuildContext) -> QDRLParts:
    del ctx
    emitter = build_emitters(config, EmitterContext.of_task(task))
    # OMG-MEGA reads every offspring's gradients: the loop evaluates with the task's gradients.
    if reads_gradients(config):
        assert task.gradient_scoring_fn is not None, "build_emitters refuses a task without"
        return QDRLParts(emitter, task.init_genotypes, task.gradient_scoring_fn, task.example_genotype())
    return QDRLParts(emitter, task.init_genotypes, task.scoring_fn, task.example_genotype())


def registry_source(
    family: EmitterFamily = EmitterFamily(), default_repertoire: Literal["grid", "cvt"] = "grid"
) -> EmitterSource:
    """The emitters of the registry (`qdrl.qd.emitters.registry`): one `[emitter]` of the
    family's kinds, or a bandit pool of `[[emitters]]` under `[scheduler]`."""
    return EmitterSource(
        parse=lambda spec, exp: parse_emitters(spec, family),
        where="emitter.batch_size",
        tables=lambda c: (
            {"emitters": c.emitters, "scheduler": c.scheduler} if isinstance(c, EmitterPool) else {"emitter": c}
        ),
        config_of=lambda s: EmitterPool(s["emitters"], s["scheduler"]) if "emitters" in s else s["emitter"],
        build=_build_registry,
        uses_cma_es=lambda c: uses_cma_es([x for x, _ in configs_of(c)]),
        default_repertoire=default_repertoire,
    )


# -- the QD-RL rows --


def _parse_ga(spec: Mapping[str, Any]) -> GAConfig:
    config: GAConfig = parse_emitter(spec.get("emitter", {}), "emitter", "isoline", GA_KINDS)
    return config


def _check_replay_buffer(section: str, capacity: int, batch: int, task: Mapping[str, Any], qd: QDConfig) -> None:
    """Refuses a replay buffer that one evaluated batch of episodes of a policy task does not fit in."""
    if not TASKS[task["name"]].policy:
        return
    steps = int(task["episode_length"])
    for name, n in (("emitter.batch_size", batch), ("qd.init_batch_size", qd.init_batch_size)):
        if steps * n > capacity:
            raise ConfigError(
                f"{section}.replay_buffer_size: expected at least {name} x task.episode_length = "
                f"{steps * n}, got {capacity}"
            )


def _policy_parts(make: Callable[[Task, Any], QDRLParts]) -> Callable[[Any, Task, BuildContext], QDRLParts]:
    def build_parts(config: Any, task: Task, ctx: BuildContext) -> QDRLParts:
        del ctx
        try:
            return make(task, config)
        except ValueError as e:
            raise ConfigError(str(e)) from e

    return build_parts


def _parse_pga_me(spec: Mapping[str, Any], exp: ExperimentConfig) -> PGAMEConfig:
    config: PGAMEConfig = build(PGAMEConfig, spec.get("pg", {}), "pg")
    return dataclasses.replace(config, ga=_parse_ga(spec))


PGA_ME = EmitterSource(
    parse=_parse_pga_me,
    where="emitter.batch_size",
    tables=lambda c: {"emitter": c.ga, "pg": c},
    config_of=lambda s: s["pg"],
    build=_policy_parts(make_pga_me),
    check=lambda c, task, qd: _check_replay_buffer("pg", c.pg.replay_buffer_size, c.offspring, task, qd),
    progress_keys=(*QD_PROGRESS, "critic_steps"),
)


def _parse_qdpg(spec: Mapping[str, Any], exp: ExperimentConfig) -> QDPGConfig:
    config: QDPGConfig = build(QDPGConfig, spec.get("dpg", {}), "dpg")
    pg = build(PGConfig, spec.get("pg", {}), "pg")
    return dataclasses.replace(config, pg=pg, ga=_parse_ga(spec))


QDPG = dataclasses.replace(
    PGA_ME,
    parse=_parse_qdpg,
    tables=lambda c: {"emitter": c.ga, "pg": c.pg, "dpg": c},
    config_of=lambda s: s["dpg"],
    build=_policy_parts(make_qdpg),
)


def _parse_dcrl_me(spec: Mapping[str, Any], exp: ExperimentConfig) -> DCRLMEConfig:
    config: DCRLMEConfig = build(DCRLMEConfig, spec.get("dcrl", {}), "dcrl")
    config = dataclasses.replace(config, ga=_parse_ga(spec))
    if config.dcrl_batch_size + config.ai_batch_size >= config.offspring:
        raise ConfigError(
            f"dcrl.dcrl_batch_size: expected dcrl.dcrl_batch_size + dcrl.ai_batch_size below "
            f"emitter.batch_size={config.offspring} (the GA makes the rest), got "
            f"{config.dcrl_batch_size} + {config.ai_batch_size}"
        )
    return config


DCRL_ME = dataclasses.replace(
    PGA_ME,
    parse=_parse_dcrl_me,
    tables=lambda c: {"emitter": c.ga, "dcrl": c},
    config_of=lambda s: s["dcrl"],
    build=_policy_parts(make_dcrl_me),
    resolve=with_task_reward_offset,
    check=lambda c, task, qd: _check_replay_buffer("dcrl", c.dcrl.replay_buffer_size, c.offspring, task, qd),
)


def _parse_me_es(spec: Mapping[str, Any], exp: ExperimentConfig) -> ESConfig:
    if "emitter" in spec:
        raise ConfigError("emitter: ME-ES has no GA emitter; its settings are in [es]")
    config: ESConfig = build(ESConfig, spec.get("es", {}), "es")
    return config


ME_ES = EmitterSource(
    parse=_parse_me_es,
    where="es.population_size (+ 1, the parent)",
    tables=lambda c: {"es": c},
    config_of=lambda s: s["es"],
    build=_policy_parts(make_me_es),
)


@dataclasses.dataclass(frozen=True)
class _MEPBT:
    """ME-PBT's emitter config: `[me_pbt]` and the `[agent]` settings PBT does not tune."""

    me_pbt: MEPBTConfig
    agent: Any
    agent_name: str

    @property
    def offspring(self) -> int:
        return self.me_pbt.offspring


def _parse_me_pbt(spec: Mapping[str, Any], exp: ExperimentConfig, agent_name: str) -> _MEPBT:
    if "emitter" in spec:
        raise ConfigError("emitter: ME-PBT takes no [emitter] section; its GA settings are in [me_pbt]")
    me_cfg = build(MEPBTConfig, spec.get("me_pbt", {}), "me_pbt")
    config_cls, _ = AGENTS[agent_name]
    agent_cfg = build(config_cls, spec.get("agent", {}), "agent")
    try:
        search_space(agent_name, me_cfg.pbt_config(), agent_cfg.hparams(), "me_pbt")
    except ValueError as e:
        raise ConfigError(str(e)) from e
    check_divisible(me_cfg.population_size, exp.num_devices, "me_pbt.population_size")
    return _MEPBT(me_cfg, agent_cfg, agent_name)


def _build_me_pbt(config: _MEPBT, task: Task, ctx: BuildContext) -> QDRLParts:
    _, make_agent = AGENTS[config.agent_name]
    if task.env is None:
        raise ConfigError(
            f"task.name: ME-PBT needs a policy task with an environment (e.g. ant_uni, "
            f"halfcheetah_uni, point_maze), got {task.name!r}"
        )
    try:
        agent = make_agent(config.agent, task.env.observation_size, task.env.action_size)
    except ValueError as e:
        raise ConfigError(f"agent: {e}") from e
    try:
        return make_me_pbt(task, agent, config.agent_name, config.me_pbt, placement=ctx.placement)
    except ValueError as e:
        raise ConfigError(str(e)) from e


def _check_me_pbt(config: _MEPBT, task: Mapping[str, Any], qd: QDConfig) -> None:
    del task
    if qd.init_batch_size < config.me_pbt.population_size:
        raise ConfigError(
            f"qd.init_batch_size: expected at least me_pbt.population_size="
            f"{config.me_pbt.population_size}, got {qd.init_batch_size}"
        )


def _me_pbt_row(row: Row) -> Row:
    """The row of the QD loop, with the population's training steps counted as env steps."""
    row["eval_env_steps"] = row["env_steps"]
    row["env_steps"] = row["eval_env_steps"] + row["train_env_steps"]
    return row


def me_pbt_source(agent_name: str) -> EmitterSource:
    """ME-PBT's emitter of `agent_name` ("sac" or "td3") agents."""
    return EmitterSource(
        parse=lambda spec, exp: _parse_me_pbt(spec, exp, agent_name),
        where="me_pbt.ga_batch_size (+ me_pbt.population_size)",
        tables=lambda c: {"agent": c.agent, "me_pbt": c.me_pbt},
        config_of=lambda s: _MEPBT(s["me_pbt"], s["agent"], agent_name),
        build=_build_me_pbt,
        check=_check_me_pbt,
        progress_keys=("qd_score", "normalised_qd_score", "coverage", "max_fitness", "population_best"),
        adjust_row=_me_pbt_row,
        summary=lambda c: {"population_size": c.me_pbt.population_size},
    )


# -- what a QD run stores its elites in --


@dataclasses.dataclass(frozen=True)
class Container:
    """A container of elites other than one elite per cell (MOME's Pareto front per cell).

    `parse(spec, sections, experiment)` checks the container's own sections (and what
    it needs of the others, e.g. the task's objectives) and returns them;
    `wrap(cells, sections, task, example)` is the empty container on the repertoire's
    cells; `metrics(task)` the QD loop's metrics function; `log_row(state, metrics,
    task)`, `finish(repertoire, out_dir, task, algorithm)` and `plot(...)` (same
    arguments) replace the plain ones.
    """

    parse: Callable[[Mapping[str, Any], Sections, ExperimentConfig], Sections]
    wrap: Callable[[Any, Sections, Task, Any], Any]
    metrics: Callable[[Task], Callable[[Any, float], dict[str, Any]]]
    log_row: Callable[[Any, Any, Task], Row]
    finish: Callable[[Any, Path, Task, str], dict[str, Any]]
    plot: Callable[[Any, Path, Task, str], None]
    progress_keys: tuple[str, ...]


# -- parsing and building a QD run --


def parse_repertoire(spec: Mapping[str, Any], default_kind: str, defaults: Mapping[str, Any]) -> RepertoireConfig:
    """The checked `[repertoire]` section, over the algorithm's defaults."""
    data = {**defaults, **check_table(spec.get("repertoire", {}), "repertoire")}
    data.setdefault("kind", default_kind)
    config: RepertoireConfig = build(RepertoireConfig, data, "repertoire")
    return config


def parse_task_and_qd(
    spec: Mapping[str, Any], exp: ExperimentConfig, offspring: int, where: str, default_task: str = "arm",
    qd_defaults: Mapping[str, Any] | None = None,
) -> tuple[dict[str, Any], QDConfig]:
    """The resolved `[task]` and checked `[qd]` of a QD spec whose emitters make `offspring`
    per iteration: each of the `experiment.devices` rolls out its share of them at once (a
    policy task's default `eval_batch`), so they, and the initial batch, must divide by it."""
    devices = exp.num_devices
    qd_data = {**(qd_defaults or {}), **check_table(spec.get("qd", {}), "qd")}
    qd: QDConfig = build(QDConfig, qd_data, "qd")
    check_divisible(offspring, devices, where)
    check_divisible(qd.init_batch_size, devices, "qd.init_batch_size")
    task = parse_task(spec.get("task", {"name": default_task}), {"eval_batch": offspring // devices})
    return task, qd


def _parse(
    spec: Mapping[str, Any], exp: ExperimentConfig, source: EmitterSource, repertoire_defaults: Mapping[str, Any],
    container: Container | None = None, search_defaults: Mapping[str, Any] | None = None,
) -> Sections:
    repertoire = parse_repertoire(spec, source.default_repertoire, repertoire_defaults)
    search = parse_search_archive(spec, search_defaults)
    if search is not None and container is not None:
        raise ConfigError("search_archive: this algorithm keeps its own container; remove [search_archive]")
    config = source.parse(spec, exp)
    where = "emitters" if isinstance(config, EmitterPool) else source.where
    task, qd = parse_task_and_qd(spec, exp, config.offspring, where)
    source.check(config, task, qd)
    if search is not None:
        check_capacity(search, config.offspring)
        check_aurora(search, task)
    if container is None:
        check_rankers(search, config)
    tables = source.tables(config)
    order = [k for k in tables if k in ("emitter", "emitters", "scheduler")]
    sections = {
        "task": task, "repertoire": repertoire, **({"search_archive": search} if search is not None else {}),
        **{k: tables[k] for k in order}, "qd": qd, **{k: v for k, v in tables.items() if k not in order},
    }
    return sections if container is None else {**sections, **container.parse(spec, sections, exp)}


def check_repertoire(repertoire: RepertoireConfig, task: Task) -> None:
    """Refuses a grid of another dimension than the task's descriptor."""
    dim = task.descriptor_size
    if repertoire.kind in ("grid", "sliding") and len(repertoire.grid_shape) != dim:
        raise ConfigError(
            f"repertoire.grid_shape: expected {dim} entries (the descriptor size of task "
            f"{task.name!r}), got {list(repertoire.grid_shape)}"
        )
    if repertoire.kind == "categorical" and len(repertoire.categories) != dim:
        raise ConfigError(
            f"repertoire.categories: expected {dim} lists (the descriptor size of task {task.name!r}), "
            f"got {len(repertoire.categories)}"
        )


def make_repertoire(config: RepertoireConfig, task: Task, example: Any, seed: int | None, centroids: Any = None) -> Any:
    """The empty repertoire of `[repertoire]` for `task`'s descriptors and genotypes `example`; a
    CVT's cells are `centroids`, or come from k-means seeded by `repertoire.cvt_seed`, else by the
    run's `seed` (`cvt_cells`)."""
    if config.kind == "grid":
        rep = grid_repertoire(example, config.grid_shape, task.descriptor_low, task.descriptor_high)
    elif config.kind == "sliding":
        return sliding_boundaries_archive(
            example, config.grid_shape, task.descriptor_low, task.descriptor_high, config.remap_frequency,
            config.buffer_capacity,
        )
    elif config.kind == "categorical":
        return categorical_archive(example, config.categories)
    else:
        if centroids is None:
            seed = config.cvt_seed if config.cvt_seed is not None else seed
            if seed is None:
                raise ValueError("make_repertoire: a CVT repertoire needs a seed or centroids")
            centroids = cvt_cells(
                seed, config.num_centroids, config.cvt_samples, tuple(map(float, task.descriptor_low)),
                tuple(map(float, task.descriptor_high)), config.kmeans_iters,
            )
        rep = cvt_repertoire(example, centroids, task.descriptor_low, task.descriptor_high)
    return rep.with_learning_rate(config.learning_rate, config.threshold_min) if config.annealed else rep


def initial_genotypes(qd: QDConfig, parts: QDRLParts) -> Callable[[jax.Array], Any]:
    """The initial population of `qd.init_batch_size` genotypes drawn from a key."""
    n = qd.init_batch_size
    if qd.initial_genotypes == "zeros":
        example = parts.example_genotype
        return lambda key: jax.tree.map(lambda x: jnp.zeros((n, *x.shape), x.dtype), example)
    return lambda key: parts.init_genotypes(key, n)


def qd_log_row(state: Any, metrics: Any, emitter: Emitter) -> Row:
    """The row of a QD chunk: counters, the last iteration's QD metrics, offspring accepted
    per iteration, and what the emitter and the repertoire report of their state (critic steps,
    restarts; a repertoire's `log_metrics()`, e.g. ME-LS' mean spread)."""
    m = jax.device_get(metrics)
    row: Row = {
        "iteration": int(state.iteration),
        "evaluations": int(state.evaluations),
        "env_steps": int(state.env_steps),
    }
    row.update(last_values(m, QD_METRICS))
    # then every other figure of the metrics function, in its order: the range and CQD scores, a
    # search archive's figures, on a feature task the repertoire read as skills (`with_range_score`)
    row.update(last_values(m, [k for k in m if k not in row and k != "added"]))
    row["added_per_iter"] = float(np.mean(m["added"]))
    row.update({k: scalar(v) for k, v in jax.device_get(emitter_metrics(emitter, state.emitter_state)).items()})
    if hasattr(state.repertoire, "log_metrics"):
        row.update({k: scalar(v) for k, v in jax.device_get(state.repertoire.log_metrics()).items()})
    return row


def plot_repertoire(
    rep: Any, out_dir: Path, task: Task, title: str, rows: list[Row] | None = None,
    fitness_range: tuple[float, float] | None = None,
) -> None:
    """A QD run's final repertoire drawn into plots/repertoire.png (on the colour scale
    `fitness_range` when given), the histogram and empirical CDF of its elites' fitnesses
    (plots/fitness_histogram.png, plots/fitness_ecdf.png), with descriptors of more than two
    dimensions their parallel axes (plots/parallel_axes.png); with the run's `rows`, also the
    one-figure summary plots/summary.png (QD score, coverage, max fitness, repertoire)."""
    vmin, vmax = fitness_range if fitness_range is not None else (None, None)
    plots = out_dir / "plots"
    plotting.plot_repertoire(
        rep, plots / "repertoire.png", task.descriptor_low, task.descriptor_high,
        title=title, labels=task.descriptor_names, vmin=vmin, vmax=vmax,
    )
    fitnesses = np.asarray(rep.fitnesses)
    plotting.plot_fitness_histogram(fitnesses, plots / "fitness_histogram.png", title=f"{title}: elites' fitness")
    plotting.plot_fitness_ecdf({title: [fitnesses]}, plots / "fitness_ecdf.png", title=f"{title}: fitness ECDF")
    if task.descriptor_size > 2:
        plotting.plot_parallel_axes(
            rep, plots / "parallel_axes.png", task.descriptor_low, task.descriptor_high,
            labels=task.descriptor_names, title=title,
        )
    if rows:
        plotting.plot_qd_summary(
            rows, rep, out_dir / "plots" / "summary.png", task.descriptor_low, task.descriptor_high,
            task.descriptor_names, title,
        )


# The CQD score's fixed draws (pyribs' cqd_score example): 5 draws of 200 target points uniform
# in the descriptor box, from one key for every run, and 5 penalties over [0, 1].
CQD_DRAWS, CQD_TARGETS, CQD_PENALTIES, CQD_KEY = 5, 200, 5, 42


def range_cqd_score(
    repertoire: Any, fitness_range: tuple[float, float], low: Any, high: Any
) -> Array:
    """The CQD score (`qdrl.qd.metrics.cqd_score`) of a repertoire's elites on the scale of
    `fitness_range` (fitnesses minus its min, on its width), at the target points every run on
    the descriptor box [low, high] shares (CQD_DRAWS draws of CQD_TARGETS, CQD_PENALTIES
    penalties, distances on the box's diagonal); jittable."""
    lo, hi = fitness_range
    low, high = jnp.asarray(low, jnp.float32), jnp.asarray(high, jnp.float32)
    targets = cqd_target_points(jax.random.PRNGKey(CQD_KEY), low, high, CQD_TARGETS, CQD_DRAWS)
    rep = result_archive(repertoire)
    return cqd_score(
        rep.descriptors, rep.fitnesses - lo, targets, CQD_PENALTIES, 0.0, hi - lo, jnp.linalg.norm(high - low),
    )


def with_range_score(
    repertoire: Any, qd_offset: float, fitness_range: tuple[float, float] | None = None,
    space: SkillSpace | None = None,
) -> dict[str, Array]:
    """`qd_metrics`, the QD score on the scale of `fitness_range` (`range_qd_score`) when given,
    a search archive's own figures (`search_archive_metrics`), and on a feature task (`space`)
    the repertoire read as a library of skills (`archive_skill_metrics`, as every skill method
    there logs it); jittable."""
    out = qd_metrics(repertoire, qd_offset)
    if isinstance(repertoire, ResultArchived):
        out.update(search_archive_metrics(repertoire.search))
    if fitness_range is not None:
        out["range_qd_score"] = range_qd_score(repertoire, fitness_range)
    if space is not None:
        out.update(archive_skill_metrics(repertoire.descriptors, repertoire.fitnesses, space))
    return out


def reevaluated(
    qd: QDConfig, parts: QDParts, rep: Any, out_dir: Path, seed: int, labels: dict[str, Any]
) -> dict[str, Any]:
    """`qd.reevaluate_samples` > 0: corrected metrics into reevaluation.json and the summary."""
    n = qd.reevaluate_samples
    if n == 0:
        return {}
    report = parts_reevaluation(parts, rep, n, seed, labels)
    write_reevaluation(report, out_dir)
    return {f"corrected_{k}": v for k, v in report["corrected"].items()} | {"reevaluate_samples": n}


def parts_reevaluation(parts: QDParts, rep: Any, samples: int, seed: int, labels: dict[str, Any]) -> dict[str, Any]:
    """`reevaluation_report` of a QD run's repertoire `rep`: its elites re-scored `samples` times
    from random start states, with the task's offset and, on a feature task, its skill metrics.
    The one call behind `qd.reevaluate_samples` and `qdrl reevaluate` (`LoadedRun.reevaluate`)."""
    task = parts.task
    return reevaluation_report(
        rep, parts.scoring(fixed_start=False), task.qd_offset, samples, seed, labels,
        random_starts=task.policy_scoring is not None, space=feature_space(task.name),
    )


def _build(
    sections: Sections, ctx: BuildContext, source: EmitterSource, container: Container | None = None,
    cells_as: Callable[[Any, Any], Any] | None = None,
) -> Algorithm:
    task = make_task_of(sections["task"])
    rep_cfg: RepertoireConfig = sections["repertoire"]
    qd: QDConfig = sections["qd"]
    check_repertoire(rep_cfg, task)
    config = source.resolve(source.config_of(sections), task)
    parts = source.build(config, task, ctx)
    lapack = single_threaded_lapack if source.uses_cma_es(config) else None

    search_cfg = sections.get("search_archive")

    def empty(seed: int | None, centroids: Any) -> Any:
        cells = make_repertoire(rep_cfg, task, parts.example_genotype, seed, centroids)
        if cells_as is not None:  # the cells as another container of one elite per cell
            cells = cells_as(cells, config)
        if search_cfg is not None:  # the repertoire is the result archive beside the search archive
            return make_search_archive(search_cfg, task, parts.example_genotype, cells, seed)
        return cells if container is None else container.wrap(cells, sections, task, parts.example_genotype)

    @functools.cache
    def map_elites() -> MapElites:
        """The loop, on the repertoire's cells; a CVT's are computed (k-means, on the host) when
        the state is first made or traced, not when the run is built (`--check`, `load_run`)."""
        with jax.ensure_compile_time_eval(), (lapack or contextlib.nullcontext)():
            repertoire = empty(ctx.seed, ctx.centroids)
        options: dict[str, Any] = {} if container is None else {"metrics_fn": container.metrics(task)}
        space = feature_space(task.name)
        if container is None and (rep_cfg.fitness_range is not None or space is not None or search_cfg is not None):
            options["metrics_fn"] = functools.partial(
                with_range_score, fitness_range=rep_cfg.fitness_range, space=space
            )
        return MapElites(
            parts.scoring_fn, parts.emitter, repertoire, qd_offset=task.qd_offset, placement=ctx.placement,
            **options,
        )

    genotypes = initial_genotypes(qd, parts)
    qd_parts = QDParts(task, lambda centroids: empty(None, centroids), functools.partial(task.scoring, parts.policy))
    title = f"{ctx.algorithm} on {task.name}"

    def init(key: jax.Array) -> Any:
        _, init_key, run_key = jax.random.split(key, 3)
        state = map_elites().init(genotypes(init_key), run_key)
        if search_cfg is not None and qd.initial_genotypes == "zeros":
            # x0 = 0 is where the emitters start (pyribs' x0), not a solution of the search: the
            # search archive starts empty (the result archive keeps x0's evaluation), so a
            # novelty search's first batch is judged as pyribs judges it, against nothing.
            rep: Any = state.repertoire
            empty: Any = map_elites().empty_repertoire
            state = state._replace(repertoire=dataclasses.replace(rep, search=empty.search))
        return state

    def log_row(state: Any, metrics: Any) -> Row:
        if container is not None:
            return container.log_row(state, metrics, task)
        row = qd_log_row(state, metrics, parts.emitter)
        return source.adjust_row(row) if source.adjust_row is not None else row

    def finish(state: Any, rows: list[Row], out_dir: Path) -> dict[str, Any]:
        del rows
        rep = result_archive(jax.device_get(state.repertoire))
        if container is not None:
            return container.finish(rep, out_dir, task, ctx.algorithm)
        export_npz(rep, out_dir / "repertoire.npz")
        write_csv(rep, out_dir / "repertoire.csv", task.descriptor_names)
        extra = source.summary(config) if source.summary is not None else {}
        labels = {"algorithm": ctx.algorithm, "task": task.name}
        return {"qd_offset": task.qd_offset, **reevaluated(qd, qd_parts, rep, out_dir, ctx.seed, labels), **extra}

    def plot(state: Any, rows: list[Row], out_dir: Path) -> None:
        rep = result_archive(jax.device_get(state.repertoire))
        if container is not None:
            container.plot(rep, out_dir, task, ctx.algorithm)
        else:
            plot_repertoire(rep, out_dir, task, title, rows, rep_cfg.fitness_range)
        target = getattr(search_cfg, "target_size", None)
        if rows and target is not None and "autoencoder_loss" in rows[-1]:  # AURORA's archive
            plotting.plot_learnt_descriptors(rows, target, out_dir / "plots" / "learnt_descriptors.png", title=title)

    def chunk(state: Any) -> tuple[Any, dict[str, Any]]:
        """`qd.log_every` iterations; with `repertoire.fitness_range`, the CQD score at the end
        (once per log point: it compares every elite with 1,000 target points)."""
        state, metrics = map_elites().run(state, qd.log_every)
        if rep_cfg.fitness_range is not None and container is None:
            metrics = {**metrics, "cqd_score": range_cqd_score(
                state.repertoire, rep_cfg.fitness_range, task.descriptor_low, task.descriptor_high,
            )}
        return state, metrics

    cells = None
    if rep_cfg.kind == "cvt" and ctx.centroids is None:
        what = f"computing {rep_cfg.num_centroids:,} CVT cells (k-means of {rep_cfg.cvt_samples:,} samples)"
        cells = (what, map_elites)
    resolved = {**sections, **source.tables(config)}
    return Algorithm(
        task=task.name,
        sections=resolved,
        num_chunks=qd.num_iterations // qd.log_every,
        progress=Progress(
            source.progress_keys if container is None else container.progress_keys, "iteration", qd.num_iterations
        ),
        init=init,
        chunk=chunk,
        log_row=log_row,
        finish=finish,
        plot=plot,
        placement=ctx.placement,
        prepare=cells,
        state_axes=qd_state_axes(parts.emitter),
        run_context=lapack,
        descriptor_space=DescriptorSpace(task.descriptor_low, task.descriptor_high, task.descriptor_names),
        qd=qd_parts,
    )


def qd_recipe(
    source: EmitterSource,
    repertoire: Mapping[str, Any] | None = None,
    description: str = "",
    container: Container | None = None,
    search_archive: Mapping[str, Any] | None = None,
    cells_as: Callable[[Any, Any], Any] | None = None,
) -> Recipe:
    """The recipe of MAP-Elites with the emitter of `source` (`repertoire`: defaults of
    `[repertoire]`, e.g. CMA-MAE's learning rate; `container`: another container than
    one elite per cell; `search_archive`: defaults of `[search_archive]`, the archive that
    steers the search beside the repertoire, which then only records results; `cells_as(cells,
    config)`: the repertoire's cells made another repertoire of the same cells, given the
    emitter source's config, e.g. the Uncertain-QD sampling methods' accumulating cells)."""
    defaults = dict(repertoire or {})
    search = dict(search_archive or {})
    return Recipe(
        parse=lambda spec, exp: _parse(spec, exp, source, defaults, container, search),
        build=lambda sections, ctx: _build(sections, ctx, source, container, cells_as),
        length_key="qd.num_iterations",
        description=description,
        array_sections=("emitters",),
    )


_MAE = {"learning_rate": 0.01, "threshold_min": 0.0}
MAP_ELITES = qd_recipe(registry_source(), description="MAP-Elites (Mouret & Clune 2015) with any emitter")
CVT_MAP_ELITES = qd_recipe(
    registry_source(default_repertoire="cvt"), description="CVT-MAP-Elites (Vassiliades et al. 2018)"
)
CMA_ME = qd_recipe(
    registry_source(EmitterFamily({"kind": "cma_improvement"}, CMA_KINDS)),
    description="CMA-ME (Fontaine et al. 2020)",
)
CMA_MAE = qd_recipe(
    registry_source(EmitterFamily(
        {"kind": "cma_improvement", "ranker": "imp", "selection_rule": "mu", "restart_rule": "basic"}, CMA_KINDS,
    )),
    repertoire=_MAE,
    description="CMA-MAE (Fontaine & Nikolaidis 2023)",
)
OMG_MEGA = qd_recipe(
    registry_source(EmitterFamily({"kind": "omg_mega"}, ("omg_mega",), pool=False)),
    description="OMG-MEGA (Fontaine & Nikolaidis 2021)",
)
CMA_MEGA = qd_recipe(
    registry_source(EmitterFamily({"kind": "cma_mega"}, ("cma_mega",))),
    description="CMA-MEGA (Fontaine & Nikolaidis 2021)",
)
CMA_MAEGA = qd_recipe(
    registry_source(EmitterFamily({"kind": "cma_mega", "ranker": "imp", "restart_rule": "basic"}, ("cma_mega",))),
    repertoire=_MAE,
    description="CMA-MAEGA (Fontaine & Nikolaidis 2023)",
)
PGA_ME_RECIPE = qd_recipe(PGA_ME, description="PGA-ME (Nilsson & Cully 2021)")
QDPG_RECIPE = qd_recipe(QDPG, description="QD-PG (Pierrot et al. 2022)")
DCRL_ME_RECIPE = qd_recipe(DCRL_ME, description="DCRL-ME (Faldor et al. 2024)")
ME_ES_RECIPE = qd_recipe(ME_ES, description="ME-ES (Colas et al. 2020)")
ME_PBT_SAC = qd_recipe(me_pbt_source("sac"), description="ME-PBT of SAC agents (Pierrot & Flajolet 2023)")
ME_PBT_TD3 = qd_recipe(me_pbt_source("td3"), description="ME-PBT of TD3 agents (Pierrot & Flajolet 2023)")

# The archives of pyribs' sphere example and QDax's DNS example (`[search_archive]`; the
# repertoire is the result archive): each row's emitters and search archive, as they set them.
_CMA_NOVELTY = {"kind": "cma_improvement", "sigma0": 0.5}
NS_CMA = qd_recipe(
    registry_source(EmitterFamily(
        {**_CMA_NOVELTY, "ranker": "nov", "selection_rule": "mu", "restart_rule": "basic"}, CMA_KINDS,
    )),
    search_archive={"kind": "proximity", "k_neighbors": 15},
    description="Novelty search with CMA-ES (Lehman & Stanley 2011; pyribs' ns_cma)",
)
NSLC = qd_recipe(
    registry_source(EmitterFamily(
        {**_CMA_NOVELTY, "ranker": "nslc", "selection_rule": "filter", "restart_rule": "no_improvement"}, CMA_KINDS,
    )),
    search_archive={"kind": "proximity", "k_neighbors": 15, "local_competition": True},
    description="Novelty search with local competition (Lehman & Stanley 2011; pyribs' nslc)",
)
NSLC_CMA_IMP = qd_recipe(
    registry_source(EmitterFamily(
        {**_CMA_NOVELTY, "ranker": "2imp", "selection_rule": "filter", "restart_rule": "no_improvement"}, CMA_KINDS,
    )),
    search_archive={"kind": "proximity", "k_neighbors": 15, "local_competition": True},
    description="NSLC's archive with CMA-ME's improvement ranking (pyribs' nslc_cma_imp)",
)
DDS = qd_recipe(
    registry_source(EmitterFamily(
        {"kind": "cma_improvement", "sigma0": 1.5, "ranker": "density", "selection_rule": "mu",
         "restart_rule": "basic"}, CMA_KINDS,
    )),
    search_archive={"kind": "density"},
    description="Density Descent Search (Lee et al. 2024)",
)
DMS = qd_recipe(
    registry_source(EmitterFamily(
        {**_CMA_NOVELTY, "ranker": "imp", "selection_rule": "mu", "restart_rule": "basic"}, CMA_KINDS,
    )),
    search_archive={"kind": "discount"},
    description="Discount Model Search (Tjanaka et al. 2026)",
)
DNS = qd_recipe(
    registry_source(default_repertoire="cvt"),
    search_archive={"kind": "dns"},
    description="Dominated Novelty Search (Bahlous-Boldi et al. 2025)",
)

AURORA = qd_recipe(
    registry_source(default_repertoire="cvt"),
    search_archive={"kind": "aurora"},
    description="AURORA (Cully 2019; Grillotti & Cully 2022): descriptors learnt by an autoencoder",
)
PGA_AURORA = qd_recipe(
    PGA_ME, search_archive={"kind": "aurora"}, description="PGA-AURORA: PGA-ME's emitters on AURORA's archive",
)
