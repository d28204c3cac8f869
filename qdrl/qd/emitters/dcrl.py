"""DCRL-ME's emitter: a descriptor-conditioned critic and actor that steer offspring to descriptors.

Faldor, Chalumeau, Flageat & Cully 2024, "Synergizing Quality-Diversity with
Descriptor-Conditioned Reinforcement Learning" (ACM TELO), as QDax's
`DCRLEmitter` / `DCRLMEEmitter` (defaults of `DCRLConfig` are QDax's `DCRLConfig`).

The emitter holds one TD3 agent (`qdrl.agents.td3`, the project's one TD3) whose
observation is the environment's observation followed by a *target descriptor*
d' (normalised to [-1, 1] by the descriptor bounds): its twin critic is
Q(s, a | d') and its actor, the DC actor, pi(s | d'). The DC actor has the
genotypes' architecture with a wider first layer, so `actor_injection` folds a
target descriptor into the first layer's bias and hands back a plain genotype.

Every evaluated episode is stored in the emitter's one replay buffer, step by
step (with the per-step state descriptors of `Transition`), together with the
episode's observed descriptor d and its target d': the descriptor the emitter
aimed at for its own offspring, the observed one for every other episode (the
GA's, the initial population's). Critic and DC actor train on batches whose
reward is relabelled by the similarity of d to d' (`relabel_reward`):

    r' = S(d, d') max(r + reward_offset, 0),   S(d, d') = exp(-||d - d'||_2 / lengthscale)

(QDax shifts the environment's reward by the task's offset and clips it at 0 so
that a lower similarity always means a lower reward.)

`emit` makes `num_pg` offspring by `num_pg_training_steps` TD3 actor steps
(`td3_actor_step`, fresh Adam moments) on parents drawn from the repertoire,
against the critic conditioned on each parent's own descriptor, and `num_ai`
offspring by "actor injection": the DC actor specialised to descriptors of
elites drawn from the repertoire. Which parents and targets the next `emit` uses
is drawn at the end of `update` (and `init`) and kept in the state, so that
`update` knows the target of each of its own offspring (the `Emitter` protocol
lets `emit` return offspring only; QDax passes them through `extra_scores`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import NamedTuple

import haiku as hk
import jax
import jax.numpy as jnp
import numpy as np
import optax

from qdrl import buffers, nets
from qdrl.agents.base import Agent
from qdrl.agents.td3 import TD3Networks, TD3State, make_td3, td3_actor_step
from qdrl.buffers import ReplayBuffer
from qdrl.config import NonNegativeInt, PositiveFloat, PositiveInt
from qdrl.qd.base import AddResult, Emitter, Evaluation, Repertoire
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.emitters.multi import MultiEmitter, concat_batches
from qdrl.qd.emitters.pg import PGConfig, insert_valid
from qdrl.qd.repertoires.cells import sample_filled_indices
from qdrl.types import Array, Genotype, Params, PRNGKey, Transition


@dataclasses.dataclass(frozen=True)
class DCRLConfig(PGConfig):
    """Hyperparameters of the DCRL emitter; defaults: QDax's `DCRLConfig` (Faldor et al. 2024).

    The TD3 fields are `PGConfig`'s; here `greedy_learning_rate` is the DC actor's
    step size and `policy_learning_rate` the one of the actor steps applied to parents.
    """

    num_critic_training_steps: NonNegativeInt = 3000
    num_pg_training_steps: NonNegativeInt = 150
    training_batch_size: PositiveInt = 100
    # Length scale of the similarity exp(-||d - d'|| / lengthscale), in normalised
    # descriptor units (each dimension spans [-1, 1]).
    lengthscale: PositiveFloat = 0.1
    # Added to every reward before clipping it at 0 and scaling it by the similarity, as
    # QDax wraps the environment in its task's reward offset; None: the task's per-step
    # offset, -qd_offset / episode length (`qdrl.qd.emitters.qd_rl.make_dcrl_me`), else 0.
    reward_offset: float | None = None

    def check(self, section: str = "dcrl") -> None:
        """Raises ValueError naming the first `section.<field>` its declared type refuses."""
        super().check(section)


class DCRLTransition(NamedTuple):
    """A stored step: the environment transition, its episode's descriptor d and its target d'.

    Descriptors are normalised to [-1, 1]; the per-step state descriptors are
    `step.desc` / `step.next_desc`.
    """

    step: Transition
    episode_desc: Array  # (..., D) observed descriptor of the episode the step belongs to
    target_desc: Array  # (..., D) descriptor the episode's policy was emitted for


class DCRLEmitterState(NamedTuple):
    """The DC TD3 agent, its one replay buffer, and the parents and targets of the next `emit`."""

    td3: TD3State  # critic Q(s, a | d'), DC actor pi(s | d'), their targets
    buffer: ReplayBuffer  # DCRLTransition items
    parents: Array  # (num_pg,) int32 repertoire cells of the next PG parents
    targets: Array  # (num_pg + num_ai, D) normalised targets of the next offspring, in order


def similarity(desc: Array, target_desc: Array, lengthscale: float | Array) -> Array:
    """S(d, d') = exp(-||d - d'||_2 / lengthscale) over the last axis (Faldor et al. 2024)."""
    return jnp.exp(-jnp.linalg.norm(desc - target_desc, axis=-1) / lengthscale)


def relabel_reward(
    reward: Array,
    desc: Array,
    target_desc: Array,
    lengthscale: float | Array,
    reward_offset: float | Array = 0.0,
) -> Array:
    """r' = S(d, d') max(r + reward_offset, 0): the reward of reaching d when aiming at d'.

    The clip keeps the relabelled reward monotone in the similarity (a negative
    reward scaled down would *reward* missing the target).
    """
    return similarity(desc, target_desc, lengthscale) * jnp.maximum(reward + reward_offset, 0.0)


def normalise_descriptors(desc: Array, low: Array, high: Array) -> Array:
    """Descriptors mapped linearly from [low, high] to [-1, 1], as the DC networks read them."""
    return 2.0 * (desc - low) / (high - low) - 1.0


def first_layer_name(network: hk.Transformed, obs_size: int, descriptor_size: int) -> str:
    """The module of `network` that reads its input: the only one whose shapes depend on its width.

    Raises ValueError unless exactly one module changes, with a "w" of shape
    (input, hidden) and a "b" (a linear first layer, as `nets.deterministic_policy`).
    """
    key = jax.random.PRNGKey(0)
    plain = jax.eval_shape(network.init, key, jnp.zeros((obs_size,)))
    wide = jax.eval_shape(network.init, key, jnp.zeros((obs_size + descriptor_size,)))
    changed = [
        name
        for name in wide
        if jax.tree.map(lambda x: x.shape, wide[name]) != jax.tree.map(lambda x: x.shape, plain[name])
    ]
    if len(changed) != 1 or set(wide[changed[0]]) != {"w", "b"}:
        raise ValueError(
            "policy_network: expected one linear first layer (params 'w', 'b') reading the "
            f"observation, got input-dependent modules {changed}"
        )
    return changed[0]


def fold_descriptor(dc_params: Params, target_desc: Array, layer: str, obs_size: int) -> Params:
    """The DC actor with `target_desc` (normalised) folded into its first layer: a plain policy.

    W [s; d'] + b = W_s s + (W_d d' + b), so the genotype keeps W_s and the bias
    b + d' W_d; every other layer is the DC actor's.
    """
    w, b = dc_params[layer]["w"], dc_params[layer]["b"]
    folded = dict(dc_params)
    folded[layer] = {"w": w[:obs_size], "b": b + target_desc @ w[obs_size:]}
    return folded


@dataclasses.dataclass(eq=False)
class DCRLEmitter:
    """DCRL emitter: `num_pg` descriptor-conditioned PG offspring, then `num_ai` injected actors.

    `policy_network` is the genotypes' network (`apply(params, obs) -> action` in
    [-1, 1]); the DC actor is the same network reading [obs, d']. Descriptors are
    normalised with `descriptor_low` / `descriptor_high`. `update` reads
    `evaluation.extras["transitions"]` (T, n, ...), `["mask"]` (T, n) and the
    episodes' descriptors `["descriptors"]` (n, D) (`qdrl.tasks.policy`; without
    it, `evaluation.descriptors`): every evaluated episode goes to the buffer. Its
    own offspring are rows `first_row` to `first_row + batch_size` of that batch
    (0 when it comes first in a `MultiEmitter`, as `dcrl_me_emitter` places it).
    """

    num_pg: int
    num_ai: int
    policy_network: hk.Transformed
    obs_size: int
    action_size: int
    descriptor_low: Sequence[float]
    descriptor_high: Sequence[float]
    config: DCRLConfig = dataclasses.field(default_factory=DCRLConfig)
    first_row: int = 0
    batch_size: int = dataclasses.field(init=False)
    networks: TD3Networks = dataclasses.field(init=False)
    agent: Agent = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.config.check()
        for name in ("num_pg", "num_ai", "first_row"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
                raise ValueError(f"{name}: expected an integer >= 0, got {value!r}")
        self.batch_size = self.num_pg + self.num_ai
        if self.batch_size < 1:
            raise ValueError("num_pg, num_ai: expected at least one offspring, got 0 and 0")
        low = np.asarray(self.descriptor_low, np.float32)
        high = np.asarray(self.descriptor_high, np.float32)
        if low.ndim != 1 or low.shape != high.shape or not bool(np.all(high > low)):
            raise ValueError(
                f"descriptor_low, descriptor_high: expected bounds of one shape (D,) with low < high, "
                f"got {list(self.descriptor_low)} and {list(self.descriptor_high)}"
            )
        self._low, self._high = low, high
        self.descriptor_size = int(low.shape[0])
        self._first_layer = first_layer_name(self.policy_network, self.obs_size, self.descriptor_size)
        td3 = self.config.td3
        self.networks = TD3Networks(
            policy=self.policy_network, critic=nets.twin_q_critic(td3.hidden, td3.activation)
        )
        self.agent = make_td3(td3, self.obs_size + self.descriptor_size, self.action_size, self.networks)
        self._reward_offset = 0.0 if self.config.reward_offset is None else self.config.reward_offset
        # A parent reads only the observation part of the conditioned input: the same
        # TD3 actor step then trains it against Q(s, a | d').
        obs_size = self.obs_size
        self._parent_networks = TD3Networks(
            policy=hk.Transformed(
                init=lambda key, x: self.policy_network.init(key, x[..., :obs_size]),
                apply=lambda params, x: self.policy_network.apply(params, x[..., :obs_size]),
            ),
            critic=self.networks.critic,
        )

    def log_metrics(self, state: DCRLEmitterState) -> dict[str, Array]:
        """The critic's gradient steps and the buffer's fill."""
        return {"critic_steps": state.td3.steps, "buffer_size": state.buffer.size}

    def normalise(self, desc: Array) -> Array:
        """Descriptors in the task's bounds mapped to [-1, 1]."""
        return normalise_descriptors(desc, jnp.asarray(self._low), jnp.asarray(self._high))

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> DCRLEmitterState:
        """A fresh agent and buffer, a first training on the initial population, the first targets."""
        del genotypes
        agent_key, learn_key = jax.random.split(key)
        transitions, _, desc = _episodes(evaluation)
        example = DCRLTransition(
            step=jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[2:], x.dtype), transitions),
            episode_desc=jnp.zeros((self.descriptor_size,), jnp.float32),
            target_desc=jnp.zeros((self.descriptor_size,), jnp.float32),
        )
        state = DCRLEmitterState(
            td3=self.agent.init(agent_key),
            buffer=buffers.init(example, self.config.replay_buffer_size),
            parents=jnp.zeros((self.num_pg,), jnp.int32),
            targets=jnp.zeros((self.batch_size, self.descriptor_size), jnp.float32),
        )
        # No episode was aimed anywhere yet: each one's target is what it reached.
        targets = self.normalise(desc)
        return self._learn(state, repertoire, evaluation, targets, learn_key)

    def emit(self, state: DCRLEmitterState, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """PG offspring of the parents chosen at the last update, then the DC actor injected at targets."""
        parts = []
        if self.num_pg > 0:
            parents = jax.tree.map(lambda x: x[state.parents], repertoire.genotypes)
            keys = jax.random.split(key, self.num_pg)
            parts.append(
                jax.vmap(self.pg_variation, in_axes=(None, 0, 0, 0))(
                    state, parents, state.targets[: self.num_pg], keys
                )
            )
        if self.num_ai > 0:
            parts.append(
                jax.vmap(self.actor_injection, in_axes=(None, 0))(
                    state.td3.policy_params, state.targets[self.num_pg :]
                )
            )
        return concat_batches(parts)

    def pg_variation(
        self, state: DCRLEmitterState, params: Params, target_desc: Array, key: PRNGKey
    ) -> Params:
        """A parent after `num_pg_training_steps` TD3 actor steps against Q(s, a | target_desc).

        Fresh Adam moments, one batch of stored observations per step, each
        conditioned on the (normalised) target: the parent's own descriptor.
        """
        lr = jnp.asarray(self.config.policy_learning_rate, jnp.float32)
        n = self.config.training_batch_size

        def step(
            carry: tuple[Params, optax.OptState], k: PRNGKey
        ) -> tuple[tuple[Params, optax.OptState], Array]:
            p, opt = carry
            batch: DCRLTransition = buffers.sample(state.buffer, k, n)
            obs = _condition(batch.step.obs, jnp.broadcast_to(target_desc, (n, self.descriptor_size)))
            p, opt, loss = td3_actor_step(
                self._parent_networks, p, opt, state.td3.critic_params, obs, lr
            )
            return (p, opt), loss

        opt_state = optax.scale_by_adam().init(params)
        keys = jax.random.split(key, self.config.num_pg_training_steps)
        (params, _), _ = jax.lax.scan(step, (params, opt_state), keys)
        return params

    def actor_injection(self, dc_params: Params, target_desc: Array) -> Params:
        """The DC actor specialised to one normalised target descriptor, as a genotype."""
        return fold_descriptor(dc_params, target_desc, self._first_layer, self.obs_size)

    def update(
        self,
        state: DCRLEmitterState,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> DCRLEmitterState:
        """Store every episode with its target, train critic and DC actor, draw the next targets."""
        del genotypes, added
        _, _, desc = _episodes(evaluation)
        n = int(desc.shape[0])
        stop = self.first_row + self.batch_size
        if stop > n:
            raise ValueError(
                f"first_row: expected this emitter's {self.batch_size} offspring within the "
                f"{n} evaluated episodes, got rows {self.first_row}..{stop}"
            )
        targets = self.normalise(desc).at[self.first_row : stop].set(state.targets)
        return self._learn(state, repertoire, evaluation, targets, key)

    def conditioned_batch(self, items: DCRLTransition) -> Transition:
        """Stored items as TD3 transitions: observations [s; d'], rewards relabelled by S(d, d')."""
        step = items.step
        reward = relabel_reward(
            step.reward, items.episode_desc, items.target_desc,
            self.config.lengthscale, self._reward_offset,
        )
        return step._replace(
            obs=_condition(step.obs, items.target_desc),
            next_obs=_condition(step.next_obs, items.target_desc),
            reward=reward.astype(step.reward.dtype),
        )

    def _learn(
        self,
        state: DCRLEmitterState,
        repertoire: Repertoire,
        evaluation: Evaluation,
        targets: Array,
        key: PRNGKey,
    ) -> DCRLEmitterState:
        transitions, mask, desc = _episodes(evaluation)
        num_steps = int(mask.shape[0])
        per_step = lambda x: jnp.broadcast_to(x[None], (num_steps, *x.shape))  # noqa: E731
        items = DCRLTransition(
            step=transitions,
            episode_desc=per_step(self.normalise(desc).astype(jnp.float32)),
            target_desc=per_step(targets.astype(jnp.float32)),
        )
        buffer = insert_valid(state.buffer, items, mask)
        train_key, select_key = jax.random.split(key)

        def train(td3: TD3State, k: PRNGKey) -> tuple[TD3State, None]:
            sample_key, update_key = jax.random.split(k)
            batch = self.conditioned_batch(
                buffers.sample(buffer, sample_key, self.config.training_batch_size)
            )
            td3, _ = self.agent.update(td3, batch, update_key)
            return td3, None

        keys = jax.random.split(train_key, self.config.num_critic_training_steps)
        td3, _ = jax.lax.scan(train, state.td3, keys)
        parents, next_targets = self._select(repertoire, select_key)
        return DCRLEmitterState(td3=td3, buffer=buffer, parents=parents, targets=next_targets)

    def _select(self, repertoire: Repertoire, key: PRNGKey) -> tuple[Array, Array]:
        """Cells drawn uniformly among the filled ones: PG parents, then elites whose descriptors AI aims at."""
        filled = repertoire.fitnesses > -jnp.inf
        cells = sample_filled_indices(key, filled, self.batch_size)
        return cells[: self.num_pg], self.normalise(repertoire.descriptors[cells]).astype(jnp.float32)


def _condition(obs: Array, target_desc: Array) -> Array:
    """The descriptor-conditioned networks' input [s; d']."""
    return jnp.concatenate([obs, target_desc.astype(obs.dtype)], axis=-1)


def _episodes(evaluation: Evaluation) -> tuple[Transition, Array, Array]:
    extras = evaluation.extras
    if "transitions" not in extras or "mask" not in extras:
        raise ValueError(
            "the DCRL emitter needs evaluation.extras['transitions'] and ['mask'] (the episodes "
            f"of a policy task, qdrl.tasks.policy); got extras {sorted(extras)}"
        )
    transitions: Transition = extras["transitions"]
    desc: Array = extras.get("descriptors", evaluation.descriptors)
    n = int(transitions.reward.shape[1])
    if desc.ndim != 2 or int(desc.shape[0]) != n:
        raise ValueError(
            f"the DCRL emitter needs the descriptors of all {n} evaluated episodes "
            f"(evaluation.extras['descriptors'], shape ({n}, D)); got shape {tuple(desc.shape)}"
        )
    return transitions, extras["mask"], desc


def dcrl_me_emitter(
    batch_size: int,
    policy_network: hk.Transformed,
    obs_size: int,
    action_size: int,
    descriptor_low: Sequence[float],
    descriptor_high: Sequence[float],
    config: DCRLConfig | None = None,
    dcrl_batch_size: int | None = None,
    ai_batch_size: int | None = None,
    make_ga: Callable[[int], Emitter] | None = None,
) -> MultiEmitter:
    """DCRL-ME's emitter (Faldor et al. 2024): the DCRL emitter first, then a GA, in one batch.

    Of `batch_size` offspring, `dcrl_batch_size` are PG offspring and `ai_batch_size`
    injected DC actors (default: a quarter of the batch each, QDax's 64 + 64 of
    256), the rest come from `make_ga(n)` (default: iso+line, iso_sigma 0.005,
    line_sigma 0.05, as QDax's DCRL-ME example). The DCRL emitter learns from
    the transitions of the whole batch.
    """
    num_pg = batch_size // 4 if dcrl_batch_size is None else dcrl_batch_size
    num_ai = batch_size // 4 if ai_batch_size is None else ai_batch_size
    for name, value in (("dcrl_batch_size", num_pg), ("ai_batch_size", num_ai)):
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
            raise ValueError(f"{name}: expected an integer >= 0, got {value!r}")
    ga_size = batch_size - num_pg - num_ai
    if ga_size < 1 or num_pg + num_ai < 1:
        raise ValueError(
            f"batch_size: expected room for the GA and the DCRL emitter "
            f"(dcrl_batch_size={num_pg}, ai_batch_size={num_ai}), got {batch_size}"
        )
    dcrl = DCRLEmitter(
        num_pg, num_ai, policy_network, obs_size, action_size, descriptor_low, descriptor_high,
        config or DCRLConfig(), first_row=0,
    )
    ga = make_ga(ga_size) if make_ga is not None else isoline_emitter(ga_size, 0.005, 0.05)
    return MultiEmitter((dcrl, ga))


__all__ = [
    "DCRLConfig",
    "DCRLEmitter",
    "DCRLEmitterState",
    "DCRLTransition",
    "dcrl_me_emitter",
    "first_layer_name",
    "fold_descriptor",
    "normalise_descriptors",
    "relabel_reward",
    "similarity",
]
