"""An off-policy agent trained on an intrinsic reward: the common core of DIAYN, DADS and SMERL.

Skill-discovery agents are SAC (or any `Agent`) whose batches are relabelled with a
reward computed by an auxiliary model — DIAYN's discriminator q(z|s'), DADS's
skill dynamics q(s' - s | s, z) — trained in the same update step on the same
batch. A `RewardModule` bundles that model: `init`, `reward` and `update`.
`with_intrinsic_reward(agent, module, ...)` returns an `Agent` whose `update`

1. computes the intrinsic reward r_div of the batch with the model's current
   parameters;
2. relabels the batch: r = c_task r_task + lambda g r_div, where the gate g is 1,
   or SMERL's [episode return >= target - margin] (Kumar et al. 2020, eq. 3);
3. runs the wrapped agent's own `update` on the relabelled batch (SAC's losses,
   unchanged);
4. takes one optimiser step of the model (`module.update`), on every update or, with
   `model_update_every = n`, on every n-th (DADS's reference code trains its model 8
   steps per 64 agent steps); the model's metrics read NaN on the updates it skips.
   Steps 1 and 4 use the same parameters and batch: a module whose reward and loss share
   their forward pass gives `reward_and_update`, which does both in one pass.

The wrapped agent trains through the one off-policy loop (`qdrl.off_policy`);
with a gate, the loop must store episode returns (`off_policy.EPISODE_RETURNS`),
and batches arrive as `(Transition, episode_return)`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.agents.base import Agent, AgentState
from qdrl.agents.common import Activation, Hidden
from qdrl.config import PositiveFloat, PositiveInt, check_fields
from qdrl.types import Array, Metrics, PRNGKey, Transition

# per-transition values (B,) by name; the agent logs their batch means
Info = dict[str, Array]
# episode returns (B,) -> gate in {0, 1} (B,)
Gate = Callable[[Array], Array]
# what a skill model reads of a state: the state descriptor or the whole observation
SkillInput = Literal["descriptor", "full"]


def check_field(ok: bool, section: str, field: str, expected: str, value: object) -> None:
    """Raise `ValueError("<section>.<field>: expected <expected>, got <value>")` unless `ok`."""
    if not ok:
        raise ValueError(f"{section}.{field}: expected {expected}, got {value!r}")


def is_positive_int(value: object) -> bool:
    """True for an int > 0 (bools excluded)."""
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


@dataclasses.dataclass(frozen=True)
class SkillModelConfig:
    """What every skill model (DIAYN's discriminator, DADS's skill dynamics) is configured by.

    The `[skills]` section of a run; `DIAYNConfig` and `DADSConfig` extend it and set
    their papers' defaults.
    """

    # K, the number of discrete skills (uniform prior p(z) = 1 / K).
    num_skills: PositiveInt = 10
    # What the model reads of a state: "descriptor" (the env's state descriptor, e.g.
    # x-y) or "full" (the observation without the skill code).
    model_input: SkillInput = "descriptor"
    # Hidden layer widths of the model.
    hidden: Hidden = (256, 256)
    # Activation of its hidden layers; a key of `qdrl.nets.ACTIVATIONS`.
    activation: Activation = "relu"
    # Adam step size of the model.
    learning_rate: PositiveFloat = 3e-4
    # lambda: weight of the intrinsic reward in the relabelled reward.
    diversity_scale: float = 1.0
    # Weight of the environment's reward in the relabelled reward (0: pure skill discovery).
    extrinsic_scale: float = 0.0
    # The model takes one Adam step every this many agent updates (1: every update).
    model_update_every: PositiveInt = 1

    def __post_init__(self) -> None:
        # TOML and JSON give lists; tuples keep the config hashable.
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, list):
                object.__setattr__(self, field.name, tuple(value))

    def check(self) -> None:
        """Raises ValueError naming the first `skills.<field>` its declared type refuses."""
        check_fields(self, "skills")


class RewardModule(NamedTuple):
    """An intrinsic reward and the model it is computed with; pure, jittable functions.

    init(key) -> aux_state
    reward(aux_state, transitions, key) -> (r_div (B,), info)   info: per-transition (B,) values
    update(aux_state, transitions, key) -> (aux_state, metrics) one training step of the model
    reward_and_update(aux_state, transitions, reward_key, update_key)
        -> (r_div, info, aux_state, metrics), optional: `reward` then `update` on the same
        batch with the same parameters, in one pass where they share work (DIAYN's
        discriminator logits are both the reward's and the loss's forward pass)
    """

    init: Callable[[PRNGKey], Any]
    reward: Callable[[Any, Transition, PRNGKey], tuple[Array, Info]]
    update: Callable[[Any, Transition, PRNGKey], tuple[Any, Metrics]]
    reward_and_update: Callable[[Any, Transition, PRNGKey, PRNGKey], tuple[Array, Info, Any, Metrics]] | None = None


class IntrinsicState(NamedTuple):
    """The wrapped agent's state, the reward model's, and the reward mixing scalars.

    `hparams` holds "diversity_scale" (lambda) and "extrinsic_scale" (c_task) as
    float32 scalars, so a population of agents may hold its own values.
    """

    agent: AgentState
    aux: Any
    hparams: dict[str, Array]
    steps: Array  # int32 scalar, updates taken (the model trains when steps % every == 0)


def relabel(
    task_reward: Array,
    diversity_reward: Array,
    diversity_scale: Array | float,
    extrinsic_scale: Array | float,
    gate: Array | None = None,
    reverse: bool = False,
) -> Array:
    """r = extrinsic_scale * r_task + diversity_scale * gate * r_div (gate 1 when None); with
    `reverse`, r = extrinsic_scale * (1 - gate) * r_task + diversity_scale * r_div."""
    if gate is not None and reverse:
        return extrinsic_scale * (1.0 - gate) * task_reward + diversity_scale * diversity_reward
    weight = diversity_scale if gate is None else diversity_scale * gate
    return extrinsic_scale * task_reward + weight * diversity_reward


def with_intrinsic_reward(
    agent: Agent,
    module: RewardModule,
    diversity_scale: float = 1.0,
    extrinsic_scale: float = 0.0,
    gate: Gate | None = None,
    model_update_every: int = 1,
    reverse_gate: bool = False,
) -> Agent:
    """`agent` trained on batches relabelled with `module`'s intrinsic reward (see the module doc).

    Args:
      agent: the learner, e.g. `make_sac(...)` on skill-conditioned observations.
      module: the intrinsic reward and its model.
      diversity_scale: lambda, weight of the intrinsic reward.
      extrinsic_scale: weight of the environment's reward (0: pure skill discovery).
      gate: None, or a function of the episode returns giving a 0/1 weight of the
        intrinsic reward per transition (SMERL); batches are then
        `(Transition, episode_return)`.
      model_update_every: the model takes one step every this many updates (1: every one).
      reverse_gate: the gate weighs the task reward instead, closed where it opens (Reverse
        SMERL: `relabel(..., reverse=True)`).
    """
    if not is_positive_int(model_update_every):
        raise ValueError(f"model_update_every: expected a positive int, got {model_update_every!r}")

    def init(key: PRNGKey) -> IntrinsicState:
        agent_key, aux_key = jax.random.split(key)
        return IntrinsicState(
            agent=agent.init(agent_key),
            aux=module.init(aux_key),
            hparams={
                "diversity_scale": jnp.asarray(diversity_scale, jnp.float32),
                "extrinsic_scale": jnp.asarray(extrinsic_scale, jnp.float32),
            },
            steps=jnp.zeros((), jnp.int32),
        )

    def act(state: IntrinsicState, obs: Array, key: PRNGKey) -> Array:
        return agent.act(state.agent, obs, key)

    def policy_params(state: IntrinsicState) -> Any:
        return agent.policy_params(state.agent)

    def reward_and_train(
        aux: Any, transitions: Transition, reward_key: PRNGKey, update_key: PRNGKey, steps: Array
    ) -> tuple[Array, Info, Any, Metrics]:
        """The batch's intrinsic reward under the model's current parameters, and the model's
        step on the updates it trains (its metrics NaN on the others)."""

        def nan_metrics(aux: Any, transitions: Transition, update_key: PRNGKey) -> Metrics:
            shapes = jax.eval_shape(module.update, aux, transitions, update_key)[1]
            return jax.tree.map(lambda x: jnp.full(x.shape, jnp.nan, x.dtype), shapes)

        both = module.reward_and_update
        trains = steps % model_update_every == 0
        # Each lax.cond below is a real branch (unless vmapped, e.g. in a population, where
        # both branches run): skipped steps cost no model step.
        if both is None:  # the reward outside the branch: computed once, vmapped or not
            r_div, info = module.reward(aux, transitions, reward_key)
            if model_update_every == 1:
                return (r_div, info, *module.update(aux, transitions, update_key))

            def skip(aux: Any, transitions: Transition, update_key: PRNGKey) -> tuple[Any, Metrics]:
                return aux, nan_metrics(aux, transitions, update_key)

            aux, metrics = jax.lax.cond(trains, module.update, skip, aux, transitions, update_key)
            return r_div, info, aux, metrics
        if model_update_every == 1:
            return both(aux, transitions, reward_key, update_key)

        def reward_only(aux: Any, transitions: Transition, reward_key: PRNGKey, update_key: PRNGKey) -> Any:
            return (*module.reward(aux, transitions, reward_key), aux, nan_metrics(aux, transitions, update_key))

        return jax.lax.cond(trains, both, reward_only, aux, transitions, reward_key, update_key)

    def update(state: IntrinsicState, batch: Any, key: PRNGKey) -> tuple[IntrinsicState, Metrics]:
        if gate is None:
            transitions, weight = batch, None
        else:
            transitions, episode_return = batch
            weight = gate(episode_return).astype(jnp.float32)
        reward_key, agent_key, aux_key = jax.random.split(key, 3)
        r_div, info, aux, aux_metrics = reward_and_train(
            state.aux, transitions, reward_key, aux_key, state.steps
        )
        r_div = jax.lax.stop_gradient(r_div)
        hp = state.hparams
        reward = relabel(
            transitions.reward, r_div, hp["diversity_scale"], hp["extrinsic_scale"], weight, reverse_gate
        )
        agent_state, metrics = agent.update(
            state.agent, transitions._replace(reward=reward), agent_key
        )
        out = dict(metrics)
        out.update(aux_metrics)
        out.update({k: jnp.mean(v) for k, v in info.items()})
        out["intrinsic_reward"] = jnp.mean(r_div)
        out["task_reward"] = jnp.mean(transitions.reward)
        if weight is not None:
            out["gate_open"] = jnp.mean(weight)
        return IntrinsicState(agent_state, aux, state.hparams, state.steps + 1), out

    return Agent(
        init=init, act=act, policy=agent.policy, policy_params=policy_params, update=update
    )


def with_skill_model(
    agent: Agent, module: RewardModule, config: SkillModelConfig, gate: Gate | None = None,
    reverse_gate: bool = False,
) -> Agent:
    """`with_intrinsic_reward` with the reward weights and model schedule of a `[skills]` config."""
    return with_intrinsic_reward(
        agent, module, config.diversity_scale, config.extrinsic_scale, gate,
        config.model_update_every, reverse_gate,
    )
