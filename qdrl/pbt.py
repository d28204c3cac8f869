"""Population-based training (Jaderberg et al. 2017) of the off-policy agents.

A population is the off-policy loop's `TrainState` with a leading member axis:
every member has its own agent (parameters, optimiser states and the PBT-tunable
hyperparameters in `agent.hparams`), its own replay buffer, environments and key.
One compiled step trains all members (`jax.vmap` of `Trainer.run_chunk`), so SAC
and TD3 are the same functions as in a single run.

Every `exploit_every` log intervals the members are ranked by their evaluation
return. *Exploit*: each of the `num_replace` worst members copies the agent
(and, if `copy_buffer`, the replay buffer) of a member drawn uniformly from the
`num_best` best. *Explore*: the copied hyperparameters are then either resampled
from their range (`explore = "resample"`, as in QDax's and ME-PBT's PBT) or each
multiplied by a factor drawn from `perturb_factors`, or with probability
`resample_probability` resampled (`explore = "perturb"`, Jaderberg et al.'s
"perturb" strategy); values stay inside their range.

Memory: every member holds a whole replay buffer, so a population costs
`population_size x buffer_size x bytes per transition` (`buffer_bytes`): on
halfcheetah (obs 18, action 6, xy descriptor, float32) a transition is 200 bytes
and a 1M-transition buffer 200 MB per member.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.config import NonNegativeInt, PositiveFloat, PositiveInt, UnitFloat, check_fields
from qdrl.off_policy import Trainer, TrainState
from qdrl.placement import Placement
from qdrl.types import Array, PRNGKey

# Search spaces of the literature (QDax's SAC-PBT / TD3-PBT, used by ME-PBT,
# Pierrot & Flajolet 2023): name -> (low, high). Learning rates are sampled
# log-uniformly (`LOG_UNIFORM`), the others uniformly.
DEFAULT_SPACES: dict[str, dict[str, tuple[float, float]]] = {
    "sac": {
        "actor_lr": (3e-5, 3e-3),
        "critic_lr": (3e-5, 3e-3),
        "alpha_lr": (3e-5, 3e-3),
        "discount": (0.9, 1.0),
        "reward_scale": (0.1, 10.0),
    },
    "td3": {
        "actor_lr": (3e-5, 3e-3),
        "critic_lr": (3e-5, 3e-3),
        "discount": (0.9, 1.0),
        "policy_noise": (0.0, 1.0),
        "noise_clip": (0.0, 1.0),
        "expl_noise": (0.0, 0.2),
    },
}
LOG_UNIFORM = ("actor_lr", "critic_lr", "alpha_lr")


@dataclasses.dataclass(frozen=True)
class PBTConfig:
    """The `[pbt]` section. Defaults: QDax/ME-PBT's ranges, Jaderberg et al.'s perturbation."""

    population_size: PositiveInt = 8  # members trained in parallel
    exploit_every: PositiveInt = 1  # log intervals (train.eval_every env steps per member) between PBT steps
    num_replace: NonNegativeInt = 2  # worst members replaced at each PBT step
    num_best: PositiveInt = 2  # best members the replaced ones copy from
    explore: Literal["perturb", "resample"] = "perturb"
    perturb_factors: tuple[PositiveFloat, ...] = (0.8, 1.2)  # "perturb": factors drawn uniformly
    resample_probability: UnitFloat = 0.25  # "perturb": chance a hyperparameter is resampled instead
    copy_buffer: bool = True  # replaced members also take their source's replay buffer
    hparams: tuple[str, ...] = ()  # names to tune; empty: the agent's DEFAULT_SPACES
    low: tuple[float, ...] = ()  # per name in `hparams`: lower bound
    high: tuple[float, ...] = ()  # per name in `hparams`: upper bound

    def __post_init__(self) -> None:
        for name in ("perturb_factors", "hparams", "low", "high"):
            value = getattr(self, name)
            if isinstance(value, list):
                object.__setattr__(self, name, tuple(value))

    def check(self, section: str = "pbt") -> None:
        """Raises ValueError naming `section.key` for a bad value (`section`: where the keys are)."""
        s = section
        check_fields(self, s)
        if self.num_best + self.num_replace > self.population_size:
            raise ValueError(
                f"{s}.num_best + {s}.num_replace: expected at most {s}.population_size="
                f"{self.population_size}, got {self.num_best} + {self.num_replace}"
            )
        if not self.perturb_factors:
            raise ValueError(f"{s}.perturb_factors: expected a list of numbers > 0, got []")
        if not len(self.hparams) == len(self.low) == len(self.high):
            raise ValueError(
                f"{s}.hparams, {s}.low, {s}.high: expected lists of one length, got "
                f"{len(self.hparams)}, {len(self.low)} and {len(self.high)} entries"
            )
        for name, lo, hi in zip(self.hparams, self.low, self.high, strict=True):
            if not lo <= hi:
                raise ValueError(f"{s}.low: expected {name}'s low <= high, got {lo} > {hi}")


class SearchSpace(NamedTuple):
    """Ranges of the tuned hyperparameters: names, and (k,) arrays of bounds and scale."""

    names: tuple[str, ...]
    low: Array
    high: Array
    log: Array  # bool: sampled log-uniformly


def search_space(
    agent: str, config: PBTConfig, agent_hparams: Mapping[str, Any], section: str = "pbt"
) -> SearchSpace:
    """The tuned hyperparameters of `agent` ("sac"/"td3"), checked against the agent's own.

    Raises ValueError naming `section.key` for a name the agent does not have, or a
    log-scaled range that is not positive.
    """
    if config.hparams:
        ranges = dict(zip(config.hparams, zip(config.low, config.high, strict=True), strict=True))
    elif agent in DEFAULT_SPACES:
        ranges = DEFAULT_SPACES[agent]
    else:
        raise ValueError(f"{section}: no default search space for agent {agent!r}; give {section}.hparams")
    unknown = sorted(set(ranges) - set(agent_hparams))
    if unknown:
        raise ValueError(
            f"{section}.hparams: {unknown[0]!r} is not a hyperparameter of {agent}; "
            f"expected some of {sorted(agent_hparams)}"
        )
    names = tuple(ranges)
    log = tuple(n in LOG_UNIFORM for n in names)
    for n, is_log in zip(names, log, strict=True):
        if is_log and ranges[n][0] <= 0:
            raise ValueError(
                f"{section}.low: {n} is sampled log-uniformly; expected low > 0, got {ranges[n][0]}"
            )
    return SearchSpace(
        names=names,
        low=jnp.asarray([ranges[n][0] for n in names], jnp.float32),
        high=jnp.asarray([ranges[n][1] for n in names], jnp.float32),
        log=jnp.asarray(log),
    )


def sample(key: PRNGKey, space: SearchSpace, n: int) -> Array:
    """(n, k) hyperparameter values drawn from the space (log-uniform where `space.log`)."""
    u = jax.random.uniform(key, (n, len(space.names)))
    lo = jnp.where(space.log, jnp.log(space.low), space.low)
    hi = jnp.where(space.log, jnp.log(space.high), space.high)
    v = lo + u * (hi - lo)
    return jnp.where(space.log, jnp.exp(v), v)


def explore(key: PRNGKey, space: SearchSpace, values: Array, config: PBTConfig) -> Array:
    """New (n, k) values from copied ones: resampled, or perturbed and clipped to the range."""
    resample_key, choice_key, factor_key = jax.random.split(key, 3)
    fresh = sample(resample_key, space, values.shape[0])
    if config.explore == "resample":
        return fresh
    factors = jnp.asarray(config.perturb_factors, jnp.float32)
    perturbed = values * jax.random.choice(factor_key, factors, values.shape)
    perturbed = jnp.clip(perturbed, space.low, space.high)
    resample = jax.random.bernoulli(choice_key, config.resample_probability, values.shape)
    return jnp.where(resample, fresh, perturbed)


def get_hparams(population: TrainState, space: SearchSpace) -> Array:
    """(population, k) current values of the tuned hyperparameters."""
    return jnp.stack([population.agent.hparams[n] for n in space.names], axis=-1)


def set_hparams(population: TrainState, space: SearchSpace, values: Array) -> TrainState:
    """The population with its tuned hyperparameters replaced by (population, k) `values`."""
    hparams = dict(population.agent.hparams)
    for i, n in enumerate(space.names):
        hparams[n] = values[:, i].astype(hparams[n].dtype)
    return population._replace(agent=population.agent._replace(hparams=hparams))


class ExploitInfo(NamedTuple):
    """Who was replaced at a PBT step, and by whom (member indices)."""

    ranked: Array  # (population,) members from the highest fitness to the lowest
    replaced: Array  # (num_replace,) the worst members
    sources: Array  # (num_replace,) the member each copied


def exploit(
    key: PRNGKey,
    population: TrainState,
    fitness: Array,
    num_best: int,
    num_replace: int,
    copy_buffer: bool = True,
) -> tuple[TrainState, ExploitInfo]:
    """PBT's exploit step on a population ranked by `fitness` (population,); NaN ranks last.

    The `num_replace` lowest members take the agent (and the buffer if `copy_buffer`)
    of members drawn uniformly from the `num_best` highest. Their environments, keys
    and step counters stay their own. Ties rank by member index (lower first).
    """
    p = fitness.shape[0]
    ranked = jnp.argsort(-jnp.where(jnp.isnan(fitness), -jnp.inf, fitness), stable=True)
    worst = ranked[p - num_replace :]
    sources = jax.random.choice(key, ranked[:num_best], (num_replace,))
    take = jnp.arange(p).at[worst].set(sources)

    def gather(x: Array) -> Array:
        return x[take]

    agent = jax.tree.map(gather, population.agent)
    buffer = jax.tree.map(gather, population.buffer) if copy_buffer else population.buffer
    return population._replace(agent=agent, buffer=buffer), ExploitInfo(ranked, worst, sources)


def exploit_and_explore(
    key: PRNGKey,
    population: TrainState,
    fitness: Array,
    space: SearchSpace,
    config: PBTConfig,
) -> tuple[TrainState, ExploitInfo]:
    """One PBT step (Jaderberg et al. 2017): `exploit`, then the replaced members explore from
    the hyperparameters they copied (`explore`: perturbed or resampled, as `config` says)."""
    p = fitness.shape[0]
    if p != config.population_size:
        raise ValueError(f"fitness: expected shape ({config.population_size},), got {fitness.shape}")
    source_key, explore_key = jax.random.split(key)
    out, info = exploit(source_key, population, fitness, config.num_best, config.num_replace, config.copy_buffer)
    values = get_hparams(out, space)
    new_values = explore(explore_key, space, values[info.replaced], config)
    out = set_hparams(out, space, values.at[info.replaced].set(new_values))
    return out, info


class PopulationStep(NamedTuple):
    """One log interval of a population: trained, evaluated, and exploited when due."""

    population: TrainState
    train_metrics: dict[str, Array]  # the loop's metrics, (population,) each
    evaluation: dict[str, Array]  # `Trainer.evaluate` of every member, (population, ...) each
    hparams: Array  # (population, k) the hyperparameters that earned the evaluation


class Population(NamedTuple):
    """A PBT population of one off-policy agent (`make_population`): pure, jittable functions.

    init(member_key, hparam_key) -> population    members with hyperparameters drawn from the space
    step(population, eval_key, pbt_key, due) -> PopulationStep
    """

    init: Callable[[PRNGKey, PRNGKey], TrainState]
    step: Callable[[TrainState, PRNGKey, PRNGKey, Array], PopulationStep]


def make_population(
    trainer: Trainer, space: SearchSpace, config: PBTConfig, placement: Placement | None = None
) -> Population:
    """PBT of `trainer`'s agent: `config.population_size` members trained by one vmapped chunk,
    each evaluated deterministically, ranked by evaluation return; `exploit_and_explore` when
    `due`. On several devices (`placement`) each trains its share of the members."""
    n = config.population_size
    place = placement or Placement()

    def init(member_key: PRNGKey, hparam_key: PRNGKey) -> TrainState:
        population = jax.vmap(trainer.init)(jax.random.split(member_key, n))
        return set_hparams(population, space, sample(hparam_key, space, n))

    def step(population: TrainState, eval_key: PRNGKey, pbt_key: PRNGKey, due: Array) -> PopulationStep:
        population, metrics = jax.vmap(trainer.run_chunk)(place.batched(population))
        ev = jax.vmap(trainer.evaluate)(population.agent, jax.random.split(eval_key, n))
        fitness = ev["eval_return"]  # (n,)
        hparams = get_hparams(population, space)  # before explore: what earned `fitness`

        def exploit_step(p: TrainState) -> TrainState:
            return exploit_and_explore(pbt_key, p, fitness, space, config)[0]

        population = place.batched(jax.lax.cond(due, exploit_step, lambda p: p, population))
        return PopulationStep(population, metrics, ev, hparams)

    return Population(init, step)


def buffer_bytes(buffer: Any) -> int:
    """Bytes of one member's replay buffer (a pytree of arrays or shape structs)."""
    return int(sum(math.prod(x.shape) * jnp.dtype(x.dtype).itemsize for x in jax.tree.leaves(buffer)))

