"""QD tasks on jumanji environments: policy genotypes, fitness = return, descriptor from the states.

Any discrete-action jumanji environment wrapped by `qdrl.envs.jumanji.JumanjiEnv`
becomes a QD policy task with `jumanji_task`: genotypes are the parameters of a
deterministic tanh MLP with one output per discrete action (the action taken is
the argmax over the allowed actions), the fitness is the episode return, and the
descriptor aggregates the env's state descriptor over the episode. `snake` is
the ready-made one.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from qdrl.config import NonNegativeInt, PositiveInt
from qdrl.tasks.base import Task
from qdrl.tasks.policy import DEFAULT_EVAL_BATCH, EpisodeDescriptor, policy_task

if TYPE_CHECKING:
    from qdrl.envs.jumanji import JumanjiEnv


def jumanji_task(
    env: JumanjiEnv,
    descriptor_low: Sequence[float],
    descriptor_high: Sequence[float],
    policy_hidden: Sequence[int] = (64, 64),
    descriptor: EpisodeDescriptor = "mean",
    qd_offset: float = 0.0,
    max_fitness: float | None = None,
    name: str | None = None,
    eval_batch: int = DEFAULT_EVAL_BATCH,
    descriptor_names: Sequence[str] = (),
) -> Task:
    """A QD task of MLP policies on a wrapped jumanji env: fitness = episode return.

    Args:
      env: the wrapped environment; its state descriptor gives the task's.
      descriptor_low, descriptor_high: bounds of the episode descriptor.
      policy_hidden: hidden layer sizes of the tanh policy.
      descriptor: "mean" (state descriptor averaged over the episode) or "final".
      qd_offset: a bound below every return (0 for non-negative rewards).
      max_fitness: the best return, when known.
      name: the task's name (default: the env's).
      eval_batch: episodes rolled out together (`qdrl.tasks.policy.policy_scoring_fn`).
      descriptor_names: plot labels of the descriptor dimensions.
    """
    return policy_task(
        env.name if name is None else name,
        env,
        descriptor,
        descriptor_low,
        descriptor_high,
        qd_offset,
        policy_hidden,
        max_fitness=max_fitness,
        clip_descriptors=False,
        eval_batch=eval_batch,
        descriptor_names=descriptor_names,
    )


def snake(
    episode_length: PositiveInt = 100,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    num_rows: PositiveInt = 12,
    num_cols: PositiveInt = 12,
    start_seed: NonNegativeInt | None = 0,
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
) -> Task:
    """Snake (jumanji Snake-v1): fitness = fruits eaten, descriptor = mean head position.

    The descriptor is the head's (row, col), scaled to [0, 1]^2 (row 0 at the top),
    averaged over the episode: the region of the board where the snake spends its
    time. Every episode starts from the same board (`start_seed`, see
    `qdrl.envs.jumanji.JumanjiEnv`), so fitness and descriptor are deterministic
    functions of the policy. Random policies spread their mean head position over
    most cells of a grid of the descriptor space, while pairs of action shares fill
    few of them (deterministic policies mostly settle into back-and-forth moves
    whose shares look alike); with random starts instead (`start_seed=None`) the
    mean head position mostly reflects the start cell, so a policy's descriptor
    moves far between two evaluations. Random policies rarely eat a fruit, so early
    fitness is flat at 0 (figures in docs/benchmarks.md).
    Returns are >= 0, so `qd_offset` is 0. The policy sees the board and the action
    mask (`qdrl.envs.jumanji.snake_observation`) and moves only where the mask
    allows.
    """
    from qdrl.envs.jumanji import snake_env  # jumanji (~0.7 s to import) only when snake is built

    env = snake_env(episode_length, num_rows, num_cols, start_seed=start_seed)
    return jumanji_task(
        env,
        descriptor_low=(0.0, 0.0),
        descriptor_high=(1.0, 1.0),
        policy_hidden=policy_hidden,
        descriptor="mean",
        qd_offset=0.0,
        name="snake",
        eval_batch=eval_batch,
        descriptor_names=("mean head row", "mean head column"),
    )
