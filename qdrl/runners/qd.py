"""QD runs for the experiment driver: MAP-Elites with any emitter of the registry (CMA-ME, CMA-MAE,
OMG-MEGA, CMA-MEGA, CMA-MAEGA, bandit pools), and the QD-RL algorithms built on it."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import inspect
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.compiling import compile_timed
from qdrl.config import (
    ConfigError,
    NonNegativeFloat,
    NonNegativeInt,
    PositiveFloat,
    PositiveInt,
    Range,
    UnitFloat,
    build,
    check_params,
    check_table,
)
from qdrl.experiment import ARRAY_SECTIONS, ExperimentConfig, Sections, register, scalar
from qdrl.lapack_threads import single_threaded_lapack
from qdrl.placement import Placement, check_divisible, make_placement
from qdrl.qd.emitters.dcrl import DCRLConfig
from qdrl.qd.emitters.ga import GAConfig, ga_emitter
from qdrl.qd.emitters.pg import PGConfig
from qdrl.qd.emitters.registry import (
    CMA_KINDS,
    EMITTER_KINDS,
    GA_KINDS,
    EmitterContext,
    build_emitter,
    build_pool,
    check_pool,
    instance_size,
    offspring_per_iteration,
    parse_emitter,
    uses_cma_es,
)
from qdrl.qd.emitters.scheduler import BanditState, SchedulerConfig

if TYPE_CHECKING:
    from qdrl.qd.base import Emitter
    from qdrl.qd.map_elites import MapElites, QDState
    from qdrl.tasks import Task


# The start value of CMA-MAE's thresholds: any number, or -inf (a cell's threshold is then its elite's fitness).
ThresholdMin = Annotated[float, Range(high=math.inf, high_open=True, finite=False)]


@dataclasses.dataclass(frozen=True)
class RepertoireConfig:
    """The `[repertoire]` section: the container of elites."""

    kind: Literal["grid", "cvt"] = "grid"  # regular grid (direct indexing) or CVT
    grid_shape: tuple[PositiveInt, ...] = (32, 32)  # grid: cells per descriptor dimension
    num_centroids: PositiveInt = 1024  # cvt: number of cells
    cvt_samples: PositiveInt = 50_000  # cvt: uniform samples clustered by k-means into centroids
    kmeans_iters: PositiveInt = 50  # cvt: at most this many Lloyd iterations (after k-means++ seeding)
    # CMA-MAE's archive learning rate alpha (Fontaine & Nikolaidis 2023): thresholds apart
    # from the elites move towards accepted fitnesses; 1 with threshold_min = -inf: plain MAP-Elites.
    learning_rate: UnitFloat = 1.0
    threshold_min: ThresholdMin = -math.inf  # the thresholds' start value (CMA-MAE: the lowest fitness)

    def check(self) -> None:
        if not self.grid_shape:
            raise ValueError("repertoire.grid_shape: expected a list of positive integers, got []")
        if self.kind == "cvt" and self.cvt_samples < self.num_centroids:
            raise ValueError(
                f"repertoire.cvt_samples: expected at least repertoire.num_centroids="
                f"{self.num_centroids}, got {self.cvt_samples}"
            )
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


@dataclasses.dataclass(frozen=True)
class EmitterFamily:
    """What a QD algorithm name means for its emitters and repertoire: defaults and allowed kinds.

    `emitter`: the default `[emitter]` table (its `kind` and the values the
    algorithm sets, under the spec's keys); `kinds`: the kinds its `[emitter]` or
    `[[emitters]]` may name (None: all); `pool`: whether `[[emitters]]` is accepted;
    `repertoire`: defaults of `[repertoire]` (CMA-MAE's learning rate).
    """

    emitter: Mapping[str, Any] = dataclasses.field(default_factory=lambda: {"kind": "isoline"})
    kinds: tuple[str, ...] | None = None
    pool: bool = True
    repertoire: Mapping[str, Any] = dataclasses.field(default_factory=dict)


ANY_EMITTER = EmitterFamily()
GA_ONLY = EmitterFamily(kinds=GA_KINDS, pool=False)
_MAE = {"learning_rate": 0.01, "threshold_min": 0.0}
FAMILIES: dict[str, EmitterFamily] = {
    "cma_me": EmitterFamily({"kind": "cma_improvement"}, CMA_KINDS),
    "cma_mae": EmitterFamily(
        {"kind": "cma_improvement", "ranker": "imp", "selection_rule": "mu", "restart_rule": "basic"},
        CMA_KINDS, repertoire=_MAE,
    ),
    "omg_mega": EmitterFamily({"kind": "omg_mega"}, ("omg_mega",), pool=False),
    "cma_mega": EmitterFamily({"kind": "cma_mega"}, ("cma_mega",)),
    "cma_maega": EmitterFamily(
        {"kind": "cma_mega", "ranker": "imp", "restart_rule": "basic"}, ("cma_mega",), repertoire=_MAE
    ),
}


def parse_task(data: Any, defaults: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The `[task]` table resolved: its name and every parameter of the task's builder.

    Each key is checked against the annotation of the builder's parameter (type,
    finiteness, declared range) without building the task. `defaults` fill the
    keys that the builder takes and `data` does not give (e.g. a policy task's
    `eval_batch`, from the run's batch size).
    """
    from qdrl.tasks import TASKS

    data = check_table(data, "task")
    name = data.get("name")
    if name is None:
        raise ConfigError(f"task.name: missing; expected one of {sorted(TASKS)}")
    if not isinstance(name, str) or name not in TASKS:
        raise ConfigError(f"task.name: expected one of {sorted(TASKS)}, got {name!r}")
    builder: Callable[..., Any] = TASKS[name]
    given = {k: v for k, v in data.items() if k != "name"}
    kwargs = check_params(builder, given, "task", owner=f"task {name!r}")
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
    from qdrl.tasks import TASKS

    params = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items() if k != "name"}
    try:
        return TASKS[table["name"]](**params)
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith("task.") else f"task: {msg}") from e


def parse_qd(
    spec: Mapping[str, Any],
    exp: ExperimentConfig,
    default_kind: str = "grid",
    eval_batch: int | None = None,
    with_emitter: bool = True,
    family: EmitterFamily = ANY_EMITTER,
    batch_where: str = "emitter.batch_size",
) -> Sections:
    """The checked `[task]`, `[repertoire]`, `[emitter]` (or `[[emitters]]` and `[scheduler]`)
    and `[qd]` sections of a QD spec.

    `family` gives the algorithm's emitter kinds and defaults; `eval_batch`: the
    offspring per iteration when the run has no `[emitter]` (the spec key
    `batch_where` sets it). Each of the `experiment.devices` rolls out its share of
    them at once (a policy task's default `eval_batch`), so they must divide by it.
    """
    devices = exp.num_devices
    rep_data = {**family.repertoire, **check_table(spec.get("repertoire", {}), "repertoire")}
    rep_data.setdefault("kind", default_kind)
    repertoire = build(RepertoireConfig, rep_data, "repertoire")
    sections: Sections = {"repertoire": repertoire}
    default_emitter = dict(family.emitter)
    default_kind_name = str(default_emitter.pop("kind"))

    def emitter_of(data: Any, section: str) -> Any:
        return parse_emitter(data, section, default_kind_name, family.kinds, default_emitter)

    if with_emitter and "emitters" in spec:
        if not family.pool:
            raise ConfigError("emitters: this algorithm takes one [emitter], not a pool of [[emitters]]")
        if "emitter" in spec:
            raise ConfigError("emitter: give either one [emitter] or a pool of [[emitters]], not both")
        tables = spec["emitters"]
        if not (isinstance(tables, list) and tables and all(isinstance(t, Mapping) for t in tables)):
            raise ConfigError(
                "emitters: expected a list of tables ([[emitters]] followed by key = value lines), "
                f"got {tables!r}"
            )
        pool = tuple(emitter_of(t, f"emitters[{i}]") for i, t in enumerate(tables))
        scheduler = build(SchedulerConfig, spec.get("scheduler", {}), "scheduler")
        check_pool(pool, scheduler)
        sections.update(emitters=pool, scheduler=scheduler)
        per_iteration = scheduler.num_active * instance_size(pool[0])
    elif with_emitter:
        emitter = emitter_of(spec.get("emitter", {}), "emitter")
        sections["emitter"] = emitter
        per_iteration = offspring_per_iteration(emitter)
    else:
        per_iteration = None
    qd = build(QDConfig, spec.get("qd", {}), "qd")
    if eval_batch is None:
        eval_batch = per_iteration
    if eval_batch is not None:
        check_divisible(eval_batch, devices, "emitters" if "emitters" in sections else batch_where)
        eval_batch //= devices  # each device rolls out its share at once
    check_divisible(qd.init_batch_size, devices, "qd.init_batch_size")
    defaults = {} if eval_batch is None else {"eval_batch": eval_batch}
    task = parse_task(spec.get("task", {"name": "arm"}), defaults)
    return {"task": task, **sections, "qd": qd}


class QDRun:
    """A QD run: MAP-Elites with any emitter of the registry (or a bandit pool of them) on a
    grid or CVT repertoire, plain or with CMA-MAE's thresholds; MAP-Elites, CMA-ME, CMA-MAE,
    OMG-MEGA, CMA-MEGA and CMA-MAEGA are this one run with different sections."""

    progress_keys: tuple[str, ...] = (
        "qd_score", "normalised_qd_score", "coverage", "max_fitness", "evaluations_per_s",
    )

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        """Builds the task of checked `sections` (`parse_qd`); the rest is built by `init`."""
        self.sections = dict(sections)
        self.rep_cfg: RepertoireConfig = sections["repertoire"]
        self.emitter_cfg: Any = sections.get("emitter")
        self.pool_cfg: tuple[Any, ...] | None = sections.get("emitters")
        self.qd_cfg: QDConfig = sections["qd"]
        self._task = make_task_of(sections["task"])
        dim = len(self._task.descriptor_low)
        if self.rep_cfg.kind == "grid" and len(self.rep_cfg.grid_shape) != dim:
            raise ConfigError(
                f"repertoire.grid_shape: expected {dim} entries (the descriptor size of task "
                f"{self._task.name!r}), got {list(self.rep_cfg.grid_shape)}"
            )
        self.algorithm = exp.algorithm
        self.task = str(sections["task"]["name"])
        self.num_chunks = self.qd_cfg.num_iterations // self.qd_cfg.log_every
        self.progress_unit, self.progress_total = "iteration", self.qd_cfg.num_iterations
        self.seed = exp.seed
        self.placement: Placement = make_placement(exp.devices)
        self._chunk: Any = None
        self.map_elites: MapElites | None = None
        for config, section in self._emitter_sections():
            if EMITTER_KINDS[config.kind].gradients != "none" and self._task.gradient_scoring_fn is None:
                build_emitter(config, self._context(), section)  # raises the ConfigError naming the key
        self._lapack = single_threaded_lapack if uses_cma_es([c for c, _ in self._emitter_sections()]) \
            else contextlib.nullcontext

    def _emitter_sections(self) -> list[tuple[Any, str]]:
        """(config, section name) of the run's `[emitter]` or each of its `[[emitters]]`."""
        if self.pool_cfg is not None:
            return [(c, f"emitters[{i}]") for i, c in enumerate(self.pool_cfg)]
        return [] if self.emitter_cfg is None else [(self.emitter_cfg, "emitter")]

    def _context(self) -> EmitterContext:
        task = self._task
        return EmitterContext(
            genotype_example=self.example_genotype(),
            genotype_low=float(task.genotype_low),
            genotype_high=float(task.genotype_high),
            descriptor_low=tuple(task.descriptor_low),
            descriptor_high=tuple(task.descriptor_high),
            gradient_scoring_fn=task.gradient_scoring_fn,
            task_name=task.name,
        )

    def _build(self, key: jax.Array) -> MapElites:
        from qdrl.qd.map_elites import MapElites

        task, ec = self._task, self.emitter_cfg
        repertoire = self.empty_repertoire(key)

        def make_ga(batch_size: int) -> Emitter:
            assert isinstance(ec, GAConfig), "a run without a GA [emitter] builds no GA"
            return ga_emitter(ec, task.genotype_low, task.genotype_high, batch_size)

        return MapElites(
            self._loop_scoring(), self._emitter(make_ga), repertoire, qd_offset=task.qd_offset,
            placement=self.placement,
        )

    def _loop_scoring(self) -> Any:
        """The QD loop's scoring function: with the task's gradients when an emitter reads every offspring's."""
        if any(EMITTER_KINDS[c.kind].gradients == "scoring" for c, _ in self._emitter_sections()):
            return self._task.gradient_scoring_fn
        return self.scoring()

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        """The run's emitter (`[emitter]`, or the bandit over `[[emitters]]`); subclasses with
        their own emitters use `make_ga(n)`, the GA of `[emitter]` with n offspring."""
        del make_ga
        if self.pool_cfg is not None:
            return build_pool(self.pool_cfg, self.sections["scheduler"], self._context())
        return build_emitter(self.emitter_cfg, self._context())

    @property
    def batch_size(self) -> int:
        """Offspring per iteration of `[emitter]` (runs without one override `_emitter`)."""
        assert self.emitter_cfg is not None
        return offspring_per_iteration(self.emitter_cfg)

    def empty_repertoire(self, key: jax.Array | None = None, centroids: Any = None) -> Any:
        """The run's empty repertoire (`[repertoire]`); a CVT's cells are `centroids`, or
        come from k-means seeded by `key` (what `init` does)."""
        from qdrl.qd.repertoires import cvt_repertoire, grid_repertoire
        from qdrl.qd.repertoires.cvt import cvt_centroids

        task, rc, example = self._task, self.rep_cfg, self.example_genotype()
        if rc.kind == "grid":
            rep = grid_repertoire(example, rc.grid_shape, task.descriptor_low, task.descriptor_high)
        else:
            if centroids is None:
                if key is None:
                    raise ValueError("empty_repertoire: a CVT repertoire needs a key or centroids")
                centroids = cvt_centroids(
                    key, rc.num_centroids, rc.cvt_samples, task.descriptor_low, task.descriptor_high,
                    num_iters=rc.kmeans_iters,
                )
            rep = cvt_repertoire(example, centroids, task.descriptor_low, task.descriptor_high)
        return rep.with_learning_rate(rc.learning_rate, rc.threshold_min) if rc.annealed else rep

    def example_genotype(self) -> Any:
        """One genotype of the run's repertoire (no batch axis, zeros): the task's."""
        return self._task.example_genotype()

    def _initial_genotypes(self, key: jax.Array, n: int) -> Any:
        if self.qd_cfg.initial_genotypes == "zeros":
            example = self.example_genotype()
            return jax.tree.map(lambda x: jnp.zeros((n, *x.shape), x.dtype), example)
        return self._task.init_genotypes(key, n)

    def init(self, key: jax.Array) -> QDState:
        with self._lapack():
            return self._init(key, jax.jit)

    def state_template(self, key: jax.Array) -> QDState:
        """`init(key)`'s state as shapes and dtypes (`jax.eval_shape`): the template of the
        run's checkpoints. The repertoire's cells are computed (CVT: k-means); nothing is
        evaluated or compiled."""
        return self._init(key, lambda start: functools.partial(jax.eval_shape, start))

    def _init(self, key: jax.Array, stage: Callable[[Callable[..., QDState]], Callable[..., Any]]) -> Any:
        cvt_key, init_key, run_key = jax.random.split(key, 3)
        self.map_elites = self._build(cvt_key)
        me = self.map_elites

        def start(k1: jax.Array, k2: jax.Array) -> QDState:
            return me.init(self._initial_genotypes(k1, self.qd_cfg.init_batch_size), k2)

        return stage(start)(init_key, run_key)

    def compile(self, state: QDState) -> float:
        assert self.map_elites is not None
        me, n = self.map_elites, self.qd_cfg.log_every
        state = self.placement.place(state, me.state_axes)  # a restored checkpoint comes back on one device
        compiled = compile_timed(lambda s: me.run(s, n), state, donate_argnums=0)
        self._chunk = compiled.fn
        return compiled.seconds

    def run_chunk(self, state: QDState) -> tuple[QDState, Any]:
        assert self.map_elites is not None
        state = self.placement.place(state, self.map_elites.state_axes)
        if self._lapack is contextlib.nullcontext:
            return self._chunk(state)
        # CMA-ES's eigendecompositions run on one OpenBLAS thread (qdrl.lapack_threads),
        # so the chunk is waited for inside the block.
        with self._lapack():
            return jax.block_until_ready(self._chunk(state))

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        m = jax.device_get(chunk_metrics)
        row: dict[str, float] = {
            "iteration": int(state.iteration),
            "evaluations": int(state.evaluations),
            "env_steps": int(state.env_steps),
        }
        for key in ("qd_score", "normalised_qd_score", "coverage", "max_fitness", "mean_fitness", "num_elites"):
            row[key] = scalar(np.asarray(m[key])[-1])
        row["added_per_iter"] = float(np.mean(m["added"]))
        restarts = _restarts(state.emitter_state)
        if restarts is not None:
            row["restarts"] = restarts
        return row

    @property
    def qd_task(self) -> Any:
        """The run's task (`qdrl.tasks.Task`); `self.task` is its name."""
        return self._task

    def scoring(self, fixed_start: bool = True, record: Callable[[Any], Any] | None = None) -> Any:
        """The task's scoring function of this run's genotypes (by default, the run's own).

        For policy tasks, `fixed_start=False` starts each episode from its own random
        state and `record` keeps part of each step's env state (`policy_scoring_fn`);
        other tasks have one scoring function, whatever its key draws.
        """
        if self._task.policy_scoring is None or (fixed_start and record is None):
            return self._task.scoring_fn
        return self._task.policy_scoring(None, fixed_start=fixed_start, record=record)

    def finish(self, state: QDState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        from qdrl import plotting
        from qdrl.qd.repertoires import export_npz, write_csv

        rep = jax.device_get(state.repertoire)
        export_npz(rep, out_dir / "repertoire.npz")
        write_csv(rep, out_dir / "repertoire.csv")
        plotting.plot_repertoire(
            rep, out_dir / "plots" / "repertoire.png", self._task.descriptor_low,
            self._task.descriptor_high, title=f"{self.algorithm} on {self.task}",
            labels=self._task.descriptor_names,
        )
        return {"qd_offset": self._task.qd_offset, **self._reevaluate(rep, out_dir)}

    def _reevaluate(self, repertoire: Any, out_dir: Path) -> dict[str, Any]:
        """`qd.reevaluate_samples` > 0: corrected metrics into reevaluation.json and the summary."""
        n = self.qd_cfg.reevaluate_samples
        if n == 0:
            return {}
        from qdrl.runs import write_reevaluation

        report = write_reevaluation(self, repertoire, out_dir, n, self.seed)
        return {f"corrected_{k}": v for k, v in report["corrected"].items()} | {"reevaluate_samples": n}


def _restarts(emitter_state: Any) -> int | None:
    """Restarts of every CMA-ES instance so far (CMA-ME, CMA-MEGA, their pools); None without any."""
    if isinstance(emitter_state, BanditState):
        counts = [_restarts(s) for s in emitter_state.pool]
        found = [c for c in counts if c is not None]
        return sum(found) if found else None
    restarts = getattr(emitter_state, "restarts", None)
    return None if restarts is None else int(np.asarray(restarts).sum())


ARRAY_SECTIONS.add("emitters")
register("map_elites", functools.partial(parse_qd, default_kind="grid"), QDRun)
register("cvt_map_elites", functools.partial(parse_qd, default_kind="cvt"), QDRun)
for _name, _family in FAMILIES.items():
    register(_name, functools.partial(parse_qd, default_kind="grid", family=_family), QDRun)


@dataclasses.dataclass(frozen=True)
class PGSection(PGConfig):
    """The `[pg]` section of PGA-ME: the Q-PG emitter's TD3 and its share of the batch."""

    # Share of `emitter.batch_size` made by the GA; the rest by Q-PG (QDax's PGA-ME: 0.5).
    proportion_mutation_ga: Annotated[float, Range(0.0, 1.0, low_open=True, high_open=True)] = 0.5


def policy_spec(task: Any, task_table: Mapping[str, Any]) -> tuple[Any, int, int]:
    """The policy network of a policy task's genotypes, its observation and action sizes.

    Sizes come from an abstract evaluation (no compilation) of one genotype, which
    also checks that the task hands transitions back (`qdrl.tasks.policy`).
    """
    import jax.numpy as jnp

    from qdrl.tasks.policy import policy_network

    example = task.example_genotype()
    batch = jax.tree.map(lambda x: jnp.zeros((1, *x.shape), x.dtype), example)
    evaluation = jax.eval_shape(task.scoring_fn, batch, jax.random.PRNGKey(0))
    if "transitions" not in evaluation.extras:
        raise ConfigError(
            f"task.name: expected a policy task whose evaluations hand back transitions "
            f"(e.g. halfcheetah_uni, point_maze), got {task.name!r}"
        )
    transitions = evaluation.extras["transitions"]
    obs_size, action_size = int(transitions.obs.shape[-1]), int(transitions.action.shape[-1])
    hidden = tuple(int(h) for h in task_table.get("policy_hidden", (64, 64)))
    network = policy_network(action_size, hidden)
    shapes = jax.eval_shape(network.init, jax.random.PRNGKey(0), jnp.zeros((obs_size,)))
    structure: Any = jax.tree.structure(shapes)
    same = structure == jax.tree.structure(example) and all(
        a.shape == b.shape for a, b in zip(jax.tree.leaves(shapes), jax.tree.leaves(example), strict=True)
    )
    if not same:
        raise ConfigError(
            f"task.policy_hidden: the genotypes of {task.name!r} are not a "
            f"policy_network({action_size}, {list(hidden)})"
        )
    return network, obs_size, action_size


def check_replay_buffer(sections: Sections, section: str, capacity: int) -> None:
    """Raises ConfigError unless one evaluated batch of episodes fits in the replay buffer."""
    steps = sections["task"].get("episode_length")
    for name, batch in (("emitter.batch_size", sections["emitter"].batch_size),
                        ("qd.init_batch_size", sections["qd"].init_batch_size)):
        if steps is not None and int(steps) * batch > capacity:
            raise ConfigError(
                f"{section}.replay_buffer_size: expected at least {name} x task.episode_length = "
                f"{int(steps) * batch}, got {capacity}"
            )


def parse_pga_me(
    spec: Mapping[str, Any], exp: ExperimentConfig, pg_section: type[PGConfig] = PGSection
) -> Sections:
    """The checked sections of a PGA-ME spec: those of `parse_qd` (CVT by default) and `[pg]`."""
    sections = parse_qd(spec, exp, default_kind="cvt", family=GA_ONLY)
    sections["pg"] = build(pg_section, spec.get("pg", {}), "pg")
    check_replay_buffer(sections, "pg", sections["pg"].replay_buffer_size)
    return sections


class PGAMERun(QDRun):
    """PGA-ME (Nilsson & Cully 2021): the GA of `[emitter]` and a Q-PG emitter (`[pg]`)."""

    progress_keys = (*QDRun.progress_keys, "critic_steps")

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        """Builds the task of checked `sections` (`parse_pga_me`) and sizes its policy network."""
        super().__init__(sections, exp)
        self.pg_cfg: PGConfig = sections["pg"]
        self._policy = policy_spec(self._task, self.sections["task"])

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        from qdrl.qd.emitters.pg import pga_me_emitter

        network, obs_size, action_size = self._policy
        pg = dataclasses.asdict(self.pg_cfg)
        share = pg.pop("proportion_mutation_ga")
        return pga_me_emitter(
            self.batch_size, network, obs_size, action_size, PGConfig(**pg),
            proportion_mutation_ga=share, make_ga=make_ga,
        )

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row = super().log_row(state, chunk_metrics, chunk)
        pg_state = state.emitter_state[1]  # the Q-PG emitter's
        row["critic_steps"] = int(pg_state.td3.steps)
        row["buffer_size"] = int(pg_state.buffer.size)
        return row


@dataclasses.dataclass(frozen=True)
class DPGSection:
    """The `[dpg]` section of QD-PG: batch shares and the novelty archive of the D-PG emitter."""

    # Shares of emitter.batch_size for the GA, Q-PG and D-PG emitters.
    shares: tuple[PositiveFloat, ...] = (0.34, 0.33, 0.33)
    # A descriptor enters the archive if farther than this from all stored (QDax: 0.1).
    acceptance_threshold: PositiveFloat = 0.1
    archive_max_size: PositiveInt = 10_000
    # k of the k-nearest-neighbour novelty reward (QDax: 5).
    num_neighbours: PositiveInt = 5
    # Visited descriptors offered to the archive per update.
    candidates_per_update: PositiveInt = 256
    novelty_scale: PositiveFloat = 1.0

    def check(self) -> None:
        if len(self.shares) != 3:
            raise ValueError(f"dpg.shares: expected 3 positive numbers (GA, Q-PG, D-PG), got {list(self.shares)}")


class QDPGRun(PGAMERun):
    """QD-PG (Pierrot et al. 2022): GA (`[emitter]`), Q-PG (`[pg]`) and D-PG (`[pg]`, `[dpg]`)."""

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        """Builds the task of checked `sections` (`parse_qdpg`) and sizes its policy network."""
        super().__init__(sections, exp)
        self.dpg_cfg: DPGSection = sections["dpg"]

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        from qdrl.qd.emitters.novelty import NoveltyReward, qdpg_emitter

        network, obs_size, action_size = self._policy
        d = self.dpg_cfg
        reward = NoveltyReward(
            self._task.descriptor_size, d.acceptance_threshold, d.archive_max_size,
            d.num_neighbours, d.candidates_per_update, d.novelty_scale,
        )
        shares = (d.shares[0], d.shares[1], d.shares[2])
        return qdpg_emitter(
            self.batch_size, network, obs_size, action_size,
            self._task.descriptor_size, self.pg_cfg, shares, reward, make_ga,
        )

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row = super().log_row(state, chunk_metrics, chunk)
        row["novelty_archive_size"] = int(state.emitter_state[2].relabel.size)
        return row


def parse_qdpg(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    """The checked sections of a QD-PG spec: those of PGA-ME (`[pg]` without the GA share) and `[dpg]`."""
    sections = parse_pga_me(spec, exp, pg_section=PGConfig)
    sections["dpg"] = build(DPGSection, spec.get("dpg", {}), "dpg")
    return sections


register("pga_me", parse_pga_me, PGAMERun)
register("qdpg", parse_qdpg, QDPGRun)


@dataclasses.dataclass(frozen=True)
class DCRLSection(DCRLConfig):
    """The `[dcrl]` section of DCRL-ME: the DCRL emitter's TD3, similarity and offspring counts.

    The GA of `[emitter]` makes the rest of `emitter.batch_size`. Without
    `reward_offset` in the spec, the task's per-step reward offset is used
    (-task.qd_offset / episode length: QDax's reward offsets, 9.231 on halfcheetah_uni).
    """

    # Offspring per iteration made by descriptor-conditioned PG steps on parents (QDax: 64).
    dcrl_batch_size: NonNegativeInt = 64
    # Offspring per iteration made by injecting the DC actor at elites' descriptors (QDax: 64).
    ai_batch_size: NonNegativeInt = 64

    def check(self, section: str = "dcrl") -> None:
        super().check(section)
        if self.dcrl_batch_size + self.ai_batch_size < 1:
            raise ValueError(
                f"{section}.dcrl_batch_size: expected dcrl_batch_size + ai_batch_size >= 1, got "
                f"{self.dcrl_batch_size} + {self.ai_batch_size}"
            )


class DCRLMERun(QDRun):
    """DCRL-ME (Faldor et al. 2024): the GA of `[emitter]` and the DCRL emitter (`[dcrl]`)."""

    progress_keys = (*QDRun.progress_keys, "critic_steps")

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        """Builds the task of checked `sections` (`parse_dcrl_me`), completes `[dcrl]` with the
        task's reward offset unless the spec gives one, and sizes the policy network."""
        super().__init__(sections, exp)
        data = dict(sections["dcrl"])
        if "reward_offset" not in data and getattr(self._task, "env", None) is not None:
            data["reward_offset"] = -float(self._task.qd_offset) / int(self._task.env.episode_length)
        self.dcrl_cfg: DCRLSection = build(DCRLSection, data, "dcrl")
        self.sections["dcrl"] = self.dcrl_cfg
        self._policy = policy_spec(self._task, self.sections["task"])

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        from qdrl.qd.emitters.dcrl import dcrl_me_emitter

        network, obs_size, action_size = self._policy
        cfg = dataclasses.asdict(self.dcrl_cfg)
        num_pg, num_ai = cfg.pop("dcrl_batch_size"), cfg.pop("ai_batch_size")
        return dcrl_me_emitter(
            self.batch_size, network, obs_size, action_size,
            self._task.descriptor_low, self._task.descriptor_high, DCRLConfig(**cfg),
            dcrl_batch_size=num_pg, ai_batch_size=num_ai, make_ga=make_ga,
        )

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row = super().log_row(state, chunk_metrics, chunk)
        dcrl_state = state.emitter_state[0]  # the DCRL emitter's (first in the batch)
        row["critic_steps"] = int(dcrl_state.td3.steps)
        row["buffer_size"] = int(dcrl_state.buffer.size)
        return row


def parse_dcrl_me(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    """The checked sections of a DCRL-ME spec: those of `parse_qd` (CVT by default) and `[dcrl]`.

    `[dcrl]` stays a table of the keys the spec gives (each checked, and the whole
    section checked with the default reward offset): the run completes it with the
    task's reward offset when the spec gives none (`DCRLMERun`).
    """
    sections = parse_qd(spec, exp, default_kind="cvt", family=GA_ONLY)
    data = dict(check_table(spec.get("dcrl", {}), "dcrl"))
    cfg = build(DCRLSection, data, "dcrl")
    batch = sections["emitter"].batch_size
    if cfg.dcrl_batch_size + cfg.ai_batch_size >= batch:
        raise ConfigError(
            f"dcrl.dcrl_batch_size: expected dcrl.dcrl_batch_size + dcrl.ai_batch_size below "
            f"emitter.batch_size={batch} (the GA makes the rest), got "
            f"{cfg.dcrl_batch_size} + {cfg.ai_batch_size}"
        )
    check_replay_buffer(sections, "dcrl", cfg.replay_buffer_size)
    sections["dcrl"] = {k: getattr(cfg, k) for k in data}
    return sections


register("dcrl_me", parse_dcrl_me, DCRLMERun)


@dataclasses.dataclass(frozen=True)
class ESSection:
    """The `[es]` section of ME-ES (Colas et al. 2020): the OpenAI-ES emitter around one elite."""

    population_size: Annotated[int, Range(low=2)] = 64  # perturbations per generation (mirrored pairs; even)
    sigma: PositiveFloat = 0.02  # std of the parameter perturbations
    learning_rate: PositiveFloat = 0.01  # Adam step size on the search centre
    l2_coefficient: NonNegativeFloat = 0.005  # weight decay of the centre
    num_optimizer_steps: PositiveInt = 10  # generations before restarting from an elite
    objective: Literal["fitness", "novelty", "explore_exploit"] = "explore_exploit"
    novelty_neighbours: PositiveInt = 10  # k of the k-nearest-neighbour novelty
    archive_size: PositiveInt = 10_000  # slots of the novelty archive of descriptors
    exploit_num_cells: PositiveInt = 2  # restarts for fitness draw among this many fittest elites
    explore_num_cells: PositiveInt = 5  # restarts for novelty draw among this many most novel elites
    last_updated_size: PositiveInt = 5  # cells last improved by the emitter, a second pool for exploit

    def check(self) -> None:
        if self.population_size % 2:
            raise ValueError(f"es.population_size: expected an even integer >= 2, got {self.population_size}")


class MEESRun(QDRun):
    """ME-ES (Colas et al. 2020): MAP-Elites whose only emitter is OpenAI-ES around one elite (`[es]`)."""

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        """Builds the task of checked `sections` (`parse_me_es`)."""
        super().__init__(sections, exp)
        self.es_cfg: ESSection = sections["es"]

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        from qdrl.qd.emitters.es import ESEmitter

        del make_ga
        c = self.es_cfg
        return ESEmitter(
            c.population_size, self._task.example_genotype(), c.sigma, c.learning_rate,
            c.l2_coefficient, c.num_optimizer_steps, c.objective, self._task.descriptor_size,
            c.novelty_neighbours, c.archive_size, exploit_num_cells=c.exploit_num_cells,
            explore_num_cells=c.explore_num_cells, last_updated_size=c.last_updated_size,
        )


def parse_me_es(spec: Mapping[str, Any], exp: ExperimentConfig) -> Sections:
    """The checked sections of an ME-ES spec: `[task]`, `[repertoire]`, `[qd]` and `[es]` (no `[emitter]`)."""
    if "emitter" in spec:
        raise ConfigError("emitter: ME-ES has no GA emitter; its settings are in [es]")
    es = build(ESSection, spec.get("es", {}), "es")
    sections = parse_qd(spec, exp, default_kind="cvt", eval_batch=es.population_size + 1, with_emitter=False,
                        batch_where="es.population_size (+ 1, the parent)")
    sections["es"] = es
    return sections


register("me_es", parse_me_es, MEESRun)
