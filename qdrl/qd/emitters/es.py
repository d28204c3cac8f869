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
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jax.flatten_util import ravel_pytree

from qdrl.agents.common import adam_step
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


@dataclasses.dataclass(eq=False)
class ESEmitter:
    """ME-ES's emitter. `batch_size` = `population_size` perturbations + the centre."""

    population_size: int
    genotype_example: Genotype
    sigma: float = 0.02
    learning_rate: float = 0.01
    l2_coefficient: float = 0.005
    num_optimizer_steps: int = 10
    objective: Objective = "fitness"
    descriptor_size: int = 2
    novelty_neighbours: int = 10
    archive_size: int = 10_000
    archive_threshold: float = 0.0
    # Restart draws: among the fittest elites (exploit), the most novel ones (explore),
    # and the cells last improved by this emitter (ME-ES: 2, 5, 5).
    exploit_num_cells: int = 2
    explore_num_cells: int = 5
    last_updated_size: int = 5
    batch_size: int = dataclasses.field(init=False)
    unravel: Callable[[Array], Genotype] = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        if self.population_size < 2 or self.population_size % 2:
            raise ValueError(f"population_size: expected an even integer >= 2, got {self.population_size}")
        for name in ("sigma", "learning_rate"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a number > 0, got {getattr(self, name)}")
        if self.l2_coefficient < 0:
            raise ValueError(f"l2_coefficient: expected a number >= 0, got {self.l2_coefficient}")
        for name in ("num_optimizer_steps", "exploit_num_cells", "explore_num_cells", "last_updated_size"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"{name}: expected a positive integer, got {getattr(self, name)!r}")
        if self.objective not in ("fitness", "novelty", "explore_exploit"):
            raise ValueError(
                f"objective: expected 'fitness', 'novelty' or 'explore_exploit', got {self.objective!r}"
            )
        self.batch_size = self.population_size + 1
        _, self.unravel = ravel_pytree(self.genotype_example)

    def _flat(self, genotypes: Genotype) -> Array:
        return jax.vmap(lambda g: ravel_pytree(g)[0])(genotypes)

    def _restart(
        self, centre: Array, key: PRNGKey, archive: DescriptorArchive, restarts: Array, recent: Array
    ) -> ESState:
        m = self.population_size // 2
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
        best = _uniform_top(best_key, jnp.arange(fitnesses.shape[0]), fitnesses, self.exploit_num_cells)
        recent_fit = jnp.where(recent >= 0, fitnesses[jnp.maximum(recent, 0)], -jnp.inf)
        from_recent = _uniform_top(recent_key, recent, recent_fit, self.exploit_num_cells)
        use_recent = (jax.random.uniform(coin_key) < 0.5) & jnp.any(recent_fit > -jnp.inf)
        exploit = jnp.where(use_recent, from_recent, best)
        scores = jnp.where(
            filled, novelty(archive, repertoire.descriptors, self.novelty_neighbours), -jnp.inf
        )
        explore = _uniform_top(novel_key, jnp.arange(fitnesses.shape[0]), scores, self.explore_num_cells)
        return jnp.where(novelty_phase, explore, exploit).astype(jnp.int32)

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> ESState:
        """Start from an elite of the initial repertoire; the archive holds the initial descriptors."""
        pick_key, noise_key = jax.random.split(key)
        centre = self._flat(repertoire.sample(pick_key, 1))[0]
        archive = add_to_archive(
            init_archive(self.archive_size, self.descriptor_size), evaluation.descriptors,
            self.archive_threshold,
        )
        recent = jnp.full((self.last_updated_size,), -1, jnp.int32)
        return self._restart(centre, noise_key, archive, jnp.zeros((), jnp.int32), recent)

    def emit(self, state: ESState, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """theta + sigma eps_i, theta - sigma eps_i, then theta."""
        del repertoire, key
        flat = jnp.concatenate(
            [state.centre + self.sigma * state.noise, state.centre - self.sigma * state.noise,
             state.centre[None]]
        )
        return jax.vmap(self.unravel)(flat)

    def use_novelty(self, state: ESState) -> Array:
        """Whether this generation's score is novelty (bool scalar)."""
        return self._novelty_phase(state.restarts)

    def _novelty_phase(self, restarts: Array) -> Array:
        if self.objective == "fitness":
            return jnp.asarray(False)
        if self.objective == "novelty":
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
        n = self.population_size
        fit = evaluation.fitnesses[:n]
        # A failed evaluation (NaN) ranks last.
        fit = jnp.where(jnp.isnan(fit), -jnp.inf, fit)
        nov = novelty(state.archive, evaluation.descriptors[:n], self.novelty_neighbours)
        scores = jnp.where(self.use_novelty(state), nov, fit)
        grad = es_gradient(state.noise, scores, self.sigma) - self.l2_coefficient * state.centre
        centre, opt_state = adam_step(state.centre, state.opt_state, -grad, self.learning_rate)
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
        restart = stepped.generation >= self.num_optimizer_steps
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
