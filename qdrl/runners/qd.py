"""QD runs (MAP-Elites, CVT-MAP-Elites) on the standard tasks, for the experiment driver."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import time
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import jax
import numpy as np

from qdrl.config import ConfigError, build, coerce
from qdrl.experiment import ExperimentConfig, register
from qdrl.qd.emitters.dcrl import DCRLConfig
from qdrl.qd.emitters.pg import PGConfig

if TYPE_CHECKING:
    from qdrl.qd.base import Emitter
    from qdrl.qd.map_elites import MapElites, QDState


@dataclasses.dataclass(frozen=True)
class RepertoireConfig:
    """The `[repertoire]` section: the container of elites."""

    kind: Literal["grid", "cvt"] = "grid"  # regular grid (direct indexing) or CVT
    grid_shape: tuple[int, ...] = (32, 32)  # grid: cells per descriptor dimension
    num_centroids: int = 1024  # cvt: number of cells
    cvt_samples: int = 50_000  # cvt: uniform samples clustered by k-means into centroids
    kmeans_iters: int = 50  # cvt: Lloyd iterations

    def check(self) -> None:
        if any(n <= 0 for n in self.grid_shape) or not self.grid_shape:
            raise ValueError(
                f"repertoire.grid_shape: expected a list of positive integers, got {list(self.grid_shape)}"
            )
        for name in ("num_centroids", "cvt_samples", "kmeans_iters"):
            if getattr(self, name) <= 0:
                raise ValueError(f"repertoire.{name}: expected a positive integer, got {getattr(self, name)}")
        if self.kind == "cvt" and self.cvt_samples < self.num_centroids:
            raise ValueError(
                f"repertoire.cvt_samples: expected at least repertoire.num_centroids="
                f"{self.num_centroids}, got {self.cvt_samples}"
            )


@dataclasses.dataclass(frozen=True)
class EmitterConfig:
    """The `[emitter]` section: how offspring are made."""

    kind: Literal["isoline", "polynomial"] = "isoline"
    batch_size: int = 1024  # offspring per iteration
    iso_sigma: float = 0.05  # isoline: isotropic Gaussian noise (Vassiliades & Mouret 2018)
    line_sigma: float = 0.1  # isoline: noise along the line between two parents
    variation_percentage: float = 1.0  # share of the batch made by crossover/variation
    eta: float = 0.05  # polynomial mutation: distribution index
    proportion_to_mutate: float = 0.5  # polynomial mutation: share of genes mutated
    crossover_proportion: float = 0.5  # polynomial crossover: share of genes exchanged

    def check(self) -> None:
        if self.batch_size <= 0:
            raise ValueError(f"emitter.batch_size: expected a positive integer, got {self.batch_size}")
        for name in ("iso_sigma", "line_sigma", "eta"):
            if getattr(self, name) < 0:
                raise ValueError(f"emitter.{name}: expected a non-negative number, got {getattr(self, name)}")
        for name in ("variation_percentage", "proportion_to_mutate", "crossover_proportion"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"emitter.{name}: expected a number in [0, 1], got {getattr(self, name)}")


@dataclasses.dataclass(frozen=True)
class QDConfig:
    """The `[qd]` section: length of the run and logging."""

    num_iterations: int = 1000  # emitter batches evaluated after the initial population
    log_every: int = 50  # iterations between log points (one compiled chunk)
    init_batch_size: int = 1024  # random genotypes evaluated to seed the repertoire
    # At the end, re-score every elite this many times from random start states and
    # report corrected metrics (Flageat & Cully 2023; `qdrl reevaluate`); 0: off.
    reevaluate_samples: int = 0

    def check(self) -> None:
        for name in ("num_iterations", "log_every", "init_batch_size"):
            if getattr(self, name) <= 0:
                raise ValueError(f"qd.{name}: expected a positive integer, got {getattr(self, name)}")
        if self.reevaluate_samples < 0:
            raise ValueError(
                f"qd.reevaluate_samples: expected a non-negative integer (0: off), got {self.reevaluate_samples}"
            )
        if self.num_iterations % self.log_every:
            raise ValueError(
                f"qd.num_iterations: expected a multiple of qd.log_every={self.log_every}, "
                f"got {self.num_iterations}"
            )


def build_task(
    data: Mapping[str, Any], defaults: Mapping[str, Any] | None = None
) -> tuple[Any, dict[str, Any]]:
    """The task named by `data["name"]`, its other keys checked against the builder's signature.

    `defaults` fill the keys that the builder takes and `data` does not give (e.g. a
    policy task's `eval_batch`, from the run's batch size).
    """
    from qdrl.tasks import TASKS

    if "name" not in data:
        raise ConfigError(f"task.name: missing; expected one of {sorted(TASKS)}")
    name = data["name"]
    if name not in TASKS:
        raise ConfigError(f"task.name: unknown task {name!r}; expected one of {sorted(TASKS)}")
    builder: Callable[..., Any] = TASKS[name]
    sig = inspect.signature(builder)
    hints = typing.get_type_hints(builder)
    params = {k: p for k, p in sig.parameters.items() if p.kind is p.KEYWORD_ONLY or p.kind is p.POSITIONAL_OR_KEYWORD}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key == "name":
            continue
        if key not in params:
            raise ConfigError(f"task.{key}: unknown key for task {name!r}; expected one of {sorted(params)}")
        kwargs[key] = coerce(value, hints.get(key, type(value)), f"task.{key}")
    for key, value in (defaults or {}).items():
        if key in params and key not in kwargs:
            kwargs[key] = value
    try:
        task = builder(**kwargs)
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith("task.") else f"task: {msg}") from e
    resolved = {"name": name}
    for key, p in params.items():
        value = kwargs.get(key, p.default)
        if value is not inspect.Parameter.empty:
            resolved[key] = list(value) if isinstance(value, tuple) else value
    return task, resolved


class QDRun:
    """MAP-Elites (grid or CVT repertoire) with a GA emitter on a standard task."""

    progress_keys: tuple[str, ...] = ("qd_score", "coverage", "max_fitness", "evaluations_per_s")

    def __init__(
        self,
        spec: Mapping[str, Any],
        exp: ExperimentConfig,
        default_kind: str,
        eval_batch: int | None = None,
    ) -> None:
        """`eval_batch`: the batch a policy task rolls out at once (default: emitter.batch_size)."""
        rep_data = dict(spec.get("repertoire", {}))
        rep_data.setdefault("kind", default_kind)
        rep_cfg = build(RepertoireConfig, rep_data, "repertoire")
        emitter_cfg = build(EmitterConfig, spec.get("emitter", {}), "emitter")
        qd_cfg = build(QDConfig, spec.get("qd", {}), "qd")
        if eval_batch is None:
            eval_batch = emitter_cfg.batch_size
        self._task, task_table = build_task(
            spec.get("task", {"name": "arm"}), defaults={"eval_batch": eval_batch}
        )
        dim = len(self._task.descriptor_low)
        if rep_cfg.kind == "grid" and len(rep_cfg.grid_shape) != dim:
            raise ConfigError(
                f"repertoire.grid_shape: expected {dim} entries (the descriptor size of task "
                f"{self._task.name!r}), got {list(rep_cfg.grid_shape)}"
            )
        self.algorithm = exp.algorithm
        self.task = str(task_table["name"])
        self.sections = {"task": task_table, "repertoire": rep_cfg, "emitter": emitter_cfg, "qd": qd_cfg}
        self.rep_cfg, self.emitter_cfg, self.qd_cfg = rep_cfg, emitter_cfg, qd_cfg
        self.num_chunks = qd_cfg.num_iterations // qd_cfg.log_every
        self.seed = exp.seed
        self._chunk: Any = None
        self.map_elites: MapElites | None = None

    def _build(self, key: jax.Array) -> MapElites:
        from qdrl.qd.emitters.ga import isoline_emitter, polynomial_emitter
        from qdrl.qd.map_elites import MapElites

        task, ec = self._task, self.emitter_cfg
        # Unbounded genotypes (policy parameters) are not clipped.
        lo = task.genotype_low if np.isfinite(task.genotype_low) else None
        hi = task.genotype_high if np.isfinite(task.genotype_high) else None
        repertoire = self.empty_repertoire(key)

        def make_ga(batch_size: int) -> Emitter:
            if ec.kind == "isoline":
                return isoline_emitter(
                    batch_size, ec.iso_sigma, ec.line_sigma, lo, hi,
                    variation_percentage=ec.variation_percentage,
                )
            return polynomial_emitter(
                batch_size, ec.eta, ec.proportion_to_mutate, task.genotype_low, task.genotype_high,
                variation_percentage=ec.variation_percentage,
                proportion_var_to_change=ec.crossover_proportion,
            )

        return MapElites(self.scoring(), self._emitter(make_ga), repertoire, qd_offset=task.qd_offset)

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        """The run's emitter; `make_ga(n)` is the GA emitter of the `[emitter]` section with n offspring."""
        return make_ga(self.emitter_cfg.batch_size)

    def empty_repertoire(self, key: jax.Array | None = None, centroids: Any = None) -> Any:
        """The run's empty repertoire (`[repertoire]`); a CVT's cells are `centroids`, or
        come from k-means seeded by `key` (what `init` does)."""
        from qdrl.qd.repertoires import cvt_repertoire, grid_repertoire
        from qdrl.qd.repertoires.cvt import cvt_centroids

        task, rc, example = self._task, self.rep_cfg, self.example_genotype()
        if rc.kind == "grid":
            return grid_repertoire(example, rc.grid_shape, task.descriptor_low, task.descriptor_high)
        if centroids is None:
            if key is None:
                raise ValueError("empty_repertoire: a CVT repertoire needs a key or centroids")
            centroids = cvt_centroids(
                key, rc.num_centroids, rc.cvt_samples, task.descriptor_low, task.descriptor_high,
                num_iters=rc.kmeans_iters,
            )
        return cvt_repertoire(example, centroids, task.descriptor_low, task.descriptor_high)

    def example_genotype(self) -> Any:
        """One genotype of the run's repertoire (no batch axis, zeros): the task's."""
        return self._task.example_genotype()

    def _initial_genotypes(self, key: jax.Array, n: int) -> Any:
        return self._task.init_genotypes(key, n)

    def init(self, key: jax.Array) -> QDState:
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
        t0 = time.perf_counter()
        self._chunk = jax.jit(lambda s: me.run(s, n), donate_argnums=0).lower(state).compile()
        return time.perf_counter() - t0

    def run_chunk(self, state: QDState) -> tuple[QDState, Any]:
        return self._chunk(state)

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        m = jax.device_get(chunk_metrics)
        row = {
            "iteration": float(state.iteration),
            "evaluations": float(state.evaluations),
            "env_steps": float(state.env_steps),
        }
        for key in ("qd_score", "coverage", "max_fitness", "mean_fitness", "num_elites"):
            row[key] = float(np.asarray(m[key])[-1])
        row["added_per_iter"] = float(np.mean(m["added"]))
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


@register("map_elites")
def _map_elites(spec: Mapping[str, Any], exp: ExperimentConfig) -> QDRun:
    return QDRun(spec, exp, default_kind="grid")


@register("cvt_map_elites")
def _cvt_map_elites(spec: Mapping[str, Any], exp: ExperimentConfig) -> QDRun:
    return QDRun(spec, exp, default_kind="cvt")


@dataclasses.dataclass(frozen=True)
class PGSection(PGConfig):
    """The `[pg]` section of PGA-ME: the Q-PG emitter's TD3 and its share of the batch."""

    # Share of `emitter.batch_size` made by the GA; the rest by Q-PG (QDax's PGA-ME: 0.5).
    proportion_mutation_ga: float = 0.5

    def check(self, section: str = "pg") -> None:
        super().check(section)
        p = self.proportion_mutation_ga
        if not 0.0 < p < 1.0:
            raise ValueError(f"{section}.proportion_mutation_ga: expected a number in (0, 1), got {p!r}")


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


def check_replay_buffer(run: QDRun, section: str, capacity: int) -> None:
    """Raises ConfigError unless one evaluated batch of episodes fits in the replay buffer."""
    steps = run.sections["task"].get("episode_length")
    for name, batch in (("emitter.batch_size", run.emitter_cfg.batch_size),
                        ("qd.init_batch_size", run.qd_cfg.init_batch_size)):
        if steps is not None and int(steps) * batch > capacity:
            raise ConfigError(
                f"{section}.replay_buffer_size: expected at least {name} x task.episode_length = "
                f"{int(steps) * batch}, got {capacity}"
            )


class PGAMERun(QDRun):
    """PGA-ME (Nilsson & Cully 2021): the GA of `[emitter]` and a Q-PG emitter (`[pg]`)."""

    progress_keys = (*QDRun.progress_keys, "critic_steps")
    pg_section: type[PGConfig] = PGSection

    def __init__(self, spec: Mapping[str, Any], exp: ExperimentConfig) -> None:
        super().__init__(spec, exp, default_kind="cvt")
        self.pg_cfg = build(self.pg_section, spec.get("pg", {}), "pg")
        self.sections["pg"] = self.pg_cfg
        self._policy = policy_spec(self._task, self.sections["task"])
        check_replay_buffer(self, "pg", self.pg_cfg.replay_buffer_size)

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        from qdrl.qd.emitters.pg import pga_me_emitter

        network, obs_size, action_size = self._policy
        pg = dataclasses.asdict(self.pg_cfg)
        share = pg.pop("proportion_mutation_ga")
        return pga_me_emitter(
            self.emitter_cfg.batch_size, network, obs_size, action_size, PGConfig(**pg),
            proportion_mutation_ga=share, make_ga=make_ga,
        )

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row = super().log_row(state, chunk_metrics, chunk)
        pg_state = state.emitter_state[1]  # the Q-PG emitter's
        row["critic_steps"] = float(pg_state.td3.steps)
        row["buffer_size"] = float(pg_state.buffer.size)
        return row


@dataclasses.dataclass(frozen=True)
class DPGSection:
    """The `[dpg]` section of QD-PG: batch shares and the novelty archive of the D-PG emitter."""

    # Shares of emitter.batch_size for the GA, Q-PG and D-PG emitters.
    shares: tuple[float, ...] = (0.34, 0.33, 0.33)
    # A descriptor enters the archive if farther than this from all stored (QDax: 0.1).
    acceptance_threshold: float = 0.1
    archive_max_size: int = 10_000
    # k of the k-nearest-neighbour novelty reward (QDax: 5).
    num_neighbours: int = 5
    # Visited descriptors offered to the archive per update.
    candidates_per_update: int = 256
    novelty_scale: float = 1.0

    def check(self) -> None:
        if len(self.shares) != 3 or any(v <= 0 for v in self.shares):
            raise ValueError(f"dpg.shares: expected 3 positive numbers (GA, Q-PG, D-PG), got {list(self.shares)}")
        for name in ("archive_max_size", "num_neighbours", "candidates_per_update"):
            if getattr(self, name) < 1:
                raise ValueError(f"dpg.{name}: expected a positive integer, got {getattr(self, name)}")
        for name in ("acceptance_threshold", "novelty_scale"):
            if not getattr(self, name) > 0:
                raise ValueError(f"dpg.{name}: expected a number > 0, got {getattr(self, name)}")


class QDPGRun(PGAMERun):
    """QD-PG (Pierrot et al. 2022): GA (`[emitter]`), Q-PG (`[pg]`) and D-PG (`[pg]`, `[dpg]`)."""

    pg_section = PGConfig

    def __init__(self, spec: Mapping[str, Any], exp: ExperimentConfig) -> None:
        super().__init__(spec, exp)
        self.dpg_cfg = build(DPGSection, spec.get("dpg", {}), "dpg")
        self.sections["dpg"] = self.dpg_cfg

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
            self.emitter_cfg.batch_size, network, obs_size, action_size,
            self._task.descriptor_size, self.pg_cfg, shares, reward, make_ga,
        )

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row = super().log_row(state, chunk_metrics, chunk)
        row["novelty_archive_size"] = float(state.emitter_state[2].relabel.size)
        return row


@register("pga_me")
def _pga_me(spec: Mapping[str, Any], exp: ExperimentConfig) -> PGAMERun:
    return PGAMERun(spec, exp)


@register("qdpg")
def _qdpg(spec: Mapping[str, Any], exp: ExperimentConfig) -> QDPGRun:
    return QDPGRun(spec, exp)


@dataclasses.dataclass(frozen=True)
class DCRLSection(DCRLConfig):
    """The `[dcrl]` section of DCRL-ME: the DCRL emitter's TD3, similarity and offspring counts.

    The GA of `[emitter]` makes the rest of `emitter.batch_size`. Without
    `reward_offset` in the spec, the task's per-step reward offset is used
    (-task.qd_offset / episode length: QDax's reward offsets, 9.231 on halfcheetah_uni).
    """

    # Offspring per iteration made by descriptor-conditioned PG steps on parents (QDax: 64).
    dcrl_batch_size: int = 64
    # Offspring per iteration made by injecting the DC actor at elites' descriptors (QDax: 64).
    ai_batch_size: int = 64

    def check(self, section: str = "dcrl") -> None:
        super().check(section)
        for name in ("dcrl_batch_size", "ai_batch_size"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
                raise ValueError(f"{section}.{name}: expected an integer >= 0, got {value!r}")
        if self.dcrl_batch_size + self.ai_batch_size < 1:
            raise ValueError(
                f"{section}.dcrl_batch_size: expected dcrl_batch_size + ai_batch_size >= 1, got "
                f"{self.dcrl_batch_size} + {self.ai_batch_size}"
            )


class DCRLMERun(QDRun):
    """DCRL-ME (Faldor et al. 2024): the GA of `[emitter]` and the DCRL emitter (`[dcrl]`)."""

    progress_keys = (*QDRun.progress_keys, "critic_steps")

    def __init__(self, spec: Mapping[str, Any], exp: ExperimentConfig) -> None:
        super().__init__(spec, exp, default_kind="cvt")
        data = dict(spec.get("dcrl", {}))
        if "reward_offset" not in data and getattr(self._task, "env", None) is not None:
            data["reward_offset"] = -float(self._task.qd_offset) / int(self._task.env.episode_length)
        self.dcrl_cfg = build(DCRLSection, data, "dcrl")
        self.sections["dcrl"] = self.dcrl_cfg
        self._policy = policy_spec(self._task, self.sections["task"])
        own = self.dcrl_cfg.dcrl_batch_size + self.dcrl_cfg.ai_batch_size
        if own >= self.emitter_cfg.batch_size:
            raise ConfigError(
                f"dcrl.dcrl_batch_size: expected dcrl.dcrl_batch_size + dcrl.ai_batch_size below "
                f"emitter.batch_size={self.emitter_cfg.batch_size} (the GA makes the rest), got "
                f"{self.dcrl_cfg.dcrl_batch_size} + {self.dcrl_cfg.ai_batch_size}"
            )
        check_replay_buffer(self, "dcrl", self.dcrl_cfg.replay_buffer_size)

    def _emitter(self, make_ga: Callable[[int], Emitter]) -> Emitter:
        from qdrl.qd.emitters.dcrl import dcrl_me_emitter

        network, obs_size, action_size = self._policy
        cfg = dataclasses.asdict(self.dcrl_cfg)
        num_pg, num_ai = cfg.pop("dcrl_batch_size"), cfg.pop("ai_batch_size")
        return dcrl_me_emitter(
            self.emitter_cfg.batch_size, network, obs_size, action_size,
            self._task.descriptor_low, self._task.descriptor_high, DCRLConfig(**cfg),
            dcrl_batch_size=num_pg, ai_batch_size=num_ai, make_ga=make_ga,
        )

    def log_row(self, state: QDState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row = super().log_row(state, chunk_metrics, chunk)
        dcrl_state = state.emitter_state[0]  # the DCRL emitter's (first in the batch)
        row["critic_steps"] = float(dcrl_state.td3.steps)
        row["buffer_size"] = float(dcrl_state.buffer.size)
        return row


@register("dcrl_me")
def _dcrl_me(spec: Mapping[str, Any], exp: ExperimentConfig) -> DCRLMERun:
    return DCRLMERun(spec, exp)


@dataclasses.dataclass(frozen=True)
class ESSection:
    """The `[es]` section of ME-ES (Colas et al. 2020): the OpenAI-ES emitter around one elite."""

    population_size: int = 64  # perturbations per generation (mirrored pairs; even)
    sigma: float = 0.02  # std of the parameter perturbations
    learning_rate: float = 0.01  # Adam step size on the search centre
    l2_coefficient: float = 0.005  # weight decay of the centre
    num_optimizer_steps: int = 10  # generations before restarting from an elite
    objective: Literal["fitness", "novelty", "explore_exploit"] = "explore_exploit"
    novelty_neighbours: int = 10  # k of the k-nearest-neighbour novelty
    archive_size: int = 10_000  # slots of the novelty archive of descriptors
    exploit_num_cells: int = 2  # restarts for fitness draw among this many fittest elites
    explore_num_cells: int = 5  # restarts for novelty draw among this many most novel elites
    last_updated_size: int = 5  # cells last improved by the emitter, a second pool for exploit

    def check(self) -> None:
        if self.population_size < 2 or self.population_size % 2:
            raise ValueError(f"es.population_size: expected an even integer >= 2, got {self.population_size}")
        for name in ("sigma", "learning_rate"):
            if not getattr(self, name) > 0:
                raise ValueError(f"es.{name}: expected a number > 0, got {getattr(self, name)}")
        if self.l2_coefficient < 0:
            raise ValueError(f"es.l2_coefficient: expected a number >= 0, got {self.l2_coefficient}")
        for name in ("num_optimizer_steps", "novelty_neighbours", "archive_size",
                     "exploit_num_cells", "explore_num_cells", "last_updated_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"es.{name}: expected a positive integer, got {getattr(self, name)}")


class MEESRun(QDRun):
    """ME-ES (Colas et al. 2020): MAP-Elites whose only emitter is OpenAI-ES around one elite (`[es]`)."""

    def __init__(self, spec: Mapping[str, Any], exp: ExperimentConfig) -> None:
        if "emitter" in spec:
            raise ConfigError("emitter: ME-ES has no GA emitter; its settings are in [es]")
        es_cfg = build(ESSection, spec.get("es", {}), "es")
        super().__init__(spec, exp, default_kind="cvt", eval_batch=es_cfg.population_size + 1)
        del self.sections["emitter"]
        self.es_cfg = es_cfg
        self.sections["es"] = self.es_cfg

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


@register("me_es")
def _me_es(spec: Mapping[str, Any], exp: ExperimentConfig) -> MEESRun:
    return MEESRun(spec, exp)
