"""The one QD loop: MAP-Elites and every algorithm that is MAP-Elites with another part.

Mouret & Clune 2015, "Illuminating search spaces by mapping elites"; with a CVT
repertoire it is CVT-MAP-Elites (Vassiliades et al. 2018); with other emitters it
is CMA-ME, PGA-ME, QD-PG, ME-ES, ME-PBT... The loop never knows which emitter or
repertoire it runs.

One iteration is `ask` (the emitter proposes offspring), evaluation by the
scoring function, and `tell` (offspring offered to the repertoire, emitter
updated). `step` chains the three under jit; `run` scans `step`. For evaluations
done outside JAX (a simulator, a NumPy objective), call `ask` and `tell` yourself.

An empty repertoire has nothing to build offspring from. Called with concrete
values, `init` (and its variants) raises when no initial evaluation has a finite
fitness and a finite descriptor, and `ask` raises on an empty repertoire. Under
`jax.jit` nothing can raise: the repertoire then stays empty, sampling it gives
NaN genotypes whose evaluations are rejected, and the metrics show it (coverage
0, QD score 0).
"""

from __future__ import annotations

import operator
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.sharding import PartitionSpec as P

from qdrl.placement import BATCH_AXIS, Placement
from qdrl.qd.base import (
    TIME_MAJOR_EXTRAS,
    AddResult,
    Emitter,
    Evaluation,
    Repertoire,
    ScoringFn,
    add_evaluation,
    evaluation_descriptor_size,
    evaluations_spent,
)
from qdrl.qd.metrics import qd_metrics
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey


class QDState(NamedTuple):
    """Everything a QD run carries between iterations; checkpointing saves exactly this."""

    repertoire: Any
    emitter_state: Any
    key: PRNGKey
    iteration: Array  # int32 iterations done
    evaluations: Array  # int32 solutions evaluated, initial population included
    env_steps: Array  # int32 environment steps spent by evaluations


def _batch_size(genotypes: Genotype, fitnesses: Array) -> int:
    leaves = jax.tree.leaves(genotypes)
    return int(leaves[0].shape[0]) if leaves else int(fitnesses.shape[0])


def _check_evaluation(
    n: int, fitnesses: Array, descriptors: Array, descriptor_size: int, num_objectives: int | None = None
) -> None:
    want = (n,) if num_objectives is None else (n, num_objectives)
    if fitnesses.shape != want:
        raise ValueError(f"fitnesses: expected shape {want}, got {fitnesses.shape}")
    if descriptors.shape != (n, descriptor_size):
        raise ValueError(
            f"descriptors: expected shape ({n}, {descriptor_size}), got {descriptors.shape}"
        )


def _is_empty_concrete(repertoire: Any) -> bool:
    """True when the repertoire holds concrete values (not traced under jit) and no elite."""
    fitnesses = repertoire.fitnesses
    if isinstance(fitnesses, jax.core.Tracer):
        return False
    return not bool(jnp.any(fitnesses > -jnp.inf))


def _check_some_finite(n: int, evaluation: Evaluation) -> None:
    """Raises when concrete evaluations hold no finite (fitness, descriptor) pair: nothing to store."""
    fitnesses, descriptors = evaluation.fitnesses, evaluation.descriptors
    if isinstance(fitnesses, jax.core.Tracer) or isinstance(descriptors, jax.core.Tracer):
        return
    finite_fit = jnp.isfinite(jnp.asarray(fitnesses, jnp.float32))
    if finite_fit.ndim > 1:  # multi-objective: every objective finite
        finite_fit = jnp.all(finite_fit, axis=-1)
    finite_desc = jnp.all(jnp.isfinite(jnp.asarray(descriptors, jnp.float32)), axis=-1)
    if not bool(jnp.any(finite_fit & finite_desc)):
        raise ValueError(
            f"init: expected at least one initial evaluation with a finite fitness and a "
            f"finite descriptor, got none of {n} ({int(jnp.sum(~finite_fit))} non-finite "
            f"fitnesses, {int(jnp.sum(~finite_desc))} non-finite descriptors): the "
            f"repertoire would stay empty"
        )


def check_evaluation_type(value: Any, where: str) -> Evaluation:
    """`value` if it is an `Evaluation`; a TypeError saying what a scoring function must return
    otherwise (raised where the scoring function is called, not deep in the loop)."""
    if isinstance(value, Evaluation):
        return value
    got = f"a tuple of {len(value)}" if isinstance(value, tuple) else type(value).__name__
    hint = (
        " (a QDax scoring function returns (fitnesses, descriptors, extras): return "
        "Evaluation(fitnesses, descriptors, extras, env_steps) instead)"
        if isinstance(value, tuple) else ""
    )
    raise TypeError(
        f"{where}: expected qdrl.qd.base.Evaluation(fitnesses (n,), descriptors (n, D), extras "
        f"dict, env_steps int32), got {got}{hint}"
    )


def _evaluation(fitnesses: Fitness, descriptors: Descriptor) -> Evaluation:
    return Evaluation(
        fitnesses=jnp.asarray(fitnesses, jnp.float32),
        descriptors=jnp.asarray(descriptors, jnp.float32),
        extras={},
        env_steps=jnp.zeros((), jnp.int32),
    )


_PACKED_DTYPES = (jnp.dtype(jnp.float32), jnp.dtype(jnp.int32), jnp.dtype(jnp.uint32))


def _pack_scalars(
    metrics: dict[str, Array], layout: list[tuple[str, Any]]
) -> tuple[Array, dict[str, Array]]:
    """Scalar 32-bit metrics as one float32 vector (bitcast), the others apart.

    Fills `layout` with every metric's (name, dtype), dtype None for those left apart.
    """
    layout.clear()
    columns, rest = [], {}
    for name, value in metrics.items():
        value = jnp.asarray(value)
        if value.shape == () and value.dtype in _PACKED_DTYPES:
            layout.append((name, value.dtype))
            columns.append(jax.lax.bitcast_convert_type(value, jnp.float32))
        else:
            layout.append((name, None))
            rest[name] = value
    return jnp.stack(columns) if columns else jnp.zeros((0,), jnp.float32), rest


def _unpack_scalars(
    packed: Array, rest: dict[str, Array], layout: list[tuple[str, Any]]
) -> dict[str, Array]:
    """Inverse of `_pack_scalars` for metrics stacked over iterations: packed (T, k)."""
    metrics, column = {}, 0
    for name, dtype in layout:
        if dtype is None:
            metrics[name] = rest[name]
        else:
            metrics[name] = jax.lax.bitcast_convert_type(packed[:, column], dtype)
            column += 1
    return metrics


def shard_scoring(scoring_fn: ScoringFn, placement: Placement) -> ScoringFn:
    """`scoring_fn` evaluating each device's share of the batch on that device (`shard_map`).

    The evaluation comes back split over the devices on its batch axis (the second
    axis for `TIME_MAJOR_EXTRAS`), its env steps summed. A lane's evaluation is the
    computation it gets on one device when the per-device batch (a policy task's
    `eval_batch`) is the same; the key each device receives has its index folded in,
    so tasks that draw random numbers draw other ones than on one device.
    """
    if placement.mesh is None:
        return scoring_fn

    def local(genotypes: Genotype, key: PRNGKey) -> Evaluation:
        ev = scoring_fn(genotypes, key)
        return ev._replace(env_steps=jnp.reshape(jnp.asarray(ev.env_steps, jnp.int32), (1,)))

    def specs(ev: Evaluation) -> Any:
        extras = {
            k: jax.tree.map(lambda _, t=k in TIME_MAJOR_EXTRAS: P(None, BATCH_AXIS) if t else P(BATCH_AXIS), v)
            for k, v in ev.extras.items()
        }
        return Evaluation(P(BATCH_AXIS), P(BATCH_AXIS), extras, P(BATCH_AXIS))  # type: ignore[arg-type]

    sharded = placement.map_batch(local, specs)

    def scoring(genotypes: Genotype, key: PRNGKey) -> Evaluation:
        ev = check_evaluation_type(sharded(placement.batched(genotypes), key), "scoring_fn returned")
        return ev._replace(env_steps=jnp.sum(ev.env_steps))

    return scoring


def qd_state_axes(emitter: Emitter) -> QDState:
    """Which axis of each part of a QD state is split over the devices (None: replicated):
    all replicated, but for an emitter that declares `state_axes` (ME-PBT's members)."""
    return QDState(None, getattr(emitter, "state_axes", None), None, None, None, None)  # type: ignore[arg-type]


class MapElites:
    """MAP-Elites over any repertoire, emitter and scoring function."""

    def __init__(
        self,
        scoring_fn: ScoringFn | None,
        emitter: Emitter,
        repertoire: Repertoire,
        qd_offset: float = 0.0,
        metrics_fn: Callable[[Any, float], dict[str, Array]] = qd_metrics,
        placement: Placement | None = None,
    ) -> None:
        """`repertoire` is the empty container to fill; `qd_offset` as in `qd_metrics`.

        `scoring_fn` may be None when every evaluation happens outside JAX
        (`init_values`, `ask`, `tell_values`). `placement` (`qdrl.placement`): offspring
        are generated and evaluated split over its devices, the repertoire and the
        emitter state are replicated and updated identically on each.
        """
        if scoring_fn is not None and not callable(scoring_fn):
            raise TypeError(
                f"scoring_fn: expected a function (genotypes, key) -> Evaluation, or None, got "
                f"{type(scoring_fn).__name__}"
            )
        self.scoring_fn = scoring_fn
        self.placement = placement or Placement()
        self._sharded_scoring = None if scoring_fn is None else shard_scoring(scoring_fn, self.placement)
        self.emitter = emitter
        self.empty_repertoire = repertoire
        self.qd_offset = qd_offset
        self.metrics_fn = metrics_fn
        self.descriptor_size = evaluation_descriptor_size(repertoire)
        # Multi-objective containers (MOME, Pareto populations) declare M: fitnesses are (n, M).
        self.num_objectives: int | None = getattr(repertoire, "num_objectives", None)

    def init(self, genotypes: Genotype, key: PRNGKey) -> QDState:
        """Evaluate an initial population, fill the repertoire with it, start the emitter.

        Raises ValueError (outside jit) when no evaluation is finite; see the module docstring.
        """
        eval_key, key = jax.random.split(key)
        return self.init_from_evaluation(genotypes, self._score(genotypes, eval_key), key)

    def init_from_evaluation(
        self, genotypes: Genotype, evaluation: Evaluation, key: PRNGKey
    ) -> QDState:
        """Fill the repertoire with an evaluated initial population and start the emitter.

        Raises ValueError (outside jit, before adding anything) when no evaluation has
        a finite fitness and a finite descriptor: the repertoire would stay empty.
        """
        evaluation = check_evaluation_type(evaluation, "init_from_evaluation: evaluation")
        n = _batch_size(genotypes, evaluation.fitnesses)
        _check_evaluation(
            n, evaluation.fitnesses, evaluation.descriptors, self.descriptor_size, self.num_objectives
        )
        _check_some_finite(n, evaluation)
        emitter_key, key = jax.random.split(key)
        genotypes, evaluation = self.placement.replicated((genotypes, evaluation))
        repertoire, _ = add_evaluation(self.empty_repertoire, genotypes, evaluation)
        emitter_state = self.emitter.init(emitter_key, repertoire, evaluation, genotypes)
        return self._replicated(QDState(
            repertoire=repertoire,
            emitter_state=emitter_state,
            key=key,
            iteration=jnp.zeros((), jnp.int32),
            evaluations=jnp.asarray(evaluations_spent(evaluation, n), jnp.int32),
            env_steps=jnp.asarray(evaluation.env_steps, jnp.int32),
        ))

    @property
    def state_axes(self) -> QDState:
        """Which axis of each part of the state is split over the devices (`qd_state_axes`)."""
        return qd_state_axes(self.emitter)

    def _replicated(self, state: QDState) -> QDState:
        return self.placement.place(state, self.state_axes)

    def init_values(
        self, genotypes: Genotype, fitnesses: Fitness, descriptors: Descriptor, key: PRNGKey
    ) -> QDState:
        """`init_from_evaluation` for plain arrays computed outside JAX (see `tell_values`)."""
        return self.init_from_evaluation(genotypes, _evaluation(fitnesses, descriptors), key)

    def _score(self, genotypes: Genotype, key: PRNGKey) -> Evaluation:
        if self._sharded_scoring is None:
            raise ValueError(
                "this MapElites has no scoring function: evaluate outside and use "
                "init_values / ask / tell_values"
            )
        return check_evaluation_type(self._sharded_scoring(genotypes, key), "scoring_fn returned")

    def ask(self, state: QDState) -> tuple[Genotype, QDState]:
        """Offspring to evaluate, and the state with its key moved on.

        Raises ValueError (outside jit) when the repertoire is empty.
        """
        if _is_empty_concrete(state.repertoire):
            raise ValueError(
                "ask: the repertoire is empty (no elite with a finite fitness and descriptor), "
                "so there is nothing to build offspring from; init it with evaluations that "
                "have finite fitnesses and descriptors"
            )
        key, emit_key = jax.random.split(state.key)
        offspring = self.emitter.emit(state.emitter_state, state.repertoire, emit_key)
        return self.placement.batched(offspring), state._replace(key=key)

    def tell(
        self,
        state: QDState,
        genotypes: Genotype,
        evaluation: Evaluation,
    ) -> tuple[QDState, dict[str, Array]]:
        """Offer evaluated offspring to the repertoire and update the emitter."""
        evaluation = check_evaluation_type(evaluation, "tell: evaluation")
        n = _batch_size(genotypes, evaluation.fitnesses)
        _check_evaluation(
            n, evaluation.fitnesses, evaluation.descriptors, self.descriptor_size, self.num_objectives
        )
        key, update_key = jax.random.split(state.key)
        genotypes, evaluation = self.placement.replicated((genotypes, evaluation))
        repertoire, added = add_evaluation(state.repertoire, genotypes, evaluation)
        emitter_state = self.emitter.update(
            state.emitter_state, repertoire, genotypes, evaluation, added, update_key
        )
        new = self._replicated(QDState(
            repertoire=repertoire,
            emitter_state=emitter_state,
            key=key,
            iteration=state.iteration + 1,
            evaluations=state.evaluations + evaluations_spent(evaluation, n),
            env_steps=state.env_steps + jnp.asarray(evaluation.env_steps, jnp.int32),
        ))
        return new, self._metrics(new, added)

    def tell_values(
        self,
        state: QDState,
        genotypes: Genotype,
        fitnesses: Fitness,
        descriptors: Descriptor,
    ) -> tuple[QDState, dict[str, Array]]:
        """`tell` for plain arrays of fitnesses and descriptors (e.g. computed with NumPy)."""
        return self.tell(state, genotypes, _evaluation(fitnesses, descriptors))

    def step(self, state: QDState) -> tuple[QDState, dict[str, Array]]:
        """One iteration: ask, evaluate, tell."""
        offspring, state = self.ask(state)
        key, eval_key = jax.random.split(state.key)
        evaluation = self._score(offspring, eval_key)
        return self.tell(state._replace(key=key), offspring, evaluation)

    def run(self, state: QDState, num_steps: int) -> tuple[QDState, dict[str, Array]]:
        """`num_steps` iterations in a `lax.scan`; metrics are stacked per iteration.

        On an accelerator the scalar 32-bit metrics leave each iteration as ONE float32
        vector (integers by their bit pattern, so exactly) and are unpacked after the
        loop: one write into the stacked output per iteration instead of one per metric
        (one kernel instead of seven). On a CPU each metric is its own output: there the
        unpacking would compile one more kernel per metric (a visible share of the
        program's code) for writes that cost nothing. `num_steps` sets the scan's length,
        so it must be a Python int when jitted: `jax.jit(me.run, static_argnums=1)`.
        """
        try:
            length = operator.index(num_steps)
        except Exception:
            raise TypeError(
                f"num_steps: expected a Python int (the scan's length), got {type(num_steps).__name__}"
                " (a traced value?): jit me.run with the number of steps static, "
                "jax.jit(me.run, static_argnums=1)"
            ) from None
        if jax.default_backend() == "cpu":
            return jax.lax.scan(lambda s, _: self.step(s), state, None, length=length)
        layout: list[tuple[str, Any]] = []  # (name, dtype) of the packed metrics, in order

        def body(s: QDState, _: None) -> tuple[QDState, tuple[Array, dict[str, Array]]]:
            s, metrics = self.step(s)
            return s, _pack_scalars(metrics, layout)

        state, (packed, rest) = jax.lax.scan(body, state, None, length=length)
        return state, _unpack_scalars(packed, rest, layout)

    def _metrics(self, state: QDState, added: AddResult) -> dict[str, Array]:
        metrics = dict(self.metrics_fn(state.repertoire, self.qd_offset))
        metrics["added"] = jnp.sum(added.added.astype(jnp.int32))
        return metrics
