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

from typing import Any, NamedTuple

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


# -- continuous skills: targets in a feature space (QDAC), directions on a sphere (METRA) --


class SkillSpace(NamedTuple):
    """Where continuous skills live and how the agent sees them.

    A box [low, high]^D of feature targets (QDAC; Grillotti et al. 2024): skills are drawn
    uniformly and shown to the agent rescaled to [-1, 1]^D, as QDAC's code normalises them.
    An angular space (`angular`): a heading theta ~ U[-pi, pi] seen as (cos theta, sin theta),
    unchanged. A unit sphere (`unit`): z ~ N(0, I) normalised to length 1 (METRA; Park et
    al. 2024), unchanged. `low` / `high` bound the raw skill (the sphere's and the circle's
    [-1, 1]^D).
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    kind: str = "box"  # "box", "angular" or "unit"

    @property
    def size(self) -> int:
        return len(self.low)

    def sample(self, key: PRNGKey, shape: tuple[int, ...] = ()) -> Array:
        """Raw skills of shape `shape + (D,)`, drawn from the space's prior."""
        d = self.size
        if self.kind == "angular":
            theta = jax.random.uniform(key, shape, minval=-jnp.pi, maxval=jnp.pi)
            return jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)
        if self.kind == "unit":
            z = jax.random.normal(key, (*shape, d))
            return z / jnp.maximum(jnp.linalg.norm(z, axis=-1, keepdims=True), 1e-8)
        low, high = jnp.asarray(self.low, jnp.float32), jnp.asarray(self.high, jnp.float32)
        return jax.random.uniform(key, (*shape, d), minval=low, maxval=high)

    def normalise(self, x: Array) -> Array:
        """Raw skills or features (..., D) as the agent sees them: a box rescaled to [-1, 1]."""
        if self.kind != "box":
            return jnp.asarray(x, jnp.float32)
        low, high = jnp.asarray(self.low, jnp.float32), jnp.asarray(self.high, jnp.float32)
        return 2.0 * (jnp.asarray(x, jnp.float32) - low) / (high - low) - 1.0

    def check(self, where: str) -> None:
        """ValueError naming `where` unless the space is well formed."""
        if self.kind not in ("box", "angular", "unit"):
            raise ValueError(f"{where}: expected a skill space kind 'box', 'angular' or 'unit', got {self.kind!r}")
        if not self.low or len(self.low) != len(self.high):
            raise ValueError(f"{where}: expected bounds of one equal, positive length, got {self.low} and {self.high}")
        if any(not lo < hi for lo, hi in zip(self.low, self.high, strict=True)):
            raise ValueError(f"{where}: expected every lower bound below its upper bound, got {self.low} and {self.high}")
        if self.kind == "angular" and self.size != 2:
            raise ValueError(f"{where}: an angular skill space is (cos, sin): expected 2 dimensions, got {self.size}")


def skill_code(obs: Array, skill_size: int) -> Array:
    """The skill code (the agent's view of z) at the end of a skill-conditioned observation."""
    return obs[..., -skill_size:]


def with_skill_code(obs: Array, code: Array) -> Array:
    """A skill-conditioned observation whose skill code is replaced by `code` (relabelling)."""
    return jnp.concatenate([obs[..., : -code.shape[-1]], code], axis=-1)


class ContinuousSkillEnv(Env):
    """`env` with a skill z drawn from `space` at every reset and its code appended to the observation.

    Reward, termination, descriptor and episode length are `env`'s; the observation grows by
    the skill's D entries (`space.normalise(z)`), which `skill_code` reads back.
    """

    def __init__(self, env: Env, space: SkillSpace) -> None:
        space.check("skill space")
        self.env = env
        self.space = space
        self.skill_size = space.size
        self.name = f"{env.name}+skills"
        self.action_size = env.action_size
        self.episode_length = env.episode_length

    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        env_key, skill_key = jax.random.split(key)
        inner, obs, desc = self.env._reset(env_key)
        code = self.space.normalise(self.space.sample(skill_key))
        obs = jnp.concatenate([jnp.asarray(obs, jnp.float32), code], axis=-1)
        return (inner, code), obs, desc

    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        env_inner, code = inner
        env_inner, obs, reward, terminated, desc = self.env._step(env_inner, action)
        obs = jnp.concatenate([jnp.asarray(obs, jnp.float32), code], axis=-1)
        return (env_inner, code), obs, reward, terminated, desc
