"""Actor-critic emitters of the QD-RL algorithms: Q-PG (PGA-ME) and D-PG (QD-PG).

A policy-gradient variation is literally TD3's actor update applied to an elite:
the emitter holds a TD3 agent (`qdrl.agents.td3`: twin critic, target networks,
greedy actor) and one replay buffer (`qdrl.buffers`). `emit` samples parents
from the repertoire and applies `num_pg_training_steps` calls of
`td3_actor_step` to each (fresh Adam moments per offspring, one sampled batch
per step, against the shared critic), and emits the greedy actor as the last
offspring. `update` stores the valid transitions of the evaluated episodes in
the buffer and trains critic, greedy actor and targets with TD3's own `update`,
`num_critic_training_steps` times.

Nilsson & Cully 2021, "Policy Gradient Assisted MAP-Elites" (GECCO), Alg. 1-2;
QDax's `QualityPGEmitter` / `PGAMEEmitter` (defaults of `PGConfig` are theirs).

The critic may learn another reward than the environment's: `relabel`
(`RewardRelabel`) keeps a state of its own (e.g. an archive of descriptors) and
rewrites the rewards of every sampled batch. D-PG (Pierrot et al. 2022,
"Diversity policy gradient for sample efficient quality-diversity
optimization", GECCO) is Q-PG whose reward is the novelty of the next state's
descriptor with respect to an archive (`qdrl.qd.emitters.novelty`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Annotated, Any, NamedTuple, Protocol, TypeVar

import haiku as hk
import jax
import jax.numpy as jnp
import optax

from qdrl import buffers, nets
from qdrl.agents.base import Agent
from qdrl.agents.td3 import TD3Config, TD3Networks, TD3State, make_td3, td3_actor_step
from qdrl.buffers import ReplayBuffer
from qdrl.config import Nested, NonNegativeInt, PositiveFloat, PositiveInt, check_fields
from qdrl.qd.base import AddResult, Emitter, Evaluation, Repertoire, emitter_metrics
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.emitters.multi import MultiEmitter, concat_batches, split_batch
from qdrl.types import Array, Genotype, Params, PRNGKey, PyTree, Transition

Items = TypeVar("Items")


# The TD3 of a policy-gradient emitter: its critic, greedy actor and targets (the
# actor is the genotypes' network; `hidden` is the critic's). PGA-ME's defaults (QDax).
PG_TD3 = TD3Config(actor_lr=3e-4, critic_lr=3e-4, hidden=(256, 256), activation="relu")


@dataclasses.dataclass(frozen=True)
class PGConfig:
    """Hyperparameters of a policy-gradient emitter; defaults: PGA-ME (Nilsson & Cully 2021, QDax).

    `td3` is the emitter's TD3 (critic, greedy actor, targets); its keys sit in the
    emitter's spec section under the names below (`critic_learning_rate` is
    `td3.critic_lr`, ...). The offspring's own optimiser is Adam at `policy_learning_rate`.
    """

    # TD3 critic steps (each also a greedy-actor step every `policy_delay`) per update.
    num_critic_training_steps: NonNegativeInt = 300
    # TD3 actor steps applied to each parent to make one offspring.
    num_pg_training_steps: NonNegativeInt = 100
    # Adam step size of the actor steps applied to offspring.
    policy_learning_rate: PositiveFloat = 1e-3
    # Transitions per sampled batch (critic and offspring steps alike).
    training_batch_size: PositiveInt = 256
    # Slots of the replay buffer.
    replay_buffer_size: PositiveInt = 1_000_000
    td3: Annotated[
        TD3Config,
        Nested(
            ("critic_learning_rate", "critic_lr"),  # Adam step size of the twin critic
            ("greedy_learning_rate", "actor_lr"),  # Adam step size of the greedy actor (TD3's own actor)
            ("discount", "discount"),
            ("tau", "tau"),  # Polyak rate of the target networks
            ("policy_noise", "policy_noise"),  # target policy smoothing noise (TD3)
            ("noise_clip", "noise_clip"),  # ... and its clip
            ("policy_delay", "policy_delay"),  # greedy actor and targets: once every this many critic steps
            ("reward_scale", "reward_scale"),
            ("critic_hidden", "hidden"),  # hidden widths of each of the twin critics (ReLU)
        ),
    ] = PG_TD3

    def check(self, section: str = "pg") -> None:
        """Raises ValueError naming the first `section.<key>` its declared type refuses."""
        check_fields(self, section)


class RewardRelabel(Protocol):
    """A learned-reward hook: its own state, updated from evaluations, rewriting sampled rewards."""

    def init(self, evaluation: Evaluation, key: PRNGKey) -> Any:
        """The hook's state from the initial population's evaluation."""
        ...

    def update(self, state: Any, evaluation: Evaluation, key: PRNGKey) -> Any:
        """The state after a batch of evaluations."""
        ...

    def relabel(self, state: Any, transitions: Transition) -> Transition:
        """`transitions` (batch, ...) with their rewards replaced."""
        ...


class PGEmitterState(NamedTuple):
    """Q-PG / D-PG emitter state: the TD3 agent, its one replay buffer, the reward hook's state."""

    td3: TD3State
    buffer: ReplayBuffer
    relabel: Any  # None for Q-PG


def flatten_valid(transitions: Items, mask: Array) -> tuple[Items, Array]:
    """(T, n, ...) transitions and (T, n) mask as (T*n, ...) items, valid ones first, and their count.

    `transitions` is any pytree of (T, n, ...) leaves (a `Transition`, or one with labels).
    """
    flat = jax.tree.map(lambda x: x.reshape((-1, *x.shape[2:])), transitions)
    valid = mask.reshape(-1) > 0
    order = jnp.argsort(~valid, stable=True)
    return jax.tree.map(lambda x: x[order], flat), jnp.sum(valid).astype(jnp.int32)


def insert_valid(buffer: ReplayBuffer, transitions: PyTree, mask: Array) -> ReplayBuffer:
    """Insert only the transitions where `mask` is 1 (steps inside an episode) into the ring.

    The number of valid items is traced, the batch shape is static: the valid
    items are moved first and `buffers.insert` writes that many. Needs T*n <= capacity.
    """
    items, num_valid = flatten_valid(transitions, mask)
    n = int(jax.tree.leaves(items)[0].shape[0])
    if n > buffer.capacity:
        raise ValueError(
            f"replay_buffer_size: expected at least the {n} transitions of one evaluation batch "
            f"(episode length x batch), got {buffer.capacity}"
        )
    return buffers.insert(buffer, items, num_valid)


@dataclasses.dataclass(eq=False)
class PGEmitter:
    """Q-PG emitter (PGA-ME); with a `relabel` hook, D-PG (QD-PG). See the module docstring.

    `batch_size` offspring per `emit`: `batch_size - 1` policy-gradient offspring of
    parents drawn uniformly from the repertoire, then the greedy actor (with
    `emit_greedy`, as QDax; otherwise all `batch_size` are PG offspring).
    `policy_network` is the genotypes' network (`apply(params, obs) -> action` in
    [-1, 1]); the TD3 actor is that network, so the greedy actor is a genotype.
    `update` reads `evaluation.extras["transitions"]` (T, n, ...) and
    `extras["mask"]` (T, n) — every evaluated episode, not only this emitter's.
    """

    batch_size: int
    policy_network: hk.Transformed
    obs_size: int
    action_size: int
    config: PGConfig = dataclasses.field(default_factory=PGConfig)
    relabel: RewardRelabel | None = None
    emit_greedy: bool = True
    networks: TD3Networks = dataclasses.field(init=False)
    agent: Agent = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.config.check()
        if not (isinstance(self.batch_size, int) and self.batch_size >= 1):
            raise ValueError(f"batch_size: expected a positive integer, got {self.batch_size!r}")
        td3 = self.config.td3
        self.networks = TD3Networks(
            policy=self.policy_network, critic=nets.twin_q_critic(td3.hidden, td3.activation)
        )
        self.agent = make_td3(td3, self.obs_size, self.action_size, self.networks)

    @property
    def num_pg(self) -> int:
        """Offspring per batch made by policy-gradient steps on a parent."""
        return self.batch_size - 1 if self.emit_greedy else self.batch_size

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> PGEmitterState:
        """A fresh TD3 agent and an empty buffer, then a first `update` on the initial population."""
        agent_key, relabel_key, update_key = jax.random.split(key, 3)
        transitions = _transitions(evaluation)
        example = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[2:], x.dtype), transitions)
        relabel = None
        if self.relabel is not None:
            relabel = self.relabel.init(evaluation, relabel_key)
        state = PGEmitterState(
            td3=self.agent.init(agent_key),
            buffer=buffers.init(example, self.config.replay_buffer_size),
            relabel=relabel,
        )
        return self._learn(state, evaluation, update_key)

    def emit(self, state: PGEmitterState, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """`num_pg` parents improved by TD3 actor steps, then the greedy actor."""
        parent_key, pg_key = jax.random.split(key)
        parts = []
        if self.num_pg > 0:
            parents = repertoire.sample(parent_key, self.num_pg)
            keys = jax.random.split(pg_key, self.num_pg)
            parts.append(jax.vmap(self.pg_variation, in_axes=(None, 0, 0))(state, parents, keys))
        if self.emit_greedy:
            parts.append(jax.tree.map(lambda x: x[None], state.td3.policy_params))
        return concat_batches(parts)

    def pg_variation(self, state: PGEmitterState, params: Params, key: PRNGKey) -> Params:
        """One parent after `num_pg_training_steps` TD3 actor steps against the emitter's critic.

        Fresh Adam moments (as QDax's `_mutation_function_pg`), one batch sampled from
        the buffer per step.
        """
        lr = jnp.asarray(self.config.policy_learning_rate, jnp.float32)

        def step(
            carry: tuple[Params, optax.OptState], k: PRNGKey
        ) -> tuple[tuple[Params, optax.OptState], Array]:
            p, opt = carry
            batch = self._sample(state, k)
            p, opt, loss = td3_actor_step(
                self.networks, p, opt, state.td3.critic_params, batch.obs, lr
            )
            return (p, opt), loss

        opt_state = optax.scale_by_adam().init(params)
        keys = jax.random.split(key, self.config.num_pg_training_steps)
        (params, _), _ = jax.lax.scan(step, (params, opt_state), keys)
        return params

    def update(
        self,
        state: PGEmitterState,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> PGEmitterState:
        """Store the evaluated transitions, then train critic and greedy actor (TD3's `update`)."""
        del repertoire, genotypes, added
        return self._learn(state, evaluation, key)

    def log_metrics(self, state: PGEmitterState) -> dict[str, Array]:
        """The critic's gradient steps and the buffer's fill; the reward hook's own metrics."""
        out = {"critic_steps": state.td3.steps, "buffer_size": state.buffer.size}
        out.update(emitter_metrics(self.relabel, state.relabel))
        return out

    def _sample(self, state: PGEmitterState, key: PRNGKey) -> Transition:
        batch: Transition = buffers.sample(state.buffer, key, self.config.training_batch_size)
        if self.relabel is not None:
            batch = self.relabel.relabel(state.relabel, batch)
        return batch

    def _learn(self, state: PGEmitterState, evaluation: Evaluation, key: PRNGKey) -> PGEmitterState:
        transitions = _transitions(evaluation)
        buffer = insert_valid(state.buffer, transitions, evaluation.extras["mask"])
        relabel_state = state.relabel
        if self.relabel is not None:
            relabel_key, key = jax.random.split(key)
            relabel_state = self.relabel.update(state.relabel, evaluation, relabel_key)
        state = PGEmitterState(td3=state.td3, buffer=buffer, relabel=relabel_state)

        def train(td3: TD3State, k: PRNGKey) -> tuple[TD3State, None]:
            sample_key, update_key = jax.random.split(k)
            batch = self._sample(state, sample_key)
            td3, _ = self.agent.update(td3, batch, update_key)
            return td3, None

        keys = jax.random.split(key, self.config.num_critic_training_steps)
        td3, _ = jax.lax.scan(train, state.td3, keys)
        return state._replace(td3=td3)


def _transitions(evaluation: Evaluation) -> Transition:
    if "transitions" not in evaluation.extras or "mask" not in evaluation.extras:
        raise ValueError(
            "policy-gradient emitters need evaluation.extras['transitions'] and ['mask'] "
            "(the episodes of a policy task, qdrl.tasks.policy); got extras "
            f"{sorted(evaluation.extras)}"
        )
    transitions: Transition = evaluation.extras["transitions"]
    return transitions


def pga_me_emitter(
    batch_size: int,
    policy_network: hk.Transformed,
    obs_size: int,
    action_size: int,
    config: PGConfig | None = None,
    proportion_mutation_ga: float = 0.5,
    make_ga: Callable[[int], Emitter] | None = None,
) -> MultiEmitter:
    """PGA-ME's emitter (Nilsson & Cully 2021): a GA and Q-PG share one batch.

    `proportion_mutation_ga` of the `batch_size` offspring come from `make_ga(n)`
    (default: iso+line variation, iso_sigma 0.005, line_sigma 0.05, as QDax's
    PGA-ME), the rest from Q-PG, whose last offspring is the greedy actor. The
    Q-PG emitter learns from the transitions of the whole batch.
    """
    if not 0.0 < proportion_mutation_ga < 1.0:
        raise ValueError(
            f"proportion_mutation_ga: expected a number in (0, 1), got {proportion_mutation_ga!r}"
        )
    ga_size, pg_size = split_batch(batch_size, (proportion_mutation_ga, 1.0 - proportion_mutation_ga))
    if ga_size < 1 or pg_size < 1:
        raise ValueError(
            f"batch_size: expected room for both the GA and the Q-PG share "
            f"(proportion_mutation_ga={proportion_mutation_ga}), got {batch_size}"
        )
    ga = make_ga(ga_size) if make_ga is not None else isoline_emitter(ga_size, 0.005, 0.05)
    pg = PGEmitter(pg_size, policy_network, obs_size, action_size, config or PGConfig())
    return MultiEmitter((ga, pg))


__all__ = [
    "PG_TD3",
    "PGConfig",
    "PGEmitter",
    "PGEmitterState",
    "RewardRelabel",
    "flatten_valid",
    "insert_valid",
    "pga_me_emitter",
]
