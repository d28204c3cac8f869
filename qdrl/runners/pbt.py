"""Population-based training runs (`sac_pbt`, `td3_pbt`) and ME-PBT (`me_pbt_sac`, `me_pbt_td3`).

The spec is a SAC/TD3 spec (`[env]`, `[agent]`, `[train]`, `[archive]`) plus a
`[pbt]` section (`qdrl.pbt.PBTConfig`). `[agent]` gives the settings PBT does
not tune; each member starts from hyperparameters drawn from the search space.
`[train]` is per member: `total_env_steps` is what each member trains for.
With `pbt.num_replace = 0` nothing is ever exploited: a population trained with
fixed random hyperparameters, the baseline PBT is compared against.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from qdrl import pbt
from qdrl.config import ConfigError, build
from qdrl.experiment import ExperimentConfig, Sections, register, scalar
from qdrl.off_policy import TrainState
from qdrl.placement import check_divisible
from qdrl.qd.emitters.me_pbt import MEPBTConfig
from qdrl.qd.metrics import qd_metrics
from qdrl.qd.repertoires import CellRepertoire, observe, passive_archive
from qdrl.runners.qd import QDRun, parse_qd
from qdrl.runners.rl import OffPolicyRun, parse_off_policy


class PBTState(NamedTuple):
    """The population (a `TrainState` with a leading member axis) and its run-level state."""

    population: TrainState
    archive: CellRepertoire
    key: jax.Array
    chunks: jax.Array  # int32, log intervals done
    exploits: jax.Array  # int32, members replaced so far


# Members are split over the devices (`qdrl.placement`); the rest is replicated.
PBT_AXES = PBTState(population=0, archive=None, key=None, chunks=None, exploits=None)  # type: ignore[arg-type]


class PBTRun(OffPolicyRun):
    """A population of SAC or TD3 agents trained in one vmapped step, with exploit/explore.

    On several devices each trains its share of the members (`PBT_AXES`); ranking and
    copying members across devices is left to XLA (a gather of the chosen members).
    """

    progress_keys: tuple[str, ...] = ("eval_return", "eval_return_median", "coverage")
    shard_envs = False
    state_axes = PBT_AXES

    def __init__(self, sections: Sections, exp: ExperimentConfig, agent_name: str) -> None:
        """Builds the environment, agent and trainer of checked `sections` (`parse_pbt`)."""
        super().__init__(sections, dataclasses.replace(exp, algorithm=agent_name))
        self.algorithm = exp.algorithm
        self.agent_name = agent_name
        self.pbt_cfg: pbt.PBTConfig = sections["pbt"]
        self.progress_total *= self.pbt_cfg.population_size  # env_steps counts every member's
        example = jax.eval_shape(self.agent.init, jax.random.PRNGKey(0))
        self.space = pbt.search_space(agent_name, self.pbt_cfg, example.hparams)
        self._pbt_key = jax.random.fold_in(jax.random.PRNGKey(exp.seed), 0x9B7)

    @property
    def buffer_bytes_per_member(self) -> int:
        shapes = jax.eval_shape(self.trainer.init, jax.random.PRNGKey(0))
        return pbt.buffer_bytes(shapes.buffer)

    def init(self, key: jax.Array) -> PBTState:  # type: ignore[override]
        cfg = self.archive_cfg
        n = self.pbt_cfg.population_size
        archive = passive_archive("grid", grid_shape=cfg.grid_shape, low=cfg.low, high=cfg.high)

        def make(k: jax.Array) -> PBTState:
            member_key, hp_key, run_key = jax.random.split(k, 3)
            population = jax.vmap(self.trainer.init)(jax.random.split(member_key, n))
            values = pbt.sample(hp_key, self.space, n)
            population = pbt.set_hparams(population, self.space, values)
            zero = jnp.zeros((), jnp.int32)
            return self.placement.place(PBTState(population, archive, run_key, zero, zero), PBT_AXES)

        return jax.jit(make)(key)

    def chunk(self, state: PBTState) -> tuple[PBTState, dict[str, Any]]:  # type: ignore[override]
        """Train every member one log interval, evaluate each, then (on schedule) exploit/explore."""
        cfg = self.pbt_cfg
        n = cfg.population_size
        population, metrics = jax.vmap(self.trainer.run_chunk)(self.placement.batched(state.population))
        key, eval_key, pbt_key = jax.random.split(state.key, 3)
        ev = jax.vmap(self.trainer.evaluate)(population.agent, jax.random.split(eval_key, n))
        desc = ev["eval_final_desc"] if self.archive_cfg.descriptor == "final" else ev["eval_mean_desc"]
        archive = observe(
            state.archive, desc.reshape((-1, desc.shape[-1])), ev["eval_returns"].reshape((-1,))
        )
        fitness = ev["eval_return"]  # (n,)
        best = jnp.argmax(jnp.where(jnp.isnan(fitness), -jnp.inf, fitness))
        hparams = pbt.get_hparams(population, self.space)  # before explore: what earned `fitness`
        chunks = state.chunks + 1
        due = (chunks % cfg.exploit_every == 0) & (cfg.num_replace > 0)

        def step(p: TrainState) -> TrainState:
            return pbt.exploit_and_explore(pbt_key, p, fitness, self.space, cfg)[0]

        population = self.placement.batched(jax.lax.cond(due, step, lambda p: p, population))
        out: dict[str, Any] = {k: jnp.nanmean(v) for k, v in metrics.items()}
        out["eval_returns_members"] = fitness
        out["eval_return"] = fitness[best]
        out["eval_return_median"] = jnp.median(fitness)
        out["eval_return_mean"] = jnp.mean(fitness)
        out["eval_return_std"] = ev["eval_return_std"][best]
        out["eval_length"] = ev["eval_length"][best]
        out["hparams_best"] = hparams[best]
        out["best_member"] = best
        out.update(qd_metrics(archive, self.archive_cfg.qd_offset))
        exploits = state.exploits + jnp.where(due, cfg.num_replace, 0)
        out["exploits"] = exploits
        return self.placement.place(PBTState(population, archive, key, chunks, exploits), PBT_AXES), out

    def log_row(self, state: PBTState, chunk_metrics: Any, chunk: int) -> dict[str, float]:  # type: ignore[override]
        m = self.placement.fetch(chunk_metrics)
        # The members' counters may live on other processes (jax.distributed): gathered.
        env_steps, grad_steps = self.placement.fetch((state.population.env_steps, state.population.grad_steps))
        member_steps = int(np.asarray(env_steps)[0])
        row: dict[str, float] = {
            "env_steps": member_steps * self.pbt_cfg.population_size,
            "member_env_steps": member_steps,
            "grad_steps": int(np.asarray(grad_steps).sum()),
        }
        for i, r in enumerate(np.asarray(m.pop("eval_returns_members"))):
            row[f"eval_return_m{i}"] = float(r)
        for name, v in zip(self.space.names, np.asarray(m.pop("hparams_best")), strict=True):
            row[f"best_{name}"] = float(v)
        row.update({k: scalar(v) for k, v in m.items()})
        return row

    def finish(self, state: PBTState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:  # type: ignore[override]
        from qdrl import plotting

        self.write_archive(state.archive, out_dir)
        members = {
            f"member {i}": [
                {"member_env_steps": r["member_env_steps"], "eval_return": r[f"eval_return_m{i}"]}
                for r in rows
            ]
            for i in range(self.pbt_cfg.population_size)
        }
        if rows:
            plotting.plot_comparison(
                members, "eval_return", "member_env_steps", out_dir / "plots" / "population.png",
                title=f"{self.algorithm} on {self.task}: each member's evaluation return",
            )
        final = pbt.get_hparams(jax.device_get(state.population), self.space)
        return {
            "population_size": self.pbt_cfg.population_size,
            "buffer_bytes_per_member": self.buffer_bytes_per_member,
            "final_hparams": {n: np.asarray(final[:, i]).tolist() for i, n in enumerate(self.space.names)},
            "grad_steps": int(np.asarray(state.population.grad_steps).sum()),
        }


def check_search_space(agent_name: str, config: pbt.PBTConfig, agent_config: Any, section: str) -> None:
    """Raises ConfigError unless `config` tunes hyperparameters `agent_name` has, in valid ranges."""
    try:
        pbt.search_space(agent_name, config, agent_config.hparams())
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if section == "pbt" else msg.replace("pbt.", f"{section}.")) from e


def parse_pbt(spec: Mapping[str, Any], exp: ExperimentConfig, agent_name: str) -> Sections:
    """The checked sections of a PBT spec: those of a SAC/TD3 spec (`parse_off_policy`) and `[pbt]`."""
    sections = parse_off_policy(spec, dataclasses.replace(exp, algorithm=agent_name), shard_envs=False)
    sections["pbt"] = build(pbt.PBTConfig, spec.get("pbt", {}), "pbt")
    check_divisible(sections["pbt"].population_size, exp.num_devices, "pbt.population_size")
    check_search_space(agent_name, sections["pbt"], sections["agent"], "pbt")
    return sections


for _agent in ("sac", "td3"):
    register(
        f"{_agent}_pbt",
        functools.partial(parse_pbt, agent_name=_agent),
        functools.partial(PBTRun, agent_name=_agent),
    )


class MEPBTRun(QDRun):
    """ME-PBT (Pierrot & Flajolet 2023): MAP-Elites whose emitter is a PBT population of agents.

    Sections: `[task]` (a policy task: its environment trains the agents and its
    scoring evaluates them), `[repertoire]`, `[qd]`, `[agent]` (the SAC/TD3
    settings PBT does not tune) and `[me_pbt]` (`MEPBTConfig`). Every iteration
    evaluates `me_pbt.ga_batch_size + me_pbt.population_size` agents; each agent
    of the population also trains `me_pbt.training_steps` env steps per iteration
    (logged as `train_env_steps`; `total_env_steps` adds the evaluations').
    """

    progress_keys: tuple[str, ...] = ("qd_score", "normalised_qd_score", "coverage", "max_fitness", "population_best")

    def __init__(self, sections: Sections, exp: ExperimentConfig, agent_name: str) -> None:
        """Builds the task, agent, trainer and emitter of checked `sections` (`parse_me_pbt`)."""
        from qdrl.agents import AGENTS
        from qdrl.off_policy import make_trainer
        from qdrl.qd.emitters.me_pbt import MEPBTEmitter

        super().__init__(sections, exp)
        _, make_agent = AGENTS[agent_name]
        agent_cfg = sections["agent"]
        self.me_cfg: MEPBTConfig = sections["me_pbt"]
        task = self._task
        if task.env is None or task.policy_scoring is None:
            raise ConfigError(
                f"task.name: ME-PBT needs a policy task with an environment (e.g. ant_uni, "
                f"halfcheetah_uni, point_maze), got {task.name!r}"
            )
        try:
            self.agent = make_agent(agent_cfg, task.env.observation_size, task.env.action_size)
        except ValueError as e:
            raise ConfigError(f"agent: {e}") from e
        example = jax.eval_shape(self.agent.init, jax.random.PRNGKey(0))
        space = pbt.search_space(agent_name, self.me_cfg.pbt_config(), example.hparams)
        trainer = make_trainer(task.env, self.agent, self.me_cfg.train_config())
        self.emitter = MEPBTEmitter(self.agent, trainer, space, self.me_cfg, placement=self.placement)

    def _emitter(self, make_ga: Any) -> Any:
        del make_ga  # ME-PBT's GA is part of its emitter ([me_pbt])
        return self.emitter

    def example_genotype(self) -> Any:
        """One genotype of the repertoire: a whole agent (`to_genotype` of its state), zeros."""
        from qdrl.qd.emitters.me_pbt import to_genotype

        example = to_genotype(jax.eval_shape(self.agent.init, jax.random.PRNGKey(0)))
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), example)

    def _initial_genotypes(self, key: jax.Array, n: int) -> Any:
        return self.emitter.init_genotypes(key, n)

    def scoring(self, fixed_start: bool = True, record: Any = None) -> Any:
        """The task's scoring function of this run's genotypes: whole agents, acting by their policy."""
        from qdrl.qd.emitters.me_pbt import agent_policy_network

        assert self._task.policy_scoring is not None
        return self._task.policy_scoring(
            agent_policy_network(self.agent), fixed_start=fixed_start, record=record
        )

    def log_row(self, state: Any, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row = super().log_row(state, chunk_metrics, chunk)
        train_steps = int(np.asarray(state.emitter_state.population.env_steps).sum())
        row["train_env_steps"] = train_steps
        row["eval_env_steps"] = row["env_steps"]
        row["env_steps"] = row["eval_env_steps"] + train_steps
        return row

    def finish(self, state: Any, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        # The repertoire's exports (genotypes: whole agents), plot and re-evaluation.
        return {**super().finish(state, rows, out_dir), "population_size": self.me_cfg.population_size}


def parse_me_pbt(spec: Mapping[str, Any], exp: ExperimentConfig, agent_name: str) -> Sections:
    """The checked sections of an ME-PBT spec: `[task]`, `[repertoire]`, `[qd]`, `[agent]`, `[me_pbt]`."""
    from qdrl.agents import AGENTS

    if "emitter" in spec:
        raise ConfigError("emitter: ME-PBT takes no [emitter] section; its GA settings are in [me_pbt]")
    me_cfg = build(MEPBTConfig, spec.get("me_pbt", {}), "me_pbt")
    sections = parse_qd(
        spec, exp, default_kind="cvt", eval_batch=me_cfg.ga_batch_size + me_cfg.population_size,
        with_emitter=False, batch_where="me_pbt.ga_batch_size (+ me_pbt.population_size)",
    )
    config_cls, _ = AGENTS[agent_name]
    agent_cfg = build(config_cls, spec.get("agent", {}), "agent")
    if sections["qd"].init_batch_size < me_cfg.population_size:
        raise ConfigError(
            f"qd.init_batch_size: expected at least me_pbt.population_size="
            f"{me_cfg.population_size}, got {sections['qd'].init_batch_size}"
        )
    check_search_space(agent_name, me_cfg.pbt_config(), agent_cfg, "me_pbt")
    check_divisible(me_cfg.population_size, exp.num_devices, "me_pbt.population_size")
    sections.update({"agent": agent_cfg, "me_pbt": me_cfg})
    return sections


for _agent in ("sac", "td3"):
    register(
        f"me_pbt_{_agent}",
        functools.partial(parse_me_pbt, agent_name=_agent),
        functools.partial(MEPBTRun, agent_name=_agent),
    )
