"""UVFA for feature-space skills: SAC on (s, z) with the reward -||phi(s') - z||.

The baseline and ablation of QDAC (Grillotti et al. 2024, ICML) named after universal value
function approximators (Schaul et al. 2015): a skill-conditioned SAC whose reward is minus
the distance from the step's feature phi(s') to the skill z, both in the agent's view of the
feature space (`SkillSpace.normalise`), optionally plus the task reward (`extrinsic_scale`).
It pursues the skill at every step rather than in the episode's average, which is what
QDAC's successor features add. The reward has no model: a `RewardModule` without parameters
on the one intrinsic-reward wrapper (`qdrl.agents.intrinsic`).
"""

from __future__ import annotations

import jax.numpy as jnp

from qdrl.agents.base import Agent
from qdrl.agents.intrinsic import Info, RewardModule, with_intrinsic_reward
from qdrl.envs.skills import SkillSpace, skill_code
from qdrl.types import Array, Metrics, PRNGKey, Transition


def feature_distance(transitions: Transition, space: SkillSpace) -> Array:
    """||phi(s') - z|| per transition (B,), in the agent's view of the feature space."""
    phi = space.normalise(transitions.next_desc)
    return jnp.linalg.norm(phi - skill_code(transitions.obs, space.size), axis=-1)


def make_uvfa_module(space: SkillSpace) -> RewardModule:
    """The reward -||phi(s') - z|| as a `RewardModule` with no parameters to train."""

    def init(key: PRNGKey) -> tuple[()]:
        del key
        return ()

    def reward(aux: tuple[()], transitions: Transition, key: PRNGKey) -> tuple[Array, Info]:
        del aux, key
        dist = feature_distance(transitions, space)
        return -dist, {"feature_distance": dist}

    def update(aux: tuple[()], transitions: Transition, key: PRNGKey) -> tuple[tuple[()], Metrics]:
        del transitions, key
        return aux, {}

    return RewardModule(init=init, reward=reward, update=update)


def make_uvfa(agent: Agent, space: SkillSpace, distance_scale: float = 1.0, extrinsic_scale: float = 0.0) -> Agent:
    """`agent` (SAC on skill-conditioned observations) trained on
    extrinsic_scale r - distance_scale ||phi(s') - z||."""
    return with_intrinsic_reward(agent, make_uvfa_module(space), distance_scale, extrinsic_scale)
