"""ME-PBT: agents as genotypes, crossover, the population update, a tiny run."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import pbt
from qdrl.agents import SACConfig, make_sac
from qdrl.config import ConfigError, build
from qdrl.experiment import run_spec
from qdrl.off_policy import make_trainer
from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.emitters.me_pbt import MEPBTConfig, MEPBTEmitter, crossover, from_genotype, to_genotype
from qdrl.qd.repertoires import grid_repertoire
from qdrl.tasks import make_task


def small_emitter(**kw: object) -> tuple[MEPBTEmitter, object]:
    task = make_task("point_maze", episode_length=10)
    agent = make_sac(SACConfig(hidden=(8, 8)), task.env.observation_size, task.env.action_size)
    data: dict[str, object] = {
        "population_size": 5, "ga_batch_size": 2, "fraction_best": 0.2, "fraction_from_best": 0.2,
        "fraction_from_repertoire": 0.4, "training_steps": 20, "env_batch_size": 2,
        "batch_size": 8, "buffer_size": 200, "learning_starts": 10,
    }
    data.update(kw)
    cfg = build(MEPBTConfig, data, "me_pbt")
    space = pbt.search_space("sac", cfg.pbt_config(), jax.eval_shape(agent.init, jax.random.PRNGKey(0)).hparams)
    return MEPBTEmitter(agent, make_trainer(task.env, agent, cfg.train_config()), space, cfg), task


def test_genotype_drops_and_regains_optimiser_states() -> None:
    agent = make_sac(SACConfig(hidden=(8, 8)), 3, 2)
    state = agent.init(jax.random.PRNGKey(0))
    g = to_genotype(state)
    assert g.policy_opt_state is None and g.critic_opt_state is None and g.alpha_opt_state is None
    assert len(jax.tree.leaves(g)) < len(jax.tree.leaves(state))
    back = from_genotype(g, agent.init(jax.random.PRNGKey(1)))
    assert jax.tree.structure(back) == jax.tree.structure(state)
    for a, b in zip(jax.tree.leaves(back.policy_params), jax.tree.leaves(state.policy_params), strict=True):
        np.testing.assert_array_equal(a, b)


def test_crossover_varies_networks_and_keeps_the_first_parents_hyperparameters() -> None:
    agent = make_sac(SACConfig(hidden=(8, 8)), 3, 2)
    init = jax.jit(lambda k: to_genotype(jax.vmap(agent.init)(jax.random.split(k, 4))))
    x1, x2 = init(jax.random.PRNGKey(0)), init(jax.random.PRNGKey(1))
    x1 = x1._replace(hparams={**x1.hparams, "actor_lr": jnp.full((4,), 1e-3)})
    child = jax.jit(lambda a, b, k: crossover(a, b, k, 0.01, 0.1))(x1, x2, jax.random.PRNGKey(2))
    p1, c = jax.tree.leaves(x1.policy_params)[0], jax.tree.leaves(child.policy_params)[0]
    assert not np.allclose(p1, c)
    np.testing.assert_allclose(np.asarray(child.hparams["actor_lr"]), 1e-3)
    for a, b in zip(jax.tree.leaves(child.target_critic_params), jax.tree.leaves(child.critic_params), strict=True):
        np.testing.assert_array_equal(a, b)


def test_update_replaces_the_worst_from_the_best_and_from_the_repertoire() -> None:
    emitter, task = small_emitter()
    genotypes = jax.jit(lambda k: emitter.init_genotypes(k, 6))(jax.random.PRNGKey(0))
    example = jax.tree.map(lambda x: x[0], genotypes)
    rep = grid_repertoire(example, (4, 4), task.descriptor_low, task.descriptor_high)  # type: ignore[attr-defined]
    # One stored agent, recognisable by its log_alpha.
    marked = genotypes._replace(log_alpha=jnp.full((6,), 7.0))
    rep, _ = rep.add(jax.tree.map(lambda x: x[:1], marked), jnp.zeros((1, 2)), jnp.ones((1,)))
    ev = Evaluation(jnp.zeros((6,)), jnp.zeros((6, 2)), {}, jnp.zeros((), jnp.int32))
    state = jax.jit(emitter.init)(jax.random.PRNGKey(1), rep, ev, genotypes)
    ids = jnp.arange(5, dtype=jnp.float32)
    state = state._replace(population=state.population._replace(
        agent=state.population.agent._replace(log_alpha=ids)
    ))
    # Population fitness (after the 2 GA offspring): member 3 best, member 1 worst, then 4, 0.
    fitness = jnp.array([0.0, 0.0, 2.0, -5.0, 3.0, 9.0, -1.0])
    ev = Evaluation(fitness, jnp.zeros((7, 2)), {}, jnp.zeros((), jnp.int32))
    added = AddResult(*(jnp.zeros((7,), bool),) * 2, jnp.zeros((7,)), jnp.zeros((7,), jnp.int32))
    before = state.population.agent.hparams
    new = jax.jit(emitter.update)(state, rep, None, ev, added, jax.random.PRNGKey(2))
    alpha = np.asarray(new.population.agent.log_alpha)
    # Training moved log_alpha a little; identities stay readable by rounding.
    who = np.round(alpha).astype(int)
    assert who[1] == 3  # the worst copied the best (num_best = 1)
    assert who[4] == 7 and who[0] == 7  # the next two worst took the repertoire agent
    assert who[2] == 2 and who[3] == 3  # the best two kept their own
    for name in emitter.space.names:
        b, a = np.asarray(before[name]), np.asarray(new.population.agent.hparams[name])
        assert a[2] == b[2] and a[3] == b[3]
        assert (a >= np.asarray(emitter.space.low)[emitter.space.names.index(name)] * (1 - 1e-6)).all()
    assert (np.asarray(new.population.env_steps) == 20).all()  # every agent trained one period


def test_bad_me_pbt_config_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"me_pbt\.training_steps: expected a multiple of me_pbt\.env_batch_size"):
        build(MEPBTConfig, {"training_steps": 30, "env_batch_size": 4}, "me_pbt")
    with pytest.raises(ConfigError, match="fraction_from_repertoire: expected at most 1"):
        build(MEPBTConfig, {"fraction_from_best": 0.7, "fraction_from_repertoire": 0.4}, "me_pbt")


SPEC = """
[experiment]
algorithm = "me_pbt_sac"
seed = 0

[task]
name = "point_maze"
episode_length = 20

[repertoire]
kind = "grid"
grid_shape = [8, 8]

[qd]
num_iterations = 4
log_every = 2
init_batch_size = 8

[agent]
hidden = [16, 16]

[me_pbt]
population_size = 4
ga_batch_size = 4
training_steps = 40
env_batch_size = 4
batch_size = 16
buffer_size = 400
learning_starts = 20

[log]
progress = false
checkpoint_every = 1
"""


@pytest.mark.parametrize(
    "algorithm", ["me_pbt_sac", pytest.param("me_pbt_td3", marks=pytest.mark.slow)]
)
def test_tiny_me_pbt_run(tmp_path: Path, algorithm: str) -> None:
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.replace('algorithm = "me_pbt_sac"', f'algorithm = "{algorithm}"'))
    summary = run_spec(spec, [], tmp_path / "out")
    assert summary["evaluations"] == 8 + 4 * 8
    assert summary["train_env_steps"] == 4 * 4 * 40
    assert summary["env_steps"] == summary["train_env_steps"] + summary["eval_env_steps"]
    assert summary["coverage"] > 0 and summary["num_elites"] >= 1
    assert (tmp_path / "out" / "plots" / "repertoire.png").stat().st_size > 1000
    with pytest.raises(ConfigError, match="ME-PBT takes no \\[emitter\\] section"):
        run_spec(spec, ["emitter.batch_size=4"], tmp_path / "bad")
