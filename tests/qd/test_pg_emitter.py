"""Q-PG emitter (PGA-ME): policy-gradient offspring, replay buffer, TD3 training, runs."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import buffers, nets
from qdrl.config import ConfigError, build
from qdrl.experiment import run_spec
from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.emitters import GAEmitter, MultiEmitter
from qdrl.qd.emitters.pg import (
    PG_TD3,
    PGConfig,
    PGEmitter,
    PGEmitterState,
    flatten_valid,
    insert_valid,
    pga_me_emitter,
)
from qdrl.types import Transition

OBS, ACT, T, N = 3, 2, 4, 3
CONFIG = PGConfig(
    num_critic_training_steps=3,
    num_pg_training_steps=5,
    training_batch_size=8,
    replay_buffer_size=40,
    td3=dataclasses.replace(PG_TD3, hidden=(8,)),
)


def transitions(t: int = T, n: int = N, start: float = 0.0) -> Transition:
    """(t, n, ...) transitions whose every field encodes its step and batch index."""
    base = start + jnp.arange(t * n, dtype=jnp.float32).reshape(t, n)
    return Transition(
        obs=jnp.repeat(base[..., None], OBS, axis=-1),
        action=jnp.tanh(jnp.repeat(base[..., None], ACT, axis=-1) / 10),
        reward=base,
        next_obs=jnp.repeat(base[..., None] + 0.5, OBS, axis=-1),
        terminated=jnp.zeros((t, n)),
        truncated=jnp.zeros((t, n)),
        desc=jnp.repeat(base[..., None], 2, axis=-1),
        next_desc=jnp.repeat(base[..., None], 2, axis=-1),
    )


def evaluation(tr: Transition, mask: jax.Array) -> Evaluation:
    n = tr.reward.shape[1]
    return Evaluation(
        fitnesses=jnp.zeros((n,)),
        descriptors=jnp.zeros((n, 2)),
        extras={"transitions": tr, "mask": mask},
        env_steps=jnp.sum(mask).astype(jnp.int32),
    )


def no_add(n: int) -> AddResult:
    return AddResult(
        added=jnp.zeros((n,), bool),
        new_cell=jnp.zeros((n,), bool),
        improvement=jnp.zeros((n,)),
        cell=jnp.zeros((n,), jnp.int32),
    )


@pytest.fixture(scope="module")
def emitter() -> PGEmitter:
    return PGEmitter(4, nets.deterministic_policy(ACT, (8,), "tanh"), OBS, ACT, CONFIG)


class FixedRepertoire:
    """A repertoire whose `sample` returns the first rows of fixed genotypes."""

    def __init__(self, genotypes: object) -> None:
        self.genotypes = genotypes

    def sample(self, key: jax.Array, n: int) -> object:
        del key
        return jax.tree.map(lambda x: x[:n], self.genotypes)


def test_flatten_valid_puts_valid_items_first_in_time_major_order() -> None:
    tr = transitions()
    mask = jnp.ones((T, N)).at[2:, 0].set(0.0).at[3, 1].set(0.0)
    items, count = flatten_valid(tr, mask)
    assert int(count) == T * N - 3
    expected = [float(v) for v in np.asarray(tr.reward).reshape(-1) if v not in (6.0, 9.0, 10.0)]
    np.testing.assert_array_equal(np.asarray(items.reward[:count]), expected)


def test_insert_valid_keeps_only_valid_transitions_and_leaves_other_slots_unchanged() -> None:
    example = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[2:], x.dtype), transitions())
    buffer = buffers.init(example, 20)
    filler = jax.tree.map(lambda x: jnp.full((2, *x.shape[2:]), -1.0, x.dtype), transitions())
    buffer = buffers.insert(buffer, filler)
    old = jax.tree.map(np.asarray, buffer.data)
    mask = jnp.ones((T, N)).at[1:, 2].set(0.0)  # the third episode ends after one step
    new = insert_valid(buffer, transitions(), mask)
    assert int(new.size) == 2 + 9 and int(new.position) == 11
    valid = [v for v in range(12) if v not in (5, 8, 11)]
    np.testing.assert_array_equal(np.asarray(new.data.reward[2:11]), valid)
    # slots past the valid items keep what they held
    np.testing.assert_array_equal(np.asarray(new.data.reward[11:]), old.reward[11:])
    np.testing.assert_array_equal(np.asarray(new.data.obs[:2]), old.obs[:2])


def test_insert_valid_wraps_around_the_ring() -> None:
    example = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[2:], x.dtype), transitions())
    buffer = insert_valid(buffers.init(example, 14), transitions(), jnp.ones((T, N)))
    buffer = insert_valid(buffer, transitions(start=100.0), jnp.ones((T, N)).at[:, 0].set(0.0))
    # 12 + 8 valid items in 14 slots: the ring holds 100+ values in slots 12, 13, 0..5
    assert int(buffer.size) == 14 and int(buffer.position) == 6
    got = np.asarray(buffer.data.reward)
    news = [100.0 + v for v in range(12) if v % 3]
    np.testing.assert_array_equal(np.concatenate([got[12:], got[:6]]), news)
    np.testing.assert_array_equal(got[6:12], np.arange(6, 12))


def test_insert_valid_rejects_a_batch_larger_than_the_buffer() -> None:
    example = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[2:], x.dtype), transitions())
    with pytest.raises(ValueError, match="replay_buffer_size"):
        insert_valid(buffers.init(example, 5), transitions(), jnp.ones((T, N)))


def test_update_stores_transitions_and_runs_td3_update(emitter: PGEmitter) -> None:
    """`update` = insert the valid transitions + TD3's own update on sampled batches, nothing else."""
    key = jax.random.PRNGKey(0)
    tr, mask = transitions(), jnp.ones((T, N)).at[3, :].set(0.0)
    state = PGEmitterState(
        td3=emitter.agent.init(key),
        buffer=buffers.init(jax.tree.map(lambda x: x[0, 0], tr), CONFIG.replay_buffer_size),
        relabel=None,
    )
    update_key = jax.random.PRNGKey(1)
    new = jax.jit(emitter.update)(state, None, None, evaluation(tr, mask), no_add(N), update_key)
    assert int(new.buffer.size) == 9
    np.testing.assert_array_equal(np.asarray(new.buffer.data.reward[:9]), np.arange(9))
    assert int(new.td3.steps) == CONFIG.num_critic_training_steps
    # the same by hand: the agent's update on batches sampled with the same keys
    buffer, td3 = new.buffer, state.td3
    for k in jax.random.split(update_key, CONFIG.num_critic_training_steps):
        sample_key, k2 = jax.random.split(k)
        td3, _ = emitter.agent.update(td3, buffers.sample(buffer, sample_key, 8), k2)
    for a, b in zip(jax.tree.leaves(td3), jax.tree.leaves(new.td3), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)


def linear_critic(emitter: PGEmitter, key: jax.Array) -> object:
    """Critic params with Q_i(s, a) = sum(a) + 10 on the region the test visits (hand-set)."""
    params: Any = emitter.networks.critic.init(key, jnp.zeros((1, OBS)), jnp.zeros((1, ACT)))
    w = jnp.zeros((OBS + ACT, 8)).at[OBS:, 0].set(1.0)
    b = jnp.zeros((8,)).at[0].set(10.0)
    out_w = jnp.zeros((8, 1)).at[0, 0].set(1.0)
    new = {}
    for name, layer in params.items():
        first = name.endswith("linear_0")
        new[name] = {"w": w if first else out_w, "b": b if first else jnp.zeros((1,))}
        assert layer["w"].shape == new[name]["w"].shape
    return new


def test_pg_variation_moves_a_parent_towards_higher_q(emitter: PGEmitter) -> None:
    key = jax.random.PRNGKey(2)
    td3 = emitter.agent.init(key)
    td3 = td3._replace(critic_params=linear_critic(emitter, key))
    tr = transitions()
    buffer = insert_valid(
        buffers.init(jax.tree.map(lambda x: x[0, 0], tr), 40), tr, jnp.ones((T, N))
    )
    state = PGEmitterState(td3=td3, buffer=buffer, relabel=None)
    parent = emitter.networks.policy.init(jax.random.PRNGKey(3), jnp.zeros((OBS,)))
    child = jax.jit(emitter.pg_variation)(state, parent, jax.random.PRNGKey(4))
    obs = buffer.data.obs[:12] / 12.0  # inside the hand-set critic's linear region

    def q(params: object) -> jax.Array:
        action = emitter.networks.policy.apply(params, obs)
        return jnp.mean(emitter.networks.critic.apply(td3.critic_params, obs, action)[:, 0])

    assert float(q(child)) > float(q(parent)) + 0.05
    grad = jax.grad(q)(parent)
    step = jax.tree.map(lambda c, p: c - p, child, parent)
    inner = sum(jnp.vdot(g, s) for g, s in zip(jax.tree.leaves(grad), jax.tree.leaves(step), strict=True))
    assert float(inner) > 0.0


def test_emit_gives_pg_offspring_then_the_greedy_actor(emitter: PGEmitter) -> None:
    key = jax.random.PRNGKey(5)
    tr = transitions()
    genotypes = jax.vmap(lambda k: emitter.networks.policy.init(k, jnp.zeros((OBS,))))(
        jax.random.split(key, 6)
    )
    repertoire = FixedRepertoire(genotypes)
    state = jax.jit(emitter.init, static_argnums=1)(key, None, evaluation(tr, jnp.ones((T, N))), genotypes)
    assert int(state.buffer.size) == T * N and int(state.td3.steps) == CONFIG.num_critic_training_steps
    offspring = emitter.emit(state, repertoire, jax.random.PRNGKey(6))  # type: ignore[arg-type]
    for leaf, parent, greedy in zip(
        jax.tree.leaves(offspring),
        jax.tree.leaves(genotypes),
        jax.tree.leaves(state.td3.policy_params),
        strict=True,
    ):
        assert leaf.shape == (4, *parent.shape[1:])
        np.testing.assert_array_equal(np.asarray(leaf[-1]), np.asarray(greedy))
        assert not np.allclose(np.asarray(leaf[:3]), np.asarray(parent[:3]))


def test_pga_me_emitter_splits_the_batch_between_ga_and_qpg() -> None:
    network = nets.deterministic_policy(ACT, (8,), "tanh")
    em = pga_me_emitter(10, network, OBS, ACT, CONFIG, proportion_mutation_ga=0.3)
    assert isinstance(em, MultiEmitter)
    ga, pg = em.emitters
    assert isinstance(ga, GAEmitter) and isinstance(pg, PGEmitter)
    assert (ga.batch_size, pg.batch_size, pg.num_pg) == (3, 7, 6)
    with pytest.raises(ValueError, match="proportion_mutation_ga"):
        pga_me_emitter(10, network, OBS, ACT, CONFIG, proportion_mutation_ga=1.0)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("critic_learning_rate", -1.0, "pg.critic_learning_rate"),
        ("policy_learning_rate", 0.0, "pg.policy_learning_rate"),
        ("critic_hidden", [0], "pg.critic_hidden"),
        ("num_pg_training_steps", -1, "pg.num_pg_training_steps"),
        ("policy_delay", 0, "pg.policy_delay"),
    ],
)
def test_bad_pg_config_names_the_key(field: str, value: object, match: str) -> None:
    with pytest.raises(ValueError, match=re.escape(match)):
        build(PGConfig, {field: value}, "pg")


SPEC = """
[experiment]
algorithm = "pga_me"
seed = 0

[task]
name = "point_maze"
episode_length = 20
policy_hidden = [8, 8]

[repertoire]
kind = "grid"
grid_shape = [8, 8]

[emitter]
batch_size = 8

[pg]
num_critic_training_steps = 8
num_pg_training_steps = 4
training_batch_size = 16
replay_buffer_size = 1000
critic_hidden = [16, 16]

[qd]
num_iterations = 4
log_every = 2
init_batch_size = 8

[log]
progress = false
plots = false
checkpoint_every = 1
"""


def test_pga_me_runs_through_qdrl_run_and_resumes_with_its_critic_and_buffer(
    tmp_path: Path, resumes_bit_identically: Any
) -> None:
    spec = tmp_path / "pga_me.toml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    summary = run_spec(spec, [], out)
    assert summary["evaluations"] == 8 + 4 * 8
    assert summary["critic_steps"] == 8 * 5  # the initial population's update and 4 more
    assert summary["buffer_size"] == 5 * 8 * 20  # episodes never end early in the point maze
    rows = (out / "metrics.csv").read_text().splitlines()
    assert len(rows) == 3
    resumes_bit_identically(
        spec, out, summary, ("qd_score", "max_fitness", "coverage", "critic_steps", "buffer_size")
    )


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("pg.proportion_mutation_ga=1.5", "pg.proportion_mutation_ga"),
        ("pg.critic_learning_rate=-1.0", "pg.critic_learning_rate"),
        ("pg.replay_buffer_size=100", "pg.replay_buffer_size"),
        ("pg.nope=1", "pg.nope"),
    ],
)
def test_bad_pga_me_spec_fails_before_compiling(tmp_path: Path, override: str, match: str) -> None:
    spec = tmp_path / "pga_me.toml"
    spec.write_text(SPEC)
    with pytest.raises(ConfigError, match=re.escape(match)):
        run_spec(spec, [override], tmp_path / "out")


def test_pga_me_needs_a_policy_task(tmp_path: Path) -> None:
    spec = tmp_path / "pga_me.toml"
    text = SPEC.replace('name = "point_maze"\nepisode_length = 20\npolicy_hidden = [8, 8]', 'name = "arm"')
    spec.write_text(text)
    with pytest.raises(ConfigError, match=r"task\.name"):
        run_spec(spec, [], tmp_path / "out")
