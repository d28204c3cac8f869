"""The ME-PBT emitter (Pierrot & Flajolet 2023, "Evolving populations of diverse RL agents
with MAP-Elites"): a population of RL agents trained by population-based training.

Genotypes are whole agents: an agent state (parameters and hyperparameters)
without its optimiser states (`to_genotype`), so a repertoire of agents costs
what their networks cost. Each iteration the emitter offers
- `ga_batch_size` offspring: iso-line crossover of two repertoire agents'
  networks (policy, critics, entropy temperature), the rest (hyperparameters,
  counters) taken from the first parent;
- its `population_size` agents, as trained so far.
After their evaluation (fitness = episode return of the agent's deterministic
policy), the population is updated as in the paper:
- the `num_from_best` lowest-ranked agents copy the agent and replay buffer of
  one of the `num_best` highest, with freshly sampled hyperparameters;
- the next `num_from_repertoire` lowest take an agent sampled from the
  repertoire (fresh optimiser states, freshly sampled hyperparameters), and
  keep their own buffer;
- then every agent trains for one chunk of the off-policy loop (vmapped over
  the population: the same SAC/TD3 update and loop as every other run).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from qdrl import pbt
from qdrl.agents.base import Agent, AgentState
from qdrl.config import (
    NonNegativeFloat,
    NonNegativeInt,
    PositiveFloat,
    PositiveInt,
    UnitFloat,
    check_fields,
)
from qdrl.off_policy import TrainConfig, Trainer, TrainState
from qdrl.placement import Placement
from qdrl.qd.base import AddResult, Evaluation, Repertoire
from qdrl.qd.emitters.ga import isoline_variation
from qdrl.types import Array, Genotype, PRNGKey

# Fields of an agent state that crossover varies (when the agent has them).
VARIED_FIELDS = ("policy_params", "critic_params", "log_alpha")


def _opt_fields(state: AgentState) -> tuple[str, ...]:
    return tuple(f for f in state._fields if f.endswith("_opt_state"))


def to_genotype(state: AgentState) -> AgentState:
    """The agent state with its optimiser states dropped (None): what a repertoire stores."""
    return state._replace(**dict.fromkeys(_opt_fields(state)))


def from_genotype(genotype: AgentState, fresh: AgentState) -> AgentState:
    """A trainable agent state: the genotype with the optimiser states of `fresh` (a new init)."""
    return genotype._replace(**{f: getattr(fresh, f) for f in _opt_fields(fresh)})


def crossover(x1: AgentState, x2: AgentState, key: PRNGKey, iso_sigma: float, line_sigma: float) -> AgentState:
    """Iso-line crossover of the networks of two batches of agents; the rest comes from `x1`.

    Target critics take the child's critic (a new network has no older target).
    """
    fields = tuple(f for f in VARIED_FIELDS if f in x1._fields)
    varied = isoline_variation(
        tuple(getattr(x1, f) for f in fields), tuple(getattr(x2, f) for f in fields),
        key, iso_sigma, line_sigma,
    )
    child = x1._replace(**dict(zip(fields, varied, strict=True)))
    if "target_critic_params" in child._fields and "critic_params" in fields:
        child = child._replace(target_critic_params=child.critic_params)
    if "target_policy_params" in child._fields and "policy_params" in fields:
        child = child._replace(target_policy_params=child.policy_params)
    return child


@dataclasses.dataclass(frozen=True)
class MEPBTConfig:
    """The `[me_pbt]` section. Defaults: Pierrot & Flajolet 2023 / QDax's ME-PBT, scaled by 1/8."""

    population_size: PositiveInt = 10  # agents trained by RL (paper: 80)
    ga_batch_size: NonNegativeInt = 30  # crossover offspring per iteration (paper: 240, 3x the population)
    iso_sigma: NonNegativeFloat = 0.005
    line_sigma: NonNegativeFloat = 0.05
    fraction_best: UnitFloat = 0.1  # share of the population the worst copy from
    fraction_from_best: UnitFloat = 0.2  # share replaced by copies of the best
    fraction_from_repertoire: UnitFloat = 0.4  # next share replaced by repertoire agents
    training_steps: PositiveInt = 5000  # env steps each agent trains between two evaluations
    env_batch_size: PositiveInt = 25  # environments each agent steps in parallel while training
    grad_updates_per_step: PositiveFloat = 1.0  # gradient steps per env step (per agent)
    batch_size: PositiveInt = 256  # transitions per gradient step
    buffer_size: PositiveInt = 100_000  # replay capacity of each agent
    learning_starts: NonNegativeInt = 1000  # env steps of random actions before an agent's first update
    hparams: tuple[str, ...] = ()  # tuned hyperparameters; empty: qdrl.pbt.DEFAULT_SPACES
    low: tuple[float, ...] = ()
    high: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for name in ("hparams", "low", "high"):
            if isinstance(getattr(self, name), list):
                object.__setattr__(self, name, tuple(getattr(self, name)))

    def check(self) -> None:
        check_fields(self, "me_pbt")
        if self.batch_size > self.buffer_size:
            raise ValueError(
                f"me_pbt.batch_size: expected at most me_pbt.buffer_size={self.buffer_size}, "
                f"got {self.batch_size}"
            )
        if self.training_steps % self.env_batch_size:
            raise ValueError(
                f"me_pbt.training_steps: expected a multiple of me_pbt.env_batch_size="
                f"{self.env_batch_size}, got {self.training_steps}"
            )
        if self.fraction_from_best + self.fraction_from_repertoire > 1.0:
            raise ValueError(
                "me_pbt.fraction_from_best + me_pbt.fraction_from_repertoire: expected at most 1, "
                f"got {self.fraction_from_best} + {self.fraction_from_repertoire}"
            )
        self.pbt_config().check("me_pbt")  # its search space is ours

    def train_config(self) -> TrainConfig:
        """The off-policy loop's settings for one agent; one chunk = one training period."""
        return TrainConfig(
            total_env_steps=self.training_steps,
            num_envs=self.env_batch_size,
            batch_size=self.batch_size,
            buffer_size=self.buffer_size,
            learning_starts=self.learning_starts,
            grad_steps_per_iter=max(1, round(self.grad_updates_per_step * self.env_batch_size)),
            eval_every=self.training_steps,
        )

    def pbt_config(self) -> pbt.PBTConfig:
        """The search space, as `qdrl.pbt` reads it."""
        return pbt.PBTConfig(population_size=self.population_size, num_replace=0, num_best=1,
                             hparams=self.hparams, low=self.low, high=self.high)

    @property
    def offspring(self) -> int:
        """Offspring per iteration: the crossover children, then the population's agents."""
        return self.ga_batch_size + self.population_size

    @property
    def num_best(self) -> int:
        return max(1, int(self.population_size * self.fraction_best))

    @property
    def num_from_best(self) -> int:
        return int(self.population_size * self.fraction_from_best)

    @property
    def num_from_repertoire(self) -> int:
        return int(self.population_size * self.fraction_from_repertoire)


class MEPBTState(NamedTuple):
    """The population: a `TrainState` per agent (agent, buffer, environments, key, counters)."""

    population: TrainState


class MEPBTEmitter:
    """ME-PBT's emitter: GA crossover of repertoire agents plus a PBT population of RL agents."""

    # The members are split over the devices (`qdrl.placement`): each trains its own.
    state_axes = MEPBTState(population=0)  # type: ignore[arg-type]

    def __init__(
        self, agent: Agent, trainer: Trainer, space: pbt.SearchSpace, config: MEPBTConfig,
        placement: Placement | None = None,
    ) -> None:
        config.check()
        self.agent, self.trainer, self.space, self.config = agent, trainer, space, config
        self.batch_size = config.offspring
        self.placement = placement or Placement()

    def init_genotypes(self, key: PRNGKey, n: int) -> AgentState:
        """`n` fresh agents (genotypes) with hyperparameters drawn from the search space."""
        init_key, hp_key = jax.random.split(key)
        agents = jax.vmap(self.agent.init)(jax.random.split(init_key, n))
        hparams = dict(agents.hparams)
        values = pbt.sample(hp_key, self.space, n)
        for i, name in enumerate(self.space.names):
            hparams[name] = values[:, i]
        return to_genotype(agents._replace(hparams=hparams))

    def _fresh(self, key: PRNGKey, n: int) -> AgentState:
        return jax.vmap(self.agent.init)(jax.random.split(key, n))

    def init(self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype) -> MEPBTState:
        """The population starts as the first `population_size` initial genotypes."""
        del repertoire, evaluation
        p = self.config.population_size
        n = jax.tree.leaves(genotypes)[0].shape[0]
        if n < p:
            raise ValueError(f"qd.init_batch_size: expected at least me_pbt.population_size={p}, got {n}")
        train_key, fresh_key = jax.random.split(key)
        population = jax.vmap(self.trainer.init)(jax.random.split(train_key, p))
        first = jax.tree.map(lambda x: x[:p], genotypes)
        population = population._replace(agent=from_genotype(first, self._fresh(fresh_key, p)))
        return MEPBTState(population=population)

    def emit(self, state: MEPBTState, repertoire: Repertoire, key: PRNGKey) -> AgentState:
        cfg = self.config
        trained = to_genotype(state.population.agent)
        if cfg.ga_batch_size == 0:
            return trained
        k1, k2, k3 = jax.random.split(key, 3)
        x1 = repertoire.sample(k1, cfg.ga_batch_size)
        x2 = repertoire.sample(k2, cfg.ga_batch_size)
        children = crossover(x1, x2, k3, cfg.iso_sigma, cfg.line_sigma)
        return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), children, trained)

    def log_metrics(self, state: MEPBTState) -> dict[str, Array]:
        """Environment steps the population trained for (beside the evaluations' steps)."""
        return {"train_env_steps": jnp.sum(state.population.env_steps)}

    def update(
        self,
        state: MEPBTState,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> MEPBTState:
        """Replace the worst agents (from the best, from the repertoire), then train the population."""
        del genotypes, added
        cfg, p = self.config, self.config.population_size
        source_key, sample_key, hp_key, fresh_key = jax.random.split(key, 4)
        fitness = evaluation.fitnesses[cfg.ga_batch_size :]
        n_copy, n_rep = cfg.num_from_best, cfg.num_from_repertoire
        pop, info = pbt.exploit(source_key, state.population, fitness, cfg.num_best, n_copy)
        ranked = info.ranked
        replaced = jnp.zeros((p,), bool).at[info.replaced].set(n_copy > 0)
        if n_rep:
            from_rep = ranked[p - n_copy - n_rep : p - n_copy]
            samples = from_genotype(repertoire.sample(sample_key, n_rep), self._fresh(fresh_key, n_rep))
            pop = pop._replace(
                agent=jax.tree.map(lambda x, s: x.at[from_rep].set(s), pop.agent, samples)
            )
            replaced = replaced.at[from_rep].set(True)
        # Replaced agents explore: fresh hyperparameters from the search space (QDax's ME-PBT).
        values = pbt.get_hparams(pop, self.space)
        values = jnp.where(replaced[:, None], pbt.sample(hp_key, self.space, p), values)
        pop = pbt.set_hparams(pop, self.space, values)
        pop, _ = jax.vmap(self.trainer.run_chunk)(self.placement.batched(pop))
        return MEPBTState(population=self.placement.batched(pop))


def agent_policy_network(agent: Agent) -> Any:
    """A `network`-like object whose `apply(genotype, obs)` is the agent's deterministic policy.

    Lets the policy tasks' one scoring function (`qdrl.tasks.policy.policy_scoring_fn`)
    evaluate agent genotypes: one observation per agent.
    """

    class _Policy:
        @staticmethod
        def apply(genotype: AgentState, obs: jax.Array) -> jax.Array:
            return agent.policy(agent.policy_params(genotype), obs[None])[0]

    return _Policy()
