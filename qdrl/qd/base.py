"""The contracts between the QD loop, repertoires, emitters and scoring functions.

- A scoring function evaluates a batch of genotypes: `scoring_fn(genotypes, key)
  -> Evaluation`.
- A repertoire is a pytree with `add(genotypes, descriptors, fitnesses) ->
  (repertoire, AddResult)` and `sample(key, n) -> genotypes`; empty cells have
  fitness -inf.
- An emitter is `init / emit / update` over a pytree state; the loop never knows
  which emitter it runs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Protocol, runtime_checkable

from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey


class Evaluation(NamedTuple):
    """What a scoring function returns for a batch of n genotypes."""

    fitnesses: Fitness  # (n,) float32; NaN marks a failed evaluation (never stored)
    descriptors: Descriptor  # (n, D) float32
    extras: dict[str, Any]  # e.g. {"transitions": Transition (T, n, ...)} for QD-RL emitters
    env_steps: Array  # () int32 environment steps spent (0 for plain functions)


ScoringFn = Callable[[Genotype, PRNGKey], Evaluation]

# Extras whose batch axis is the second (time-major, (T, n, ...)); every other extra
# is batch-major (n, ...). Sharded evaluation (`qdrl.qd.map_elites.shard_scoring`)
# splits each on its batch axis.
TIME_MAJOR_EXTRAS = frozenset({"transitions", "mask", "recorded"})

# The extra of a candidate evaluated several times (`qdrl.qd.sampling`): its per-sample values,
# batch-major, {"fitnesses": (n, N), "descriptors": (n, N, D)}.
SAMPLES = "samples"


def evaluations_spent(evaluation: Evaluation, n: int) -> int:
    """How many evaluations a batch of n candidates cost: n, or n x N when each candidate was
    evaluated N times (`extras["samples"]`). Static: read from shapes."""
    samples = evaluation.extras.get(SAMPLES)
    return n if samples is None else n * int(samples["fitnesses"].shape[1])


class AddResult(NamedTuple):
    """Per-candidate outcome of `repertoire.add`, for emitters that rank offspring.

    Archives without cells of their own (proximity, density, discount-model archives) judge
    each candidate themselves: they fill `status` and `value` (`qdrl.qd.emitters.rankers`
    then uses them as they are) and `info`, the per-candidate fields their rankers read
    ("novelty", "local_competition", "density"), as pyribs' `add_info`.
    """

    added: Array  # (n,) bool: the candidate is now the elite of its cell
    new_cell: Array  # (n,) bool: it filled an empty cell
    improvement: Array  # (n,) fitness minus the cell's previous elite (its fitness if new)
    cell: Array  # (n,) int32 cell index (-1 when rejected outright, e.g. NaN fitness)
    # (n,) int32 pyribs' add status (0 not added, 1 improved, 2 new), when the archive judges it
    status: Array | None = None
    value: Array | None = None  # (n,) float32 what the status ranks by (improvement), with `status`
    info: dict[str, Array] | None = None  # (n,) per-candidate fields for rankers


class Repertoire(Protocol):
    """What the loop, emitters and metrics rely on (see qdrl.qd.repertoires)."""

    @property
    def genotypes(self) -> Genotype:
        """Leaves (C, ...)."""
        ...

    @property
    def fitnesses(self) -> Array:
        """(C,) float32, -inf where empty."""
        ...

    @property
    def descriptors(self) -> Array:
        """(C, D) float32."""
        ...

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[Repertoire, AddResult]: ...

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype: ...


class Emitter(Protocol):
    """Produces offspring from a repertoire and learns from their evaluation.

    `batch_size` offspring per `emit`. Everything is jittable; the state is a pytree
    (None for stateless emitters).
    """

    batch_size: int

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> Any:
        """Emitter state, given the initial population and its evaluation."""
        ...

    def emit(self, state: Any, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """`batch_size` offspring genotypes."""
        ...

    def update(
        self,
        state: Any,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> Any:
        """The new emitter state after its offspring were evaluated and offered to the repertoire."""
        ...


def add_evaluation(repertoire: Any, genotypes: Genotype, evaluation: Evaluation) -> tuple[Any, AddResult]:
    """`repertoire.add(genotypes, descriptors, fitnesses)` of an evaluated batch; a repertoire that
    reads more of the evaluation than its fitnesses and descriptors (AURORA's observations, the
    samples of a candidate evaluated several times) defines `add_evaluation(genotypes,
    evaluation)`, which is then called instead."""
    add = getattr(repertoire, "add_evaluation", None)
    if add is not None:
        return add(genotypes, evaluation)  # type: ignore[no-any-return]
    return repertoire.add(genotypes, evaluation.descriptors, evaluation.fitnesses)  # type: ignore[no-any-return]


def evaluation_descriptor_size(repertoire: Any) -> int:
    """The width D of the descriptors a scoring function gives the repertoire: its stored
    descriptors' unless it declares `evaluation_descriptor_size` (AURORA stores learnt codes
    of another width than the task's hand-made descriptor, which its result archive reads)."""
    size = getattr(repertoire, "evaluation_descriptor_size", None)
    return int(repertoire.descriptors.shape[-1]) if size is None else int(size)


@runtime_checkable
class ReportsMetrics(Protocol):
    """An emitter that reports counters of its state on each log row (a critic's steps, restarts)."""

    def log_metrics(self, state: Any) -> dict[str, Array]:
        """Named 0-d values read from the emitter's state."""
        ...


def emitter_metrics(emitter: Any, state: Any) -> dict[str, Array]:
    """`emitter.log_metrics(state)` for an emitter that reports metrics (`ReportsMetrics`), else {}."""
    return dict(emitter.log_metrics(state)) if isinstance(emitter, ReportsMetrics) else {}
