"""Skill discovery one call away: SAC on a skill-conditioned environment with DIAYN's or DADS's
intrinsic reward, SMERL's gate on either.

    sd = make_skill_discovery(env, SACConfig(), DIAYNConfig(num_skills=5), SMERLConfig(target=...))
    trainer = make_trainer(sd.env, sd.agent, TrainConfig(...), sd.storage)

The agent acts on the environment's observation followed by a one-hot skill
(`qdrl.envs.skills.SkillEnv`); its batches are relabelled by the skill model's
reward (`qdrl.agents.intrinsic`); SMERL's batches carry each transition's episode
return (`qdrl.off_policy.EPISODE_RETURNS`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp

from qdrl import off_policy
from qdrl.agents.base import Agent, AgentState
from qdrl.agents.dads import DADSConfig, make_dads_module
from qdrl.agents.diayn import DIAYNConfig, make_diayn_module
from qdrl.agents.intrinsic import RewardModule, with_skill_model
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.smerl import SMERLConfig, smerl_gate
from qdrl.envs.base import Env
from qdrl.envs.skills import SkillEnv, append_skill
from qdrl.rollout import Episodes, RecordFn, run_episodes
from qdrl.types import Array, PRNGKey

__all__ = [
    "SkillDiscovery",
    "episode_descriptors",
    "evaluate_skills",
    "make_skill_discovery",
    "skill_episodes",
    "skill_module",
    "skill_policy",
]


class SkillDiscovery(NamedTuple):
    """A skill-discovery agent and what trains it."""

    env: SkillEnv  # the environment with the skill appended to its observation
    agent: Agent  # SAC with the intrinsic reward (and SMERL's gate)
    module: RewardModule  # the skill model: discriminator (DIAYN) or skill dynamics (DADS)
    storage: off_policy.Storage  # where the off-policy loop stores transitions


def skill_module(skills: DIAYNConfig | DADSConfig, obs_size: int, descriptor_size: int) -> RewardModule:
    """DIAYN's discriminator or DADS's skill-dynamics model, by the config's type."""
    if isinstance(skills, DIAYNConfig):
        return make_diayn_module(skills, obs_size, descriptor_size)
    return make_dads_module(skills, obs_size, descriptor_size)


def make_skill_discovery(
    env: Env, sac: SACConfig, skills: DIAYNConfig | DADSConfig, smerl: SMERLConfig | None = None
) -> SkillDiscovery:
    """DIAYN or DADS (by `skills`' type) on `env`; SMERL (Kumar et al. 2020) when `smerl` is given.

    Raises ValueError for sizes the networks refuse (messages name `skills.` keys for the
    skill model's).
    """
    skill_env = SkillEnv(env, skills.num_skills)
    agent = make_sac(sac, skill_env.observation_size, skill_env.action_size)
    module = skill_module(skills, env.observation_size, env.descriptor_size)
    gate = None if smerl is None else smerl_gate(smerl.target, smerl.margin)
    storage = off_policy.REPLAY if smerl is None else off_policy.EPISODE_RETURNS
    return SkillDiscovery(skill_env, with_skill_model(agent, module, skills, gate), module, storage)


def skill_policy(sd: SkillDiscovery, agent_state: AgentState, skill: int) -> Callable[[Array], Array]:
    """The deterministic policy of skill `skill`: observations (..., obs_size) of the environment
    without skill -> actions (..., action_size), the skill's one-hot appended as in training;
    jittable."""
    k = sd.env.num_skills
    if isinstance(skill, bool) or not isinstance(skill, int) or not 0 <= skill < k:
        raise ValueError(f"skill: expected an int in [0, {k}), got {skill!r}")
    params = sd.agent.policy_params(agent_state)

    def policy(obs: Array) -> Array:
        obs = jnp.asarray(obs, jnp.float32)
        return sd.agent.policy(params, append_skill(obs, jnp.full(obs.shape[:-1], skill, jnp.int32), k))

    return policy


def skill_episodes(
    sd: SkillDiscovery, agent_state: AgentState, key: PRNGKey, num_episodes: int, record: RecordFn | None = None
) -> Episodes:
    """The episodes `evaluate_skills` plays from its `key`'s first half: episode i plays skill
    i % K deterministically on the environment without skill (`sd.env.env`), from the random
    start the key gives it; `record` as in `run_episodes`. Jittable."""
    k, env = sd.env.num_skills, sd.env.env
    params = sd.agent.policy_params(agent_state)
    skills = jnp.arange(num_episodes, dtype=jnp.int32) % k

    def policy(obs: Array, _: PRNGKey) -> Array:
        return sd.agent.policy(params, append_skill(obs, skills, k))

    return run_episodes(env, policy, key, num_episodes, record=record)


def episode_descriptors(
    ep: Episodes,
    descriptor: Literal["final", "mean"] = "final",
    low: Sequence[float] | None = None,
    high: Sequence[float] | None = None,
) -> Array:
    """Each episode's descriptor (B, D): its final or mean state descriptor, clipped to
    [low, high] when they are given."""
    desc = ep.final_desc if descriptor == "final" else ep.mean_desc
    if low is not None and high is not None:
        desc = jnp.clip(desc, jnp.asarray(low), jnp.asarray(high))
    return desc


def evaluate_skills(
    sd: SkillDiscovery,
    agent_state: AgentState,
    key: PRNGKey,
    num_episodes: int,
    descriptor: Literal["final", "mean"] = "final",
    low: Sequence[float] | None = None,
    high: Sequence[float] | None = None,
) -> dict[str, Array]:
    """Every skill played deterministically: episode i plays skill i % K on the environment
    without skill (`sd.env.env`; `skill_episodes` on the first half of `key`); jittable.

    Returns the episodes' mean, std and min return and mean length (`eval_*`), the
    skill model's metrics on the evaluation steps as the training batches see them
    (`eval_<name>` over every step, `eval_final_<name>` at the episodes' last step),
    each episode's `returns`, `lengths` and descriptor (`descriptors`: "final" or
    "mean", clipped to [low, high] when given), and the `trajectories` of state
    descriptors and `mask`.
    """
    k = sd.env.num_skills
    skills = jnp.arange(num_episodes, dtype=jnp.int32) % k
    run_key, model_key = jax.random.split(key)
    ep = skill_episodes(sd, agent_state, run_key, num_episodes)
    desc = episode_descriptors(ep, descriptor, low, high)
    tr = ep.transitions
    steps = tr.obs.shape[0]
    per_step = jnp.broadcast_to(skills, (steps, num_episodes))
    tr = tr._replace(obs=append_skill(tr.obs, per_step, k), next_obs=append_skill(tr.next_obs, per_step, k))
    flat = jax.tree.map(lambda x: x.reshape((-1, *x.shape[2:])), tr)
    _, info = sd.module.reward(agent_state.aux, flat, model_key)
    mask = ep.mask
    last = jax.nn.one_hot(ep.lengths - 1, steps, axis=0) * mask  # (T, B) the last step
    out: dict[str, Array] = {
        "eval_return": jnp.mean(ep.returns),
        "eval_return_std": jnp.std(ep.returns),
        "eval_return_min": jnp.min(ep.returns),
        "eval_length": jnp.mean(ep.lengths.astype(jnp.float32)),
        "returns": ep.returns,
        "lengths": ep.lengths,
        "descriptors": desc,
        "trajectories": tr.next_desc,
        "mask": mask,
    }
    for name, value in info.items():
        v = value.reshape(mask.shape)
        out[f"eval_{name}"] = jnp.sum(v * mask) / jnp.sum(mask)
        out[f"eval_final_{name}"] = jnp.sum(v * last) / jnp.sum(last)
    return out
