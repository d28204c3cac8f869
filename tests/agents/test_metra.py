"""METRA / LSD: losses, dual variable and reward against hand-computed values, the centred discrete
skills, training that meets the temporal-distance constraint, LSD's 1-Lipschitz phi, config checks."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.typing import ArrayLike

from qdrl.agents.metra import (
    METRAConfig,
    centred_skill,
    constraint_penalty,
    dual_loss,
    make_metra,
    make_metra_module,
    metra_reward,
    representation_loss,
    representation_network,
    sample_unit_skill,
    squared_step,
)
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.envs.skills import append_skill
from qdrl.types import Transition

VARIANTS: list[Callable[[Any], Any]] = [lambda f: f, jax.jit]
VARIANT_IDS = ["eager", "jit"]

# A tiny batch with a hand-set linear phi(x) = x W + b, W = diag(1, 2), on 2-D descriptors.
W = np.array([[1.0, 0.0], [0.0, 2.0]], np.float32)
B = np.array([0.5, -1.0], np.float32)  # cancels in phi(s') - phi(s)
S = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]], np.float32)
S_NEXT = np.array([[0.6, 0.0], [1.0, 2.0], [0.5, 1.5]], np.float32)
Z = np.array([[1.0, 0.0], [0.0, 1.0], [0.6, 0.8]], np.float32)
# phi(s') - phi(s) = (0.6, 0), (0, 2), (0.5, 1): r = 0.6, 2, 1.1; ||.||^2 = 0.36, 4, 1.25;
# penalty min(1e-3, 1 - ||.||^2) = 1e-3, -3, -0.25.
R = np.array([0.6, 2.0, 1.1])
SQ = np.array([0.36, 4.0, 1.25])
PENALTY = np.array([1e-3, -3.0, -0.25])
# -(mean(r) + 30 mean(penalty)) = -((0.6 + 2 + 1.1) + 30 (1e-3 - 3 - 0.25)) / 3
REP_LOSS = -((0.6 + 2.0 + 1.1) + 30.0 * (1e-3 - 3.0 - 0.25)) / 3.0  # 31.2566...
DUAL_LOSS = math.log(30.0) * (1e-3 - 3.0 - 0.25) / 3.0


def _transitions(
    env_obs: ArrayLike,
    next_env_obs: ArrayLike,
    z: ArrayLike,
    desc: ArrayLike,
    next_desc: ArrayLike,
) -> Transition:
    """A batch whose observations are `concat(env_obs, z)`."""
    code = jnp.asarray(z, jnp.float32)
    n = code.shape[0]
    zero = jnp.zeros((n,))
    return Transition(
        obs=jnp.concatenate([jnp.asarray(env_obs, jnp.float32), code], axis=-1),
        action=jnp.zeros((n, 2)),
        reward=zero,
        next_obs=jnp.concatenate([jnp.asarray(next_env_obs, jnp.float32), code], axis=-1),
        terminated=zero,
        truncated=zero,
        desc=jnp.asarray(desc, jnp.float32),
        next_desc=jnp.asarray(next_desc, jnp.float32),
    )


def _hand_batch() -> Transition:
    return _transitions(np.zeros((3, 3)), np.zeros((3, 3)), Z, S, S_NEXT)


def _linear_module(**kwargs: Any) -> tuple[Any, Any]:
    """The module with phi = the hand-set linear layer (no hidden layer), on descriptors."""
    config = METRAConfig(hidden=(), model_input="descriptor", **kwargs)
    module = make_metra_module(config, 3, 2)
    state = module.init(jax.random.PRNGKey(0))
    params = {"linear_0": {"w": jnp.asarray(W), "b": jnp.asarray(B)}}
    return module, state._replace(params=params, opt_state=state.opt_state)


@pytest.mark.parametrize("variant", VARIANTS, ids=VARIANT_IDS)
def test_losses_and_reward_by_hand(variant: Callable[[Any], Any]) -> None:
    phi_s, phi_next = jnp.asarray(S @ W + B), jnp.asarray(S_NEXT @ W + B)
    z = jnp.asarray(Z)
    np.testing.assert_allclose(variant(metra_reward)(phi_s, phi_next, z), R, rtol=1e-6)
    np.testing.assert_allclose(variant(squared_step)(phi_s, phi_next), SQ, rtol=1e-6)
    penalty = variant(constraint_penalty)(phi_s, phi_next, 1e-3)
    np.testing.assert_allclose(penalty, PENALTY, rtol=1e-6)
    loss = variant(representation_loss)(phi_s, phi_next, z, 30.0, 1e-3)
    np.testing.assert_allclose(loss, REP_LOSS, rtol=1e-6)
    np.testing.assert_allclose(variant(dual_loss)(jnp.log(30.0), penalty), DUAL_LOSS, rtol=1e-6)
    # LSD: lambda = 0 leaves -E[r]
    lsd = variant(representation_loss)(phi_s, phi_next, z, 0.0, 1e-3)
    np.testing.assert_allclose(lsd, -R.mean(), rtol=1e-6)
    # the authors' code measures the step by its mean square over the d = 2 dimensions:
    # 0.18, 2, 0.625 -> penalty 1e-3, -1, 1e-3
    per_dim = variant(functools.partial(constraint_penalty, mean_over_dims=True))(
        phi_s, phi_next, 1e-3
    )
    np.testing.assert_allclose(per_dim, [1e-3, -1.0, 1e-3], rtol=1e-6)


def test_loss_gradients_flow_to_phi_only_through_reward_and_penalty() -> None:
    # lambda and the dual's penalty are not differentiated: d loss / d lambda = 0 and the dual
    # loss's gradient in phi is 0; its gradient in log lambda is the mean penalty.
    phi_s, phi_next, z = jnp.asarray(S @ W), jnp.asarray(S_NEXT @ W), jnp.asarray(Z)
    g_lam = jax.grad(lambda lam: representation_loss(phi_s, phi_next, z, lam, 1e-3))(30.0)
    assert float(g_lam) == 0.0

    def dual_of(phi_next: jax.Array) -> jax.Array:
        return dual_loss(jnp.log(30.0), constraint_penalty(phi_s, phi_next, 1e-3))

    assert float(jnp.abs(jax.grad(dual_of)(phi_next)).max()) == 0.0
    g_log = jax.grad(dual_loss)(jnp.log(30.0), jnp.asarray(PENALTY))
    np.testing.assert_allclose(g_log, PENALTY.mean(), rtol=1e-6)


@pytest.mark.parametrize("variant", VARIANTS, ids=VARIANT_IDS)
def test_module_step_by_hand(variant: Callable[[Any], Any]) -> None:
    lr, dual_lr = 1e-4, 1e-3
    module, state = _linear_module(learning_rate=lr, dual_learning_rate=dual_lr)
    tr = _hand_batch()
    key = jax.random.PRNGKey(1)
    r, info = variant(module.reward)(state, tr, key)
    np.testing.assert_allclose(r, R, rtol=1e-6)
    np.testing.assert_allclose(info["phi_step_sq"], SQ, rtol=1e-6)
    r1, info1, new, metrics = variant(module.reward_and_update)(state, tr, key, key)
    np.testing.assert_allclose(r1, R, rtol=1e-6)  # the reward of the parameters before the step
    np.testing.assert_allclose(info1["phi_step_sq"], SQ, rtol=1e-6)
    np.testing.assert_allclose(metrics["representation_loss"], REP_LOSS, rtol=1e-6)
    np.testing.assert_allclose(metrics["dual_loss"], DUAL_LOSS, rtol=1e-5)
    np.testing.assert_allclose(metrics["dual_lambda"], 30.0, rtol=1e-6)
    np.testing.assert_allclose(metrics["phi_delta_dot_z"], R.mean(), rtol=1e-6)
    np.testing.assert_allclose(metrics["phi_step_sq_max"], 4.0, rtol=1e-6)
    # d loss / dW = -(1/3) sum_i [ds_i^T z_i - 2 lambda [penalty active] ds_i^T dphi_i]
    #            = [[4.7, 9.8667], [4.9, 49.5333]]: all positive, so Adam's first step (lr times
    # the gradient's sign) lowers every entry by lr. b's gradient is 0 up to rounding (b cancels
    # in phi(s') - phi(s)), which Adam's normalisation may blow up to a step of at most lr.
    np.testing.assert_allclose(new.params["linear_0"]["w"], W - lr, rtol=0, atol=1e-8)
    np.testing.assert_allclose(new.params["linear_0"]["b"], B, rtol=0, atol=1.001 * lr)
    # the mean penalty is negative (violated): log lambda rises by dual_lr
    np.testing.assert_allclose(new.log_lambda, math.log(30.0) + dual_lr, rtol=1e-6)
    new2, metrics2 = variant(module.update)(state, tr, key)  # `update` is the same step
    for a, b in zip(jax.tree.leaves(new2), jax.tree.leaves(new), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6)
    assert set(metrics2) == set(metrics)


def test_dual_lambda_rises_when_violated_and_falls_with_slack() -> None:
    module, state = _linear_module(learning_rate=1e-8, dual_learning_rate=1e-2)
    rng = np.random.default_rng(0)
    s = rng.normal(size=(32, 2)).astype(np.float32)
    z = np.asarray(sample_unit_skill(jax.random.PRNGKey(0), (32,), 2))
    tr = _transitions(np.zeros((32, 3)), np.zeros((32, 3)), z, s, s + z)  # unit steps
    update = jax.jit(module.update)
    for scale, rises in ((3.0, True), (0.1, False)):  # ||dphi||^2 = 9 or 0.01 for unit steps
        st = state._replace(params={"linear_0": {"w": scale * jnp.eye(2), "b": jnp.zeros(2)}})
        lams = [float(jnp.exp(st.log_lambda))]
        for _ in range(5):
            st, _ = update(st, tr, jax.random.PRNGKey(0))
            lams.append(float(jnp.exp(st.log_lambda)))
        steps = np.diff(lams)
        assert np.all(steps > 0) if rises else np.all(steps < 0), (scale, lams)


def test_training_meets_the_constraint_while_the_reward_grows() -> None:
    # States anywhere in the plane, each skill z a unit vector stepping the state by z: the best
    # phi is an isometry along the steps, (phi(s') - phi(s))^T z = 1 with ||dphi||^2 = 1.
    config = METRAConfig(
        num_skills=2,
        hidden=(64, 64),
        model_input="descriptor",
        learning_rate=3e-4,
        dual_learning_rate=1e-3,
    )
    module = make_metra_module(config, 1, 2)

    def batch(key: jax.Array) -> Transition:
        s_key, z_key = jax.random.split(key)
        s = jax.random.uniform(s_key, (256, 2), minval=-5.0, maxval=5.0)
        z = sample_unit_skill(z_key, (256,), 2)
        zero = jnp.zeros((256, 1))
        return _transitions(zero, zero, z, s, s + z)

    def step(state: Any, key: jax.Array) -> tuple[Any, Any]:
        return module.update(state, batch(key), key)

    @jax.jit
    def train(state: Any, key: jax.Array) -> tuple[Any, Any]:
        return jax.lax.scan(step, state, jax.random.split(key, 400))

    state = module.init(jax.random.PRNGKey(0))
    eval_batch = batch(jax.random.PRNGKey(123))
    r0, _ = module.reward(state, eval_batch, jax.random.PRNGKey(0))
    state, metrics = train(state, jax.random.PRNGKey(1))
    r, info = module.reward(state, eval_batch, jax.random.PRNGKey(0))
    assert float(jnp.mean(r)) > 0.9 > float(jnp.mean(r0)) + 0.5, (
        float(jnp.mean(r0)),
        float(jnp.mean(r)),
    )
    assert float(jnp.max(info["phi_step_sq"])) <= 1.05, float(jnp.max(info["phi_step_sq"]))
    assert float(jnp.max(metrics["phi_step_sq_max"][-50:])) <= 1.05
    assert np.all(np.isfinite(np.asarray(metrics["dual_lambda"])))


def _lipschitz_ratio(apply: Callable[[jax.Array], jax.Array], key: jax.Array, size: int) -> float:
    """max ||phi(x) - phi(y)|| / ||x - y|| over random pairs, near and far."""
    kx, ky, ks = jax.random.split(key, 3)
    x = 3.0 * jax.random.normal(kx, (2000, size))
    scale = jnp.exp(jax.random.uniform(ks, (2000, 1), minval=-6.0, maxval=1.0))
    y = x + scale * jax.random.normal(ky, (2000, size))
    ratio = jnp.linalg.norm(apply(x) - apply(y), axis=-1) / jnp.linalg.norm(x - y, axis=-1)
    return float(jnp.max(ratio))


def _converged_net_state(network: Any, params: Any, net_state: Any, size: int) -> Any:
    """The spectral-norm state after 50 more power-iteration steps on fixed weights."""
    for _ in range(50):
        _, net_state = network.apply(params, net_state, jnp.zeros((1, size)))
    return net_state


def test_lsd_trains_phi_without_dual_and_phi_is_1_lipschitz() -> None:
    config = METRAConfig(
        num_skills=2, hidden=(32, 32), model_input="full", lsd=True, learning_rate=1e-3
    )
    module = make_metra_module(config, 3, 2)
    state = module.init(jax.random.PRNGKey(0))
    assert set(state.net_state) == {f"linear_{i}/spectral_norm" for i in range(3)}
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(128, 3)).astype(np.float32)
    z = np.asarray(sample_unit_skill(jax.random.PRNGKey(1), (128,), 2))
    tr = _transitions(
        obs, obs + rng.normal(size=(128, 3)).astype(np.float32), z, obs[:, :2], obs[:, :2]
    )
    update = jax.jit(module.update)
    r0, _ = module.reward(state, tr, jax.random.PRNGKey(0))
    for _ in range(100):  # phi trains; each update takes one power-iteration step per layer
        state, metrics = update(state, tr, jax.random.PRNGKey(0))
    assert set(metrics) == {"representation_loss", "phi_delta_dot_z", "phi_step_sq_max"}
    np.testing.assert_allclose(state.log_lambda, math.log(config.dual_init), rtol=1e-6)
    r, _ = module.reward(state, tr, jax.random.PRNGKey(0))
    assert float(jnp.mean(r)) > float(jnp.mean(r0)) + 0.05  # LSD's loss is -E[r]
    # Each layer's weight over its estimated norm has spectral norm 1 once the power
    # iteration has converged, so phi's Lipschitz bound, their product, is 1.
    network = representation_network(2, config.hidden, config.activation, spectral_norm=True)
    net_state = _converged_net_state(network, state.params, state.net_state, 3)
    bound = 1.0
    for name, layer_state in net_state.items():
        w = np.asarray(state.params[name.split("/")[0]]["w"])
        bound *= np.linalg.svd(w, compute_uv=False)[0] / float(layer_state["sigma"])
    np.testing.assert_allclose(bound, 1.0, rtol=1e-3)

    def phi(x: jax.Array) -> jax.Array:
        return network.apply(state.params, net_state, x)[0]

    assert _lipschitz_ratio(jax.jit(phi), jax.random.PRNGKey(2), 3) <= 1.0 + 1e-3


def test_spectrally_normalised_linear_phi_is_an_exact_contraction() -> None:
    # A linear phi attains its Lipschitz constant ||W|| / sigma: random pairs reach it, whatever
    # the weights' scale; without the normalisation the same weights stretch distances 100-fold.
    network = representation_network(3, (), spectral_norm=True)
    params, net_state = network.init(jax.random.PRNGKey(0), jnp.zeros((1, 4)))
    params = jax.tree.map(lambda p: 100.0 * p, params)
    net_state = _converged_net_state(network, params, net_state, 4)

    def phi(x: jax.Array) -> jax.Array:
        return network.apply(params, net_state, x)[0]

    assert 0.95 <= _lipschitz_ratio(jax.jit(phi), jax.random.PRNGKey(1), 4) <= 1.0 + 1e-3
    plain = representation_network(3, ())
    assert (
        _lipschitz_ratio(lambda x: plain.apply(params, {}, x)[0], jax.random.PRNGKey(1), 4) > 10.0
    )


def test_discrete_skills_are_centred_one_hots() -> None:
    one_hot = jax.nn.one_hot(jnp.array([2, 0]), 4)
    expected = np.array([[-1 / 3, -1 / 3, 1.0, -1 / 3], [1.0, -1 / 3, -1 / 3, -1 / 3]])
    np.testing.assert_allclose(centred_skill(one_hot), expected, rtol=1e-6)
    np.testing.assert_allclose(jnp.sum(centred_skill(one_hot), axis=-1), 0.0, atol=1e-6)
    np.testing.assert_allclose(centred_skill(jax.nn.one_hot(jnp.array([1]), 2)), [[-1.0, 1.0]])
    # the module reads the one-hot as SkillEnv appends it: r = dphi^T centred(z)
    config = METRAConfig(num_skills=4, discrete=True, hidden=(), model_input="full")
    module = make_metra_module(config, 3, 2)
    state = module.init(jax.random.PRNGKey(0))
    w = jnp.arange(12.0).reshape(3, 4) / 10.0
    state = state._replace(params={"linear_0": {"w": w, "b": jnp.ones(4)}})
    env_obs = np.array([[0.0, 0.0, 0.0], [1.0, -1.0, 2.0]], np.float32)
    next_env_obs = env_obs + np.array([[1.0, 0.0, 0.0], [0.0, 0.5, -1.0]], np.float32)
    skills = jnp.array([2, 0])
    tr = Transition(
        obs=append_skill(jnp.asarray(env_obs), skills, 4),
        action=jnp.zeros((2, 1)),
        reward=jnp.zeros(2),
        next_obs=append_skill(jnp.asarray(next_env_obs), skills, 4),
        terminated=jnp.zeros(2),
        truncated=jnp.zeros(2),
        desc=jnp.zeros((2, 2)),
        next_desc=jnp.zeros((2, 2)),
    )
    r, info = jax.jit(module.reward)(state, tr, jax.random.PRNGKey(0))
    dphi = (next_env_obs - env_obs) @ np.asarray(
        w
    )  # rows (0, .1, .2, .3) and (-.6, -.65, -.7, -.75)
    np.testing.assert_allclose(r, np.sum(dphi * expected, axis=-1), rtol=1e-5)
    np.testing.assert_allclose(r, [0.2 - 0.4 / 3, -0.6 + 2.1 / 3], rtol=1e-5)
    np.testing.assert_allclose(info["phi_step_sq"], np.sum(dphi**2, axis=-1), rtol=1e-5)


def test_sample_unit_skill() -> None:
    z = sample_unit_skill(jax.random.PRNGKey(0), (5, 7), 3)
    assert z.shape == (5, 7, 3)
    np.testing.assert_allclose(jnp.linalg.norm(z, axis=-1), 1.0, rtol=1e-5)
    many = sample_unit_skill(jax.random.PRNGKey(1), (4000,), 2)
    np.testing.assert_allclose(jnp.mean(many, axis=0), 0.0, atol=0.05)  # no preferred direction


def test_full_input_reads_obs_without_skill_and_shapes_are_checked() -> None:
    module = make_metra_module(METRAConfig(num_skills=2, hidden=(8,)), 3, 5)
    state = module.init(jax.random.PRNGKey(0))
    assert state.params["linear_0"]["w"].shape == (3, 8)
    assert state.params["linear_1"]["w"].shape == (8, 2)
    z = np.asarray(sample_unit_skill(jax.random.PRNGKey(0), (4,), 2))
    obs = np.ones((4, 3), np.float32)
    tr = _transitions(obs, obs, z, np.zeros((4, 5)), np.ones((4, 5)))
    r, _ = module.reward(state, tr, jax.random.PRNGKey(0))
    np.testing.assert_allclose(r, 0.0, atol=1e-6)  # same env obs: no step, whatever the descriptor
    bad = tr._replace(obs=tr.obs[:, 1:])
    with pytest.raises(ValueError, match=r"transitions\.obs: expected 5 entries"):
        module.reward(state, bad, jax.random.PRNGKey(0))


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("num_skills", 0),
        ("learning_rate", -1.0),
        ("dual_init", 0.0),
        ("dual_slack", -1e-3),
        ("dual_learning_rate", 0.0),
        ("model_input", "pixels"),
        ("hidden", (0,)),
        ("activation", "sigmoidal"),
        ("lsd", "yes"),
        ("discrete", 1),
    ],
)
def test_bad_config_refused(field: str, value: Any) -> None:
    config = dataclasses.replace(METRAConfig(), **{field: value})
    with pytest.raises(ValueError, match=rf"skills\.{field}"):
        config.check()
    with pytest.raises(ValueError, match=rf"skills\.{field}"):
        make_metra_module(config, 3, 2)


def test_one_discrete_skill_refused() -> None:
    with pytest.raises(ValueError, match=r"skills\.num_skills: expected at least 2 discrete"):
        make_metra_module(METRAConfig(num_skills=1, discrete=True), 3, 2)
    make_metra_module(
        METRAConfig(num_skills=1, hidden=(4,)), 3, 2
    )  # a 1-D continuous skill is fine


def test_metra_agent_updates_under_jit_and_compiles_once() -> None:
    d, obs_size = 2, 3
    sac = make_sac(SACConfig(hidden=(16, 16)), obs_size + d, 2)
    config = METRAConfig(num_skills=d, hidden=(16, 16))
    agent = make_metra(sac, config, obs_size, 2)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(32, obs_size)).astype(np.float32)
    z = np.asarray(sample_unit_skill(jax.random.PRNGKey(0), (32,), d))
    tr = _transitions(obs, obs + 0.1, z, obs[:, :2], obs[:, :2])
    tr = tr._replace(action=jnp.asarray(rng.uniform(-1, 1, (32, 2)), jnp.float32))
    traces = []

    def update(state: Any, batch: Transition, key: jax.Array) -> Any:
        traces.append(1)
        return agent.update(state, batch, key)

    update_jit = jax.jit(update)
    state = agent.init(jax.random.PRNGKey(0))
    for i in range(3):
        state, metrics = update_jit(state, tr, jax.random.PRNGKey(i))
    assert len(traces) == 1
    for name in (
        "representation_loss",
        "dual_loss",
        "dual_lambda",
        "phi_delta_dot_z",
        "phi_step_sq",
        "intrinsic_reward",
        "critic_loss",
    ):
        assert np.isfinite(float(metrics[name])), name
    # the relabelled reward is (phi(s') - phi(s))^T z with the parameters before each step
    np.testing.assert_allclose(metrics["intrinsic_reward"], metrics["phi_delta_dot_z"], rtol=1e-6)
