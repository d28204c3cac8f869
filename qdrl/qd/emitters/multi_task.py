"""Multi-task MAP-Elites' emitter: offspring of elites, each sent to a task near its parent's.

Mouret & Maguire 2020, "Quality Diversity for Multi-task Optimization" (GECCO). The
repertoire keeps one elite per task (a CVT repertoire whose cells ARE the tasks: cell i's
centroid is task i's parameters, `qdrl.tasks.multi_task`). Each batch:

1. parents: pairs of elites drawn uniformly; the child is a variation of the pair (SBX
   with eta = 10 in the authors' code, or Iso+LineDD);
2. the child's task: a tournament among `t` tasks drawn uniformly (with replacement), won
   by the task whose parameters are closest (Euclidean) to the first parent's task;
3. `t` is one of `tournament_sizes` (the authors' {1, 10, 50, 100, 500}), the same for the
   whole batch, chosen by UCB1 (Auer et al. 2002): the size a of the highest
   mean_a + sqrt(2 ln n / n_a), with n batches so far, n_a of them with size a, and
   mean_a the mean reward of those; sizes never tried come first, in order. A batch's
   reward is the number of its offspring that became their task's elite (`"count"`, as
   the authors' code) or that number over the batch size (`"rate"`, UCB1's rewards in [0, 1]).

Genotypes are `{"x": (d,), "task": ()}` pytrees (`qdrl.tasks.multi_task.GENES`, `TASK`):
the emitter writes the task each offspring is scored on, the scoring function reads it.
The bandit is the emitter's state, so checkpoints carry it and a resumed run continues exactly.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.config import ConfigError, NonNegativeFloat, PositiveInt, check_fields
from qdrl.qd.base import AddResult, Evaluation, Repertoire
from qdrl.qd.emitters.ga import VariationFn, isoline_variation, sbx_crossover
from qdrl.qd.emitters.scheduler import ucb1
from qdrl.tasks.multi_task import GENES, TASK
from qdrl.types import Array, Genotype, PRNGKey

__all__ = [
    "BanditState",
    "MTMEConfig",
    "MultiTaskEmitter",
    "closest_task_tournament",
    "make_multi_task_emitter",
    "ucb1_choose",
    "ucb1_update",
    "ucb1_values",
]

BanditReward = Literal["count", "rate"]


class BanditState(NamedTuple):
    """UCB1 over the tournament sizes: what each size earned, and the size of the next batch."""

    pulls: Array  # (K,) int32 batches made with each size
    rewards: Array  # (K,) float32 summed rewards of those batches
    arm: Array  # () int32 index of the size the next batch uses


def ucb1_values(pulls: Array, rewards: Array) -> Array:
    """(K,) UCB1 indices mean_a + sqrt(2 ln n / n_a), n = sum of pulls; +inf for arms never pulled.

    Auer, Cesa-Bianchi & Fischer 2002, "Finite-time analysis of the multiarmed bandit problem".
    """
    values = ucb1(rewards, pulls.astype(jnp.float32), math.sqrt(2.0))  # the bandit scheduler's, zeta = sqrt(2)
    return jnp.where(pulls > 0, values, jnp.inf)


def ucb1_choose(pulls: Array, rewards: Array) -> Array:
    """() int32 the arm of the largest UCB1 index (the first of ties: untried arms in order)."""
    return jnp.argmax(ucb1_values(pulls, rewards)).astype(jnp.int32)


def ucb1_update(state: BanditState, reward: Array | float) -> BanditState:
    """The bandit after the arm `state.arm` earned `reward`, with the next arm chosen."""
    pulls = state.pulls.at[state.arm].add(1)
    rewards = state.rewards.at[state.arm].add(jnp.asarray(reward, jnp.float32))
    return BanditState(pulls, rewards, ucb1_choose(pulls, rewards))


def closest_task_tournament(
    key: PRNGKey, parent_tasks: Array, task_parameters: Array, size: Array | int, max_size: int
) -> Array:
    """(n,) int32: for each parent task, the closest (Euclidean, in task parameters) of `size`
    tasks drawn uniformly with replacement; `size` may be traced, at most `max_size`.

    The `max_size` draws are made for every size; a tournament of `size` reads the first ones.
    """
    n, num_tasks = parent_tasks.shape[0], task_parameters.shape[0]
    drawn = jax.random.randint(key, (n, max_size), 0, num_tasks, jnp.int32)
    here = task_parameters[parent_tasks][:, None, :]
    distances = jnp.sum(jnp.square(task_parameters[drawn] - here), axis=-1)
    distances = jnp.where(jnp.arange(max_size) < size, distances, jnp.inf)
    return jnp.take_along_axis(drawn, jnp.argmin(distances, axis=1)[:, None], axis=1)[:, 0]


@dataclasses.dataclass(eq=False)
class MultiTaskEmitter:
    """Multi-task MAP-Elites' emitter (see the module docstring); state `BanditState`."""

    batch_size: int
    variation_fn: VariationFn  # (x1, x2, key) -> x over the solution leaves
    tournament_sizes: tuple[int, ...] = (1, 10, 50, 100, 500)
    bandit_reward: BanditReward = "count"

    def __post_init__(self) -> None:
        if self.batch_size < 1:
            raise ValueError(f"batch_size: expected an integer >= 1, got {self.batch_size}")
        if not self.tournament_sizes or min(self.tournament_sizes) < 1:
            raise ValueError(f"tournament_sizes: expected integers >= 1, got {list(self.tournament_sizes)}")
        if self.bandit_reward not in ("count", "rate"):
            raise ValueError(f"bandit_reward: expected 'count' or 'rate', got {self.bandit_reward!r}")

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> BanditState:
        """No batch made yet: every size untried, the first comes first."""
        del key, repertoire, evaluation, genotypes
        k = len(self.tournament_sizes)
        return BanditState(jnp.zeros((k,), jnp.int32), jnp.zeros((k,), jnp.float32), jnp.zeros((), jnp.int32))

    def tournament_size(self, state: BanditState) -> Array:
        """() int32 the tournament size of the next batch."""
        return jnp.asarray(self.tournament_sizes, jnp.int32)[state.arm]

    def emit(self, state: BanditState, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """`batch_size` children `{"x", "task"}` of pairs of elites, each on the tournament's task.

        Keys: `sample_key, variation_key, task_key = split(key, 3)`; one
        `repertoire.sample(sample_key, 2 * batch_size)`, its first half the first parents.
        """
        sample_key, variation_key, task_key = jax.random.split(key, 3)
        n = self.batch_size
        parents = repertoire.sample(sample_key, 2 * n)
        first = jax.tree.map(lambda a: a[:n], parents)
        second = jax.tree.map(lambda a: a[n:], parents)
        x = self.variation_fn(first[GENES], second[GENES], variation_key)
        # The repertoire's cells are the tasks: cell i's centroid is task i's parameters.
        centroids: Array = repertoire.centroids  # type: ignore[attr-defined]
        parent_tasks = jnp.clip(first[TASK].astype(jnp.int32), 0, centroids.shape[0] - 1)
        tasks = closest_task_tournament(
            task_key, parent_tasks, centroids, self.tournament_size(state), max(self.tournament_sizes)
        )
        return {GENES: x, TASK: tasks}

    def update(
        self,
        state: BanditState,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> BanditState:
        """The bandit rewarded by the batch's offspring that became their task's elite."""
        del repertoire, genotypes, evaluation, key
        successes = jnp.sum(added.added.astype(jnp.float32))
        reward = successes if self.bandit_reward == "count" else successes / self.batch_size
        return ucb1_update(state, reward)

    def log_metrics(self, state: BanditState) -> dict[str, Array]:
        """The tournament size the bandit chose for the next batch."""
        return {"tournament_size": self.tournament_size(state)}


@dataclasses.dataclass(frozen=True)
class MTMEConfig:
    """The `[mt_me]` section: Multi-task MAP-Elites' emitter (defaults: the authors' arm settings)."""

    batch_size: PositiveInt = 100  # offspring per iteration
    # the tournament sizes the bandit chooses among ([1]: every child on a random task)
    tournament_sizes: tuple[PositiveInt, ...] = (1, 10, 50, 100, 500)
    # a batch's reward: its offspring that improved their task's elite ("count"), or their share ("rate")
    bandit_reward: BanditReward = "count"
    variation: Literal["sbx", "isoline"] = "sbx"  # SBX (the authors') or Iso+LineDD of the two parents
    sbx_eta: NonNegativeFloat = 10.0  # sbx: distribution index (larger: children nearer the parents)
    iso_sigma: NonNegativeFloat = 0.01  # isoline: isotropic Gaussian noise
    line_sigma: NonNegativeFloat = 0.2  # isoline: noise along the line between the parents

    def check(self, section: str = "mt_me") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value."""
        check_fields(self, section)
        sizes = list(self.tournament_sizes)
        if not sizes:
            raise ConfigError(f"{section}.tournament_sizes: expected at least one size, got []")
        if len(set(sizes)) != len(sizes):
            raise ConfigError(f"{section}.tournament_sizes: expected distinct sizes, got {sizes}")

    @property
    def offspring(self) -> int:
        """Offspring per iteration."""
        return self.batch_size


def make_multi_task_emitter(config: MTMEConfig, genotype_low: float, genotype_high: float) -> MultiTaskEmitter:
    """The emitter of `config` for solutions in [genotype_low, genotype_high] (children clipped to it)."""
    variation: Any
    if config.variation == "sbx":
        # every gene where the parents differ is crossed, as in the authors' code (no mutation)
        variation = functools.partial(
            sbx_crossover, eta=config.sbx_eta, minval=genotype_low, maxval=genotype_high,
            crossover_prob=1.0, prob_var=1.0,
        )
    else:
        variation = functools.partial(
            isoline_variation, iso_sigma=config.iso_sigma, line_sigma=config.line_sigma,
            minval=genotype_low, maxval=genotype_high,
        )
    return MultiTaskEmitter(config.batch_size, variation, tuple(config.tournament_sizes), config.bandit_reward)
