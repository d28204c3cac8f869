"""Skill-conditioned environments: a skill drawn at every reset, its one-hot code in the observation.

Skill-discovery agents (DIAYN, Eysenbach et al. 2018; DADS, Sharma et al. 2020;
SMERL, Kumar et al. 2020) condition the policy on a latent skill z held fixed for
a whole episode. `SkillEnv` keeps z in the environment's state: each reset
(the first, and every automatic one) draws z uniformly from `num_skills` skills
and the observation becomes `concat(obs, one_hot(z))`. The policy (and SAC's
critics) thus see obs + z, and the one rollout loop, its auto-reset and the
replay buffer work unchanged. The skill of any stored transition is recovered
from its observation's last `num_skills` entries (`skill_of`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from qdrl.envs.base import Env
from qdrl.types import Array, PRNGKey


def append_skill(obs: Array, skills: Array, num_skills: int) -> Array:
    """`concat(obs, one_hot(skills))` along the last axis; `skills` int of shape `obs.shape[:-1]`."""
    return jnp.concatenate([obs, jax.nn.one_hot(skills, num_skills, dtype=obs.dtype)], axis=-1)


def skill_of(obs: Array, num_skills: int) -> Array:
    """The skill index (int32, shape `obs.shape[:-1]`) coded in a skill-conditioned observation."""
    return jnp.argmax(obs[..., -num_skills:], axis=-1).astype(jnp.int32)


def strip_skill(obs: Array, num_skills: int) -> Array:
    """The environment's own observation: a skill-conditioned one without its one-hot code."""
    return obs[..., :-num_skills]


class SkillEnv(Env):
    """`env` with a uniformly drawn skill per episode, appended to the observation as a one-hot.

    Reward, termination, descriptor and episode length are `env`'s; only the
    observation grows by `num_skills` entries.
    """

    def __init__(self, env: Env, num_skills: int) -> None:
        if isinstance(num_skills, bool) or not isinstance(num_skills, int) or num_skills < 1:
            raise ValueError(f"num_skills: expected a positive int, got {num_skills!r}")
        self.env = env
        self.num_skills = num_skills
        self.name = f"{env.name}+skills"
        self.action_size = env.action_size
        self.episode_length = env.episode_length

    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        env_key, skill_key = jax.random.split(key)
        inner, obs, desc = self.env._reset(env_key)
        skill = jax.random.randint(skill_key, (), 0, self.num_skills, dtype=jnp.int32)
        obs = append_skill(jnp.asarray(obs, jnp.float32), skill, self.num_skills)
        return (inner, skill), obs, desc

    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        env_inner, skill = inner
        env_inner, obs, reward, terminated, desc = self.env._step(env_inner, action)
        obs = append_skill(jnp.asarray(obs, jnp.float32), skill, self.num_skills)
        return (env_inner, skill), obs, reward, terminated, desc
