"""The one CMA-ES of qdrl: a jittable (mu/mu_w, lambda)-CMA-ES whose state is a pytree.

Hansen 2016, "The CMA Evolution Strategy: A Tutorial" (arXiv:1604.00772): the
equations and default constants of its Table 1 and Appendix A, with positive
(truncation) recombination weights as pyribs uses them; sep-CMA-ES (Ros & Hansen
2008, "A Simple Modification in CMA-ES Achieving Linear Time and Space
Complexity") keeps only the diagonal of the covariance, for genotypes of
thousands of parameters.

The update takes solutions already RANKED (best first) and a number of parents,
so that what "best" means (fitness, archive improvement, a random direction in
descriptor space, ...) stays outside: CMA-ME's rankers, CMA-MEGA's coefficient
search and the plain `cma_es` baseline all use this one state and update.
A restart is `init(new_mean)`.

One generation, with y_i = (x_i - m) / sigma for the k ranked parents and log-rank
weights w_i = ln(k + 1/2) - ln(i) normalised to sum 1 (mu_eff = 1 / sum w_i^2):

    m'      = sum_i w_i x_i
    p_sigma = (1 - c_sigma) p_sigma + sqrt(c_sigma (2 - c_sigma) mu_eff) C^(-1/2) y_w
    p_c     = (1 - c_c) p_c + h_sigma sqrt(c_c (2 - c_c) mu_eff) y_w
    C       = (1 + c_1 delta(h_sigma) - c_1 - c_mu) C + c_1 p_c p_c^T + c_mu sum_i w_i y_i y_i^T
    sigma   = sigma exp((c_sigma / d_sigma) (|p_sigma| / E|N(0, I)| - 1))

with y_w = (m' - m) / sigma. The learning rates follow from mu_eff (Table 1), so a
generation with fewer parents (CMA-ME's "filter" selection) gets its own weights
and rates, as in pyribs. sep-CMA-ES multiplies c_1 and c_mu by (n + 2) / 3 and
keeps diag(C) only.

Two sets of update equations (`update_rule`):

- "pyribs" (default): the reference implementation of CMA-ME, CMA-MAE and
  CMA-MEGA, pyribs' `CMAEvolutionStrategy` (after Hansen's purecma), including
  its quirks: the covariance path is kept in solution units (p_c above times
  sigma) and its rank-one term is c_1^2 p_c p_c^T, i.e. c_1^2 sigma^2 times the
  tutorial's (for n = 100, sigma = 0.5: about 5e-5 of it, the rank-one update all
  but vanishes); sigma moves by exp(min(1, (c_sigma / d_sigma) (|p_sigma|^2 / n - 1) / 2))
  and h_sigma tests |p_sigma|^2 / n / (1 - (1 - c_sigma)^(2 g)) < 2 + 4 / (n + 1).
- "tutorial": Hansen 2016's equations as written above.

The eigendecomposition C = B diag(D^2) B^T behind sampling and C^(-1/2) is lazy.
By default ("generations") it is refreshed once ceil(0.5 lambda / (n (c_1 + c_mu)))
generations have passed since the last (the rule pyribs and QDax use, counted as QDax counts it:
every 101 generations for n = 100, lambda = 36). "evaluations" follows pyribs'
and purecma's code, which count the same number in EVALUATIONS: refreshed once
more than that many evaluations have passed, i.e. every floor(that / lambda) + 1
generations (3 for n = 100, lambda = 36). An integer `eigen_gap` sets the number
of generations.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal, NamedTuple

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from qdrl.config import NonNegativeInt, PositiveFloat, PositiveInt, check_fields
from qdrl.types import Array, PRNGKey

if TYPE_CHECKING:
    from qdrl.tasks.base import Task

__all__ = [
    "CMAES",
    "CMAESRunState",
    "CMAESSearch",
    "CMAESSearchConfig",
    "CMAESState",
    "cma_es_search",
    "default_population_size",
    "recombination_weights",
]

# Stop tolerances of pyribs / pycma.
MAX_CONDITION = 1e14
MIN_AREA = 1e-11  # sigma * sqrt(largest eigenvalue) below this: the search has collapsed
MAX_SIGMA_FACTOR = 1e20  # sigma / sigma0 * sqrt(largest eigenvalue) above this: it diverges
FLAT_FITNESS = 1e-12
UPDATE_RULES = ("pyribs", "tutorial")
EigenGapRule = Literal["generations", "evaluations"]
EIGEN_GAP_RULES = ("generations", "evaluations")


class CMAESState(NamedTuple):
    """Everything one CMA-ES carries between generations (vmap it for many instances).

    `eigvecs` is (n, n) for the full CMA-ES and (0,) for sep-CMA-ES (diagonal C,
    eigenvalues = the diagonal). `eigvals` are those of the last decomposition.
    """

    mean: Array  # (n,)
    sigma: Array  # () step size
    cov: Array  # (n, n), or (n,) for sep-CMA-ES
    eigvecs: Array  # (n, n) B, or (0,)
    eigvals: Array  # (n,) D^2, eigenvalues of cov at the last decomposition
    p_sigma: Array  # (n,) evolution path of the step size
    p_c: Array  # (n,) evolution path of the covariance
    generation: Array  # int32 updates since the last (re)start
    decomposed_at: Array  # int32 generation of the last eigendecomposition


def default_population_size(num_dims: int) -> int:
    """lambda = 4 + floor(3 ln n) (Hansen 2016, Table 1)."""
    return 4 + math.floor(3.0 * math.log(num_dims))


def recombination_weights(num_parents: Array | int, population_size: int) -> Array:
    """(lambda,) log-rank weights of the first `num_parents` ranked solutions, 0 after; sum 1.

    w_i = ln(k + 1/2) - ln(i) for i <= k (for k = lambda / 2 this is Hansen's
    ln((lambda + 1) / 2) - ln(i)); all zeros when k = 0. `num_parents` may be traced.
    """
    k = jnp.asarray(num_parents, jnp.float32)
    i = jnp.arange(1, population_size + 1, dtype=jnp.float32)
    raw = jnp.where(i <= k, jnp.log(k + 0.5) - jnp.log(i), 0.0)
    return raw / jnp.maximum(jnp.sum(raw), 1e-30)


@dataclasses.dataclass(frozen=True)
class CMAES:
    """A CMA-ES over R^num_dims: hyperparameters here (static), the state in `CMAESState`.

    Args:
      num_dims: n, the dimension searched.
      population_size: lambda, solutions per generation (default 4 + floor(3 ln n)).
      sigma0: initial step size, > 0.
      separable: sep-CMA-ES (diagonal covariance, O(n) memory and time).
      eigen_gap: generations between eigendecompositions, or "generations" (the
        default: ceil(0.5 lambda / (n (c_1 + c_mu)))) or "evaluations" (pyribs':
        more than that many evaluations).
      update_rule: "pyribs" (the reference's equations) or "tutorial" (Hansen 2016).
    """

    num_dims: int
    population_size: int | None = None
    sigma0: float = 1.0
    separable: bool = False
    eigen_gap: int | EigenGapRule = "generations"
    update_rule: str = "pyribs"

    def __post_init__(self) -> None:
        if not (isinstance(self.num_dims, int) and self.num_dims >= 1):
            raise ValueError(f"num_dims: expected a positive integer, got {self.num_dims!r}")
        if self.population_size is None:
            object.__setattr__(self, "population_size", default_population_size(self.num_dims))
        if not (isinstance(self.population_size, int) and self.population_size >= 2):
            raise ValueError(
                f"population_size: expected an integer >= 2, got {self.population_size!r}"
            )
        if not (math.isfinite(self.sigma0) and self.sigma0 > 0):
            raise ValueError(f"sigma0: expected a finite number > 0, got {self.sigma0!r}")
        if self.eigen_gap not in EIGEN_GAP_RULES and not (
            isinstance(self.eigen_gap, int) and not isinstance(self.eigen_gap, bool) and self.eigen_gap >= 1
        ):
            raise ValueError(
                f"eigen_gap: expected a positive integer, 'generations' or 'evaluations', got {self.eigen_gap!r}"
            )
        if self.update_rule not in UPDATE_RULES:
            raise ValueError(f"update_rule: expected one of {list(UPDATE_RULES)}, got {self.update_rule!r}")

    @property
    def lam(self) -> int:
        """lambda, the population size."""
        assert self.population_size is not None
        return self.population_size

    @property
    def chi_n(self) -> float:
        """E|N(0, I_n)| ~ sqrt(n) (1 - 1/(4n) + 1/(21 n^2))."""
        n = self.num_dims
        return math.sqrt(n) * (1.0 - 1.0 / (4.0 * n) + 1.0 / (21.0 * n * n))

    def rates(self, mueff: Array | float) -> tuple[Array, Array, Array, Array, Array]:
        """(c_sigma, d_sigma, c_c, c_1, c_mu) for a given mu_eff (Hansen 2016, Table 1)."""
        n = float(self.num_dims)
        mueff = jnp.asarray(mueff, jnp.float32)
        c_sigma = (mueff + 2.0) / (n + mueff + 5.0)
        d_sigma = 1.0 + 2.0 * jnp.maximum(0.0, jnp.sqrt((mueff - 1.0) / (n + 1.0)) - 1.0) + c_sigma
        c_c = (4.0 + mueff / n) / (n + 4.0 + 2.0 * mueff / n)
        c_1 = 2.0 / ((n + 1.3) ** 2 + mueff)
        c_mu = jnp.minimum(1.0 - c_1, 2.0 * (mueff - 2.0 + 1.0 / mueff) / ((n + 2.0) ** 2 + mueff))
        if self.separable:
            scale = (n + 2.0) / 3.0
            c_1 = c_1 * scale
            c_mu = jnp.minimum(1.0 - c_1, c_mu * scale)
        return c_sigma, d_sigma, c_c, c_1, c_mu

    @property
    def eigen_period(self) -> int:
        """Generations between eigendecompositions (`eigen_gap`; see the module docstring)."""
        if isinstance(self.eigen_gap, int):
            return self.eigen_gap
        # Plain floats: this is static (shapes, loop lengths), not traced.
        mu = self.lam // 2
        raw = [math.log(mu + 0.5) - math.log(i) for i in range(1, mu + 1)]
        mueff = sum(raw) ** 2 / sum(w * w for w in raw)
        n = float(self.num_dims)
        c_1 = 2.0 / ((n + 1.3) ** 2 + mueff)
        c_mu = min(1.0 - c_1, 2.0 * (mueff - 2.0 + 1.0 / mueff) / ((n + 2.0) ** 2 + mueff))
        if self.separable:
            c_1 *= (n + 2.0) / 3.0
            c_mu = min(1.0 - c_1, c_mu * (n + 2.0) / 3.0)
        gap = 0.5 * self.lam / (n * (c_1 + c_mu))
        if self.eigen_gap == "evaluations":
            return math.floor(gap / self.lam) + 1
        return max(1, math.ceil(gap))

    def init(self, mean: Array, sigma: Array | float | None = None) -> CMAESState:
        """A fresh search around `mean` (n,): C = I, sigma = sigma0, zero paths. Also the restart."""
        n = self.num_dims
        mean = jnp.asarray(mean, jnp.float32)
        if mean.shape != (n,):
            raise ValueError(f"mean: expected shape ({n},), got {mean.shape}")
        return CMAESState(
            mean=mean,
            sigma=jnp.asarray(self.sigma0 if sigma is None else sigma, jnp.float32),
            cov=jnp.ones((n,), jnp.float32) if self.separable else jnp.eye(n, dtype=jnp.float32),
            eigvecs=jnp.zeros((0,), jnp.float32) if self.separable else jnp.eye(n, dtype=jnp.float32),
            eigvals=jnp.ones((n,), jnp.float32),
            p_sigma=jnp.zeros((n,), jnp.float32),
            p_c=jnp.zeros((n,), jnp.float32),
            generation=jnp.zeros((), jnp.int32),
            decomposed_at=jnp.zeros((), jnp.int32),
        )

    def _scale(self, state: CMAESState, z: Array) -> Array:
        """B diag(D) z for rows z (..., n): a N(0, I) sample turned into N(0, C)."""
        d = jnp.sqrt(jnp.maximum(state.eigvals, 0.0))
        if self.separable:
            return z * d
        return (z * d) @ state.eigvecs.T

    def _invsqrt(self, state: CMAESState, y: Array) -> Array:
        """C^(-1/2) y = B diag(1/D) B^T y, with the last decomposition."""
        inv_d = 1.0 / jnp.sqrt(jnp.maximum(state.eigvals, jnp.finfo(jnp.float32).tiny))
        if self.separable:
            return y * inv_d
        return state.eigvecs @ ((state.eigvecs.T @ y) * inv_d)

    def sample(self, state: CMAESState, key: PRNGKey, num: int | None = None) -> Array:
        """`num` (default lambda) solutions x = m + sigma B D z, z ~ N(0, I): (num, n)."""
        z = jax.random.normal(key, (self.lam if num is None else num, self.num_dims), jnp.float32)
        return state.mean + state.sigma * self._scale(state, z)

    def decompose(self, state: CMAESState) -> CMAESState:
        """Refresh B and D^2 from the current C (symmetrised first)."""
        if self.separable:
            return state._replace(eigvals=state.cov, decomposed_at=state.generation)
        cov = 0.5 * (state.cov + state.cov.T)
        eigvals, eigvecs = jnp.linalg.eigh(cov)
        return state._replace(
            cov=cov, eigvals=eigvals, eigvecs=eigvecs, decomposed_at=state.generation
        )

    def due(self, state: CMAESState) -> Array:
        """Whether more than `eigen_period - 1` generations passed since the last decomposition."""
        return state.generation - state.decomposed_at >= self.eigen_period

    def update(
        self,
        state: CMAESState,
        ranked: Array,
        num_parents: Array | int,
        decompose: Array | bool | None = None,
    ) -> CMAESState:
        """One generation from `ranked` (lambda, n) solutions, best first; the first `num_parents` recombine.

        With `num_parents` 0 nothing is learnt (only the generation count moves, as
        in pyribs). `decompose` forces (True) or skips (False) the lazy
        eigendecomposition after the update; None decides by `due`. Passing a flag
        that is the same for every instance keeps it a real `lax.cond` under vmap
        (a per-instance flag would make vmap compute both branches).
        """
        lam, n = self.lam, self.num_dims
        if ranked.shape != (lam, n):
            raise ValueError(f"ranked: expected shape ({lam}, {n}), got {ranked.shape}")
        k = jnp.asarray(num_parents, jnp.int32)
        weights = recombination_weights(k, lam)
        mueff = 1.0 / jnp.maximum(jnp.sum(weights**2), 1e-30)
        c_sigma, d_sigma, c_c, c_1, c_mu = self.rates(mueff)

        y = (ranked - state.mean) / state.sigma  # (lam, n)
        y_w = weights @ y
        mean = state.mean + state.sigma * y_w
        p_sigma = (1.0 - c_sigma) * state.p_sigma + jnp.sqrt(
            c_sigma * (2.0 - c_sigma) * mueff
        ) * self._invsqrt(state, y_w)
        sq_p_sigma = jnp.sum(p_sigma * p_sigma)
        generations = (state.generation + 1).astype(jnp.float32)
        unbiased = 1.0 - (1.0 - c_sigma) ** (2.0 * generations)  # p_sigma's start from 0
        pyribs = self.update_rule == "pyribs"
        if pyribs:
            h_sigma = (sq_p_sigma / n / unbiased < 2.0 + 4.0 / (n + 1.0)).astype(jnp.float32)
            # pyribs keeps the path in solution units and scales its rank-one term by c_1 twice
            path_step = state.sigma * y_w
            rank_one_rate = c_1 * c_1
        else:
            h_sigma = (
                jnp.sqrt(sq_p_sigma / unbiased) < (1.4 + 2.0 / (n + 1.0)) * self.chi_n
            ).astype(jnp.float32)
            path_step = y_w
            rank_one_rate = c_1
        p_c = (1.0 - c_c) * state.p_c + h_sigma * jnp.sqrt(c_c * (2.0 - c_c) * mueff) * path_step
        delta = (1.0 - h_sigma) * c_c * (2.0 - c_c)
        decay = 1.0 + c_1 * delta - c_1 - c_mu  # the positive weights sum to 1
        if self.separable:
            rank_mu = weights @ (y * y)
            cov = decay * state.cov + rank_one_rate * p_c * p_c + c_mu * rank_mu
        else:
            rank_mu = (weights[:, None] * y).T @ y
            cov = decay * state.cov + rank_one_rate * jnp.outer(p_c, p_c) + c_mu * rank_mu
        if pyribs:
            log_step = jnp.minimum(1.0, (c_sigma / d_sigma) * (sq_p_sigma / n - 1.0) / 2.0)
        else:
            log_step = (c_sigma / d_sigma) * (jnp.sqrt(sq_p_sigma) / self.chi_n - 1.0)
        sigma = state.sigma * jnp.exp(log_step)

        learnt = state._replace(
            mean=mean, sigma=sigma, cov=cov, p_sigma=p_sigma, p_c=p_c
        )
        stepped = jax.tree.map(lambda a, b: jnp.where(k > 0, a, b), learnt, state)
        stepped = stepped._replace(generation=state.generation + 1)
        flag = self.due(stepped) if decompose is None else jnp.asarray(decompose)
        return jax.lax.cond(flag, self.decompose, lambda s: s, stepped)

    def stop(self, state: CMAESState, ranking_values: Array | None = None) -> Array:
        """Bool: the standard stop conditions (pyribs / pycma tolerances).

        NaN or inf anywhere in the mean, step or covariance; condition number of C
        above 1e14 (or a non-positive eigenvalue); sigma sqrt(max eig) below 1e-11
        (the search collapsed) or sigma / sigma0 sqrt(max eig) above 1e20 (it
        diverges); and, given the ranking values of the last generation in ranked
        order ((lambda,) or (lambda, m), best first), a flat ranking: the first and
        the last differ by less than 1e-12.
        """
        eig = state.eigvals
        max_eig = jnp.max(eig)
        min_eig = jnp.min(eig)
        finite = (
            jnp.all(jnp.isfinite(state.mean))
            & jnp.isfinite(state.sigma)
            & jnp.all(jnp.isfinite(state.cov))
            & jnp.all(jnp.isfinite(eig))
        )
        ill = (min_eig <= 0.0) | (max_eig > MAX_CONDITION * min_eig)
        spread = state.sigma * jnp.sqrt(jnp.maximum(max_eig, 0.0))
        stop = ~finite | ill | (spread < MIN_AREA) | (spread / self.sigma0 > MAX_SIGMA_FACTOR)
        if ranking_values is not None:
            v = jnp.asarray(ranking_values, jnp.float32)
            gap = v[0] - v[-1]
            gap = jnp.abs(gap) if gap.ndim == 0 else jnp.linalg.norm(gap)
            stop = stop | ((v.shape[0] >= 2) & (gap < FLAT_FITNESS))
        return stop


# -- CMA-ES as an optimiser of a task's fitness (the `cma_es` baseline) --


@dataclasses.dataclass(frozen=True)
class CMAESSearchConfig:
    """One CMA-ES maximising a task's fitness, restarted when it stops (the `[cma_es]` keys)."""

    population_size: NonNegativeInt = 0  # lambda; 0: 4 + floor(3 ln n)
    sigma0: PositiveFloat = 0.3  # initial step size (in genotype units) of every (re)start
    separable: bool = False  # sep-CMA-ES: diagonal covariance, for thousands of parameters
    # Generations between eigendecompositions, or 0.5 lambda / (n (c_1 + c_mu)) counted in
    # "generations" (as QDax counts it) or in "evaluations" (as pyribs' code does).
    eigen_gap: PositiveInt | EigenGapRule = "generations"
    update_rule: Literal["pyribs", "tutorial"] = "pyribs"
    restarts: bool = True  # start again from a random genotype when a stop condition fires

    def check(self, section: str = "cma_es") -> None:
        check_fields(self, section)
        if self.population_size == 1:
            raise ValueError(f"{section}.population_size: expected 0 (the default) or an integer >= 2, got 1")


class CMAESRunState(NamedTuple):
    """The search, its key and what a run reports; checkpointing saves exactly this."""

    es: CMAESState
    key: Array
    generation: Array  # int32 generations done
    evaluations: Array  # int32
    env_steps: Array  # int32
    best_fitness: Array  # () best fitness ever evaluated
    best_genotype: Array  # (n,) flat genotype of best_fitness
    restarts: Array  # int32


class CMAESSearch(NamedTuple):
    """CMA-ES on a task (`cma_es_search`): pure, jittable functions and the CMA-ES they step.

    init(key) -> state; step(state) -> (state, {"generation_best_fitness", "generation_mean_fitness"})
    """

    es: CMAES
    init: Callable[[PRNGKey], CMAESRunState]
    step: Callable[[CMAESRunState], tuple[CMAESRunState, dict[str, Array]]]


def cma_es_search(task: Task, config: CMAESSearchConfig = CMAESSearchConfig()) -> CMAESSearch:
    """CMA-ES maximising `task`'s fitness (descriptors are ignored), restarting when it stops.

    Each generation samples lambda genotypes, clips them to the task's genotype bounds
    when finite (as CMA-ME's emitter does), scores them, ranks them by fitness (NaN
    last) and updates the search; a stop condition (with `config.restarts`) starts it
    again from a new random genotype with sigma0.
    """
    flat, unravel = ravel_pytree(task.example_genotype())
    c = config
    es = CMAES(int(flat.shape[0]), c.population_size or None, c.sigma0, c.separable, c.eigen_gap, c.update_rule)
    clip = bool(math.isfinite(task.genotype_low) or math.isfinite(task.genotype_high))

    def start(key: Array) -> Array:
        """A random flat genotype of the task (its initial distribution)."""
        return ravel_pytree(jax.tree.map(lambda x: x[0], task.init_genotypes(key, 1)))[0]

    def init(key: PRNGKey) -> CMAESRunState:
        start_key, key = jax.random.split(key)
        return CMAESRunState(
            es=es.init(start(start_key)),
            key=key,
            generation=jnp.zeros((), jnp.int32),
            evaluations=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
            best_fitness=jnp.asarray(-jnp.inf, jnp.float32),
            best_genotype=jnp.zeros((es.num_dims,), jnp.float32),
            restarts=jnp.zeros((), jnp.int32),
        )

    def step(state: CMAESRunState) -> tuple[CMAESRunState, dict[str, Array]]:
        """One generation: sample, score, rank by fitness (NaN last), update, maybe restart."""
        key, sample_key, eval_key, restart_key = jax.random.split(state.key, 4)
        x = es.sample(state.es, sample_key)
        if clip:
            x = jnp.clip(x, task.genotype_low, task.genotype_high)
        evaluation = task.scoring_fn(jax.vmap(unravel)(x), eval_key)
        fitness = jnp.where(jnp.isnan(evaluation.fitnesses), -jnp.inf, evaluation.fitnesses)
        order = jnp.argsort(-fitness, stable=True)
        new_es = es.update(state.es, x[order], es.lam // 2)
        restart = es.stop(new_es, fitness[order]) & c.restarts
        new_es = jax.lax.cond(restart, lambda: es.init(start(restart_key)), lambda: new_es)
        best = fitness[order[0]]
        improved = best > state.best_fitness
        new = CMAESRunState(
            es=new_es,
            key=key,
            generation=state.generation + 1,
            evaluations=state.evaluations + es.lam,
            env_steps=state.env_steps + jnp.asarray(evaluation.env_steps, jnp.int32),
            best_fitness=jnp.where(improved, best, state.best_fitness),
            best_genotype=jnp.where(improved, x[order[0]], state.best_genotype),
            restarts=state.restarts + restart.astype(jnp.int32),
        )
        finite = jnp.isfinite(fitness)
        mean = jnp.sum(jnp.where(finite, fitness, 0.0)) / jnp.maximum(jnp.sum(finite), 1)
        return new, {"generation_best_fitness": best, "generation_mean_fitness": mean}

    return CMAESSearch(es, init, step)
