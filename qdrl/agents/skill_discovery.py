"""Skill discovery one call away: SAC on a skill-conditioned environment with DIAYN's, DADS's or
METRA's (LSD's) intrinsic reward, SMERL's gate on any; DOMiNO's agent on one-hot skills.

    sd = make_skill_discovery(env, SACConfig(), DIAYNConfig(num_skills=5), SMERLConfig(target=...))
    trainer = make_trainer(sd.env, sd.agent, TrainConfig(...), sd.storage)

The agent acts on the environment's observation followed by a skill code: a one-hot
(`qdrl.envs.skills.SkillEnv`), or a continuous skill (`ContinuousSkillEnv`: METRA's unit
vectors, continuous DIAYN's [-1, 1]^d); its batches are relabelled by the skill model's reward
(`qdrl.agents.intrinsic`); SMERL's batches carry each transition's episode return
(`qdrl.off_policy.EPISODE_RETURNS`). Evaluations play a fixed set of skills, `sd.codes`: the
K one-hots, or (continuous skills) one skill per evaluation episode: unit vectors evenly
spread over the circle (d = 2), else drawn once from a fixed key.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from qdrl import off_policy
from qdrl.agents.base import Agent, AgentState
from qdrl.agents.dads import DADSConfig, make_dads_module
from qdrl.agents.diayn import DIAYNConfig, make_diayn_module
from qdrl.agents.domino import DOMiNOConfig, make_domino
from qdrl.agents.intrinsic import RewardModule, with_skill_model
from qdrl.agents.metra import METRAConfig, make_metra_module
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.smerl import SMERLConfig, smerl_gate
from qdrl.config import PositiveInt, check_fields
from qdrl.envs.base import Env
from qdrl.envs.skills import ContinuousSkillEnv, SkillEnv, SkillSpace
from qdrl.rollout import Episodes, RecordFn, run_episodes
from qdrl.types import Array, PRNGKey

__all__ = [
    "DiscreteSkills",
    "SkillConfig",
    "SkillDiscovery",
    "episode_descriptors",
    "evaluate_skills",
    "evaluation_codes",
    "make_skill_discovery",
    "skill_episodes",
    "skill_module",
    "skill_policy",
]


@dataclasses.dataclass(frozen=True)
class DiscreteSkills:
    """The `[skills]` section of an agent whose skills need no model: K one-hot skills (DOMiNO,
    whose own settings are the `[domino]` section)."""

    # K, the number of discrete skills.
    num_skills: PositiveInt = 10

    def check(self) -> None:
        check_fields(self, "skills")


# The skill models' configs (the `[skills]` section).
SkillConfig = DIAYNConfig | DADSConfig | METRAConfig | DiscreteSkills


class SkillDiscovery(NamedTuple):
    """A skill-discovery agent and what trains and evaluates it."""

    env: SkillEnv | ContinuousSkillEnv  # the environment with the skill appended to its observation
    agent: Agent  # SAC with the intrinsic reward (and SMERL's gate)
    # the skill model: discriminator (DIAYN), skill dynamics (DADS), phi (METRA); None (DOMiNO)
    module: RewardModule | None
    storage: off_policy.Storage  # where the off-policy loop stores transitions
    codes: Array  # (K, code size) the evaluation skills' codes; episode i plays skill i % K

    @property
    def num_skills(self) -> int:
        """K, the skills an evaluation plays."""
        return int(self.codes.shape[0])

    @property
    def base_env(self) -> Env:
        """The environment without skill."""
        return self.env.env


def skill_space(skills: SkillConfig) -> SkillSpace | None:
    """Where continuous skills are drawn: METRA's unit sphere, continuous DIAYN's [-1, 1]^d box;
    None for one-hot skills."""
    d = skills.num_skills
    if isinstance(skills, METRAConfig) and not skills.discrete:
        return SkillSpace((-1.0,) * d, (1.0,) * d, "unit")
    if isinstance(skills, DIAYNConfig) and skills.continuous:
        return SkillSpace((-1.0,) * d, (1.0,) * d, "box")
    return None


def evaluation_codes(skills: SkillConfig, num_eval: int) -> Array:
    """The codes of the skills evaluations play: the K one-hots, or `num_eval` continuous skills
    (unit vectors with d = 2: evenly spaced angles; else drawn once from key 0)."""
    space = skill_space(skills)
    if space is None:
        return jnp.eye(skills.num_skills, dtype=jnp.float32)
    if space.kind == "unit" and space.size == 2:
        theta = 2.0 * np.pi * np.arange(num_eval) / num_eval
        return jnp.asarray(np.stack([np.cos(theta), np.sin(theta)], axis=-1), jnp.float32)
    with jax.ensure_compile_time_eval():
        return space.sample(jax.random.PRNGKey(0), (num_eval,))


def skill_module(skills: SkillConfig, obs_size: int, descriptor_size: int) -> RewardModule:
    """DIAYN's discriminator, DADS's skill-dynamics model or METRA's phi, by the config's type."""
    if isinstance(skills, DIAYNConfig):
        return make_diayn_module(skills, obs_size, descriptor_size)
    if isinstance(skills, METRAConfig):
        return make_metra_module(skills, obs_size, descriptor_size)
    if isinstance(skills, DADSConfig):
        return make_dads_module(skills, obs_size, descriptor_size)
    raise ValueError(f"skills: {type(skills).__name__} has no skill model")


def make_skill_discovery(
    env: Env, sac: SACConfig, skills: SkillConfig, smerl: SMERLConfig | None = None, num_eval: int = 0,
    domino: DOMiNOConfig | None = None,
) -> SkillDiscovery:
    """DIAYN, DADS or METRA (by `skills`' type) on `env`; SMERL (Kumar et al. 2020) when `smerl`
    is given; DOMiNO (Zahavy et al. 2023) on `DiscreteSkills` when `domino` is given, its
    feature the state descriptor. `num_eval`: the evaluation episodes (continuous skills: one
    skill each).

    Raises ValueError for sizes the networks refuse (messages name `skills.` keys for the
    skill model's).
    """
    if domino is not None or isinstance(skills, DiscreteSkills):
        if domino is None or not isinstance(skills, DiscreteSkills):
            raise ValueError("DOMiNO: expected DiscreteSkills with a DOMiNOConfig")
        k = skills.num_skills
        one_hot_env = SkillEnv(env, k)
        agent = make_domino(
            sac, domino, k, one_hot_env.observation_size, one_hot_env.action_size, env.descriptor_size
        )
        return SkillDiscovery(one_hot_env, agent, None, off_policy.REPLAY, evaluation_codes(skills, k))
    skill_env: SkillEnv | ContinuousSkillEnv
    space = skill_space(skills)
    if space is not None:
        skill_env = ContinuousSkillEnv(env, space)
    else:
        skill_env = SkillEnv(env, skills.num_skills)
    agent = make_sac(sac, skill_env.observation_size, skill_env.action_size)
    module = skill_module(skills, env.observation_size, env.descriptor_size)
    gate = None if smerl is None else smerl_gate(smerl.target, smerl.margin)
    storage = off_policy.REPLAY if smerl is None else off_policy.EPISODE_RETURNS
    codes = evaluation_codes(skills, max(num_eval, 1))
    reverse = smerl is not None and smerl.reverse
    return SkillDiscovery(skill_env, with_skill_model(agent, module, skills, gate, reverse), module, storage, codes)


def with_codes(obs: Array, codes: Array) -> Array:
    """Observations (..., obs_size) followed by skill codes (..., code size), broadcast over steps."""
    codes = jnp.broadcast_to(codes, (*obs.shape[:-1], codes.shape[-1]))
    return jnp.concatenate([obs, codes.astype(obs.dtype)], axis=-1)


def skill_policy(sd: SkillDiscovery, agent_state: AgentState, skill: int) -> Callable[[Array], Array]:
    """The deterministic policy of skill `skill`: observations (..., obs_size) of the environment
    without skill -> actions (..., action_size), the skill's code appended as in training;
    jittable."""
    k = sd.num_skills
    if isinstance(skill, bool) or not isinstance(skill, int) or not 0 <= skill < k:
        raise ValueError(f"skill: expected an int in [0, {k}), got {skill!r}")
    params = sd.agent.policy_params(agent_state)
    code = sd.codes[skill]

    def policy(obs: Array) -> Array:
        return sd.agent.policy(params, with_codes(jnp.asarray(obs, jnp.float32), code))

    return policy


def skill_episodes(
    sd: SkillDiscovery, agent_state: AgentState, key: PRNGKey, num_episodes: int, record: RecordFn | None = None
) -> Episodes:
    """The episodes `evaluate_skills` plays from its `key`'s first half: episode i plays skill
    i % K deterministically on the environment without skill (`sd.base_env`), from the random
    start the key gives it; `record` as in `run_episodes`. Jittable."""
    params = sd.agent.policy_params(agent_state)
    codes = sd.codes[jnp.arange(num_episodes) % sd.num_skills]

    def policy(obs: Array, _: PRNGKey) -> Array:
        return sd.agent.policy(params, with_codes(obs, codes))

    return run_episodes(sd.base_env, policy, key, num_episodes, record=record)


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
    without skill (`sd.base_env`; `skill_episodes` on the first half of `key`); jittable.

    Returns the episodes' mean, std and min return and mean length (`eval_*`), the
    skill model's metrics on the evaluation steps as the training batches see them
    (`eval_<name>` over every step, `eval_final_<name>` at the episodes' last step),
    each episode's `returns`, `lengths` and descriptor (`descriptors`: "final" or
    "mean", clipped to [low, high] when given), and the `trajectories` of state
    descriptors and `mask`.
    """
    codes = sd.codes[jnp.arange(num_episodes) % sd.num_skills]
    run_key, model_key = jax.random.split(key)
    ep = skill_episodes(sd, agent_state, run_key, num_episodes)
    desc = episode_descriptors(ep, descriptor, low, high)
    tr = ep.transitions
    steps = tr.obs.shape[0]
    tr = tr._replace(obs=with_codes(tr.obs, codes), next_obs=with_codes(tr.next_obs, codes))
    flat = jax.tree.map(lambda x: x.reshape((-1, *x.shape[2:])), tr)
    info = {} if sd.module is None else sd.module.reward(agent_state.aux, flat, model_key)[1]
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
