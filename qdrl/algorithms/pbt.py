"""Population-based training recipes (`sac_pbt`, `td3_pbt`): a population of SAC or TD3 agents
trained in one vmapped step, with exploit/explore (`qdrl.pbt`).

The spec is a SAC/TD3 spec (`[env]`, `[agent]`, `[train]`, `[archive]`) plus a
`[pbt]` section (`qdrl.pbt.PBTConfig`). `[agent]` gives the settings PBT does
not tune; each member starts from hyperparameters drawn from the search space.
`[train]` is per member: `total_env_steps` is what each member trains for.
With `pbt.num_replace = 0` nothing is ever exploited: a population trained with
fixed random hyperparameters, the baseline PBT is compared against. On several
devices each trains its share of the members; ranking and copying members across
devices is left to XLA (a gather of the chosen members).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from qdrl import pbt, plotting
from qdrl.agents import AGENTS
from qdrl.algorithms.base import (
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
from qdrl.algorithms.rl import (
    RL_CURVES,
    archive_labels,
    make_env,
    parse_off_policy,
    plot_archive,
    write_archive,
)
from qdrl.config import ConfigError, build
from qdrl.off_policy import TrainState, make_trainer
from qdrl.placement import check_divisible
from qdrl.qd.repertoires import CellRepertoire
from qdrl.qd.repertoires.passive import feed

__all__ = ["PBT_AXES", "SAC_PBT", "TD3_PBT", "PBTState"]

class PBTState(NamedTuple):
    """The population (a `TrainState` with a leading member axis) and its run-level state."""

    population: TrainState
    archive: CellRepertoire
    key: jax.Array
    chunks: jax.Array  # int32, log intervals done
    exploits: jax.Array  # int32, members replaced so far


# Members are split over the devices (`qdrl.placement`); the rest is replicated.
PBT_AXES = PBTState(population=0, archive=None, key=None, chunks=None, exploits=None)  # type: ignore[arg-type]


def parse_pbt(spec: Mapping[str, Any], exp: ExperimentConfig, agent_name: str) -> Sections:
    """The checked sections of a PBT spec: those of a SAC/TD3 spec and `[pbt]`."""
    sections = parse_off_policy(spec, exp, agent_name, shard_envs=False)
    config = build(pbt.PBTConfig, spec.get("pbt", {}), "pbt")
    check_divisible(config.population_size, exp.num_devices, "pbt.population_size")
    try:
        pbt.search_space(agent_name, config, sections["agent"].hparams())
    except ValueError as e:
        raise ConfigError(str(e)) from e
    return {**sections, "pbt": config}


def _build(sections: Sections, ctx: BuildContext, agent_name: str) -> Algorithm:
    _, make_agent = AGENTS[agent_name]
    env_cfg, train_cfg, archive_cfg = sections["env"], sections["train"], sections["archive"]
    cfg: pbt.PBTConfig = sections["pbt"]
    env = make_env(env_cfg)
    try:
        agent = make_agent(sections["agent"], env.observation_size, env.action_size)
    except ValueError as e:
        raise ConfigError(f"agent: {e}") from e
    archive_cfg.check_size(env.descriptor_size, env_cfg.name)
    trainer = make_trainer(env, agent, train_cfg)  # each member on one device: no placement
    example = jax.eval_shape(agent.init, jax.random.PRNGKey(0))
    space = pbt.search_space(agent_name, cfg, example.hparams)
    population = pbt.make_population(trainer, space, cfg, ctx.placement)
    place = ctx.placement
    n = cfg.population_size
    labels = archive_labels(env, archive_cfg)
    title = f"{ctx.algorithm} on {env_cfg.name}"

    def init(key: jax.Array) -> PBTState:
        member_key, hp_key, run_key = jax.random.split(key, 3)
        zero = jnp.zeros((), jnp.int32)
        state = PBTState(population.init(member_key, hp_key), archive_cfg.empty(ctx.seed), run_key, zero, zero)
        return place.place(state, PBT_AXES)

    def chunk(state: PBTState) -> tuple[PBTState, dict[str, Any]]:
        """Train every member one log interval, evaluate each, then (on schedule) exploit/explore."""
        key, eval_key, pbt_key = jax.random.split(state.key, 3)
        chunks = state.chunks + 1
        due = (chunks % cfg.exploit_every == 0) & (cfg.num_replace > 0)
        out_step = population.step(state.population, eval_key, pbt_key, due)
        ev = out_step.evaluation
        desc = ev["eval_final_desc"] if archive_cfg.descriptor == "final" else ev["eval_mean_desc"]
        archive, qd = feed(state.archive, desc, ev["eval_returns"], archive_cfg.qd_offset, archive_cfg.fitness_range)
        fitness = ev["eval_return"]  # (n,)
        best = jnp.argmax(jnp.where(jnp.isnan(fitness), -jnp.inf, fitness))
        out: dict[str, Any] = {k: jnp.nanmean(v) for k, v in out_step.train_metrics.items()}
        out["eval_returns_members"] = fitness
        out["eval_return"] = fitness[best]
        out["eval_return_median"] = jnp.median(fitness)
        out["eval_return_mean"] = jnp.mean(fitness)
        out["eval_return_std"] = ev["eval_return_std"][best]
        out["eval_length"] = ev["eval_length"][best]
        out["hparams_best"] = out_step.hparams[best]
        out["best_member"] = best
        out.update(qd)
        exploits = state.exploits + jnp.where(due, cfg.num_replace, 0)
        out["exploits"] = exploits
        new = PBTState(out_step.population, archive, key, chunks, exploits)
        return place.place(new, PBT_AXES), out

    def log_row(state: PBTState, metrics: Any) -> Row:
        m = place.fetch(metrics)
        # The members' counters may live on other processes (jax.distributed): gathered.
        env_steps, grad_steps = place.fetch((state.population.env_steps, state.population.grad_steps))
        member_steps = int(np.asarray(env_steps)[0])
        row: Row = {
            "env_steps": member_steps * n,
            "member_env_steps": member_steps,
            "grad_steps": int(np.asarray(grad_steps).sum()),
        }
        for i, r in enumerate(np.asarray(m.pop("eval_returns_members"))):
            row[f"eval_return_m{i}"] = float(r)
        for name, v in zip(space.names, np.asarray(m.pop("hparams_best")), strict=True):
            row[f"best_{name}"] = float(v)
        row.update({k: scalar(v) for k, v in m.items()})
        return row

    def plot(state: PBTState, rows: list[Row], out_dir: Path) -> None:
        plot_archive(state.archive, archive_cfg, labels, out_dir, title, rows)
        members = {
            f"member {i}": [
                {"member_env_steps": r["member_env_steps"], "eval_return": r[f"eval_return_m{i}"]} for r in rows
            ]
            for i in range(n)
        }
        if rows:
            plotting.plot_comparison(
                members, "eval_return", "member_env_steps", out_dir / "plots" / "population.png",
                title=f"{title}: each member's evaluation return",
            )

    def finish(state: PBTState, rows: list[Row], out_dir: Path) -> dict[str, Any]:
        del rows
        write_archive(state.archive, out_dir)
        final = pbt.get_hparams(jax.device_get(state.population), space)
        shapes = jax.eval_shape(trainer.init, jax.random.PRNGKey(0))
        return {
            "population_size": n,
            "buffer_bytes_per_member": pbt.buffer_bytes(shapes.buffer),
            "final_hparams": {name: np.asarray(final[:, i]).tolist() for i, name in enumerate(space.names)},
            "grad_steps": int(np.asarray(state.population.grad_steps).sum()),
        }

    return Algorithm(
        curves=RL_CURVES,
        task=env_cfg.name,
        sections=sections,
        num_chunks=train_cfg.num_chunks,
        # env_steps counts every member's
        progress=Progress(
            ("eval_return", "eval_return_median", "coverage"), "env_steps", train_cfg.num_chunks * train_cfg.eval_every * n
        ),
        init=init,
        chunk=chunk,
        log_row=log_row,
        finish=finish,
        plot=plot,
        placement=place,
        state_axes=PBT_AXES,
        descriptor_space=DescriptorSpace(archive_cfg.low, archive_cfg.high, labels),
    )


SAC_PBT, TD3_PBT = (
    Recipe(
        functools.partial(parse_pbt, agent_name=agent), functools.partial(_build, agent_name=agent),
        "train.total_env_steps", f"PBT (Jaderberg et al. 2017) of {agent.upper()} agents",
    )
    for agent in ("sac", "td3")
)
