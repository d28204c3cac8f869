"""A bandit scheduler: UCB1 chooses which emitter instances of a pool emit each iteration.

Cully 2021, "Multi-Emitter MAP-Elites: Improving Quality, Diversity and Data
Efficiency with Heterogeneous Sets of Emitters" (GECCO); pyribs'
`BanditScheduler`. The pool is a set of emitters with an instance axis (CMA-ME's
`CMAEmitter`, CMA-MEGA's, or any stateless emitter such as the GA wrapped in
`StatelessInstances`), all with the same number b of offspring per instance.
`num_active` of the K instances emit each iteration; an instance's reward is the
number of its offspring the archive accepted (`rankers.outcome`), its count the
number of offspring it emitted, and the instances to (re)place are chosen by

    UCB1_i = successes_i / selections_i + zeta sqrt(ln(sum_j selections_j) / selections_i),

never-selected instances first (Cully's N, the total number of selections, under
the logarithm; pyribs puts the total successes there, undefined before the first
success). With `reselect="terminated"` only the active instances that restarted
at their last update (a stateless emitter restarts every iteration) give up
their place, with `"all"` every active instance does; the ones that stay are
kept, the free places go to the best UCB1 scores (ties: the lower index).

Shapes stay fixed under jit: every instance of the pool emits, the chosen ones'
offspring are kept; every instance runs its update, the others' new states are
thrown away (`active`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, NamedTuple, Protocol

import jax
import jax.numpy as jnp

from qdrl.config import ConfigError, NonNegativeFloat, PositiveInt, check_fields
from qdrl.qd.base import AddResult, Emitter, Evaluation, Repertoire, emitter_metrics
from qdrl.qd.emitters.rankers import Outcome, outcome
from qdrl.types import Array, Genotype, PRNGKey

__all__ = [
    "BanditScheduler",
    "BanditState",
    "InstancedEmitter",
    "InstancesAsEmitter",
    "SchedulerConfig",
    "StatelessInstances",
    "choose",
    "ucb1",
]

# Above any UCB1 score of an instance that emitted (those are at most 1 + zeta sqrt(ln N)).
_UNTRIED = 3.0e38


class InstancedEmitter(Protocol):
    """An emitter with an instance axis: K searches of b offspring each."""

    num_instances: int

    @property
    def instance_batch_size(self) -> int: ...

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> Any: ...

    def emit_instances(self, state: Any, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """Leaves (K, b, ...)."""
        ...

    def update_instances(
        self, state: Any, repertoire: Repertoire, genotypes: Genotype, out: Outcome,
        active: Array, key: PRNGKey,
    ) -> Any:
        """Only the `active` (K,) instances learn; the others keep their state."""
        ...

    def restarted(self, state: Any) -> Array:
        """(K,) bool: restarted at the last update."""
        ...


class InstancesAsEmitter:
    """An instanced emitter used alone: `emit` and `update` over all K instances at once.

    Mixed into emitters that define `num_instances`, `instance_batch_size`,
    `batch_size` (= K * b), `emit_instances` and `update_instances` (CMA-ME's,
    CMA-MEGA's): offspring come instance after instance, and every instance learns
    from its own b rows.
    """

    batch_size: int

    @property
    def num_instances(self) -> int:
        raise NotImplementedError

    @property
    def instance_batch_size(self) -> int:
        raise NotImplementedError

    def emit_instances(self, state: Any, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        raise NotImplementedError

    def update_instances(
        self, state: Any, repertoire: Repertoire, genotypes: Genotype, out: Outcome,
        active: Array, key: PRNGKey,
    ) -> Any:
        raise NotImplementedError

    def emit(self, state: Any, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """`batch_size` offspring, instance after instance."""
        per_instance = self.emit_instances(state, repertoire, key)
        return jax.tree.map(lambda x: x.reshape((self.batch_size, *x.shape[2:])), per_instance)

    def update(
        self,
        state: Any,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> Any:
        """Every instance learns from its own rows (in `emit` order)."""
        out = outcome(repertoire, evaluation.fitnesses, evaluation.descriptors, added)
        k, b = int(self.num_instances), int(self.instance_batch_size)

        def split(x: Array) -> Array:
            return x.reshape((k, b, *x.shape[1:]))

        return self.update_instances(
            state, repertoire, jax.tree.map(split, genotypes), jax.tree.map(split, out),
            jnp.ones((k,), bool), key,
        )

    def log_metrics(self, state: Any) -> dict[str, Array]:
        """Restarts of every instance so far."""
        return {"restarts": jnp.sum(state.restarts)}


@dataclasses.dataclass(eq=False)
class StatelessInstances:
    """`num_instances` copies of a stateless emitter (e.g. the GA), each emitting its batch_size."""

    emitter: Emitter
    num_instances: int

    @property
    def instance_batch_size(self) -> int:
        return int(self.emitter.batch_size)

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> Any:
        return self.emitter.init(key, repertoire, evaluation, genotypes)

    def emit_instances(self, state: Any, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        keys = jax.random.split(key, self.num_instances)
        return jax.vmap(lambda k: self.emitter.emit(state, repertoire, k))(keys)

    def update_instances(
        self, state: Any, repertoire: Repertoire, genotypes: Genotype, out: Outcome,
        active: Array, key: PRNGKey,
    ) -> Any:
        del repertoire, genotypes, out, active, key
        return state

    def restarted(self, state: Any) -> Array:
        """A stateless emitter is reselected every iteration (pyribs)."""
        del state
        return jnp.ones((self.num_instances,), bool)


@dataclasses.dataclass(frozen=True)
class SchedulerConfig:
    """The `[scheduler]` section of a pool (`[[emitters]]`); defaults: pyribs' `BanditScheduler`
    (zeta 0.05, reselect terminated) with the papers' 15 emitters at a time."""

    num_active: PositiveInt = 15  # instances that emit each iteration (at most the pool's instances)
    zeta: NonNegativeFloat = 0.05  # weight of the exploration term of UCB1
    # "terminated": only instances that restarted give up their place; "all": every active one.
    reselect: Literal["terminated", "all"] = "terminated"

    def check(self, num_instances: int | None = None, section: str = "scheduler") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value; with
        `num_instances`, also when more instances should emit than the pool has."""
        check_fields(self, section)
        if num_instances is not None and self.num_active > num_instances:
            raise ConfigError(
                f"{section}.num_active: expected an integer in [1, {num_instances}] (the pool's "
                f"instances), got {self.num_active!r}"
            )


class BanditState(NamedTuple):
    """The pool's states and the bandit's statistics over its K instances."""

    pool: tuple[Any, ...]  # one state per pool member
    chosen: Array  # (num_active,) int32 instances emitting next, ascending
    successes: Array  # (K,) float32 accepted offspring so far
    selections: Array  # (K,) float32 offspring emitted so far


def ucb1(successes: Array, selections: Array, zeta: float) -> Array:
    """(K,) UCB1 scores; instances never selected score above every other."""
    tried = selections > 0
    n = jnp.maximum(selections, 1.0)
    total = jnp.maximum(jnp.sum(selections), 1.0)
    score = successes / n + zeta * jnp.sqrt(jnp.log(total) / n)
    return jnp.where(tried, score, _UNTRIED)


def choose(
    successes: Array, selections: Array, active: Array, reselect: Array, num_active: int, zeta: float
) -> Array:
    """(num_active,) ascending instances: the active ones not reselected, then the best UCB1 scores."""
    kept = active & ~reselect
    priority = jnp.where(kept, jnp.inf, ucb1(successes, selections, zeta))
    _, top = jax.lax.top_k(priority, num_active)
    return jnp.sort(top).astype(jnp.int32)


@dataclasses.dataclass(eq=False)
class BanditScheduler:
    """An `Emitter` over a pool of instanced emitters; batch_size = num_active * b."""

    pool: tuple[InstancedEmitter, ...]
    config: SchedulerConfig = dataclasses.field(default_factory=SchedulerConfig)
    batch_size: int = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.pool = tuple(self.pool)
        if not self.pool:
            raise ValueError("scheduler.pool: expected at least one emitter")
        sizes = {int(e.instance_batch_size) for e in self.pool}
        if len(sizes) != 1:
            raise ValueError(
                f"scheduler.pool: expected one number of offspring per instance, got {sorted(sizes)}"
            )
        self.config.check(self.num_instances)
        self.batch_size = self.config.num_active * self.instance_batch_size

    @property
    def num_instances(self) -> int:
        """K, the instances of the whole pool."""
        return sum(int(e.num_instances) for e in self.pool)

    @property
    def instance_batch_size(self) -> int:
        return int(self.pool[0].instance_batch_size)

    def _offsets(self) -> list[tuple[int, int]]:
        bounds, start = [], 0
        for e in self.pool:
            bounds.append((start, start + int(e.num_instances)))
            start += int(e.num_instances)
        return bounds

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> BanditState:
        """The pool's states; the first `num_active` instances emit first (pyribs)."""
        keys = jax.random.split(key, len(self.pool))
        states = tuple(
            e.init(k, repertoire, evaluation, genotypes) for e, k in zip(self.pool, keys, strict=True)
        )
        k = self.num_instances
        return BanditState(
            pool=states,
            chosen=jnp.arange(self.config.num_active, dtype=jnp.int32),
            successes=jnp.zeros((k,), jnp.float32),
            selections=jnp.zeros((k,), jnp.float32),
        )

    def emit(self, state: BanditState, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """The chosen instances' offspring, in ascending instance order."""
        keys = jax.random.split(key, len(self.pool))
        parts = [
            e.emit_instances(s, repertoire, k)
            for e, s, k in zip(self.pool, state.pool, keys, strict=True)
        ]
        every = jax.tree.map(lambda *xs: jnp.concatenate(xs, axis=0), *parts)
        return jax.tree.map(
            lambda x: x[state.chosen].reshape((self.batch_size, *x.shape[2:])), every
        )

    def update(
        self,
        state: BanditState,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> BanditState:
        """The chosen instances learn; rewards counted; the next instances chosen by UCB1."""
        m, b, k = self.config.num_active, self.instance_batch_size, self.num_instances
        out = outcome(repertoire, evaluation.fitnesses, evaluation.descriptors, added)

        def spread(x: Array) -> Array:
            rows = x.reshape((m, b, *x.shape[1:]))
            return jnp.zeros((k, b, *x.shape[1:]), x.dtype).at[state.chosen].set(rows)

        every_genotype = jax.tree.map(spread, genotypes)
        every_out = jax.tree.map(spread, out)
        active = jnp.zeros((k,), bool).at[state.chosen].set(True)
        keys = jax.random.split(key, len(self.pool))
        new_pool = []
        restarted = []
        for e, s, (lo, hi), kk in zip(self.pool, state.pool, self._offsets(), keys, strict=True):
            part = lambda x, lo=lo, hi=hi: x[lo:hi]  # noqa: E731
            new = e.update_instances(
                s, repertoire, jax.tree.map(part, every_genotype), jax.tree.map(part, every_out),
                active[lo:hi], kk,
            )
            new_pool.append(new)
            restarted.append(e.restarted(new))
        accepted = jnp.sum(every_out.status > 0, axis=1).astype(jnp.float32)
        successes = state.successes + jnp.where(active, accepted, 0.0)
        selections = state.selections + jnp.where(active, float(b), 0.0)
        reselect = active if self.config.reselect == "all" else active & jnp.concatenate(restarted)
        chosen = choose(successes, selections, active, reselect, m, self.config.zeta)
        return BanditState(
            pool=tuple(new_pool), chosen=chosen, successes=successes, selections=selections
        )

    def log_metrics(self, state: BanditState) -> dict[str, Array]:
        """Restarts of the pool's instances so far (when some member restarts: CMA-ES ones)."""
        counts = [
            emitter_metrics(e, s)["restarts"] for e, s in zip(self.pool, state.pool, strict=True)
            if "restarts" in emitter_metrics(e, s)
        ]
        return {"restarts": sum(counts[1:], counts[0])} if counts else {}
