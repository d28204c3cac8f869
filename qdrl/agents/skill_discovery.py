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

from typing import NamedTuple

from qdrl import off_policy
from qdrl.agents.base import Agent
from qdrl.agents.dads import DADSConfig, make_dads_module
from qdrl.agents.diayn import DIAYNConfig, make_diayn_module
from qdrl.agents.intrinsic import RewardModule, with_skill_model
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.smerl import SMERLConfig, smerl_gate
from qdrl.envs.base import Env
from qdrl.envs.skills import SkillEnv

__all__ = ["SkillDiscovery", "make_skill_discovery", "skill_module"]


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
