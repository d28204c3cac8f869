"""Skill discovery: DIAYN / DADS losses and rewards against hand-computed values, the SMERL gate,
the trajectory buffer's episode returns, the skill-conditioned env, and a tiny training run."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from qdrl import buffers, off_policy
from qdrl.agents.dads import (
    DADSConfig,
    RunningMoments,
    dads_reward,
    make_dads_module,
    mixture_log_prob,
    normalize,
    skill_dynamics_network,
    skill_dynamics_outputs,
    update_moments,
)
from qdrl.agents.diayn import (
    DIAYNConfig,
    diayn_reward,
    discriminator_loss,
    discriminator_network,
    gaussian_diayn_reward,
    make_diayn,
    make_diayn_module,
)
from qdrl.agents.intrinsic import RewardModule, relabel, with_intrinsic_reward
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.smerl import SMERLConfig, make_smerl, smerl_gate
from qdrl.envs.point_maze import PointMazeEnv
from qdrl.envs.skills import SkillEnv, append_skill, skill_of, strip_skill
from qdrl.off_policy import TrainConfig, make_trainer
from qdrl.types import Transition

K = 4


def _transitions(n: int, skills: np.ndarray, desc: np.ndarray, next_desc: np.ndarray) -> Transition:
    obs = append_skill(jnp.zeros((n, 3)), jnp.asarray(skills), K)
    z = jnp.zeros((n,))
    return Transition(
        obs=obs, action=jnp.zeros((n, 2)), reward=jnp.arange(n, dtype=jnp.float32),
        next_obs=obs, terminated=z, truncated=z,
        desc=jnp.asarray(desc, jnp.float32), next_desc=jnp.asarray(next_desc, jnp.float32),
    )


# -- DIAYN ------------------------------------------------------------------------------


def test_diayn_reward_and_loss_by_hand() -> None:
    logits = jnp.array([[2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    skills = jnp.array([0, 3])
    # log q(z|s) = 2 - log(e^2 + 3) for row 0, log(1/4) for row 1; r = log q + log 4.
    log_q0 = 2.0 - math.log(math.exp(2.0) + 3.0)
    expected = np.array([log_q0 + math.log(4.0), 0.0])
    np.testing.assert_allclose(diayn_reward(logits, skills), expected, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(
        discriminator_loss(logits, skills), -(log_q0 + math.log(0.25)) / 2.0, rtol=1e-6
    )


def test_diayn_module_learns_to_discriminate_positions() -> None:
    # Skill i always ends at corner i: the discriminator must reach full accuracy and the
    # reward must approach its maximum log K.
    module = make_diayn_module(DIAYNConfig(num_skills=K, hidden=(32,), learning_rate=1e-2), 3, 2)
    skills = np.arange(64) % K
    corners = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], np.float32)[skills]
    tr = _transitions(64, skills, np.zeros((64, 2)), corners)
    state = module.init(jax.random.PRNGKey(0))
    update = jax.jit(module.update)
    for _ in range(200):
        state, metrics = update(state, tr, jax.random.PRNGKey(1))
    r, info = module.reward(state, tr, jax.random.PRNGKey(2))
    assert float(jnp.mean(info["discriminator_accuracy"])) == 1.0
    assert float(jnp.min(r)) > math.log(K) - 0.1
    assert float(metrics["discriminator_loss"]) < 0.1


def test_diayn_one_pass_equals_reward_then_update() -> None:
    # The agent's update calls `reward_and_update`: one forward pass of the discriminator
    # serves the reward and the loss. It must equal the reward of `reward` and a separate
    # Adam step on the cross-entropy of the same network (written out here, not the module's).
    config = DIAYNConfig(num_skills=K, hidden=(16, 16))
    module = make_diayn_module(config, 3, 2)
    assert module.reward_and_update is not None
    rng = np.random.default_rng(0)
    skills = rng.integers(0, K, 32)
    tr = _transitions(32, skills, rng.normal(size=(32, 2)), rng.normal(size=(32, 2)))
    state = module.init(jax.random.PRNGKey(0))
    key = jax.random.PRNGKey(1)
    r, info = module.reward(state, tr, key)
    network = discriminator_network(K, config.hidden, config.activation)
    adam = optax.adam(config.learning_rate)

    def loss_fn(params):  # type: ignore[no-untyped-def]
        return discriminator_loss(network.apply(params, tr.next_desc), jnp.asarray(skills))

    loss, grads = jax.value_and_grad(loss_fn)(state.params)
    updates, opt_state = adam.update(grads, state.opt_state, state.params)
    expected = (optax.apply_updates(state.params, updates), opt_state)
    r1, info1, new1, metrics1 = jax.jit(module.reward_and_update)(state, tr, key, key)
    np.testing.assert_allclose(r1, r, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(info1["discriminator_accuracy"], info["discriminator_accuracy"])
    np.testing.assert_allclose(metrics1["discriminator_loss"], loss, rtol=1e-6)
    for a, b in zip(jax.tree.leaves(new1), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    new, metrics = module.update(state, tr, key)  # the module's update is the same step
    np.testing.assert_allclose(metrics["discriminator_loss"], loss, rtol=1e-6)
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    # the loss is the mean of log K - r (cross-entropy = -log q(z|s'))
    np.testing.assert_allclose(metrics1["discriminator_loss"], jnp.mean(math.log(K) - r1), rtol=1e-5)


def test_intrinsic_agent_uses_the_one_pass_on_the_updates_that_train_the_model() -> None:
    # Trained every 2nd update: the one pass on updates 0 and 2, the reward alone on 1.
    from qdrl.agents.base import Agent

    calls: list[str] = []
    inner = Agent(lambda k: 0, lambda s, o, k: o, lambda p, o: o, lambda s: s,
                  lambda s, t, k: (s, {}))

    def one_pass(a, t, k1, k2):  # type: ignore[no-untyped-def]
        calls.append("both")
        return jnp.full(t.reward.shape, 2.0), {}, a + 1.0, {"model_loss": a + 1.0}

    def reward(a, t, k):  # type: ignore[no-untyped-def]
        calls.append("reward")
        return jnp.full(t.reward.shape, 2.0), {}

    module = RewardModule(init=lambda k: jnp.zeros(()), reward=reward,
                          update=lambda a, t, k: (a + 1.0, {"model_loss": a + 1.0}),
                          reward_and_update=one_pass)
    agent = with_intrinsic_reward(inner, module, model_update_every=2)
    tr = _transitions(2, np.zeros(2, int), np.zeros((2, 2)), np.zeros((2, 2)))
    state = agent.init(jax.random.PRNGKey(0))
    losses = []
    for i in range(3):
        state, metrics = agent.update(state, tr, jax.random.PRNGKey(i))
        losses.append(float(metrics["model_loss"]))
    assert float(state.aux) == 2.0 and float(metrics["intrinsic_reward"]) == 2.0
    np.testing.assert_array_equal(losses, [1.0, np.nan, 2.0])
    assert "both" in calls and "reward" in calls  # both branches traced (lax.cond)


def test_diayn_full_state_input_reads_obs_without_skill() -> None:
    module = make_diayn_module(DIAYNConfig(num_skills=K, model_input="full", hidden=(8,)), 3, 2)
    state = module.init(jax.random.PRNGKey(0))
    assert state.params["mlp/~/linear_0"]["w"].shape == (3, 8)
    tr = _transitions(5, np.arange(5) % K, np.zeros((5, 2)), np.zeros((5, 2)))
    r, _ = module.reward(state, tr, jax.random.PRNGKey(0))
    assert r.shape == (5,)


# -- DADS -------------------------------------------------------------------------------


def test_mixture_log_prob_by_hand() -> None:
    # Two 1-D components, weights softmax([0, log 3]) = (1/4, 3/4), means 0 and 2, std 1 and 0.5.
    logits = jnp.array([0.0, math.log(3.0)])
    means = jnp.array([[0.0], [2.0]])
    log_std = jnp.log(jnp.array([[1.0], [0.5]]))
    x = jnp.array([1.0])

    def normal(v: float, m: float, s: float) -> float:
        return math.exp(-0.5 * ((v - m) / s) ** 2) / (s * math.sqrt(2 * math.pi))

    expected = math.log(0.25 * normal(1.0, 0.0, 1.0) + 0.75 * normal(1.0, 2.0, 0.5))
    np.testing.assert_allclose(mixture_log_prob(logits, means, log_std, x), expected, rtol=1e-6)


def test_dads_reward_by_hand() -> None:
    # q(delta|s,z) = 0.5; the alternatives give 0.5, 0.1, 0.1, 0.3 -> mean 0.25.
    log_q = jnp.log(jnp.array([0.5]))
    log_alt = jnp.log(jnp.array([[0.5, 0.1, 0.1, 0.3]]))
    np.testing.assert_allclose(dads_reward(log_q, log_alt), [math.log(0.5 / 0.25)], rtol=1e-6)


def test_running_moments_match_numpy() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(1.0, 2.0, (50, 3)), rng.normal(-1.0, 0.5, (30, 3))
    m = RunningMoments(jnp.zeros(3), jnp.ones(3), jnp.zeros(()))
    m = update_moments(update_moments(m, jnp.asarray(a)), jnp.asarray(b))
    both = np.concatenate([a, b])
    np.testing.assert_allclose(m.mean, both.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(m.var, both.var(0), rtol=1e-4)
    np.testing.assert_allclose(normalize(m, jnp.asarray(both)).std(0), 1.0, rtol=1e-3)


def test_dads_module_learns_skill_dynamics() -> None:
    # Skill i moves by 0.1 in direction i (right, up, left, down). Normalised (batch mean 0,
    # std 0.1 / sqrt(2)), the four changes are sqrt(2) e_i. Once the fixed-variance model
    # predicts them exactly, log q = log N(0; 0, I_2) = -log(2 pi), and the other skills' means
    # lie at squared distance 4 (two neighbours) and 8 (the opposite one), so
    # r = log 4 - log(1 + 2 e^-2 + e^-4).
    cfg = DADSConfig(num_skills=K, hidden=(32,), learning_rate=1e-2, num_components=2)
    module = make_dads_module(cfg, 3, 2)
    skills = np.arange(64) % K
    rng = np.random.default_rng(0)
    desc = rng.uniform(-1, 1, (64, 2)).astype(np.float32)
    steps = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], np.float32)[skills]
    tr = _transitions(64, skills, desc, desc + 0.1 * steps)
    state = module.init(jax.random.PRNGKey(0))
    update = jax.jit(module.update)
    _, info0 = module.reward(state, tr, jax.random.PRNGKey(1))
    for _ in range(400):
        state, _ = update(state, tr, jax.random.PRNGKey(1))
    r, info = module.reward(state, tr, jax.random.PRNGKey(2))
    log_likelihood = float(jnp.mean(info["dynamics_log_likelihood"]))
    assert log_likelihood > float(jnp.mean(info0["dynamics_log_likelihood"]))
    assert log_likelihood == pytest.approx(-math.log(2 * math.pi), abs=0.02)
    expected = math.log(4.0) - math.log(1.0 + 2.0 * math.exp(-2.0) + math.exp(-4.0))
    np.testing.assert_allclose(r, expected, atol=0.05)


def test_dads_sampled_alternatives_and_omitted_dims() -> None:
    cfg = DADSConfig(num_skills=K, hidden=(8,), num_alt_skills=16, omit_input_dims=(0,))
    module = make_dads_module(cfg, 3, 2)
    state = module.init(jax.random.PRNGKey(0))
    assert state.params["mlp/~/linear_0"]["w"].shape == (1 + K, 8)  # x dropped from the input
    tr = _transitions(6, np.arange(6) % K, np.zeros((6, 2)), np.ones((6, 2)))
    r, _ = module.reward(state, tr, jax.random.PRNGKey(0))
    assert r.shape == (6,) and bool(jnp.all(r <= math.log(16) + 1e-5))
    with pytest.raises(ValueError, match=r"skills\.omit_input_dims"):
        make_dads_module(DADSConfig(num_skills=K, omit_input_dims=(5,)), 3, 2)


@pytest.mark.parametrize("learn_variance", [False, True])
def test_factored_pass_matches_the_network_on_one_hot_inputs(learn_variance: bool) -> None:
    # skill_dynamics_outputs shares the first layer's state part between skills; it must
    # give what the network gives on [s; one_hot(z)] for each skill, for any skill list.
    net = skill_dynamics_network(2, 3, (16, 8), "tanh", learn_variance)
    params = net.init(jax.random.PRNGKey(0), jnp.zeros((1, 3)), jnp.zeros((1, K)))
    s = jax.random.normal(jax.random.PRNGKey(1), (5, 3))
    skills = jax.random.randint(jax.random.PRNGKey(2), (5, 7), 0, K)
    for chosen in (skills, None):
        z = jnp.broadcast_to(jnp.arange(K), (5, K)) if chosen is None else chosen
        got = skill_dynamics_outputs(params, s, chosen, "tanh")
        want = net.apply(params, jnp.broadcast_to(s[:, None], (*z.shape, 3)), jax.nn.one_hot(z, K))
        assert got[1].shape == (5, z.shape[1], 3, 2)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(g, w, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("num_alt", [0, 3])
def test_dads_reward_matches_a_pass_per_skill(num_alt: int) -> None:
    # The reward as first written: one pass of the network per skill, one-hot inputs, and
    # the played skill's likelihood from a pass of its own.
    cfg = DADSConfig(num_skills=K, hidden=(16, 16), num_alt_skills=num_alt)
    module = make_dads_module(cfg, 3, 2)
    state = module.init(jax.random.PRNGKey(0))
    rng = np.random.default_rng(1)
    desc = rng.normal(size=(9, 2)).astype(np.float32)
    tr = _transitions(9, np.arange(9) % K, desc, desc + rng.normal(size=(9, 2)))
    # Moments as after some training, so the targets are normalised.
    state = state._replace(moments=RunningMoments(jnp.array([0.1, -0.2]), jnp.array([0.5, 2.0]),
                                                  jnp.array(100.0)))
    net = skill_dynamics_network(2, cfg.num_components, cfg.hidden, cfg.activation, False)
    x = normalize(state.moments, tr.next_desc - tr.desc)

    def log_q(z: jnp.ndarray) -> jnp.ndarray:
        return mixture_log_prob(*net.apply(state.params, tr.desc, jax.nn.one_hot(z, K)), x)

    key = jax.random.PRNGKey(3)
    alt = (jnp.broadcast_to(jnp.arange(K), (9, K)) if num_alt == 0
           else jax.random.randint(key, (9, num_alt), 0, K, jnp.int32))
    log_alt = jnp.stack([log_q(alt[:, i]) for i in range(alt.shape[1])], axis=1)
    played = log_q(skill_of(tr.obs, K))
    r, info = module.reward(state, tr, key)
    np.testing.assert_allclose(r, dads_reward(played, log_alt), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(info["dynamics_log_likelihood"], played, rtol=1e-5, atol=1e-5)


def test_dads_module_update_is_a_maximum_likelihood_step() -> None:
    # One update: the moments see the batch, then one Adam step on -mean log q under them.
    cfg = DADSConfig(num_skills=K, hidden=(8,), learning_rate=1e-2)
    module = make_dads_module(cfg, 3, 2)
    state = module.init(jax.random.PRNGKey(0))
    desc = np.random.default_rng(0).normal(size=(6, 2)).astype(np.float32)
    tr = _transitions(6, np.arange(6) % K, desc, 2.0 * desc)
    new_state, metrics = module.update(state, tr, jax.random.PRNGKey(1))
    moments = update_moments(state.moments, tr.next_desc - tr.desc)
    np.testing.assert_allclose(new_state.moments.mean, np.mean(desc, 0), rtol=1e-5)
    net = skill_dynamics_network(2, cfg.num_components, cfg.hidden, cfg.activation, False)
    x = normalize(moments, tr.next_desc - tr.desc)

    def loss(params: dict) -> jnp.ndarray:  # type: ignore[type-arg]
        out = net.apply(params, tr.desc, jax.nn.one_hot(skill_of(tr.obs, K), K))
        return -jnp.mean(mixture_log_prob(*out, x))

    np.testing.assert_allclose(metrics["dynamics_loss"], loss(state.params), rtol=1e-5)
    # Adam's first step moves every weight by lr * sign(gradient) (up to its epsilon).
    grads = jax.grad(loss)(state.params)
    w = "mlp/~/linear_0"
    step = new_state.params[w]["w"] - state.params[w]["w"]
    nonzero = np.abs(np.asarray(grads[w]["w"])) > 1e-4  # where Adam's epsilon is negligible
    assert nonzero.sum() > 10
    np.testing.assert_allclose(np.asarray(step)[nonzero],
                               -1e-2 * np.sign(np.asarray(grads[w]["w"]))[nonzero], rtol=1e-3)


# -- SMERL, relabelling and the trajectory buffer ---------------------------------------


def test_smerl_gate_on_constructed_batch() -> None:
    gate = smerl_gate(target=100.0, margin=10.0)
    returns = jnp.array([120.0, 90.0, 89.9, jnp.nan, -5.0])
    np.testing.assert_array_equal(gate(returns), [1.0, 1.0, 0.0, 0.0, 0.0])
    r = relabel(jnp.full(5, 2.0), jnp.full(5, 0.5), 4.0, 1.0, gate(returns))
    np.testing.assert_allclose(r, [4.0, 4.0, 2.0, 2.0, 2.0])


def test_intrinsic_agent_relabels_the_batch_sac_sees() -> None:
    # A constant intrinsic reward of 3 and an agent that records the reward it gets.
    seen = []

    def agent_update(state, transitions, key):  # type: ignore[no-untyped-def]
        seen.append(transitions.reward)
        return state, {}

    from qdrl.agents.base import Agent

    inner = Agent(lambda k: 0, lambda s, o, k: o, lambda p, o: o, lambda s: s, agent_update)
    module = RewardModule(
        init=lambda k: jnp.zeros(()),
        reward=lambda a, t, k: (jnp.full(t.reward.shape, 3.0), {}),
        update=lambda a, t, k: (a + 1.0, {"aux_steps": a + 1.0}),
    )
    tr = _transitions(3, np.zeros(3, int), np.zeros((3, 2)), np.zeros((3, 2)))
    agent = with_intrinsic_reward(inner, module, diversity_scale=2.0, extrinsic_scale=0.5,
                                  gate=smerl_gate(0.0, 0.0))
    state = agent.init(jax.random.PRNGKey(0))
    state, metrics = agent.update(state, (tr, jnp.array([1.0, -1.0, jnp.nan])), jax.random.PRNGKey(0))
    # reward = 0.5 * [0, 1, 2] + 2 * 3 * gate, gate = [1, 0, 0]
    np.testing.assert_allclose(seen[0], [6.0, 0.5, 1.0])
    assert float(state.aux) == 1.0 and float(metrics["gate_open"]) == pytest.approx(1 / 3)


def test_model_trains_every_nth_update_and_reports_nan_between() -> None:
    # A model that counts its steps, trained on updates 0, 3 and 6 of 7 (every 3rd).
    from qdrl.agents.base import Agent

    inner = Agent(lambda k: 0, lambda s, o, k: o, lambda p, o: o, lambda s: s,
                  lambda s, t, k: (s, {"agent_loss": jnp.ones(())}))
    module = RewardModule(
        init=lambda k: jnp.zeros(()),
        reward=lambda a, t, k: (jnp.zeros(t.reward.shape), {}),
        update=lambda a, t, k: (a + 1.0, {"model_loss": a + 1.0}),
    )
    agent = with_intrinsic_reward(inner, module, model_update_every=3)
    tr = _transitions(2, np.zeros(2, int), np.zeros((2, 2)), np.zeros((2, 2)))
    state = agent.init(jax.random.PRNGKey(0))
    update = jax.jit(agent.update)
    losses = []
    for i in range(7):
        state, metrics = update(state, tr, jax.random.PRNGKey(i))
        losses.append(float(metrics["model_loss"]))
    assert float(state.aux) == 3.0 and int(state.steps) == 7
    np.testing.assert_array_equal(losses, [1.0, np.nan, np.nan, 2.0, np.nan, np.nan, 3.0])
    assert DADSConfig().model_update_every == 8 and DIAYNConfig().model_update_every == 1
    with pytest.raises(ValueError, match="model_update_every"):
        with_intrinsic_reward(inner, module, model_update_every=0)


def test_trajectory_buffer_knows_episode_returns() -> None:
    buf = buffers.trajectory_init({"t": jnp.zeros((), jnp.int32)}, capacity=16, num_envs=2)
    # env 0: episodes of 2 steps with reward 1 each step -> return 2; env 1 one episode of 4.
    for t in range(4):
        done = jnp.array([t % 2 == 1, t == 3], jnp.float32)
        ret = jnp.array([2.0 if t % 2 == 1 else jnp.nan, 40.0 if t == 3 else jnp.nan])
        items = {"t": jnp.array([10 * t, 10 * t + 1], jnp.int32)}
        buf = buffers.trajectory_insert(buf, items, done, ret)
    # one more step: env 0's third episode is running
    buf = buffers.trajectory_insert(buf, {"t": jnp.array([40, 41], jnp.int32)},
                                    jnp.zeros(2), jnp.zeros(2))
    items, returns = buffers.trajectory_sample(buf, jax.random.PRNGKey(0), 200)
    by_item = dict(zip(np.asarray(items["t"]).tolist(), np.asarray(returns).tolist(), strict=True))
    assert int(buf.size) == 10 and len(by_item) == 10
    for t in range(4):
        assert by_item[10 * t] == 2.0 and by_item[10 * t + 1] == 40.0
    assert math.isnan(by_item[40]) and math.isnan(by_item[41])
    assert int(buf.next_id) == 5  # 2 initial ids + 3 finished episodes


def test_trajectory_buffer_stale_slot_reads_nan() -> None:
    # A table of capacity + num_envs = 3 slots: env 1's episode outlives 3 episodes of env 0,
    # whose ids reuse its slot; its transitions must then read NaN, not another's return.
    buf = buffers.trajectory_init(jnp.zeros(()), capacity=2, num_envs=1)
    buf = buf._replace(episode_ids=jnp.array([0]), next_id=jnp.array(1))
    for t in range(4):
        buf = buffers.trajectory_insert(buf, jnp.array([float(t)]), jnp.ones(1), jnp.array([t]))
    # episode ids 0..3; id 3 uses slot 0 again (table 3): only ids 1..3 known, item 0 evicted
    _, returns = buffers.trajectory_sample(buf, jax.random.PRNGKey(0), 50)
    assert set(np.asarray(returns).tolist()) == {2.0, 3.0}


# -- environment, loop, and a tiny run ----------------------------------------------------


def test_skill_env_appends_a_fixed_skill_per_episode() -> None:
    base = PointMazeEnv(episode_length=3)
    env = SkillEnv(base, K)
    assert env.observation_size == base.observation_size + K
    states = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 64))
    skills = skill_of(states.obs, K)
    assert set(np.asarray(skills).tolist()) == set(range(K))
    np.testing.assert_array_equal(strip_skill(states.obs, K), states.desc)
    stepped = jax.vmap(env.step)(states, jnp.ones((64, 2)))
    np.testing.assert_array_equal(skill_of(stepped.obs, K), skills)


def test_default_storage_is_the_ring_buffer() -> None:
    env = PointMazeEnv(episode_length=10)
    sac = make_sac(SACConfig(hidden=(8,)), env.observation_size, env.action_size)
    cfg = TrainConfig(total_env_steps=64, num_envs=4, batch_size=8, buffer_size=64,
                      learning_starts=8, grad_steps_per_iter=1, eval_every=32, num_eval_envs=4)
    a = make_trainer(env, sac, cfg)
    b = make_trainer(env, sac, cfg, off_policy.REPLAY)
    sa, _ = jax.jit(a.run_chunk)(a.init(jax.random.PRNGKey(0)))
    sb, _ = jax.jit(b.run_chunk)(b.init(jax.random.PRNGKey(0)))
    assert isinstance(sa.buffer, buffers.ReplayBuffer)
    for x, y in zip(jax.tree.leaves(sa), jax.tree.leaves(sb), strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("algo", ["diayn", pytest.param("dads", marks=pytest.mark.slow)])  # the gate is DIAYN's or DADS's alike
def test_smerl_trains_through_the_loop_with_episode_returns(algo: str) -> None:
    base = PointMazeEnv(episode_length=10)
    env = SkillEnv(base, K)
    sac = make_sac(SACConfig(hidden=(16,)), env.observation_size, env.action_size)
    skills = (DIAYNConfig if algo == "diayn" else DADSConfig)(
        num_skills=K, hidden=(16,), extrinsic_scale=1.0
    )
    # Every return of the point maze in 10 steps is above -30: the gate is always open.
    agent = make_smerl(sac, algo, skills, SMERLConfig(target=-20.0, margin=10.0), 2, 2)  # type: ignore[arg-type]
    cfg = TrainConfig(total_env_steps=160, num_envs=4, batch_size=16, buffer_size=160,
                      learning_starts=40, grad_steps_per_iter=1, eval_every=80, num_eval_envs=4)
    trainer = make_trainer(env, agent, cfg, off_policy.EPISODE_RETURNS)
    state, metrics = jax.jit(trainer.run_chunk)(trainer.init(jax.random.PRNGKey(0)))
    assert isinstance(state.buffer, buffers.TrajectoryBuffer) and int(state.buffer.size) == 80
    # 8 finished episodes per env... 80 steps / 4 envs = 20 steps = 2 episodes per env.
    assert int(state.buffer.next_id) == 4 + 8
    gate_open = float(metrics["gate_open"])
    # the transitions of finished episodes pass the gate, the running ones read NaN
    assert 0.0 < gate_open <= 1.0
    assert np.isfinite(float(metrics["critic_loss"]))
    # DADS's model trains on one update in 8: the chunk still reports its loss.
    model_loss = "discriminator_loss" if algo == "diayn" else "dynamics_loss"
    assert np.isfinite(float(metrics[model_loss]))


@pytest.mark.slow  # learning: the skill model's accuracy after training
def test_diayn_tiny_run_discriminates_skills() -> None:
    """DIAYN on the open point maze: the discriminator separates 4 skills well above chance."""
    base = PointMazeEnv(episode_length=20, walls=())
    env = SkillEnv(base, K)
    sac = make_sac(SACConfig(hidden=(64, 64), learn_alpha=False, init_alpha=0.1),
                   env.observation_size, env.action_size)
    agent = make_diayn(sac, DIAYNConfig(num_skills=K, hidden=(32, 32), learning_rate=1e-3), 2, 2)
    cfg = TrainConfig(total_env_steps=6_000, num_envs=8, batch_size=128, buffer_size=10_000,
                      learning_starts=400, grad_steps_per_iter=8, eval_every=1_000,
                      num_eval_envs=8)
    trainer = make_trainer(env, agent, cfg)
    run = jax.jit(trainer.run_chunk)
    state = trainer.init(jax.random.PRNGKey(0))
    accuracies = []
    for _ in range(cfg.num_chunks):
        state, metrics = run(state)
        accuracies.append(float(metrics["discriminator_accuracy"]))
    assert accuracies[-1] > 0.6, accuracies  # chance is 0.25


def test_reverse_smerl_gates_the_task_reward_instead() -> None:
    task, div = jnp.array([1.0, 2.0, 3.0]), jnp.array([10.0, 20.0, 30.0])
    gate = jnp.array([1.0, 0.0, 1.0])  # episodes at or above target - margin
    # SMERL: r = c r_task + lambda g r_div; Reverse SMERL: r = c (1 - g) r_task + lambda r_div
    np.testing.assert_allclose(relabel(task, div, 0.5, 2.0, gate), [2 + 5, 4 + 0, 6 + 15])
    np.testing.assert_allclose(relabel(task, div, 0.5, 2.0, gate, reverse=True), [0 + 5, 4 + 10, 0 + 15])
    np.testing.assert_allclose(relabel(task, div, 0.5, 2.0, None, reverse=True), [2 + 5, 4 + 10, 6 + 15])


def test_continuous_diayn_reward_is_the_gaussian_log_likelihood_plus_log_of_the_box() -> None:
    # discriminator output: mean (0.5, -0.5) and a raw log std whose mapped value is log sigma
    out = jnp.array([[0.5, -0.5, 0.0, 0.0]])
    log_sigma = -5.0 + 0.5 * 7.0 * (math.tanh(0.0) + 1.0)  # LOG_STD_MIN + ... = -1.5
    z = jnp.array([[0.2, 0.1]])
    sigma = math.exp(log_sigma)
    by_hand = sum(
        -0.5 * ((zi - mi) / sigma) ** 2 - log_sigma - 0.5 * math.log(2 * math.pi)
        for zi, mi in ((0.2, 0.5), (0.1, -0.5))
    ) + 2 * math.log(2.0)
    assert float(gaussian_diayn_reward(out, z)[0]) == pytest.approx(by_hand, rel=1e-5)


def test_continuous_diayn_discriminator_learns_a_skill_from_its_state() -> None:
    """States that are a fixed function of z: the log-likelihood of z given s' rises by training."""
    config = DIAYNConfig(num_skills=2, continuous=True, hidden=(32, 32), learning_rate=3e-3)
    module = make_diayn_module(config, obs_size=3, descriptor_size=2)
    state = module.init(jax.random.PRNGKey(0))
    z = jax.random.uniform(jax.random.PRNGKey(1), (256, 2), minval=-1.0, maxval=1.0)
    obs = jnp.concatenate([jnp.zeros((256, 3)), z], axis=-1)
    desc = jnp.stack([z[:, 0] + z[:, 1], z[:, 0] - z[:, 1]], axis=-1)
    zeros = jnp.zeros((256,))
    tr = Transition(obs, jnp.zeros((256, 1)), zeros, obs, zeros, zeros, desc, desc)
    step = jax.jit(module.reward_and_update)  # type: ignore[arg-type]
    first, info, state, _ = step(state, tr, jax.random.PRNGKey(2), jax.random.PRNGKey(3))
    assert "discriminator_log_likelihood" in info
    for i in range(300):
        last, _, state, _ = step(state, tr, jax.random.PRNGKey(i), jax.random.PRNGKey(i))
    assert float(jnp.mean(last)) > float(jnp.mean(first)) + 2.0
