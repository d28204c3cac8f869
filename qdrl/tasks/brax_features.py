"""The brax tasks of QDAC: skills are targets of an episode's average feature.

Grillotti, Faldor, González León and Cully, ICML 2024, "Quality-Diversity
Actor-Critic: Learning High-Performing and Diverse Behaviors via Value and
Successor Features Critics" (code: adaptive-intelligent-robotics/QDAC, its
features in `dreamerv3/embodied/core/feat_wrappers.py`). Each task pairs a robot
with a per-step feature function (a state descriptor of `qdrl.envs.brax`); a skill
is a target for the average of the feature over an episode, so the episode
descriptor is the mean of the per-step features (clipped to the bounds):

| task | feature (per step) | bounds | fitness (episode return) | QDax reward offset |
|---|---|---|---|---|
| walker2d_feet_contact | feet contact, 0/1 per foot (2) | [0, 1]^2 | forward + survival - control | 1.413 |
| ant_feet_contact | feet contact, 0/1 per foot (4) | [0, 1]^4 | forward + survival - control | 3.24 |
| humanoid_feet_contact | feet contact, 0/1 per foot (2) | [0, 1]^2 | forward + survival - control | 0.0 |
| ant_velocity | torso x-y velocity | [-5, 5]^2 | forward + survival - control | 3.24 |
| humanoid_jump | lowest contact point's height | [0, 0.25] | forward + survival - control | 0.0 |
| humanoid_angle | pelvis heading (cos, sin) | [-1, 1]^2 | forward + survival - control | 0.0 |

The fitness is brax's own reward of the robot, as in QDAC's QDax baselines (which
build the environments with `brax.envs.create`), and `qd_offset` is
`-reward_offset * episode_length` with QDax's offset of the robot's feet-contact
task (`qdrl.tasks.brax_qd.REWARD_OFFSETS`). `FEATURE_SPACES` holds each task's
feature space: the state descriptor, its bounds, and whether the skills are angles
(humanoid_angle's skills are angles drawn in [-pi, pi] and mapped to (cos, sin),
QDAC's `AngularSpace`).

Genotypes, policies and backends are those of `qdrl.tasks.brax_qd`: tanh MLP
policies, brax's `spring` pipeline by default.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from qdrl.config import PositiveInt
from qdrl.envs.brax import Backend, BraxEnv, state_descriptor_names
from qdrl.envs.skills import SkillSpace
from qdrl.tasks.base import Task
from qdrl.tasks.brax_qd import DEFAULT_BACKEND, REWARD_OFFSETS, brax_policy_task
from qdrl.tasks.policy import DEFAULT_EVAL_BATCH, Activation


@dataclasses.dataclass(frozen=True)
class FeatureSpace:
    """A task's feature space: the state descriptor, its bounds, and whether skills are angles.

    `angular`: the feature is an angle's (cos, sin); a skill is an angle in [-pi, pi],
    mapped to (cos, sin) (QDAC's `AngularSpace`).
    """

    state_descriptor: str
    low: tuple[float, ...]
    high: tuple[float, ...]
    angular: bool = False


FEATURE_SPACES: dict[str, FeatureSpace] = {
    "walker2d_feet_contact": FeatureSpace("feet_contact", (0.0,) * 2, (1.0,) * 2),
    "ant_feet_contact": FeatureSpace("feet_contact", (0.0,) * 4, (1.0,) * 4),
    "humanoid_feet_contact": FeatureSpace("feet_contact", (0.0,) * 2, (1.0,) * 2),
    "ant_velocity": FeatureSpace("velocity", (-5.0, -5.0), (5.0, 5.0)),
    "humanoid_jump": FeatureSpace("jump", (0.0,), (0.25,)),
    "humanoid_angle": FeatureSpace("angle", (-1.0, -1.0), (1.0, 1.0), angular=True),
}


def _feature_task(
    task: str,
    episode_length: int,
    backend: str,
    policy_hidden: tuple[int, ...],
    eval_batch: int,
    policy_activation: str,
) -> Task:
    robot = task.split("_", 1)[0]
    space = FEATURE_SPACES[task]
    env = BraxEnv(robot, backend, episode_length, state_descriptor=space.state_descriptor)
    return brax_policy_task(
        task,
        env,
        "mean",
        space.low,
        space.high,
        -REWARD_OFFSETS[f"{robot}_uni"] * episode_length,
        policy_hidden,
        eval_batch,
        state_descriptor_names(space.state_descriptor, robot) or (),
        policy_activation,
    )


def walker2d_feet_contact(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDAC's Walker Feet Contact: feet-contact rates (right, left) in [0, 1]^2; fitness = its reward.

    Reward per step: forward velocity + 1 (survival) - 0.001 |a|^2; terminates when
    the torso falls or tilts.
    """
    return _feature_task(
        "walker2d_feet_contact",
        episode_length,
        backend,
        policy_hidden,
        eval_batch,
        policy_activation,
    )


def ant_feet_contact(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDAC's Ant Feet Contact: contact rates of the ant's 4 feet in [0, 1]^4; fitness = its reward.

    Reward per step: forward velocity + 1 (survival) - 0.5 |a|^2; terminates when the
    torso leaves z in [0.2, 1].
    """
    return _feature_task(
        "ant_feet_contact", episode_length, backend, policy_hidden, eval_batch, policy_activation
    )


def humanoid_feet_contact(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDAC's Humanoid Feet Contact: contact rates (right, left; the shin links) in [0, 1]^2.

    Fitness = brax's humanoid reward summed: 1.25 x centre-of-mass forward velocity
    + 5 (survival) - 0.1 |ctrl|^2; terminates when the torso leaves z in [1, 2].
    """
    return _feature_task(
        "humanoid_feet_contact",
        episode_length,
        backend,
        policy_hidden,
        eval_batch,
        policy_activation,
    )


def ant_velocity(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDAC's Ant Velocity: the ant's average torso x-y velocity in [-5, 5]^2; fitness = its reward.

    Reward per step: forward velocity + 1 (survival) - 0.5 |a|^2; terminates when the
    torso leaves z in [0.2, 1].
    """
    return _feature_task(
        "ant_velocity", episode_length, backend, policy_hidden, eval_batch, policy_activation
    )


def humanoid_jump(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDAC's Humanoid Jump: the average height of the lowest contact point in [0, 0.25].

    The contact points are brax's, midway between a foot and the floor
    (`qdrl.envs.brax.lowest_contact_height`). Fitness = brax's humanoid reward summed:
    1.25 x centre-of-mass forward velocity + 5 (survival) - 0.1 |ctrl|^2.
    """
    return _feature_task(
        "humanoid_jump", episode_length, backend, policy_hidden, eval_batch, policy_activation
    )


def humanoid_angle(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    policy_activation: Activation = "tanh",
) -> Task:
    """QDAC's Humanoid Angle: the average (cos, sin) of the pelvis' heading in [-1, 1]^2.

    Skills are headings in [-pi, pi] (`FEATURE_SPACES["humanoid_angle"].angular`).
    Fitness = brax's humanoid reward summed: 1.25 x centre-of-mass forward velocity
    + 5 (survival) - 0.1 |ctrl|^2.
    """
    return _feature_task(
        "humanoid_angle", episode_length, backend, policy_hidden, eval_batch, policy_activation
    )


FEATURE_TASKS: dict[str, Callable[..., Task]] = {
    "walker2d_feet_contact": walker2d_feet_contact,
    "ant_feet_contact": ant_feet_contact,
    "humanoid_feet_contact": humanoid_feet_contact,
    "ant_velocity": ant_velocity,
    "humanoid_jump": humanoid_jump,
    "humanoid_angle": humanoid_angle,
}


def feature_space(task: str) -> SkillSpace | None:
    """The skill space of feature task `task` (where its skills and evaluation targets are
    drawn), None for a task that is not one of `FEATURE_SPACES`."""
    fs = FEATURE_SPACES.get(task)
    if fs is None:
        return None
    return SkillSpace(tuple(fs.low), tuple(fs.high), "angular" if fs.angular else "box")
