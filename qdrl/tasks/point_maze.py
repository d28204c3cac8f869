"""Point-maze QD task: policy genotypes, fitness = return, descriptor = final x-y position.

The QD-PG / QDax point maze (`qdrl.envs.point_maze.PointMazeEnv`; Pierrot et al.
2022, Flageat et al. 2022, "Benchmarking quality-diversity algorithms on
neuroevolution for reinforcement learning"): genotypes are the parameters of a
deterministic tanh MLP policy, the fitness is the episode return (minus the summed
distance to the goal, so a policy that reaches the goal quickly scores highest),
and the descriptor is where the point ends the episode, in [-1, 1]^2.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp

from qdrl.envs.point_maze import PointMazeEnv
from qdrl.tasks.base import Task
from qdrl.tasks.policy import init_policies, num_parameters, policy_network, policy_scoring_fn
from qdrl.types import Params, PRNGKey


def point_maze(episode_length: int = 100, policy_hidden: tuple[int, ...] = (64, 64)) -> Task:
    """Point maze with MLP policies (QDax `pointmaze`): fitness = return, descriptor = final x-y.

    `qd_offset` is -2 sqrt(2) x `episode_length`: no point of the arena is farther
    than the arena's diagonal from the goal, so every return is above it.
    """
    env = PointMazeEnv(episode_length=episode_length)
    hidden: Sequence[int] = tuple(int(h) for h in policy_hidden)
    network = policy_network(env.action_size, hidden)
    # zeros of the right shapes: an actual init, unjitted, costs seconds on CPU
    shapes = jax.eval_shape(
        lambda key: init_policies(network, env.observation_size, key, 1), jax.random.PRNGKey(0)
    )
    template: Params = jax.tree.map(lambda s: jnp.zeros(s.shape[1:], s.dtype), shapes)

    def init_fn(key: PRNGKey, n: int) -> Params:
        return init_policies(network, env.observation_size, key, n)

    return Task(
        name="point_maze",
        scoring_fn=policy_scoring_fn(env, network, descriptor="final"),
        descriptor_low=(-1.0, -1.0),
        descriptor_high=(1.0, 1.0),
        genotype_size=num_parameters(template),
        genotype_low=-math.inf,
        genotype_high=math.inf,
        qd_offset=-2.0 * math.sqrt(2.0) * episode_length,
        init_fn=init_fn,
        genotype_template=template,
    )
