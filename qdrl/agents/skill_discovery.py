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

from collections.abc import Sequence
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
from qdrl.rollout import run_episodes
from qdrl.types import Array, PRNGKey

__all__ = ["SkillDiscovery", "evaluate_skills", "make_skill_discovery", "skill_module"]


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
    without skill (`sd.env.env`); jittable.

    Returns the episodes' mean, std and min return and mean length (`eval_*`), the
    skill model's metrics on the evaluation steps as the training batches see them
    (`eval_<name>` over every step, `eval_final_<name>` at the episodes' last step),
    each episode's `returns` and descriptor (`descriptors`: "final" or "mean", clipped
    to [low, high] when given), and the `trajectories` of state descriptors and `mask`.
    """
    k, env = sd.env.num_skills, sd.env.env
    params = sd.agent.policy_params(agent_state)
    skills = jnp.arange(num_episodes, dtype=jnp.int32) % k
    run_key, model_key = jax.random.split(key)

    def policy(obs: Array, _: PRNGKey) -> Array:
        return sd.agent.policy(params, append_skill(obs, skills, k))

    ep = run_episodes(env, policy, run_key, num_episodes)
    desc = ep.final_desc if descriptor == "final" else ep.mean_desc
    if low is not None and high is not None:
        desc = jnp.clip(desc, jnp.asarray(low), jnp.asarray(high))
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
        "descriptors": desc,
        "trajectories": tr.next_desc,
        "mask": mask,
    }
    for name, value in info.items():
        v = value.reshape(mask.shape)
        out[f"eval_{name}"] = jnp.sum(v * mask) / jnp.sum(mask)
        out[f"eval_final_{name}"] = jnp.sum(v * last) / jnp.sum(last)
    return out
