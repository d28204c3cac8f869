"""OpenAI-ES emitter around one elite: ME-ES (Colas et al. 2020) with fitness, novelty, explore-exploit.

Colas, Madhavan, Huizinga & Clune 2020, "Scaling MAP-Elites to deep neuroevolution"
(GECCO). The emitter keeps one search centre theta. `emit` proposes
`population_size` perturbations theta +- sigma eps_i (mirrored sampling) and theta
itself (last row); all are evaluated and offered to the repertoire. `update`
turns the scores of the perturbations into centred ranks and estimates the
gradient of the smoothed objective (Salimans et al. 2017, "Evolution strategies
as a scalable alternative to reinforcement learning"):

    g = 1 / (n sigma) sum_i u_i eps_i,    u_i = rank_i / (n - 1) - 1/2,

then takes an Adam step on theta (ascent) with L2 decay. The score is the
fitness ("fitness"), the novelty of the descriptor against an archive of the
descriptors seen so far ("novelty", ME-ES's ME-NS-ES), or one of the two,
alternating at every restart ("explore_exploit", ME-ES). Every
`num_optimizer_steps` updates theta restarts from an elite, drawn as ME-ES
draws it: for a fitness phase, uniformly among the `exploit_num_cells` fittest
elites, of the whole repertoire or (half of the time) of the
`last_updated_size` cells this emitter last improved; for a novelty phase,
uniformly among the `explore_num_cells` elites whose descriptors are the most
novel against the archive.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Annotated, Literal, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jax.flatten_util import ravel_pytree

from qdrl.agents.common import adam_step
from qdrl.config import NonNegativeFloat, PositiveFloat, PositiveInt, Range, check_fields
from qdrl.qd.base import AddResult, Evaluation, Repertoire
from qdrl.qd.emitters.novelty import DescriptorArchive, add_to_archive, init_archive, novelty
from qdrl.types import Array, Genotype, PRNGKey

Objective = Literal["fitness", "novelty", "explore_exploit"]


class ESState(NamedTuple):
    """The search centre (flat), its Adam moments, the generation count and the novelty archive."""

    centre: Array  # (d,) flat genotype
    opt_state: optax.OptState
    noise: Array  # (population_size // 2, d) this generation's eps (mirrored)
    generation: Array  # int32 updates since the last restart
    restarts: Array  # int32 restarts so far (explore-exploit alternates on it)
    archive: DescriptorArchive
    recent: Array  # (last_updated_size,) int32 cells this emitter last improved, -1 for none


def centred_ranks(scores: Array) -> Array:
    """(n,) scores -> ranks mapped to [-1/2, 1/2] (0 for the worst, n-1 for the best)."""
    n = scores.shape[0]
    ranks = jnp.argsort(jnp.argsort(scores)).astype(jnp.float32)
    return ranks / max(n - 1, 1) - 0.5


def es_gradient(noise: Array, scores: Array, sigma: float) -> Array:
    """OpenAI-ES estimate with mirrored noise: rows of `scores` are [+eps_1..+eps_m, -eps_1..-eps_m].

    g = 1/(n sigma) sum_i u_i e_i with e_i = +-eps and u the centred ranks of `scores`.
    """
    weights = centred_ranks(scores)
    m = noise.shape[0]
    signed = weights[:m] - weights[m:]
    return signed @ noise / (2 * m * sigma)


@dataclasses.dataclass(frozen=True)
class ESConfig:
    """The `[es]` section of ME-ES (Colas et al. 2020): the OpenAI-ES emitter around one elite."""

    population_size: Annotated[int, Range(low=2)] = 64  # perturbations per generation (mirrored pairs; even)
    sigma: PositiveFloat = 0.02  # std of the parameter perturbations
    learning_rate: PositiveFloat = 0.01  # Adam step size on the search centre
    l2_coefficient: NonNegativeFloat = 0.005  # weight decay of the centre
    num_optimizer_steps: PositiveInt = 10  # generations before restarting from an elite
    objective: Objective = "explore_exploit"
    novelty_neighbours: PositiveInt = 10  # k of the k-nearest-neighbour novelty
    archive_size: PositiveInt = 10_000  # slots of the novelty archive of descriptors
    exploit_num_cells: PositiveInt = 2  # restarts for fitness draw among this many fittest elites
    explore_num_cells: PositiveInt = 5  # restarts for novelty draw among this many most novel elites
    last_updated_size: PositiveInt = 5  # cells last improved by the emitter, a second pool for exploit

    def check(self, section: str = "es") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value."""
        check_fields(self, section)
        if self.population_size % 2:
            raise ValueError(f"{section}.population_size: expected an even integer >= 2, got {self.population_size}")

    @property
    def offspring(self) -> int:
        """Offspring per iteration: the perturbations and the centre."""
        return self.population_size + 1


@dataclasses.dataclass(eq=False)
class ESEmitter:
    """ME-ES's emitter. `batch_size` = `config.population_size` perturbations + the centre.

    `archive_threshold`: a descriptor enters the novelty archive when farther than this
    from every stored one (0: every descriptor enters).
    """

    config: ESConfig
    genotype_example: Genotype
    descriptor_size: int = 2
    archive_threshold: float = 0.0
    batch_size: int = dataclasses.field(init=False)
    unravel: Callable[[Array], Genotype] = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.config.check()
        self.batch_size = self.config.offspring
        _, self.unravel = ravel_pytree(self.genotype_example)

    def log_metrics(self, state: ESState) -> dict[str, Array]:
        """Restarts of the search from an elite so far."""
        return {"restarts": state.restarts}

    def _flat(self, genotypes: Genotype) -> Array:
        return jax.vmap(lambda g: ravel_pytree(g)[0])(genotypes)

    def _restart(
        self, centre: Array, key: PRNGKey, archive: DescriptorArchive, restarts: Array, recent: Array
    ) -> ESState:
        m = self.config.population_size // 2
        return ESState(
            centre=centre,
            opt_state=optax.scale_by_adam().init(centre),
            noise=jax.random.normal(key, (m, centre.shape[0])),
            generation=jnp.zeros((), jnp.int32),
            restarts=restarts,
            archive=archive,
            recent=recent,
        )

    def restart_cell(
        self, repertoire: Repertoire, archive: DescriptorArchive, recent: Array, novelty_phase: Array,
        key: PRNGKey,
    ) -> Array:
        """The cell whose elite the next search centre starts from (ME-ES's biased draw).

        Explore (`novelty_phase`): uniform among the `explore_num_cells` filled cells
        whose descriptors are most novel against `archive`. Exploit: uniform among
        the `exploit_num_cells` fittest elites of the repertoire, or, with
        probability 1/2, of the `recent` cells (when any is filled).
        """
        fitnesses = repertoire.fitnesses
        filled = fitnesses > -jnp.inf
        coin_key, best_key, recent_key, novel_key = jax.random.split(key, 4)
        best = _uniform_top(best_key, jnp.arange(fitnesses.shape[0]), fitnesses, self.config.exploit_num_cells)
        recent_fit = jnp.where(recent >= 0, fitnesses[jnp.maximum(recent, 0)], -jnp.inf)
        from_recent = _uniform_top(recent_key, recent, recent_fit, self.config.exploit_num_cells)
        use_recent = (jax.random.uniform(coin_key) < 0.5) & jnp.any(recent_fit > -jnp.inf)
        exploit = jnp.where(use_recent, from_recent, best)
        scores = jnp.where(
            filled, novelty(archive, repertoire.descriptors, self.config.novelty_neighbours), -jnp.inf
        )
        explore = _uniform_top(novel_key, jnp.arange(fitnesses.shape[0]), scores, self.config.explore_num_cells)
        return jnp.where(novelty_phase, explore, exploit).astype(jnp.int32)

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> ESState:
        """Start from an elite of the initial repertoire; the archive holds the initial descriptors."""
        pick_key, noise_key = jax.random.split(key)
        centre = self._flat(repertoire.sample(pick_key, 1))[0]
        archive = add_to_archive(
            init_archive(self.config.archive_size, self.descriptor_size), evaluation.descriptors,
            self.archive_threshold,
        )
        recent = jnp.full((self.config.last_updated_size,), -1, jnp.int32)
        return self._restart(centre, noise_key, archive, jnp.zeros((), jnp.int32), recent)

    def emit(self, state: ESState, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """theta + sigma eps_i, theta - sigma eps_i, then theta."""
        del repertoire, key
        flat = jnp.concatenate(
            [state.centre + self.config.sigma * state.noise, state.centre - self.config.sigma * state.noise,
             state.centre[None]]
        )
        return jax.vmap(self.unravel)(flat)

    def use_novelty(self, state: ESState) -> Array:
        """Whether this generation's score is novelty (bool scalar)."""
        return self._novelty_phase(state.restarts)

    def _novelty_phase(self, restarts: Array) -> Array:
        if self.config.objective == "fitness":
            return jnp.asarray(False)
        if self.config.objective == "novelty":
            return jnp.asarray(True)
        return restarts % 2 == 1  # exploit first, then explore, alternating

    def update(
        self,
        state: ESState,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> ESState:
        """ES step from the perturbations' scores; restart from an elite every `num_optimizer_steps`."""
        del genotypes
        n = self.config.population_size
        fit = evaluation.fitnesses[:n]
        # A failed evaluation (NaN) ranks last.
        fit = jnp.where(jnp.isnan(fit), -jnp.inf, fit)
        nov = novelty(state.archive, evaluation.descriptors[:n], self.config.novelty_neighbours)
        scores = jnp.where(self.use_novelty(state), nov, fit)
        grad = es_gradient(state.noise, scores, self.config.sigma) - self.config.l2_coefficient * state.centre
        centre, opt_state = adam_step(state.centre, state.opt_state, -grad, self.config.learning_rate)
        archive = add_to_archive(state.archive, evaluation.descriptors, self.archive_threshold)
        recent = _last_improved(state.recent, jnp.where(added.added, added.cell, -1))
        noise_key, pick_key, restart_key = jax.random.split(key, 3)
        stepped = ESState(
            centre=centre,
            opt_state=opt_state,
            noise=jax.random.normal(noise_key, state.noise.shape),
            generation=state.generation + 1,
            restarts=state.restarts,
            archive=archive,
            recent=recent,
        )
        restarts = state.restarts + 1
        cell = self.restart_cell(repertoire, archive, recent, self._novelty_phase(restarts), pick_key)
        elite = jax.tree.map(lambda x: x[cell], repertoire.genotypes)
        fresh = self._restart(ravel_pytree(elite)[0], restart_key, archive, restarts, recent)
        restart = stepped.generation >= self.config.num_optimizer_steps
        return jax.tree.map(lambda a, b: jnp.where(restart, a, b), fresh, stepped)


def _uniform_top(key: PRNGKey, cells: Array, scores: Array, k: int) -> Array:
    """One of `cells`, uniformly among the (at most) `k` with the highest finite `scores`."""
    k = min(k, scores.shape[0])
    top, idx = jax.lax.top_k(scores, k)
    logits = jnp.where(top > -jnp.inf, 0.0, -jnp.inf)
    # With no finite score every logit is -inf; pick the first (callers check emptiness).
    logits = jnp.where(jnp.any(top > -jnp.inf), logits, jnp.zeros_like(logits))
    return cells[idx[jax.random.categorical(key, logits)]]


def _last_improved(recent: Array, cells: Array) -> Array:
    """`recent` (L,) followed by the valid (>= 0) entries of `cells`, keeping the last L valid ones."""
    combined = jnp.concatenate([recent, cells.astype(jnp.int32)])
    order = jnp.where(combined >= 0, jnp.arange(combined.shape[0]), -1)
    kept, idx = jax.lax.top_k(order, recent.shape[0])
    return jnp.where(kept >= 0, combined[idx], -1).astype(jnp.int32)


__all__ = ["ESEmitter", "ESState", "centred_ranks", "es_gradient"]
