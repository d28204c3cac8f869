"""Tests for qdrl.qd.discount_model and qdrl.qd.repertoires.discount (Discount Model Search).

The model's training is checked on a known surface (its loss falls below the cutoff
within the epochs, then it stops), the archive's judgement against a NumPy forward pass
of the MLP with pyribs' status and value rules, and its training data (CMA-MAE's
threshold update, the empty points, the initial points) by recording what `add` and
the builder hand to `fit`. One small archive serves most tests, so each jitted function
compiles once for the module.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import qdrl.qd.repertoires.discount as discount_module
from qdrl.qd.discount_model import DiscountModel, FitConfig, FitResult, fit
from qdrl.qd.repertoires import grid_repertoire
from qdrl.qd.repertoires.discount import DiscountArchive, discount_archive, sample_empty_cells

N = 8  # candidates per batch
LOW, HIGH = (-1.0, 0.0), (1.0, 2.0)
CELLS = (4, 5)  # 20 cells, so empty points run out late in a test
SMALL: dict[str, Any] = {
    "hidden": (16, 16),
    "cells": CELLS,
    "threshold_min": 1.0,
    "discount_range": (0.0, 10.0),
    "init_train_points": 12,
    "empty_points": 6,
    "train_epochs": 3,
}

_fit = jax.jit(fit, static_argnums=(0, 1))
_add = jax.jit(lambda a, d, f: a.add(None, d, f))


@pytest.fixture(scope="module")
def small() -> DiscountArchive:
    return discount_archive(LOW, HIGH, **SMALL, key=jax.random.PRNGKey(0))


def numpy_discount(archive: DiscountArchive, descriptors: np.ndarray) -> np.ndarray:
    """The MLP by hand: inputs to [-1, 1], ReLU layers, outputs from [0, 1] to the discount range."""
    low, high = np.asarray(LOW), np.asarray(HIGH)
    h = 2.0 * (descriptors.astype(np.float64) - low) / (high - low) - 1.0
    layers = sorted(archive.params, key=lambda name: int(name.split("_")[-1]))
    for i, name in enumerate(layers):
        h = h @ np.asarray(archive.params[name]["w"], np.float64) + np.asarray(archive.params[name]["b"])
        if i < len(layers) - 1:
            h = np.maximum(h, 0.0)
    lo, hi = SMALL["discount_range"]
    return h[:, 0] * (hi - lo) + lo


def batch(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    descriptors = rng.uniform(LOW, HIGH, size=(N, 2)).astype(np.float32)
    return descriptors, rng.uniform(0.0, 10.0, size=N).astype(np.float32)


class Recorder:
    """Stands in for `fit` in the archive's module and keeps what it was given, under jit too.

    A function traced before the patch would not call it: the tests that use it jit afresh.
    """

    def __init__(self) -> None:
        self.calls: list[dict[str, np.ndarray]] = []

    def keep(self, descriptors: Any, targets: Any, mask: Any) -> None:
        self.calls.append(
            {"descriptors": np.asarray(descriptors), "targets": np.asarray(targets), "mask": np.asarray(mask)}
        )

    def __call__(self, model: Any, config: Any, params: Any, opt_state: Any, descriptors: Any,
                 targets: Any, mask: Any, key: Any) -> FitResult:
        jax.debug.callback(self.keep, descriptors, targets, mask)
        return fit(model, config, params, opt_state, descriptors, targets, mask, key)

    def last(self) -> dict[str, np.ndarray]:
        jax.effects_barrier()
        return self.calls[-1]


# -- the model's training ------------------------------------------------------------------


def test_fit_learns_a_known_surface_below_the_cutoff_and_stops() -> None:
    # DMS' network (128, 128) and loop (5 epochs, batch 32, cutoff 0.05) on a surface over
    # the objective range [0, 100], trained in the [0, 1] scale as pyribs' "zero_one".
    model = DiscountModel((128, 128), (-1.0, -1.0), (1.0, 1.0), (0.0, 100.0))
    config = FitConfig()
    rng = np.random.default_rng(0)

    def surface(x: np.ndarray) -> np.ndarray:
        return (60.0 + 30.0 * x[:, 0] - 20.0 * x[:, 1] ** 2).astype(np.float32)

    x = rng.uniform(-1, 1, (1000, 2)).astype(np.float32)
    params = model.init(jax.random.PRNGKey(0))
    result = _fit(
        model, config, params, config.optimizer().init(params), x, surface(x),
        np.ones(1000, bool), jax.random.PRNGKey(1),
    )
    epochs = int(result.epochs)
    losses = np.asarray(result.losses)
    assert 1 <= epochs < config.epochs  # stopped early
    assert losses[0] > config.cutoff_loss  # it had to learn
    assert losses[epochs - 1] <= config.cutoff_loss
    assert np.all(losses[: epochs - 1] > config.cutoff_loss)  # the first epoch under it stops
    assert np.all(np.isnan(losses[epochs:]))
    held_out = rng.uniform(-1, 1, (500, 2)).astype(np.float32)
    err = (np.asarray(model(result.params, held_out)) - surface(held_out)) / 100.0
    assert np.mean(err**2) < config.cutoff_loss
    assert int(result.opt_state[0].count) == epochs * 32  # one Adam step per minibatch


def test_fit_runs_every_epoch_without_cutoff_and_ignores_masked_rows() -> None:
    model = DiscountModel((8,), (0.0,), (1.0,))
    config = FitConfig(epochs=4, cutoff_loss=0.0, batch_size=4)
    params = model.init(jax.random.PRNGKey(0))
    state = config.optimizer().init(params)
    x = np.linspace(0, 1, 10, dtype=np.float32)[:, None]
    y = np.ones(10, np.float32)
    mask = np.arange(10) % 2 == 0  # 5 rows: minibatches of 4 and 1
    x[~mask] = np.nan  # masked rows may hold anything
    y[~mask] = np.inf
    result = _fit(model, config, params, state, x, y, mask, jax.random.PRNGKey(1))
    assert int(result.epochs) == 4 and np.all(np.isfinite(np.asarray(result.losses)))
    assert int(result.opt_state[0].count) == 4 * 2
    assert all(np.all(np.isfinite(np.asarray(p))) for p in jax.tree_util.tree_leaves(result.params))
    # No valid row: one empty epoch of loss 0, nothing changes.
    none = _fit(model, config, params, state, x, y, np.zeros(10, bool), jax.random.PRNGKey(1))
    assert int(none.epochs) == 1 and float(none.losses[0]) == 0.0
    for a, b in zip(jax.tree_util.tree_leaves(none.params), jax.tree_util.tree_leaves(params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


# -- the archive's judgement and training data ----------------------------------------------


def test_status_and_value_match_a_numpy_reference(small: DiscountArchive) -> None:
    descriptors, _ = batch(1)
    descriptors[7] = (3.0, -2.0)  # outside the box: the model extrapolates, as pyribs'
    discount = numpy_discount(small, descriptors)
    offsets = np.array([1.0, -1.0, 0.5, -0.5, 2.0, 0.0, -3.0, 0.25])
    fitnesses = (discount + offsets).astype(np.float32)
    # f equal to the discount `add` computes (read from a first call; XLA may round the
    # standalone `discount` differently): not above it, so status 0 (strict, as pyribs).
    first = _add(small, descriptors, fitnesses)[1].info
    assert first is not None
    fitnesses[5] = np.asarray(first["discount"])[5]
    fitnesses[3] = np.nan  # a failed evaluation
    _, result = _add(small, descriptors, fitnesses)
    assert result.status is not None and result.value is not None and result.info is not None
    got_discount = np.asarray(result.info["discount"])
    np.testing.assert_allclose(got_discount, discount, rtol=1e-5, atol=1e-5)
    valid = ~np.isnan(fitnesses)
    want_value = np.where(valid, fitnesses - got_discount, -np.inf)
    # atol: under one float32 ulp of the discount (|f_theta| < 1 here). jax 0.10's XLA drops
    # the barrier and may fuse the model's last multiply-add into the subtraction (one
    # rounding fewer): the tie's value is then 1.5e-8, not 0; its status stays 0.
    np.testing.assert_allclose(np.asarray(result.value), want_value, rtol=1e-6, atol=6e-8)
    np.testing.assert_array_equal(np.asarray(result.improvement), np.asarray(result.value))
    want_status = np.where(valid & (fitnesses > got_discount), 2, 0)
    np.testing.assert_array_equal(np.asarray(result.status), want_status)
    np.testing.assert_array_equal(want_status, [2, 0, 2, 0, 2, 0, 0, 2])
    np.testing.assert_array_equal(np.asarray(result.added), want_status == 2)


def test_training_data_are_the_threshold_update_and_empty_points(
    small: DiscountArchive, monkeypatch: pytest.MonkeyPatch
) -> None:
    recorder = Recorder()
    monkeypatch.setattr(discount_module, "fit", recorder)
    add = jax.jit(lambda a, d, f: a.add(None, d, f))  # traced with the recorder
    archive = small
    filled_cells: set[int] = set()
    grid = grid_repertoire(None, CELLS, LOW, HIGH)
    # Each batch visits 8 distinct cells, around their centres; 20 cells in all.
    order = np.random.default_rng(5).permutation(20)
    width = (np.asarray(HIGH) - np.asarray(LOW)) / np.asarray(CELLS)
    for b in range(3):
        cells_b = order[(8 * b + np.arange(N)) % 20]
        jitter = np.random.default_rng(b).uniform(-0.3, 0.3, (N, 2)) * width
        descriptors = (np.asarray(grid.centroids)[cells_b] + jitter).astype(np.float32)
        fitnesses = np.random.default_rng(b).uniform(0.0, 10.0, N).astype(np.float32)
        fitnesses[b] = np.nan  # rejected: no training row, its cell stays empty
        discount = np.asarray(archive.discount(descriptors))
        archive, result = add(archive, descriptors, fitnesses)
        data = recorder.last()
        valid = ~np.isnan(fitnesses)
        # CMA-MAE's update with alpha 0.1 toward f where f beats the discount.
        want = np.where(fitnesses > discount, 0.9 * discount + 0.1 * fitnesses, discount)
        np.testing.assert_array_equal(data["mask"][:N], valid)
        np.testing.assert_array_equal(data["descriptors"][:N], descriptors)
        np.testing.assert_allclose(data["targets"][:N][valid], want[valid], rtol=1e-5)
        # The empty points: distinct centres of cells still empty AFTER this batch.
        filled_cells |= set(cells_b[valid].tolist())
        empty = set(range(20)) - filled_cells
        rows = data["mask"][N:]
        assert data["descriptors"].shape == (N + 6, 2)
        assert int(rows.sum()) == min(6, len(empty))
        centres = data["descriptors"][N:][rows]
        cells = np.asarray(grid.cell_index(centres))
        np.testing.assert_allclose(centres, np.asarray(grid.centroids)[cells], rtol=1e-6)
        assert len(set(cells.tolist())) == len(cells) and set(cells.tolist()) <= empty
        np.testing.assert_array_equal(data["targets"][N:][rows], np.full(rows.sum(), 1.0))
        # The record is a result archive of the same cells fed the same candidates.
        np.testing.assert_array_equal(np.flatnonzero(np.asarray(archive.filled)), sorted(filled_cells))
        np.testing.assert_array_equal(np.asarray(result.cell), np.where(valid, cells_b, -1))
    assert 20 - len(filled_cells) < 6  # the last training had fewer empty points than asked


def test_initial_training_targets_threshold_min_on_empty_cells(monkeypatch: pytest.MonkeyPatch) -> None:
    recorder = Recorder()
    monkeypatch.setattr(discount_module, "fit", recorder)
    # 1000 initial points: a static argument no other test uses, so the builder's jitted
    # training is traced afresh, with the recorder.
    archive = discount_archive(LOW, HIGH, **{**SMALL, "init_train_points": 1000}, key=jax.random.PRNGKey(0))
    data = recorder.last()
    assert len(recorder.calls) == 1
    # More points asked than cells: every cell's centre once (pyribs samples without replacement).
    assert data["descriptors"].shape == (20, 2) and bool(data["mask"].all())
    np.testing.assert_array_equal(data["targets"], np.full(20, 1.0))
    centres = {tuple(c) for c in np.asarray(archive.record.centroids).tolist()}
    assert {tuple(c) for c in data["descriptors"].tolist()} == centres
    assert int(archive.epochs) >= 1


def test_initial_training_brings_the_discount_to_threshold_min() -> None:
    archive = discount_archive(
        LOW, HIGH, hidden=(32, 32), cells=(10, 10), init_train_points=100, threshold_min=2.0,
        model_lr=1e-2, train_epochs=60, train_cutoff_loss=1e-3, key=jax.random.PRNGKey(0),
    )
    assert 1 <= int(archive.epochs) < 60 and float(archive.loss) <= 1e-3
    discount = np.asarray(archive.discount(archive.record.centroids))
    assert np.max(np.abs(discount - 2.0)) < 0.2


def test_sample_empty_cells_draws_distinct_empty_cells() -> None:
    filled = jnp.asarray(np.arange(12) % 3 == 0)  # cells 1, 2, 4, 5, 7, 8, 10, 11 are empty
    empty = set(np.flatnonzero(~np.asarray(filled)).tolist())
    cells, valid = sample_empty_cells(jax.random.PRNGKey(0), filled, 5)
    assert cells.shape == (5,) and bool(valid.all())
    assert len(set(np.asarray(cells).tolist())) == 5 and set(np.asarray(cells).tolist()) <= empty
    cells, valid = sample_empty_cells(jax.random.PRNGKey(0), filled, 100)
    assert cells.shape == (12,) and int(valid.sum()) == 8
    assert set(np.asarray(cells)[np.asarray(valid)].tolist()) == empty
    _, valid = sample_empty_cells(jax.random.PRNGKey(0), jnp.ones(12, bool), 4)
    assert not bool(valid.any())
    assert sample_empty_cells(jax.random.PRNGKey(0), filled, 0)[0].shape == (0,)


def test_add_compiles_once_runs_under_scan_and_resumes_bit_exactly(small: DiscountArchive) -> None:
    traces: list[None] = []

    def counted(a: DiscountArchive, d: jax.Array, f: jax.Array) -> Any:
        traces.append(None)
        return a.add(None, d, f)

    add = jax.jit(counted)
    structure: Any = jax.tree_util.tree_structure(small)  # Any: mypy cannot type PyTreeDef
    archive = small
    for seed in range(3):
        archive, _ = add(archive, *batch(20 + seed))
    assert len(traces) == 1 and jax.tree_util.tree_structure(archive) == structure
    # The params, Adam's state and the key are leaves: a checkpoint resumes bit-exactly.
    leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(archive)]
    resumed = jax.tree_util.tree_unflatten(structure, [jnp.asarray(x) for x in leaves])
    a, ra = add(archive, *batch(30))
    b, rb = add(resumed, *batch(30))
    for x, y in zip(jax.tree_util.tree_leaves((a, ra)), jax.tree_util.tree_leaves((b, rb)), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))

    def body(arch: DiscountArchive, xs: tuple[jax.Array, jax.Array]) -> tuple[DiscountArchive, jax.Array]:
        arch, result = arch.add(None, *xs)
        return arch, result.status

    descriptors = np.stack([batch(40 + i)[0] for i in range(3)])
    fitnesses = np.stack([batch(40 + i)[1] for i in range(3)])
    scanned, statuses = jax.jit(lambda a, xs: jax.lax.scan(body, a, xs))(archive, (descriptors, fitnesses))
    assert isinstance(scanned, DiscountArchive) and statuses.shape == (3, N)


def test_views_and_sample(small: DiscountArchive) -> None:
    assert small.genotypes is None and small.num_cells == 20 and bool(small.is_empty)
    descriptors, fitnesses = batch(50)
    archive, _ = _add(small, descriptors, fitnesses)
    passive, _ = grid_repertoire(None, CELLS, LOW, HIGH).add(None, descriptors, fitnesses)
    np.testing.assert_array_equal(np.asarray(archive.fitnesses), np.asarray(passive.fitnesses))
    np.testing.assert_array_equal(np.asarray(archive.filled), np.asarray(passive.filled))
    with pytest.raises(NotImplementedError, match="result archive"):
        archive.sample(jax.random.PRNGKey(0), 4)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"learning_rate": 0.0}, "learning_rate"),
        ({"learning_rate": 1.5}, "learning_rate"),
        ({"threshold_min": -math.inf}, "threshold_min"),
        ({"model_lr": 0.0}, "model_lr"),
        ({"train_epochs": 0}, "train_epochs"),
        ({"train_cutoff_loss": -0.1}, "train_cutoff_loss"),
        ({"train_batch_size": 0}, "train_batch_size"),
        ({"init_train_points": -1}, "init_train_points"),
        ({"empty_points": -1}, "empty_points"),
        ({"hidden": (16, 0)}, "hidden"),
        ({"cells": (4, 0)}, "cells"),
        ({"discount_range": (1.0, 1.0)}, "discount_range"),
        ({"descriptor_high": (1.0, -1.0)}, "descriptor_high"),
        ({"descriptor_low": 0.0, "descriptor_high": 1.0, "cells": 10}, "descriptor_low"),
    ],
)
def test_bad_parameters_raise_naming_them(kwargs: dict[str, Any], name: str) -> None:
    args: dict[str, Any] = {"descriptor_low": LOW, "descriptor_high": HIGH, **SMALL, **kwargs}
    with pytest.raises(ValueError, match=f"^{name}:"):
        discount_archive(**args, key=jax.random.PRNGKey(0))
