"""SMERL: Structured Maximum Entropy RL (Kumar et al. 2020, arXiv:2010.14484), on DIAYN or DADS.

SMERL learns skills that all solve the task, each in its own way: the policy
maximises the task reward, plus a diversity reward only on trajectories that
are already near-optimal (eq. 3 of the paper),

    r = r_task + lambda * 1[R(tau) >= R* - epsilon] * r_div,

where R(tau) is the return of the episode the transition belongs to, R* the
target return and epsilon the margin. Reverse SMERL (`reverse`, the QDAC paper's
baseline) moves the gate to the task reward: r = 1[R(tau) < R* - epsilon] r_task + lambda r_div. r_div is DIAYN's discriminator reward (the
paper) or DADS's skill-dynamics reward. Episode returns are only known when an
episode ends, so the training loop stores transitions with their episode's return
(`off_policy.EPISODE_RETURNS`, a `buffers.TrajectoryBuffer`); transitions of
episodes still running read NaN and get no diversity reward.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax.numpy as jnp

from qdrl.agents.base import Agent
from qdrl.agents.dads import DADSConfig, make_dads
from qdrl.agents.diayn import DIAYNConfig, make_diayn
from qdrl.agents.intrinsic import Gate
from qdrl.config import NonNegativeFloat, check_fields
from qdrl.types import Array


@dataclasses.dataclass(frozen=True)
class SMERLConfig:
    """The `[smerl]` section: when trajectories count as near-optimal.

    Kumar et al. 2020 set R* to the return of a policy trained on the task alone
    and epsilon to a fraction of it; both are absolute returns here (as in QDax).
    lambda is the skill model's `diversity_scale` and the task reward's weight its
    `extrinsic_scale`, which SMERL runs default to 1 (the paper's r_task).
    """

    # R*, the target episode return.
    target: float = 0.0
    # epsilon: episodes with return >= target - margin receive the diversity reward.
    margin: NonNegativeFloat = 0.0
    # Reverse SMERL (a baseline of the QDAC paper, Grillotti et al. 2024): the diversity reward on
    # every transition, the task reward only on episodes below target - margin.
    reverse: bool = False

    def check(self) -> None:
        """Raises ValueError naming `smerl.target` or `smerl.margin` when out of range."""
        check_fields(self, "smerl")


def smerl_gate(target: float, margin: float) -> Gate:
    """episode_return -> 1.0 where return >= target - margin, else 0.0 (NaN: 0.0)."""
    threshold = float(target) - float(margin)

    def gate(episode_return: Array) -> Array:
        return (episode_return >= threshold).astype(jnp.float32)

    return gate


def make_smerl(
    agent: Agent,
    base: Literal["diayn", "dads"],
    skills: DIAYNConfig | DADSConfig,
    config: SMERLConfig,
    obs_size: int,
    descriptor_size: int,
) -> Agent:
    """SMERL on DIAYN's or DADS's diversity reward; batches are `(Transition, episode_return)`.

    Train it with `make_trainer(..., storage=off_policy.EPISODE_RETURNS)`.
    """
    config.check()
    gate = smerl_gate(config.target, config.margin)
    if base == "diayn" and isinstance(skills, DIAYNConfig):
        return make_diayn(agent, skills, obs_size, descriptor_size, gate)
    if base == "dads" and isinstance(skills, DADSConfig):
        return make_dads(agent, skills, obs_size, descriptor_size, gate)
    raise ValueError(
        f"make_smerl: base {base!r} needs a {'DIAYNConfig' if base == 'diayn' else 'DADSConfig'}, "
        f"got {type(skills).__name__}"
    )
