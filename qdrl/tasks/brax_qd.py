"""The brax QD tasks of the QD-RL literature: feet contact (uni), final position (omni), maze, trap.

Definitions follow QDax's brax tasks (`qdax/tasks/brax/v2/__init__.py` and, for the
maze and the trap, `qdax/environments/exploration_wrappers.py`; Chalumeau, Lim et al.
2023, "QDax: A library for quality-diversity and population-based algorithms with
hardware acceleration"), which the benchmark of Flageat et al. 2022 ("Benchmarking
quality-diversity algorithms on neuroevolution for reinforcement learning") uses:

| task | descriptor | bounds | fitness (episode return) | QDax reward offset |
|---|---|---|---|---|
| ant_uni | feet-contact rates (4) | [0, 1]^4 | forward + survival - control | 3.24 |
| halfcheetah_uni | feet-contact rates (2) | [0, 1]^2 | forward - control | 9.231 |
| walker2d_uni | feet-contact rates (2) | [0, 1]^2 | forward + survival - control | 1.413 |
| hopper_uni | feet-contact rate (1) | [0, 1] | forward + survival - control | 0.9 |
| humanoid_uni | feet-contact rates (2) | [0, 1]^2 | forward + survival - control | 0.0 |
| ant_omni | final torso x-y | [-30, 30]^2 | survival - control | 3.0 |
| halfcheetah_omni | final torso x | [-0.75 T, 0.75 T] | -control | 0.6 (exact) |
| humanoid_omni | final torso x-y | [-30, 30]^2 | survival - control | 0.0 |
| ant_trap | final torso x-y | [0, 30] x [-8, 8] | forward + survival - control | 3.38 |
| ant_maze | final torso x-y | [-5, 40]^2 | -sum of distances to the target | 40.32 |

The feet-contact descriptor is the mean over the episode's steps of the per-step
0/1 vector "foot i touches the ground" (QDax `get_feet_contact_proportion` averages
the descriptors before each step, including the reset state; here the ones after
each step: a one-step shift). Final x-y descriptors are clipped to their bounds,
as QDax's `XYPositionWrapper` clips its state descriptor.

`qd_offset` is what qdrl subtracts from fitnesses before summing the QD score:
`-reward_offset * episode_length`, with QDax's experimentally determined reward
offsets (which make most, not provably all, returns positive). For the maze, whose
per-step reward is minus a distance, it is minus the largest distance from the
target to a point of the descriptor bounds (|(35, 0) - (-5, 40)| = 56.57) times the
episode length, so every return in the bounds counts non-negatively (QDax uses
40.32, the distance to the corner (-5, -5)).

Genotypes are batched haiku parameter trees of `policy_network(action_size,
policy_hidden)` (tanh MLP, 64x64 in the literature), initialised by
`init_policies`; they are unbounded (`genotype_low/high = -inf/inf`).

Backends: every task defaults to brax's `spring` pipeline, the fastest on CPU (env
steps/s per task in docs/benchmarks.md) and QDax's own default for these tasks.
Spring resolves foot-floor contacts and, the walls being static geoms like the
floor, foot/torso-wall contacts: a thrown ant stops at the walls
(tests/test_brax_walls.py). `mjx` (physically closest to MuJoCo, contacts always
computed) and `positional` also stop the ant at the walls;
`generalized` does too, but on this stack (brax 0.14.2, mujoco 4.0) its ant sinks
through the floor (torso z from 0.59 to 0.30 in 40 zero-action steps, without any
wall), so it is not meaningful for the ant tasks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from qdrl.config import PositiveInt
from qdrl.envs.brax import FEET_NAMES, Backend, BraxEnv
from qdrl.tasks.base import Task
from qdrl.tasks.policy import DEFAULT_EVAL_BATCH, Activation, EpisodeDescriptor, policy_task

# QDax `reward_offset` (qdax/tasks/brax/v2/__init__.py; anttrap and antmaze from
# qdax/environments/__init__.py).
REWARD_OFFSETS: dict[str, float] = {
    "ant_uni": 3.24,
    "halfcheetah_uni": 9.231,
    "walker2d_uni": 1.413,
    "hopper_uni": 0.9,
    "humanoid_uni": 0.0,
    "ant_omni": 3.0,
    "humanoid_omni": 0.0,
    "ant_trap": 3.38,
    "ant_maze": 40.32,
}

OMNI_BOUNDS = ((-30.0, -30.0), (30.0, 30.0))
TRAP_BOUNDS = ((0.0, -8.0), (30.0, 8.0))
MAZE_BOUNDS = ((-5.0, -5.0), (40.0, 40.0))
MAZE_TARGET = (35.0, 0.0)
# Largest distance from the maze target to a point of the descriptor bounds.
MAZE_MAX_DISTANCE = max(
    math.dist(MAZE_TARGET, (x, y))
    for x in (MAZE_BOUNDS[0][0], MAZE_BOUNDS[1][0])
    for y in (MAZE_BOUNDS[0][1], MAZE_BOUNDS[1][1])
)

DEFAULT_BACKEND: Backend = "spring"


FINAL_XY_NAMES = ("final x", "final y")
# halfcheetah_omni's bound on the final x, per step of the episode: 15 m/s for brax's 0.05 s
# step, above the fastest running gaits SAC learns (about 12 m/s).
CHEETAH_X_PER_STEP = 0.75
# The largest control cost per step of halfcheetah (0.1 |a|^2, six actions in [-1, 1]).
CHEETAH_MAX_CONTROL_COST = 0.6


def brax_policy_task(
    name: str,
    env: BraxEnv,
    descriptor: EpisodeDescriptor,
    descriptor_low: Sequence[float],
    descriptor_high: Sequence[float],
    qd_offset: float,
    policy_hidden: Sequence[int] = (64, 64),
    eval_batch: int = DEFAULT_EVAL_BATCH,
    descriptor_names: Sequence[str] = (),
    policy_activation: str = "tanh",
    random_start: bool = False,
) -> Task:
    """A `Task` whose genotypes are policies acting in `env` for one episode each.

    The episode's state descriptor ("final" or "mean" over its steps) is clipped to
    the descriptor bounds; the fitness is the episode return. Episodes are rolled
    out in blocks of `eval_batch` (`qdrl.tasks.policy.policy_scoring_fn`), from one fixed
    start state, or each from its own random one with `random_start`.
    """
    return policy_task(
        name, env, descriptor, descriptor_low, descriptor_high, qd_offset, policy_hidden,
        eval_batch=eval_batch, descriptor_names=descriptor_names, policy_activation=policy_activation,
        random_start=random_start,
    )


def _uni(
    task: str, robot: str, episode_length: int, backend: str, policy_hidden: Sequence[int],
    eval_batch: int, policy_activation: str, random_start: bool = False,
) -> Task:
    env = BraxEnv(robot, backend, episode_length, state_descriptor="feet_contact")
    n_feet = env.descriptor_size
    return brax_policy_task(
        task,
        env,
        "mean",
        (0.0,) * n_feet,
        (1.0,) * n_feet,
        -REWARD_OFFSETS[task] * episode_length,
        policy_hidden,
        eval_batch,
        FEET_NAMES[robot],
        policy_activation,
        random_start,
    )


def _omni(
    task: str, robot: str, episode_length: int, backend: str, policy_hidden: Sequence[int],
    eval_batch: int, policy_activation: str,
) -> Task:
    env = BraxEnv(robot, backend, episode_length, state_descriptor="xy", reward="no_forward")
    return brax_policy_task(
        task, env, "final", *OMNI_BOUNDS, -REWARD_OFFSETS[task] * episode_length, policy_hidden,
        eval_batch, FINAL_XY_NAMES, policy_activation,
    )


def ant_uni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
    random_start: bool = False,  # each episode from its own random state (noisy evaluations)
) -> Task:
    """Ant, feet-contact rates of its 4 feet in [0, 1]^4; fitness = brax's ant reward summed.

    Reward per step: forward velocity + 1 (survival) - 0.5 |a|^2 (brax's contact
    cost is 0). The episode terminates when the torso leaves z in [0.2, 1].
    Default backend spring (fastest; QDax's default).
    """
    return _uni(
        "ant_uni", "ant", episode_length, backend, policy_hidden, eval_batch, policy_activation, random_start,
    )


def halfcheetah_uni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
    random_start: bool = False,  # each episode from its own random state (noisy evaluations)
) -> Task:
    """HalfCheetah, feet-contact rates (back foot, front foot) in [0, 1]^2; fitness = its reward.

    Reward per step: forward velocity - 0.1 |a|^2; never terminates. Default
    backend spring (halfcheetah on mjx with brax's default solver is several times
    slower).
    """
    return _uni(
        "halfcheetah_uni", "halfcheetah", episode_length, backend, policy_hidden, eval_batch, policy_activation, random_start,
    )


def walker2d_uni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
    random_start: bool = False,  # each episode from its own random state (noisy evaluations)
) -> Task:
    """Walker2d, feet-contact rates (right foot, left foot) in [0, 1]^2; fitness = its reward.

    Reward per step: forward velocity + 1 (survival) - 0.001 |a|^2; terminates
    when the torso falls or tilts. Default backend spring (fastest).
    """
    return _uni(
        "walker2d_uni", "walker2d", episode_length, backend, policy_hidden, eval_batch, policy_activation, random_start,
    )


def hopper_uni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
    random_start: bool = False,  # each episode from its own random state (noisy evaluations)
) -> Task:
    """Hopper, contact rate of its foot in [0, 1]; fitness = its reward.

    Reward per step: forward velocity + 1 (survival) - 0.001 |a|^2; terminates
    when unhealthy. Default backend spring (fastest).
    """
    return _uni(
        "hopper_uni", "hopper", episode_length, backend, policy_hidden, eval_batch, policy_activation, random_start,
    )


def humanoid_uni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
    random_start: bool = False,  # each episode from its own random state (noisy evaluations)
) -> Task:
    """Humanoid, contact rates of its feet (right, left; the shin links) in [0, 1]^2.

    Fitness = brax's humanoid reward summed: 1.25 x centre-of-mass forward velocity
    + 5 (survival) - 0.1 |ctrl|^2; terminates when the torso leaves z in [1, 2].
    Default backend spring (fastest; QDax's default).
    """
    return _uni(
        "humanoid_uni", "humanoid", episode_length, backend, policy_hidden, eval_batch, policy_activation, random_start,
    )


def ant_omni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """Ant, final torso x-y in [-30, 30]^2; fitness = survival - control cost (no forward term).

    Reward per step: brax's ant reward minus its `reward_forward` metric, i.e.
    1 - 0.5 |a|^2. Default backend spring (fastest; QDax's default).
    """
    return _omni("ant_omni", "ant", episode_length, backend, policy_hidden, eval_batch, policy_activation)


def halfcheetah_omni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """HalfCheetah, final torso x in [-0.75 T, 0.75 T] (T the episode length); fitness = minus
    the control cost (brax's reward without its run term: -0.1 |a|^2).

    The one-dimensional final-position task: running either way is diversity, not fitness.
    METRA (Park, Rybkin & Levine 2024) measures its HalfCheetah skills by the x positions they
    reach (the count of 1-wide x bins visited). Its QD offset is the largest control cost,
    0.6 per step, so every return is non-negative. Default backend spring.
    """
    env = BraxEnv("halfcheetah", backend, episode_length, state_descriptor="x", reward="no_forward")
    bound = CHEETAH_X_PER_STEP * episode_length
    return brax_policy_task(
        "halfcheetah_omni", env, "final", (-bound,), (bound,), -CHEETAH_MAX_CONTROL_COST * episode_length,
        policy_hidden, eval_batch, ("final x",), policy_activation,
    )


def humanoid_omni(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """Humanoid, final torso x-y in [-30, 30]^2; fitness = survival - control cost.

    Reward per step: brax's humanoid reward minus its `reward_linvel` metric, i.e.
    5 - 0.1 |ctrl|^2. Default backend spring (fastest; QDax's default).
    """
    return _omni("humanoid_omni", "humanoid", episode_length, backend, policy_hidden, eval_batch, policy_activation)


def ant_trap(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDax's AntTrap: final torso x-y in [0, 30] x [-8, 8]; fitness = the ant's reward.

    A U-shaped trap opens towards the ant (`qdrl.envs.brax_walls.AntTrap`); the
    forward reward leads straight into it, the descriptor rewards going around.
    Default backend spring: the fastest, and it collides the feet and torso with
    the walls (checked in the tests).
    """
    env = BraxEnv("anttrap", backend, episode_length, state_descriptor="xy")
    return brax_policy_task(
        "ant_trap",
        env,
        "final",
        *TRAP_BOUNDS,
        -REWARD_OFFSETS["ant_trap"] * episode_length,
        policy_hidden,
        eval_batch,
        FINAL_XY_NAMES,
        policy_activation,
    )


def ant_maze(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDax's AntMaze: final torso x-y in [-5, 40]^2; fitness = -sum over steps of the distance to the target.

    The target (35, 0) hides behind a wall (`qdrl.envs.brax_walls.AntMaze`).
    qd_offset = -56.57 x episode_length (the largest distance inside the bounds).
    Default backend spring: the fastest, and it collides the feet and torso with
    the walls (checked in the tests).
    """
    env = BraxEnv("antmaze", backend, episode_length, state_descriptor="xy")
    return brax_policy_task(
        "ant_maze",
        env,
        "final",
        *MAZE_BOUNDS,
        -MAZE_MAX_DISTANCE * episode_length,
        policy_hidden,
        eval_batch,
        FINAL_XY_NAMES,
        policy_activation,
    )


BRAX_TASKS = {
    "ant_uni": ant_uni,
    "halfcheetah_uni": halfcheetah_uni,
    "walker2d_uni": walker2d_uni,
    "hopper_uni": hopper_uni,
    "humanoid_uni": humanoid_uni,
    "ant_omni": ant_omni,
    "halfcheetah_omni": halfcheetah_omni,
    "humanoid_omni": humanoid_omni,
    "ant_trap": ant_trap,
    "ant_maze": ant_maze,
}
