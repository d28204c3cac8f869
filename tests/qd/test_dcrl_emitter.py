"""DCRL emitter (DCRL-ME): similarity relabelling, actor injection, DC policy gradient, buffer, runs."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import buffers, nets
from qdrl.config import ConfigError, build
from qdrl.experiment import run_spec
from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.emitters import GAEmitter, MultiEmitter
from qdrl.qd.emitters.dcrl import (
    DCRLConfig,
    DCRLEmitter,
    DCRLEmitterState,
    DCRLTransition,
    dcrl_me_emitter,
    fold_descriptor,
    relabel_reward,
    similarity,
)
from qdrl.qd.emitters.pg import PG_TD3, insert_valid
from qdrl.types import Transition

OBS, ACT, D, T = 3, 2, 2, 4
LOW, HIGH = (0.0, -1.0), (2.0, 3.0)  # normalised: d_n = (d_0 - 1, (d_1 - 1) / 2)
CONFIG = DCRLConfig(
    num_critic_training_steps=3,
    num_pg_training_steps=5,
    training_batch_size=8,
    replay_buffer_size=40,
    td3=dataclasses.replace(PG_TD3, hidden=(8,)),
    lengthscale=0.5,
    reward_offset=1.0,
)


def make_emitter(num_pg: int = 1, num_ai: int = 2, first_row: int = 0) -> DCRLEmitter:
    return DCRLEmitter(
        num_pg, num_ai, nets.deterministic_policy(ACT, (8,), "tanh"), OBS, ACT, LOW, HIGH,
        CONFIG, first_row=first_row,
    )


@pytest.fixture(scope="module")
def emitter() -> DCRLEmitter:
    return make_emitter()


def transitions(n: int, t: int = T) -> Transition:
    """(t, n, ...) transitions whose every field encodes its step and batch index."""
    base = jnp.arange(t * n, dtype=jnp.float32).reshape(t, n)
    return Transition(
        obs=jnp.repeat(base[..., None], OBS, axis=-1) / 10,
        action=jnp.tanh(jnp.repeat(base[..., None], ACT, axis=-1) / 10),
        reward=base,
        next_obs=jnp.repeat(base[..., None] + 0.5, OBS, axis=-1) / 10,
        terminated=jnp.zeros((t, n)),
        truncated=jnp.zeros((t, n)),
        desc=jnp.repeat(base[..., None], D, axis=-1),
        next_desc=jnp.repeat(base[..., None] + 1, D, axis=-1),
    )


def evaluation(descriptors: jax.Array, mask: jax.Array) -> Evaluation:
    n = descriptors.shape[0]
    return Evaluation(
        fitnesses=jnp.zeros((n,)),
        descriptors=descriptors,
        extras={"transitions": transitions(n), "mask": mask, "descriptors": descriptors},
        env_steps=jnp.sum(mask).astype(jnp.int32),
    )


def no_add(n: int) -> AddResult:
    return AddResult(
        added=jnp.zeros((n,), bool),
        new_cell=jnp.zeros((n,), bool),
        improvement=jnp.zeros((n,)),
        cell=jnp.zeros((n,), jnp.int32),
    )


class FixedRepertoire(NamedTuple):
    """Cells with fixed genotypes, fitnesses (-inf = empty) and descriptors (a pytree, so jittable)."""

    genotypes: Any
    fitnesses: jax.Array
    descriptors: jax.Array


def policies(em: DCRLEmitter, n: int, seed: int = 0) -> Any:
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    return jax.vmap(lambda k: em.policy_network.init(k, jnp.zeros((OBS,))))(keys)


def test_similarity_and_relabelled_reward_by_hand() -> None:
    d = jnp.array([[0.0, 0.0], [0.5, -0.5], [1.0, 1.0]])
    target = jnp.array([[0.3, 0.4], [0.5, -0.5], [1.0, 1.0]])
    # ||d - d'|| = 0.5, 0, 0; lengthscale 0.1: S = exp(-5), 1, 1
    np.testing.assert_allclose(np.asarray(similarity(d, target, 0.1)), [math.exp(-5.0), 1.0, 1.0], rtol=1e-6)
    reward = jnp.array([2.0, -0.5, -3.0])
    # offset 1: r + 1 = 3, 0.5, -2 -> clipped at 0
    got = relabel_reward(reward, d, target, 0.1, reward_offset=1.0)
    np.testing.assert_allclose(np.asarray(got), [3.0 * math.exp(-5.0), 0.5, 0.0], rtol=1e-6)


def test_conditioned_batch_appends_the_target_and_relabels(emitter: DCRLEmitter) -> None:
    step = jax.tree.map(lambda x: x[1], transitions(2))  # (2, ...) items
    items = DCRLTransition(
        step=step,
        episode_desc=jnp.array([[0.0, 0.0], [0.2, 0.2]]),
        target_desc=jnp.array([[0.0, 0.5], [0.2, 0.2]]),
    )
    batch = jax.jit(emitter.conditioned_batch)(items)
    np.testing.assert_array_equal(np.asarray(batch.obs[:, :OBS]), np.asarray(step.obs))
    np.testing.assert_array_equal(np.asarray(batch.obs[:, OBS:]), np.asarray(items.target_desc))
    np.testing.assert_array_equal(np.asarray(batch.next_obs[:, OBS:]), np.asarray(items.target_desc))
    # rewards 2 and 3, offset 1, lengthscale 0.5: 3 exp(-0.5 / 0.5) and 4 * 1
    np.testing.assert_allclose(np.asarray(batch.reward), [3.0 * math.exp(-1.0), 4.0], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(batch.action), np.asarray(step.action))


def test_injected_actor_acts_as_the_dc_actor_with_that_descriptor(emitter: DCRLEmitter) -> None:
    key = jax.random.PRNGKey(0)
    dc_params = emitter.policy_network.init(key, jnp.zeros((OBS + D,)))
    # a non-zero bias, so the fold must add to it rather than replace it
    dc_params = jax.tree.map(lambda x: x + 0.1, dc_params)
    obs = jax.random.normal(jax.random.PRNGKey(1), (16, OBS))
    for target in (jnp.array([0.3, -0.7]), jnp.array([-1.0, 1.0])):
        folded = jax.jit(emitter.actor_injection)(dc_params, target)
        plain = emitter.policy_network.apply(folded, obs)
        dc = emitter.policy_network.apply(dc_params, jnp.concatenate([obs, jnp.tile(target, (16, 1))], -1))
        np.testing.assert_allclose(np.asarray(plain), np.asarray(dc), rtol=1e-6, atol=1e-6)
        # a genotype of the task's network: the same tree and shapes as a plain policy
        template = emitter.policy_network.init(key, jnp.zeros((OBS,)))
        assert jax.tree.structure(folded) == jax.tree.structure(template)
        for a, b in zip(jax.tree.leaves(folded), jax.tree.leaves(template), strict=True):
            assert a.shape == b.shape
        # the first layer is the one that reads [s; d']
        by_name = fold_descriptor(dc_params, target, "policy/~/linear_0", OBS)
        for a, b in zip(jax.tree.leaves(folded), jax.tree.leaves(by_name), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def linear_critic(em: DCRLEmitter, key: jax.Array) -> Any:
    """Critic params with Q_i(s, a | d') = sum(a) + 10 on the region the test visits (hand-set)."""
    width = OBS + D + ACT
    params: Any = em.networks.critic.init(key, jnp.zeros((1, OBS + D)), jnp.zeros((1, ACT)))
    w = jnp.zeros((width, 8)).at[OBS + D :, 0].set(1.0)
    b = jnp.zeros((8,)).at[0].set(10.0)
    out_w = jnp.zeros((8, 1)).at[0, 0].set(1.0)
    new = {}
    for name, layer in params.items():
        first = name.endswith("linear_0")
        new[name] = {"w": w if first else out_w, "b": b if first else jnp.zeros((1,))}
        assert layer["w"].shape == new[name]["w"].shape
    return new


def filled_buffer(em: DCRLEmitter, n: int = 3) -> buffers.ReplayBuffer:
    tr = transitions(n)
    items = DCRLTransition(step=tr, episode_desc=jnp.zeros((T, n, D)), target_desc=jnp.zeros((T, n, D)))
    example = jax.tree.map(lambda x: x[0, 0], items)
    insert = jax.jit(insert_valid)
    return insert(buffers.init(example, 40), items, jnp.ones((T, n)))  # type: ignore[arg-type]


def test_pg_variation_moves_a_parent_towards_higher_q(emitter: DCRLEmitter) -> None:
    key = jax.random.PRNGKey(2)
    td3 = jax.jit(emitter.agent.init)(key)
    td3 = td3._replace(critic_params=linear_critic(emitter, key))
    state = DCRLEmitterState(
        td3=td3, buffer=filled_buffer(emitter),
        parents=jnp.zeros((1,), jnp.int32), targets=jnp.zeros((3, D)),
    )
    parent = emitter.policy_network.init(jax.random.PRNGKey(3), jnp.zeros((OBS,)))
    target = jnp.array([0.5, -0.5])
    child = jax.jit(emitter.pg_variation)(state, parent, target, jax.random.PRNGKey(4))
    obs = jnp.concatenate([state.buffer.data.step.obs[:12], jnp.tile(target, (12, 1))], axis=-1)

    def q(params: Any) -> jax.Array:
        action = emitter.policy_network.apply(params, obs[:, :OBS])
        return jnp.mean(emitter.networks.critic.apply(td3.critic_params, obs, action)[:, 0])

    q = jax.jit(q)
    assert float(q(child)) > float(q(parent)) + 0.05
    grad = jax.jit(jax.grad(q))(parent)
    step = jax.tree.map(lambda c, p: c - p, child, parent)
    inner = sum(jnp.vdot(g, s) for g, s in zip(jax.tree.leaves(grad), jax.tree.leaves(step), strict=True))
    assert float(inner) > 0.0


def test_update_stores_every_episode_with_its_descriptor_and_target() -> None:
    """Own rows get the targets they were emitted for, other rows their observed descriptor."""
    em = make_emitter(num_pg=1, num_ai=1, first_row=1)
    key = jax.random.PRNGKey(5)
    desc = jnp.array([[1.0, 1.0], [2.0, 3.0], [0.0, -1.0], [1.5, 0.0]])  # 4 episodes
    desc_n = np.array([[0.0, 0.0], [1.0, 1.0], [-1.0, -1.0], [0.5, -0.5]])
    mask = jnp.ones((T, 4)).at[2:, 0].set(0.0)  # the first episode ends after 2 steps
    state = DCRLEmitterState(
        td3=jax.jit(em.agent.init)(key),
        buffer=buffers.init(
            DCRLTransition(jax.tree.map(lambda x: x[0, 0], transitions(4)), jnp.zeros(D), jnp.zeros(D)),
            CONFIG.replay_buffer_size,
        ),
        parents=jnp.zeros((1,), jnp.int32),
        targets=jnp.array([[0.25, 0.25], [-0.5, 0.75]]),  # rows 1 and 2 were aimed there
    )
    cells_desc = jnp.array([[0.0, 3.0], [2.0, -1.0], [1.0, 1.0]])
    repertoire = FixedRepertoire(policies(em, 3), jnp.array([1.0, -jnp.inf, 2.0]), cells_desc)
    new = jax.jit(em.update)(state, repertoire, None, evaluation(desc, mask), no_add(4), jax.random.PRNGKey(6))
    assert int(new.buffer.size) == T * 4 - 2
    data = jax.tree.map(lambda x: np.asarray(x[: T * 4 - 2]), new.buffer.data)
    # valid items in time-major order; batch index = reward % 4
    rows = data.step.reward.astype(int) % 4
    np.testing.assert_array_equal(data.step.reward, [v for v in range(16) if v not in (8, 12)])
    targets = np.array([desc_n[0], [0.25, 0.25], [-0.5, 0.75], desc_n[3]])
    np.testing.assert_allclose(data.episode_desc, desc_n[rows], rtol=1e-6)
    np.testing.assert_allclose(data.target_desc, targets[rows], rtol=1e-6)
    assert int(new.td3.steps) == CONFIG.num_critic_training_steps
    # the next parent and targets come from filled cells only (0 and 2)
    assert set(np.asarray(new.parents).tolist()) <= {0, 2}
    allowed = {(-1.0, 1.0), (0.0, 0.0)}
    assert {tuple(map(float, t)) for t in np.asarray(new.targets)} <= allowed
    np.testing.assert_allclose(
        np.asarray(new.targets[0]), em.normalise(cells_desc[int(new.parents[0])]), rtol=1e-6
    )


def test_emit_gives_pg_offspring_then_injected_actors(emitter: DCRLEmitter) -> None:
    key = jax.random.PRNGKey(7)
    genotypes = policies(emitter, 4, seed=1)
    desc = jnp.array([[0.5, 0.0], [1.0, 1.0], [1.5, 2.0], [2.0, 3.0]])
    repertoire = FixedRepertoire(genotypes, jnp.zeros((4,)), desc)
    state = jax.jit(emitter.init)(key, repertoire, evaluation(desc, jnp.ones((T, 4))), genotypes)
    # the initial population's episodes are stored with their own descriptors as targets
    data = state.buffer.data
    np.testing.assert_array_equal(np.asarray(data.target_desc[:16]), np.asarray(data.episode_desc[:16]))
    offspring = jax.jit(emitter.emit)(state, repertoire, jax.random.PRNGKey(8))
    parent = jax.tree.map(lambda x: x[state.parents[0]], genotypes)
    for i, target in enumerate(state.targets[1:]):
        injected = emitter.actor_injection(state.td3.policy_params, target)
        for a, b in zip(jax.tree.leaves(offspring), jax.tree.leaves(injected), strict=True):
            np.testing.assert_array_equal(np.asarray(a[1 + i]), np.asarray(b))
    for a, b in zip(jax.tree.leaves(offspring), jax.tree.leaves(parent), strict=True):
        assert a.shape[0] == 3
        assert not np.allclose(np.asarray(a[0]), np.asarray(b))
    # the PG parent's target is its own descriptor
    np.testing.assert_allclose(
        np.asarray(state.targets[0]), np.asarray(emitter.normalise(desc[state.parents[0]])), rtol=1e-6
    )


def test_dcrl_me_emitter_puts_dcrl_first_then_the_ga() -> None:
    network = nets.deterministic_policy(ACT, (8,), "tanh")
    em = dcrl_me_emitter(16, network, OBS, ACT, LOW, HIGH, CONFIG)
    assert isinstance(em, MultiEmitter)
    dcrl, ga = em.emitters
    assert isinstance(dcrl, DCRLEmitter) and isinstance(ga, GAEmitter)
    assert (dcrl.num_pg, dcrl.num_ai, dcrl.first_row, ga.batch_size) == (4, 4, 0, 8)
    with pytest.raises(ValueError, match="batch_size"):
        dcrl_me_emitter(8, network, OBS, ACT, LOW, HIGH, CONFIG, dcrl_batch_size=4, ai_batch_size=4)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("lengthscale", 0.0, "dcrl.lengthscale"),
        ("lengthscale", float("nan"), "dcrl.lengthscale"),
        ("reward_offset", float("inf"), "dcrl.reward_offset"),
        ("critic_learning_rate", -1.0, "dcrl.critic_learning_rate"),
        ("num_pg_training_steps", -1, "dcrl.num_pg_training_steps"),
        ("training_batch_size", 0, "dcrl.training_batch_size"),
    ],
)
def test_bad_dcrl_config_names_the_field(field: str, value: object, match: str) -> None:
    with pytest.raises(ValueError, match=re.escape(match)):
        build(DCRLConfig, {field: value}, "dcrl")


SPEC = """
[experiment]
algorithm = "dcrl_me"
seed = 0

[task]
name = "point_maze"
episode_length = 10
policy_hidden = [8, 8]

[repertoire]
kind = "grid"
grid_shape = [8, 8]

[emitter]
batch_size = 8

[dcrl]
dcrl_batch_size = 2
ai_batch_size = 2
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


@pytest.mark.slow  # the driver's resume of an actor-critic emitter's state: PGA-ME's test, by default
def test_dcrl_me_runs_through_qdrl_run_and_resumes_with_its_emitter_state(
    tmp_path: Path, resumes_bit_identically: Any
) -> None:
    spec = tmp_path / "dcrl_me.toml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    summary = run_spec(spec, [], out)
    assert summary["evaluations"] == 8 + 4 * 8
    assert summary["critic_steps"] == 8 * 5  # the initial population's update and 4 more
    assert summary["buffer_size"] == 5 * 8 * 10  # episodes never end early in the point maze
    resolved = (out / "config.toml").read_text()
    # the task's reward offset (2 sqrt(2) per step in the point maze) is filled in
    assert re.search(r"reward_offset = 2\.828", resolved)
    resumes_bit_identically(
        spec, out, summary, ("qd_score", "max_fitness", "coverage", "critic_steps", "buffer_size")
    )


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("dcrl.lengthscale=-0.1", "dcrl.lengthscale"),
        ("dcrl.dcrl_batch_size=6", "dcrl.dcrl_batch_size"),
        ("dcrl.ai_batch_size=-1", "dcrl.ai_batch_size"),
        ("dcrl.replay_buffer_size=50", "dcrl.replay_buffer_size"),
        ("dcrl.nope=1", "dcrl.nope"),
    ],
)
def test_bad_dcrl_me_spec_fails_before_compiling(tmp_path: Path, override: str, match: str) -> None:
    spec = tmp_path / "dcrl_me.toml"
    spec.write_text(SPEC)
    with pytest.raises(ConfigError, match=re.escape(match)):
        run_spec(spec, [override], tmp_path / "out")
