"""The archive of Discount Model Search: a discount model in place of CMA-MAE's per-cell thresholds.

Tjanaka, Chen, Fontaine & Nikolaidis 2026, "Discount Model Search for Quality Diversity
Optimization in High-Dimensional Measure Spaces" (ICLR 2026, https://discount-models.github.io/);
pyribs' `DiscountArchive`. A candidate of fitness f and descriptor d is judged against
the discount f_theta(d) of a small network (`qdrl.qd.discount_model`): its value is
f - f_theta(d) and it counts as new (status 2) when f > f_theta(d), else not added
(status 0). After judging a batch, the archive trains the network (`fit`) on

- every valid candidate, with target CMA-MAE's threshold update
  (1 - alpha) f_theta(d) + alpha f where f > f_theta(d), else f_theta(d) (Eq. 1 of the
  paper; alpha = `learning_rate`, f_theta as it was when the batch was judged);
- up to `empty_points` centres of cells that no candidate has reached yet, drawn
  without replacement, with target `threshold_min`: they hold the discount low where
  the search has not been.

The archive is built trained on `init_train_points` such centres (target
`threshold_min`), so the discount starts near `threshold_min` everywhere (pyribs'
`init_discount_model`).

pyribs draws the empty points from the run's result archive. This archive keeps its own
record instead, a passive `CellRepertoire` (no genotype) over the same cells, offered
every candidate: its empty cells are those of a result archive of that layout fed the
same candidates, and its fitnesses and descriptors are what the archive's views read.
pyribs trains when the user calls `train_discount_model` after each `tell`; here `add`
judges and then trains, which is the same order. Everything has fixed shapes (masks
for the invalid candidates and for the empty points a nearly full record cannot give),
so `add` jits once and runs under `lax.scan`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.qd.base import AddResult
from qdrl.qd.discount_model import DiscountModel, FitConfig, fit
from qdrl.qd.repertoires.cells import (
    CellRepertoire,
    as_bounds,
    check_batch,
    grid_repertoire,
    valid_candidates,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype, Params, PRNGKey

__all__ = ["DiscountArchive", "discount_archive", "sample_empty_cells"]


def sample_empty_cells(key: PRNGKey, filled: Array, num: int) -> tuple[Array, Array]:
    """Up to `num` distinct empty cells, drawn uniformly without replacement; jittable.

    Returns (cells (m,) int32, valid (m,) bool) with m = min(num, C): `valid` is False
    for the entries past the number of empty cells (pyribs then returns fewer points).
    Each cell gets a uniform priority in [0, 1), filled cells -1, and the m highest win.
    """
    size = int(filled.shape[0])
    m = min(int(num), size)
    if m == 0:
        return jnp.zeros((0,), jnp.int32), jnp.zeros((0,), bool)
    priority = jnp.where(filled, -1.0, jax.random.uniform(key, (size,)))
    top, cells = jax.lax.top_k(priority, m)
    return cells.astype(jnp.int32), top >= 0.0


@dataclasses.dataclass(frozen=True, eq=False)
class DiscountArchive:
    """A discount model, its optimiser and a record of the cells reached; stores no genotype.

    Attributes:
      params: the network's parameters (a haiku tree).
      opt_state: Adam's state, carried across trainings as pyribs' optimizer is.
      key: split at every `add` (empty points, minibatch shuffles).
      record: passive `CellRepertoire` (genotypes None) offered every candidate: the
        best fitness per cell, and the cells still empty.
      epochs: () int32 epochs of the latest training.
      loss: () float32 mean loss of its last epoch (in the network's normalised scale).
      model, fit_config: the network and its training (static).
      learning_rate: alpha of the threshold update.
      threshold_min: the target of the empty (and initial) points.
      empty_points: empty points per training.

    The cell-repertoire views (`fitnesses`, `descriptors`, `num_cells`, `filled`, ...)
    read `record`: the best candidate offered per cell, as a result archive of the same
    cells would hold, without its genotype.
    """

    params: Params
    opt_state: Any
    key: PRNGKey
    record: CellRepertoire
    epochs: Array
    loss: Array
    model: DiscountModel
    fit_config: FitConfig
    learning_rate: float
    threshold_min: float
    empty_points: int

    @property
    def genotypes(self) -> None:
        """None: the archive stores no solution."""
        return None

    @property
    def fitnesses(self) -> Array:
        """(C,) float32 best fitness offered per cell of the record, -inf where none."""
        return self.record.fitnesses

    @property
    def descriptors(self) -> Array:
        """(C, D) float32 descriptor of that best candidate."""
        return self.record.descriptors

    @property
    def num_cells(self) -> int:
        """Number of cells C of the record (static)."""
        return self.record.num_cells

    @property
    def descriptor_dim(self) -> int:
        """Descriptor dimension D (static)."""
        return self.record.descriptor_dim

    @property
    def filled(self) -> Array:
        """(C,) bool, the cells some valid candidate reached."""
        return self.record.filled

    @property
    def num_filled(self) -> Array:
        """() int32 number of cells reached."""
        return self.record.num_filled

    @property
    def is_empty(self) -> Array:
        """() bool, True before any valid candidate was offered."""
        return self.record.is_empty

    def discount(self, descriptors: Descriptor) -> Array:
        """(n,) the model's discount values at descriptors (n, D)."""
        return self.model(self.params, jnp.asarray(descriptors, jnp.float32))

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[DiscountArchive, AddResult]:
        """Judges n candidates against the discount model, then trains it (module docstring).

        `genotypes` is ignored (any pytree, or None). A candidate whose fitness or
        descriptor is not finite is rejected (status 0, value -inf) and kept out of the
        training data (pyribs raises on them). Subnormal fitnesses count as 0.

        Returns:
          The new archive and an `AddResult`: `status` 2 where f > f_theta(d), else 0;
          `value` and `improvement` f - f_theta(d) (-inf when rejected); `added` where
          status is 2; `new_cell` and `cell` the candidate's cell in the record, and
          whether it reached it first; `info["discount"]` f_theta(d), the model as it
          was before this batch's training.
        """
        descriptors, fitnesses = check_batch(
            None, self.descriptor_dim, None, descriptors, fitnesses, "add"
        )
        valid = valid_candidates(descriptors, fitnesses)
        # One rounding of the discount for status, value, target and info: without the
        # barrier XLA may fuse (and round) its last multiply-add into each consumer apart.
        # jax 0.10's XLA drops the barrier: there `value` may be f - f_theta(d) rounded once
        # (within an ulp of f - info["discount"]); status and info still agree.
        discount = jax.lax.optimization_barrier(self.discount(descriptors))
        beats = valid & (fitnesses > discount)
        alpha = self.learning_rate
        targets = jnp.where(beats, (1.0 - alpha) * discount + alpha * fitnesses, discount)
        record, reached = self.record.add(None, descriptors, fitnesses)
        key, empty_key, fit_key = jax.random.split(self.key, 3)
        cells, has_cell = sample_empty_cells(empty_key, record.filled, self.empty_points)
        floor = jnp.full(cells.shape, self.threshold_min, jnp.float32)
        new = self._train(
            jnp.concatenate([descriptors, record.centroids[cells]]),
            jnp.concatenate([targets, floor]),
            jnp.concatenate([valid, has_cell]),
            fit_key,
        )
        new = dataclasses.replace(new, record=record, key=key)
        value = jnp.where(valid, fitnesses - discount, -jnp.inf).astype(jnp.float32)
        return new, AddResult(
            added=beats,
            new_cell=reached.new_cell,
            improvement=value,
            cell=reached.cell,
            status=jnp.where(beats, 2, 0).astype(jnp.int32),
            value=value,
            info={"discount": discount.astype(jnp.float32)},
        )

    def _train(
        self, descriptors: Array, targets: Array, mask: Array, key: PRNGKey
    ) -> DiscountArchive:
        """The archive after fitting its model to `targets` at `descriptors` where `mask` holds."""
        result = fit(
            self.model, self.fit_config, self.params, self.opt_state, descriptors, targets, mask, key
        )
        last = result.losses[jnp.maximum(result.epochs - 1, 0)]
        return dataclasses.replace(
            self, params=result.params, opt_state=result.opt_state, epochs=result.epochs, loss=last
        )

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """Not available: the archive stores no solution; sample the run's result archive."""
        raise NotImplementedError(
            "DiscountArchive stores no genotypes (Discount Model Search keeps a discount "
            "model); sample parents from the run's result archive instead"
        )


jax.tree_util.register_dataclass(
    DiscountArchive,
    data_fields=["params", "opt_state", "key", "record", "epochs", "loss"],
    meta_fields=["model", "fit_config", "learning_rate", "threshold_min", "empty_points"],
)


def _is_int(value: object) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def discount_archive(
    descriptor_low: float | Sequence[float],
    descriptor_high: float | Sequence[float],
    hidden: Sequence[int] = (128, 128),
    learning_rate: float = 0.1,
    threshold_min: float = 0.0,
    model_lr: float = 1e-3,
    train_epochs: int = 5,
    train_cutoff_loss: float = 0.05,
    train_batch_size: int = 32,
    init_train_points: int = 1000,
    empty_points: int = 100,
    cells: int | Sequence[int] | CellRepertoire = 100,
    discount_range: tuple[float, float] | None = None,
    *,
    key: PRNGKey,
) -> DiscountArchive:
    """A DMS archive (Tjanaka et al. 2026) whose model starts trained to `threshold_min`.

    The defaults are pyribs' DMS config (its sphere example), but for `discount_range`.

    Args:
      descriptor_low, descriptor_high: the descriptor box (scalars or D values, low <
        high); descriptors enter the network mapped to [-1, 1].
      hidden: the MLP's hidden layer sizes (ReLU).
      learning_rate: alpha of the threshold update, in (0, 1].
      threshold_min: the discount of unexplored regions (finite; pyribs requires it).
      model_lr: Adam's step size (betas 0.9, 0.999).
      train_epochs: most epochs per training (>= 1).
      train_cutoff_loss: training stops after an epoch whose mean loss is at most this (>= 0).
      train_batch_size: rows per Adam step (>= 1).
      init_train_points: empty cells trained to `threshold_min` when the archive is built
        (>= 0; 0 leaves the network as initialised).
      empty_points: empty cells added to each training (>= 0).
      cells: the layout of the record whose empty cells give the empty points, that of the
        run's result archive: bins per dimension of a grid over the descriptor box (an int
        is used for every dimension; pyribs' example: 100 x 100), or a passive
        `CellRepertoire` (genotypes None, e.g. `passive_archive("cvt", ...)`).
      discount_range: (lo, hi) with lo < hi, to train on targets mapped to [0, 1] (pyribs'
        `normalize_discount="zero_one"`; its DMS example passes the objective range, (0,
        100)); None trains on raw discount values (pyribs' default).
      key: for the network's initialisation, the initial training and the archive's key.
    """
    dim = _descriptor_dim(descriptor_low, descriptor_high, cells)
    low = as_bounds(descriptor_low, dim, "descriptor_low")
    high = as_bounds(descriptor_high, dim, "descriptor_high")
    if any(h <= lo for lo, h in zip(low, high, strict=True)):
        raise ValueError(
            f"descriptor_high: expected descriptor_low < descriptor_high in every dimension, "
            f"got {low} and {high}"
        )
    sizes = tuple(hidden)
    if not all(_is_int(h) and h >= 1 for h in sizes):
        raise ValueError(f"hidden: expected positive ints, got {hidden!r}")
    if not (_is_real(learning_rate) and 0.0 < learning_rate <= 1.0):
        raise ValueError(f"learning_rate: expected a number in (0, 1], got {learning_rate!r}")
    if not (_is_real(threshold_min) and math.isfinite(threshold_min)):
        raise ValueError(f"threshold_min: expected a finite number, got {threshold_min!r}")
    if not (_is_real(model_lr) and 0.0 < model_lr < math.inf):
        raise ValueError(f"model_lr: expected a finite number > 0, got {model_lr!r}")
    if not (_is_int(train_epochs) and train_epochs >= 1):
        raise ValueError(f"train_epochs: expected an int >= 1, got {train_epochs!r}")
    if not (_is_real(train_cutoff_loss) and 0.0 <= train_cutoff_loss < math.inf):
        raise ValueError(f"train_cutoff_loss: expected a finite number >= 0, got {train_cutoff_loss!r}")
    if not (_is_int(train_batch_size) and train_batch_size >= 1):
        raise ValueError(f"train_batch_size: expected an int >= 1, got {train_batch_size!r}")
    if not (_is_int(init_train_points) and init_train_points >= 0):
        raise ValueError(f"init_train_points: expected an int >= 0, got {init_train_points!r}")
    if not (_is_int(empty_points) and empty_points >= 0):
        raise ValueError(f"empty_points: expected an int >= 0, got {empty_points!r}")
    if discount_range is not None:
        lo_hi = tuple(discount_range)
        if not (
            len(lo_hi) == 2
            and all(_is_real(v) and math.isfinite(v) for v in lo_hi)
            and lo_hi[0] < lo_hi[1]
        ):
            raise ValueError(
                f"discount_range: expected (lo, hi) finite with lo < hi, got {discount_range!r}"
            )
        discount_range = (float(lo_hi[0]), float(lo_hi[1]))
    record = _record(cells, low, high)

    model = DiscountModel(
        hidden=tuple(int(h) for h in sizes),
        descriptor_low=low,
        descriptor_high=high,
        discount_range=discount_range,
    )
    fit_config = FitConfig(
        learning_rate=float(model_lr),
        epochs=int(train_epochs),
        cutoff_loss=float(train_cutoff_loss),
        batch_size=int(train_batch_size),
    )
    params_key, points_key, fit_key, state_key = jax.random.split(key, 4)
    params = model.init(params_key)
    archive = DiscountArchive(
        params=params,
        opt_state=fit_config.optimizer().init(params),
        key=state_key,
        record=record,
        epochs=jnp.zeros((), jnp.int32),
        loss=jnp.zeros((), jnp.float32),
        model=model,
        fit_config=fit_config,
        learning_rate=float(learning_rate),
        threshold_min=float(threshold_min),
        empty_points=int(empty_points),
    )
    if init_train_points == 0:
        return archive
    return _init_train(archive, points_key, fit_key, int(init_train_points))


def _descriptor_dim(
    low: float | Sequence[float], high: float | Sequence[float], cells: Any
) -> int:
    """D from the first of low, high, cells that is not a scalar."""
    if isinstance(cells, CellRepertoire):
        return cells.descriptor_dim
    for value in (low, high, cells):
        if np.ndim(value) == 1:
            return int(np.size(value))
    raise ValueError(
        "descriptor_low: expected D bounds (or D bins in cells, or a CellRepertoire), "
        f"got scalars {low!r}, {high!r} and cells={cells!r}: the descriptor dimension is unknown"
    )


def _record(
    cells: int | Sequence[int] | CellRepertoire, low: tuple[float, ...], high: tuple[float, ...]
) -> CellRepertoire:
    if isinstance(cells, CellRepertoire):
        if cells.genotypes is not None:
            raise ValueError("cells: expected a passive CellRepertoire (genotypes None)")
        return cells
    shape = np.broadcast_to(np.asarray(cells), (len(low),))
    if not all(_is_int(v) and v >= 1 for v in shape.tolist()):
        raise ValueError(
            f"cells: expected a positive int, {len(low)} positive ints or a passive "
            f"CellRepertoire, got {cells!r}"
        )
    return grid_repertoire(None, tuple(int(v) for v in shape), low, high)


@functools.partial(jax.jit, static_argnums=(3,))
def _init_train(
    archive: DiscountArchive, points_key: PRNGKey, fit_key: PRNGKey, num: int
) -> DiscountArchive:
    """pyribs' `init_discount_model`: train on `num` empty cells' centres, target `threshold_min`."""
    cells, has_cell = sample_empty_cells(points_key, archive.record.filled, num)
    floor = jnp.full(cells.shape, archive.threshold_min, jnp.float32)
    return archive._train(archive.record.centroids[cells], floor, has_cell, fit_key)
