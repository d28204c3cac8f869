"""Off-policy RL recipes (SAC, TD3): trainer chunks, each followed by a deterministic evaluation
whose episodes feed a passive archive. A loaded run acts with and replays its trained agent
(`Algorithm.agent`, `qdrl.load_run`).

Sections: `[env]`, `[agent]` (the agent's config), `[train]` (`qdrl.off_policy.TrainConfig`),
`[archive]` (the passive archive that measures the run with QD metrics).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple

import jax
import numpy as np

from qdrl import plotting
from qdrl.agents import AGENTS
from qdrl.algorithms.base import (
    AgentParts,
    Algorithm,
    BuildContext,
    DescriptorSpace,
    ExperimentConfig,
    Progress,
    Recipe,
    Row,
    Sections,
    scalar,
)
from qdrl.config import ConfigError, OneOf, PositiveInt, build
from qdrl.envs import env_names, make
from qdrl.envs.brax import STATE_DESCRIPTORS, Backend
from qdrl.off_policy import STATE_AXES, TrainConfig, TrainState, make_trainer
from qdrl.placement import check_divisible
from qdrl.qd.repertoires import CellRepertoire, export_npz, passive_archive, write_csv
from qdrl.qd.repertoires.cvt import cvt_cells
from qdrl.qd.repertoires.passive import feed
from qdrl.rollout import Episodes
from qdrl.types import Array, PRNGKey

__all__ = ["SAC", "TD3", "ArchiveConfig", "EnvConfig", "RLState", "archive_labels", "plot_archive", "write_archive"]

# The metrics an RL or skill run draws one PNG each; plots/summary.png draws them all.
RL_CURVES = ("eval_return",)

EnvName = Annotated[str, OneOf(env_names)]
StateDescriptor = Annotated[str, OneOf(lambda: STATE_DESCRIPTORS)]
EVAL_KEYS = ("eval_return", "eval_return_std", "eval_length")


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """The `[env]` section: which brax environment, on which physics backend."""

    name: EnvName = "halfcheetah"  # "point" or a brax registry name (`qdrl list` shows them)
    backend: Backend = "spring"  # brax physics pipeline
    episode_length: PositiveInt = 1000  # steps before truncation
    state_descriptor: StateDescriptor = "xy"  # brax: state descriptor recorded with every transition


@dataclasses.dataclass(frozen=True)
class ArchiveConfig:
    """The `[archive]` section: the passive archive that measures the run with QD metrics.

    Each evaluation's episodes are offered to it as (episode descriptor, return). A grid
    (`grid_shape` cells over [low, high]) or a CVT (`num_centroids` k-means cells of
    `cvt_samples` uniform samples, seeded by the run's seed as a CVT QD run seeds its
    repertoire, so that a skill run and a MAP-Elites run of one seed share their cells).
    """

    descriptor: Literal["final", "mean"] = "final"  # last or episode-averaged state descriptor
    kind: Literal["grid", "cvt"] = "grid"  # regular grid or CVT cells
    grid_shape: tuple[PositiveInt, ...] = (32, 32)  # grid: cells per descriptor dimension
    num_centroids: PositiveInt = 1024  # cvt: number of cells
    cvt_samples: PositiveInt = 50_000  # cvt: uniform samples clustered by k-means into centroids
    kmeans_iters: PositiveInt = 50  # cvt: at most this many Lloyd iterations
    low: tuple[float, ...] = (-50.0, -50.0)  # descriptor lower bounds (edge cells beyond)
    high: tuple[float, ...] = (50.0, 50.0)  # descriptor upper bounds
    qd_offset: float = 0.0  # QD score = sum over cells of (return - qd_offset)
    # [min, max] return: the archive plots' colour scale, and `range_qd_score`, the QD score
    # with each return clipped to the range and scaled to [0, 1], per cell, in [0, 1]
    fitness_range: tuple[float, float] | None = None

    def check(self) -> None:
        dims = len(self.grid_shape) if self.kind == "grid" else len(self.low)
        if self.kind == "grid" and not self.grid_shape:
            raise ValueError("archive.grid_shape: expected a list of positive integers, got []")
        if len(self.low) != dims or len(self.high) != dims or not dims:
            what = "one per grid dimension" if self.kind == "grid" else "one per descriptor dimension"
            raise ValueError(
                f"archive.low / archive.high: expected {dims or 'at least 1'} entries each "
                f"({what}), got {list(self.low)} and {list(self.high)}"
            )
        if any(lo >= hi for lo, hi in zip(self.low, self.high, strict=True)):
            raise ValueError(
                f"archive.low: expected every entry below archive.high, got {list(self.low)} "
                f"and {list(self.high)}"
            )
        if self.kind == "cvt" and self.cvt_samples < self.num_centroids:
            raise ValueError(
                f"archive.cvt_samples: expected at least archive.num_centroids={self.num_centroids}, "
                f"got {self.cvt_samples}"
            )
        if self.fitness_range is not None and not self.fitness_range[0] < self.fitness_range[1]:
            raise ValueError(
                f"archive.fitness_range: expected [min, max] with min < max, got {list(self.fitness_range)}"
            )

    @property
    def num_dims(self) -> int:
        """The descriptor dimensions the archive covers."""
        return len(self.grid_shape) if self.kind == "grid" else len(self.low)

    def empty(self, seed: int) -> CellRepertoire:
        """The empty passive archive of a run of seed `seed` (the seed only draws CVT cells)."""
        if self.kind == "grid":
            return passive_archive("grid", grid_shape=self.grid_shape, low=self.low, high=self.high)
        low, high = tuple(map(float, self.low)), tuple(map(float, self.high))
        # the CVT cells of a QD run of this seed; k-means on concrete arrays, also inside a traced init
        with jax.ensure_compile_time_eval():
            centroids = cvt_cells(seed, self.num_centroids, self.cvt_samples, low, high, self.kmeans_iters)
        return passive_archive("cvt", centroids=centroids)

    def check_size(self, descriptor_size: int, where: str) -> None:
        """Refuses an archive of another dimension than the state descriptor of `where`."""
        if self.num_dims != descriptor_size:
            key = "archive.grid_shape" if self.kind == "grid" else "archive.low"
            given = list(self.grid_shape) if self.kind == "grid" else list(self.low)
            raise ConfigError(
                f"{key}: expected {descriptor_size} entries (the state "
                f"descriptor size of {where!r}), got {given}"
            )


class RLState(NamedTuple):
    """A run's state: the trainer's, plus the passive archive of evaluated episodes."""

    train: TrainState
    archive: CellRepertoire


def check_train_devices(train: TrainConfig, devices: int) -> None:
    """ConfigError unless `[train]`'s environments and gradient batch split evenly over `devices`."""
    check_divisible(train.num_envs, devices, "train.num_envs")
    check_divisible(train.batch_size, devices, "train.batch_size")


def parse_off_policy(spec: Mapping[str, Any], exp: ExperimentConfig, agent: str, shard_envs: bool = True) -> Sections:
    """The checked sections of a SAC or TD3 spec (`agent` names it); with `shard_envs`,
    `[train]`'s batches are checked to split over `experiment.devices`."""
    config_cls, _ = AGENTS[agent]
    train = build(TrainConfig, spec.get("train", {}), "train")
    if shard_envs:
        check_train_devices(train, exp.num_devices)
    return {
        "env": build(EnvConfig, spec.get("env", {}), "env"),
        "agent": build(config_cls, spec.get("agent", {}), "agent"),
        "train": train,
        "archive": build(ArchiveConfig, spec.get("archive", {}), "archive"),
    }


def archive_labels(env: Any, archive: ArchiveConfig) -> tuple[str, ...]:
    """The passive archive's descriptor names, for plots (e.g. "final x", "final back foot contact")."""
    names = tuple(f"{archive.descriptor} {n}" for n in env.descriptor_names)
    size = len(archive.grid_shape)
    return names if len(names) == size else tuple(f"descriptor {i}" for i in range(size))


def write_archive(archive: CellRepertoire, out_dir: Path) -> None:
    """The passive archive as QD runs write their repertoire: archive.npz (every cell) and
    archive.csv (one row per filled cell)."""
    archive = jax.device_get(archive)
    export_npz(archive, out_dir / "archive.npz")
    write_csv(archive, out_dir / "archive.csv")


def plot_archive(
    archive: CellRepertoire, config: ArchiveConfig, labels: tuple[str, ...], out_dir: Path, title: str,
    rows: list[Row] | None = None,
) -> None:
    """The passive archive drawn into plots/archive.png; with the run's `rows`, also the
    one-figure summary plots/summary.png (evaluation return, archive, losses, every metric)."""
    archive = jax.device_get(archive)
    vmin, vmax = config.fitness_range if config.fitness_range is not None else (None, None)
    plotting.plot_repertoire(
        archive, out_dir / "plots" / "archive.png", config.low, config.high,
        title=f"{title}: passive archive ({config.descriptor} descriptor)", labels=labels,
        vmin=vmin, vmax=vmax,
    )
    if rows:
        plotting.plot_rl_summary(
            rows, archive, out_dir / "plots" / "summary.png", config.low, config.high, labels, title
        )


def rl_log_row(counters: Row, metrics: Any) -> Row:
    """The row of an RL chunk: `counters`, the evaluation's return and length, then every
    other metric of the chunk (0-d)."""
    m = jax.device_get(metrics)
    row = dict(counters)
    for key in EVAL_KEYS:
        row[key] = float(m.pop(key))
    row.update({k: scalar(v) for k, v in m.items()})
    return row


def make_env(config: EnvConfig) -> Any:
    """The environment of `[env]`."""
    return make(config.name, config.backend, config.episode_length, state_descriptor=config.state_descriptor)


def eval_key(seed: int) -> jax.Array:
    """The key every evaluation of a run folds its env steps into."""
    return jax.random.fold_in(jax.random.PRNGKey(seed), 0x5EED)


def _build(sections: Sections, ctx: BuildContext, agent_name: str) -> Algorithm:
    _, make_agent = AGENTS[agent_name]
    env_cfg: EnvConfig = sections["env"]
    train_cfg: TrainConfig = sections["train"]
    archive_cfg: ArchiveConfig = sections["archive"]
    env = make_env(env_cfg)
    try:
        agent = make_agent(sections["agent"], env.observation_size, env.action_size)
    except ValueError as e:
        raise ConfigError(f"agent: {e}") from e
    archive_cfg.check_size(env.descriptor_size, env_cfg.name)
    trainer = make_trainer(env, agent, train_cfg, placement=ctx.placement)
    key0 = eval_key(ctx.seed)

    def eval_key_at(env_steps: Array) -> PRNGKey:
        """The key of the evaluation after `env_steps` (the chunk's, and a replay's)."""
        return jax.random.fold_in(key0, env_steps)

    labels = archive_labels(env, archive_cfg)
    title = f"{ctx.algorithm} on {env_cfg.name}"

    def init(key: jax.Array) -> RLState:
        return RLState(trainer.init(key), archive_cfg.empty(ctx.seed))

    def chunk(state: RLState) -> tuple[RLState, dict[str, Any]]:
        """Train for one log interval, evaluate, and offer the episodes to the archive."""
        train, metrics = trainer.run_chunk(state.train)
        ev = trainer.evaluate(train.agent, eval_key_at(train.env_steps))
        desc = ev["eval_final_desc"] if archive_cfg.descriptor == "final" else ev["eval_mean_desc"]
        archive, qd = feed(state.archive, desc, ev["eval_returns"], archive_cfg.qd_offset, archive_cfg.fitness_range)
        out = dict(metrics)
        out.update({k: ev[k] for k in EVAL_KEYS})
        out.update(qd)
        return RLState(train, archive), out

    def log_row(state: RLState, metrics: Any) -> Row:
        counters = {"env_steps": int(state.train.env_steps), "grad_steps": int(state.train.grad_steps)}
        return rl_log_row(counters, metrics)

    def policy(agent_state: Any, skill: int | None) -> Callable[[Array], Array]:
        del skill  # one policy, no skill input
        params = agent.policy_params(agent_state)
        return lambda obs: agent.policy(params, obs)

    def evaluation(state: RLState, record: Any) -> tuple[Episodes, Array]:
        """The episodes of `trainer.evaluate` after `state`'s env steps (the chunk's key)."""
        ep = trainer.episodes(state.train.agent, eval_key_at(state.train.env_steps), record)
        return ep, ep.final_desc if archive_cfg.descriptor == "final" else ep.mean_desc

    def finish(state: RLState, rows: list[Row], out_dir: Path) -> dict[str, Any]:
        del rows
        write_archive(state.archive, out_dir)
        return {"grad_steps": int(np.asarray(state.train.grad_steps))}

    return Algorithm(
        curves=RL_CURVES,
        task=env_cfg.name,
        sections=sections,
        num_chunks=train_cfg.num_chunks,
        progress=Progress(("eval_return", "coverage"), "env_steps", train_cfg.num_chunks * train_cfg.eval_every),
        init=init,
        chunk=chunk,
        log_row=log_row,
        finish=finish,
        plot=lambda state, rows, out_dir: plot_archive(state.archive, archive_cfg, labels, out_dir, title, rows),
        placement=ctx.placement,
        state_axes=RLState(STATE_AXES, None),  # type: ignore[arg-type]
        descriptor_space=DescriptorSpace(archive_cfg.low, archive_cfg.high, labels),
        agent=AgentParts(env, 0, lambda state: state.train.agent, policy, evaluation),
    )


SAC, TD3 = (
    Recipe(
        functools.partial(parse_off_policy, agent=agent), functools.partial(_build, agent_name=agent),
        "train.total_env_steps", f"{name} with a passive archive of its evaluations",
    )
    for agent, name in (("sac", "SAC (Haarnoja et al. 2018)"), ("td3", "TD3 (Fujimoto et al. 2018)"))
)
