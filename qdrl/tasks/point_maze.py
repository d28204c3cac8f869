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

from qdrl.config import PositiveInt
from qdrl.envs.point_maze import PointMazeEnv
from qdrl.tasks.base import Task
from qdrl.tasks.policy import DEFAULT_EVAL_BATCH, Activation, policy_task


def point_maze(
    episode_length: PositiveInt = 100,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """Point maze with MLP policies (QDax `pointmaze`): fitness = return, descriptor = final x-y.

    `qd_offset` is -2 sqrt(2) x `episode_length`: no point of the arena is farther
    than the arena's diagonal from the goal, so every return is above it.
    """
    env = PointMazeEnv(episode_length=episode_length)
    return policy_task(
        "point_maze",
        env,
        "final",
        (-1.0, -1.0),
        (1.0, 1.0),
        qd_offset=-2.0 * math.sqrt(2.0) * episode_length,
        policy_hidden=policy_hidden,
        policy_activation=policy_activation,
        clip_descriptors=False,
        eval_batch=eval_batch,
        descriptor_names=("final x", "final y"),
    )
