"""Differentiable QD: OMG-MEGA and CMA-MEGA (with gradient ascent or Adam), CMA-MAEGA.

Fontaine & Nikolaidis 2021, "Differentiable Quality Diversity" (NeurIPS); CMA-MAEGA
is CMA-MEGA on CMA-MAE's archive (Fontaine & Nikolaidis 2023). pyribs'
`GradientOperatorEmitter` and `GradientArborescenceEmitter` are the reference
for the options. Both emitters read the task's gradients: the fitness gradient
and the descriptor Jacobian that a task's `gradient_scoring_fn` hands back in
`Evaluation.extras` (`qdrl.qd.dqd`); run OMG-MEGA's loop with that scoring
function. Genotypes are flat vectors (n,).

OMG-MEGA: an offspring is an elite x plus |c_0| g_f(x) + sum_j c_j g_j(x), c ~
N(0, sigma_g^2 I), with the (normalised) gradients of the fitness and of each
descriptor at x. As QDax's `OMGMEGAEmitter`, the emitter keeps the gradients of
every elite beside the repertoire (one row per cell, written when an offspring
becomes its cell's elite), so a parent's gradients come from its own evaluation
and every evaluation is an offspring (pyribs re-evaluates parents for them).
Feed it the whole batch: inside a `MultiEmitter` another emitter's new elites
would have no gradients here.

CMA-MEGA: each instance keeps a solution point theta and a CMA-ES over the
1 + D gradient coefficients (the one `qdrl.qd.cma_es`, started at 0 with
`sigma0`); it emits theta + sum_j c_ij g_j(theta) for lambda coefficient samples
c_i, ranks them with a ranker (`qdrl.qd.emitters.rankers`), updates the
coefficient CMA-ES on the ranked c_i and moves theta towards the weighted mean of
the best offspring, by gradient ascent (theta += lr (mean - theta)) or Adam
(optax). Restarts as CMA-ME's (selection and restart rules are the same
functions). Each instance also emits theta itself (one row after its lambda
offspring), so the archive sees the solution point as in pyribs and the loop
counts the same evaluations (lambda + 1 per instance); the gradients at a new
theta come from one call of the task's scoring function by the emitter itself.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import optax

from qdrl.config import PositiveFloat, PositiveInt, check_fields
from qdrl.qd.base import AddResult, Evaluation, Repertoire, ScoringFn
from qdrl.qd.cma_es import CMAES, CMAESState, recombination_weights
from qdrl.qd.dqd import jacobian
from qdrl.qd.emitters.cma import (
    Lambda,
    RankerName,
    RestartRule,
    SelectionRule,
    UpdateRule,
    must_restart,
    num_parents,
    tree_select,
)
from qdrl.qd.emitters.rankers import Outcome, random_direction, rank, uses_direction
from qdrl.qd.emitters.scheduler import InstancesAsEmitter
from qdrl.qd.repertoires.cells import sample_filled_indices
from qdrl.types import Array, Genotype, PRNGKey

__all__ = [
    "CMAMegaConfig",
    "CMAMegaEmitter",
    "CMAMegaState",
    "OMGMegaConfig",
    "OMGMegaEmitter",
    "normalise_rows",
]

EPSILON = 1e-8  # pyribs' epsilon in the gradient norms


def normalise_rows(jac: Array) -> Array:
    """Every gradient (last axis) divided by its norm + 1e-8 (pyribs `normalize_grad`)."""
    return jac / (jnp.linalg.norm(jac, axis=-1, keepdims=True) + EPSILON)


@dataclasses.dataclass(frozen=True)
class OMGMegaConfig:
    """The `[emitter]` section of OMG-MEGA (`kind = "omg_mega"`); defaults: the DQD
    paper's LP runs (sigma_g 10, normalised gradients), 36 offspring per iteration."""

    kind: Literal["omg_mega"] = "omg_mega"
    batch_size: PositiveInt = 36  # offspring per iteration
    sigma_g: PositiveFloat = 10.0  # standard deviation of the gradient coefficients
    normalize_gradients: bool = True  # each gradient divided by its norm (+ 1e-8)

    def check(self, section: str = "emitter") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value."""
        check_fields(self, section)

    @property
    def offspring(self) -> int:
        """Offspring per iteration."""
        return self.batch_size


@dataclasses.dataclass(eq=False)
class OMGMegaEmitter:
    """OMG-MEGA; its state is the (C, 1 + D, n) gradients of the repertoire's elites."""

    config: OMGMegaConfig
    batch_size: int = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.config.check()
        self.batch_size = self.config.batch_size

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> Array:
        """The gradients of the initial elites (the initial candidates that won their cells)."""
        del key
        jac = jacobian(evaluation.extras)
        rep: Any = repertoire
        num_cells = int(rep.fitnesses.shape[0])
        n = int(jac.shape[0])
        cell = rep.cell_index(evaluation.descriptors)
        is_elite = evaluation.fitnesses == rep.fitnesses[cell]
        index = jnp.arange(n, dtype=jnp.int32)
        # the repertoire keeps the first of equally fit candidates of a cell
        first = jax.ops.segment_min(jnp.where(is_elite, index, n), cell, num_segments=num_cells)
        winner = is_elite & (first[cell] == index)
        store = jnp.zeros((num_cells, *jac.shape[1:]), jnp.float32)
        return store.at[jnp.where(winner, cell, num_cells)].set(jac, mode="drop")

    def emit(self, state: Array, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """Elites stepped along |c_0| g_f + sum_j c_j g_j."""
        rep: Any = repertoire
        pick_key, coeff_key = jax.random.split(key)
        cells = sample_filled_indices(pick_key, rep.filled, self.batch_size)
        parents = rep.genotypes[cells]
        jac = state[cells]
        if self.config.normalize_gradients:
            jac = normalise_rows(jac)
        coeffs = self.config.sigma_g * jax.random.normal(coeff_key, jac.shape[:2])
        coeffs = coeffs.at[:, 0].set(jnp.abs(coeffs[:, 0]))
        return parents + jnp.einsum("bk,bkn->bn", coeffs, jac)

    def update(
        self,
        state: Array,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> Array:
        """The new elites' gradients replace their cells'."""
        del repertoire, genotypes, key
        jac = jacobian(evaluation.extras)
        target = jnp.where(added.added, added.cell, state.shape[0])
        return state.at[target].set(jac, mode="drop")


@dataclasses.dataclass(frozen=True)
class CMAMegaConfig:
    """The `[emitter]` section of CMA-MEGA (`kind = "cma_mega"`); defaults: the DQD
    paper's LP runs (one instance of 35 coefficient samples plus theta, sigma_g 10,
    gradient ascent at 1.0, `2imp`, mu, no_improvement).

    CMA-MEGA (Adam): `optimizer="adam", learning_rate=0.002`. CMA-MAEGA:
    `ranker="imp", restart_rule="basic"` on a repertoire with a learning rate.
    """

    kind: Literal["cma_mega"] = "cma_mega"
    num_instances: PositiveInt = 1
    batch_size: Lambda = 35  # coefficient samples per instance (lambda); theta is emitted as well
    sigma0: PositiveFloat = 10.0  # initial step size of the coefficient CMA-ES (sigma_g)
    learning_rate: PositiveFloat = 1.0  # step size of theta's optimiser
    optimizer: Literal["gradient_ascent", "adam"] = "gradient_ascent"
    ranker: RankerName = "2imp"
    selection_rule: SelectionRule = "mu"
    restart_rule: RestartRule = "no_improvement"
    normalize_gradients: bool = True
    update_rule: UpdateRule = "pyribs"  # the coefficient CMA-ES's equations

    def check(self, section: str = "emitter") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value."""
        check_fields(self, section)

    @property
    def offspring(self) -> int:
        """Offspring per iteration: lambda + 1 (theta) per instance."""
        return self.num_instances * (self.batch_size + 1)

    @property
    def instance_size(self) -> int:
        """Offspring of one instance per iteration (every arm of a pool emits as many)."""
        return self.batch_size + 1


class CMAMegaState(NamedTuple):
    """Every leaf but `clock` has a leading instance axis K."""

    theta: Array  # (K, n) solution points
    jacobian: Array  # (K, 1 + D, n) gradients at theta (normalised when configured)
    coeff_es: CMAESState  # (K, ...) CMA-ES over the 1 + D coefficients
    coeffs: Array  # (K, lambda, 1 + D) the coefficients this iteration emits
    opt_state: Any  # (K, ...) theta's optimiser state (optax)
    direction: Array  # (K, D) for the random-direction rankers
    restarts: Array  # (K,) int32
    restarted: Array  # (K,) bool
    clock: Array  # () int32 updates so far


@dataclasses.dataclass(eq=False)
class CMAMegaEmitter(InstancesAsEmitter):
    """CMA-MEGA with `num_instances` solution points; batch_size = num_instances * (lambda + 1).

    Args:
      config: the options (see `CMAMegaConfig`).
      gradient_fn: the task's `gradient_scoring_fn`; the emitter calls it on its
        solution points (K rows) when they move.
      num_dims: n, the genotype size.
      descriptor_low, descriptor_high: the descriptor box, for the random-direction
        rankers (default: the grid repertoire's bounds).
    """

    config: CMAMegaConfig
    gradient_fn: ScoringFn
    num_dims: int
    descriptor_low: Sequence[float] | None = None
    descriptor_high: Sequence[float] | None = None
    batch_size: int = dataclasses.field(init=False)
    _optimizer: optax.GradientTransformation = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.config.check()
        self.batch_size = self.config.num_instances * (self.config.batch_size + 1)
        self._optimizer = (
            optax.adam(self.config.learning_rate)
            if self.config.optimizer == "adam"
            else optax.sgd(self.config.learning_rate)
        )

    @property
    def num_instances(self) -> int:
        return self.config.num_instances

    @property
    def instance_batch_size(self) -> int:
        """lambda offspring plus theta."""
        return self.config.batch_size + 1

    def _coeff_es(self, num_coeffs: int) -> CMAES:
        c = self.config
        return CMAES(num_coeffs, c.batch_size, float(c.sigma0), update_rule=c.update_rule)

    def _gradients(self, theta: Array, key: PRNGKey) -> Array:
        jac = jacobian(self.gradient_fn(theta, key).extras)
        return normalise_rows(jac) if self.config.normalize_gradients else jac

    def _fresh(
        self, repertoire: Repertoire, num_coeffs: int, key: PRNGKey
    ) -> tuple[Array, CMAESState, Any, Array]:
        """K restarts: theta an elite, coefficients' CMA-ES at 0, a new optimiser and direction."""
        k = self.num_instances
        elite_key, direction_key = jax.random.split(key)
        theta = repertoire.sample(elite_key, k)
        es_states = jax.vmap(self._coeff_es(num_coeffs).init)(jnp.zeros((k, num_coeffs)))
        opt_state = jax.vmap(self._optimizer.init)(theta)
        dim = num_coeffs - 1
        if uses_direction(self.config.ranker):
            rep: Any = repertoire
            low = self.descriptor_low if self.descriptor_low is not None else rep.low
            high = self.descriptor_high if self.descriptor_high is not None else rep.high
            if low is None or high is None:
                raise ValueError(
                    f"emitter.ranker: {self.config.ranker!r} needs descriptor_low and descriptor_high"
                )
            keys = jax.random.split(direction_key, k)
            directions = jax.vmap(lambda kk: random_direction(kk, jnp.asarray(low), jnp.asarray(high)))(keys)
        else:
            directions = jnp.zeros((k, dim), jnp.float32)
        return theta, es_states, opt_state, directions

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> CMAMegaState:
        """Every solution point starts at an elite of the initial repertoire (pyribs' x0)."""
        del evaluation, genotypes
        num_coeffs = int(repertoire.descriptors.shape[-1]) + 1
        start_key, grad_key, coeff_key = jax.random.split(key, 3)
        theta, es_states, opt_state, directions = self._fresh(repertoire, num_coeffs, start_key)
        k = self.num_instances
        return CMAMegaState(
            theta=theta,
            jacobian=self._gradients(theta, grad_key),
            coeff_es=es_states,
            coeffs=self._sample(es_states, coeff_key, num_coeffs),
            opt_state=opt_state,
            direction=directions,
            restarts=jnp.zeros((k,), jnp.int32),
            restarted=jnp.zeros((k,), bool),
            clock=jnp.zeros((), jnp.int32),
        )

    def _sample(self, es_states: CMAESState, key: PRNGKey, num_coeffs: int) -> Array:
        keys = jax.random.split(key, self.num_instances)
        return jax.vmap(self._coeff_es(num_coeffs).sample)(es_states, keys)

    def emit_instances(self, state: CMAMegaState, repertoire: Repertoire, key: PRNGKey) -> Array:
        """(K, lambda + 1, n): theta + c_i . jacobian for the state's coefficients, then theta."""
        del repertoire, key  # the coefficients were drawn at the last update
        offspring = state.theta[:, None, :] + jnp.einsum("kbc,kcn->kbn", state.coeffs, state.jacobian)
        return jnp.concatenate([offspring, state.theta[:, None, :]], axis=1)

    def update_instances(
        self,
        state: CMAMegaState,
        repertoire: Repertoire,
        genotypes: Array,
        out: Outcome,
        active: Array,
        key: PRNGKey,
    ) -> CMAMegaState:
        """Rank the lambda offspring of each active instance, step its CMA-ES and theta, maybe restart."""
        c = self.config
        lam = c.batch_size
        num_coeffs = int(state.coeffs.shape[-1])
        es = self._coeff_es(num_coeffs)
        decompose = (state.clock + 1) % es.eigen_period == 0
        offspring = genotypes[:, :lam]
        out = jax.tree.map(lambda x: x[:, :lam], out)

        def tell(
            es_state: CMAESState, coeffs: Array, x: Array, theta: Array, opt_state: Any,
            o: Outcome, direction: Array,
        ) -> tuple[CMAESState, Array, Any, Array]:
            order, values = rank(c.ranker, o, direction)
            k = num_parents(c.selection_rule, o.status, lam)
            new_es = es.update(es_state, coeffs[order], k, decompose)
            weights = recombination_weights(k, lam)
            step = jnp.where(k > 0, weights @ x[order] - theta, 0.0)
            updates, new_opt = self._optimizer.update(-step, opt_state, theta)
            restart = must_restart(c.restart_rule, es.stop(new_es, values), o.status, new_es.generation)
            return new_es, theta + updates, new_opt, restart

        stepped_es, stepped_theta, stepped_opt, restart = jax.vmap(tell)(
            state.coeff_es, state.coeffs, offspring, state.theta, state.opt_state, out, state.direction
        )
        restart = restart & active
        fresh_key, grad_key, coeff_key = jax.random.split(key, 3)
        theta0, es0, opt0, directions = self._fresh(repertoire, num_coeffs, fresh_key)
        theta = jnp.where(restart[:, None], theta0, jnp.where(active[:, None], stepped_theta, state.theta))
        es_state = tree_select(restart, es0, tree_select(active, stepped_es, state.coeff_es))
        opt_state = tree_select(restart, opt0, tree_select(active, stepped_opt, state.opt_state))
        jac = jnp.where(active[:, None, None], self._gradients(theta, grad_key), state.jacobian)
        coeffs = jnp.where(active[:, None, None], self._sample(es_state, coeff_key, num_coeffs), state.coeffs)
        return CMAMegaState(
            theta=theta,
            jacobian=jac,
            coeff_es=es_state,
            coeffs=coeffs,
            opt_state=opt_state,
            direction=jnp.where(restart[:, None], directions, state.direction),
            restarts=state.restarts + restart.astype(jnp.int32),
            restarted=restart,
            clock=state.clock + 1,
        )

    def restarted(self, state: CMAMegaState) -> Array:
        """(K,) bool: the instances that restarted at the last update."""
        return state.restarted
