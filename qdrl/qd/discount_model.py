"""The discount model of Discount Model Search: an MLP from a descriptor to a discount value.

Tjanaka, Chen, Fontaine & Nikolaidis 2026, "Discount Model Search for Quality Diversity
Optimization in High-Dimensional Measure Spaces" (ICLR 2026, https://discount-models.github.io/);
pyribs' `MLP` and `DiscountModelManager` (`ribs.discount_models`). CMA-MAE keeps one
threshold, or discount, per cell of a histogram; DMS replaces the histogram by a small
network f(descriptor), regressed after every batch onto CMA-MAE's threshold update, so
that nearby descriptors share their discount. This module holds the network and its
training; the archive that builds the training data is `qdrl.qd.repertoires.discount`.

`fit` is pyribs' training loop in fixed shapes, so that it jits: epochs of shuffled
minibatches of the mean squared error, each an Adam step, until an epoch's mean loss is
at most the cutoff or the epochs run out. Rows are masked instead of dropped, so one
compiled program serves every batch whatever the number of valid rows.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import haiku as hk
import jax
import jax.numpy as jnp
import optax

from qdrl.types import Array, Params, PRNGKey

__all__ = ["DiscountModel", "FitConfig", "FitResult", "discount_network", "fit"]


def discount_network(hidden: Sequence[int] = (128, 128)) -> hk.Transformed:
    """x (n, D) -> (n,): ReLU hidden layers, a linear output (pyribs' `MLP` of the DMS config).

    Weights and biases start uniform in +-1/sqrt(fan_in), the default of torch's
    `nn.Linear` that pyribs' MLP uses. Matmuls run at HIGHEST precision, so a GPU does
    not use TF32 and the discounts, hence the statuses, agree across backends.
    """
    sizes = [*(int(h) for h in hidden), 1]

    def forward(x: Array) -> Array:
        h = x
        for i, size in enumerate(sizes):
            bound = 1.0 / math.sqrt(h.shape[-1])
            init = hk.initializers.RandomUniform(-bound, bound)
            h = hk.Linear(size, w_init=init, b_init=init, name=f"linear_{i}")(
                h, precision=jax.lax.Precision.HIGHEST
            )
            if i < len(sizes) - 1:
                h = jax.nn.relu(h)
        return h[..., 0]

    return hk.without_apply_rng(hk.transform(forward))


@dataclasses.dataclass(frozen=True)
class DiscountModel:
    """The network and its normalisations: static configuration, hashable (the params live apart).

    Descriptors enter the network mapped from [low, high] to [-1, 1] (pyribs'
    `normalize_measures="negative_one_one"`). With `discount_range` = (lo, hi) the
    network regresses targets mapped from [lo, hi] to [0, 1] and its outputs are mapped
    back (pyribs' `normalize_discount="zero_one"`, which DMS uses with the objective's
    range); without it the network outputs discounts as they are.
    """

    hidden: tuple[int, ...]
    descriptor_low: tuple[float, ...]
    descriptor_high: tuple[float, ...]
    discount_range: tuple[float, float] | None = None

    @property
    def network(self) -> hk.Transformed:
        """The haiku (init, apply) pair; rebuilt on each access, which costs nothing at run time."""
        return discount_network(self.hidden)

    def inputs(self, descriptors: Array) -> Array:
        """Descriptors (n, D) mapped from [low, high] to [-1, 1] per dimension."""
        low = jnp.asarray(self.descriptor_low, jnp.float32)
        high = jnp.asarray(self.descriptor_high, jnp.float32)
        return 2.0 * (jnp.asarray(descriptors, jnp.float32) - low) / (high - low) - 1.0

    def to_unit(self, discounts: Array) -> Array:
        """Discount values in the network's output scale ([lo, hi] -> [0, 1] with `discount_range`)."""
        discounts = jnp.asarray(discounts, jnp.float32)
        if self.discount_range is None:
            return discounts
        lo, hi = self.discount_range
        return (discounts - lo) / (hi - lo)

    def from_unit(self, outputs: Array) -> Array:
        """The network's outputs as discount values (the inverse of `to_unit`)."""
        if self.discount_range is None:
            return outputs
        lo, hi = self.discount_range
        return outputs * (hi - lo) + lo

    def init(self, key: PRNGKey) -> Params:
        """Fresh network parameters."""
        return self.network.init(key, jnp.zeros((1, len(self.descriptor_low)), jnp.float32))

    def __call__(self, params: Params, descriptors: Array) -> Array:
        """(n,) discount values at descriptors (n, D)."""
        return self.from_unit(self.network.apply(params, self.inputs(descriptors)))


@dataclasses.dataclass(frozen=True)
class FitConfig:
    """How `fit` trains: Adam and the loop of pyribs' DMS config (static, hashable).

    Attributes:
      learning_rate: Adam's step size (torch's Adam defaults otherwise: eps 1e-8, no decay).
      b1, b2: Adam's moment decays.
      epochs: most epochs of one `fit`.
      cutoff_loss: `fit` stops after the first epoch whose mean loss is at most this.
      batch_size: rows per Adam step (the last minibatch of an epoch may hold fewer).
    """

    learning_rate: float = 1e-3
    b1: float = 0.9
    b2: float = 0.999
    epochs: int = 5
    cutoff_loss: float = 0.05
    batch_size: int = 32

    def optimizer(self) -> optax.GradientTransformation:
        """optax's Adam: the same update as torch's (eps added to sqrt of the corrected second moment)."""
        return optax.adam(self.learning_rate, b1=self.b1, b2=self.b2, eps=1e-8)


class FitResult(NamedTuple):
    """What `fit` returns."""

    params: Params
    opt_state: Any
    epochs: Array  # () int32 epochs run
    losses: Array  # (config.epochs,) float32 mean loss of each epoch run, NaN after the stop


def fit(
    model: DiscountModel,
    config: FitConfig,
    params: Params,
    opt_state: Any,
    descriptors: Array,
    targets: Array,
    mask: Array,
    key: PRNGKey,
) -> FitResult:
    """Regresses the model onto `targets` at `descriptors`, the rows where `mask` holds; jittable.

    pyribs' `DiscountModelManager.training_loop`: each epoch shuffles the m valid rows
    and takes one Adam step on the mean squared error (in the network's normalised
    scale) of each minibatch of `config.batch_size` of them, the last one smaller; the
    epoch's loss is the mean of the minibatch losses weighted by their sizes. Training
    stops after the first epoch whose loss is at most `config.cutoff_loss`, or after
    `config.epochs`. Epochs are a `lax.while_loop` and minibatches a `lax.fori_loop` up to
    ceil(m / batch_size), so masked rows cost nothing and never enter a step. With no
    valid row, one empty epoch of loss 0 runs and nothing changes.

    Args:
      model, config: the network and the loop (static).
      params, opt_state: the network's parameters and Adam's state (from
        `config.optimizer().init(params)`), carried from one `fit` to the next.
      descriptors: (N, D) inputs, not normalised; masked rows may hold anything.
      targets: (N,) discount values, not normalised.
      mask: (N,) bool, the rows to train on.
      key: the shuffles' key (split once per epoch).
    """
    n = descriptors.shape[0]
    batch = config.batch_size
    mask = jnp.asarray(mask, bool)
    # Masked rows are zeroed: a NaN there would reach the gradient through 0 * NaN.
    x = model.inputs(jnp.where(mask[:, None], descriptors, 0.0))
    y = model.to_unit(jnp.where(mask, targets, 0.0))
    count = jnp.sum(mask, dtype=jnp.int32)
    num_batches = (count + batch - 1) // batch
    padded = -(-n // batch) * batch
    optimizer = config.optimizer()
    apply = model.network.apply

    def batch_loss(p: Params, xb: Array, yb: Array, wb: Array) -> Array:
        err = apply(p, xb) - yb
        return jnp.sum(wb * err * err) / jnp.maximum(jnp.sum(wb), 1.0)

    grad_fn = jax.value_and_grad(batch_loss)

    def epoch(carry: tuple[Any, ...]) -> tuple[Any, ...]:
        p, state, done, _, losses, k = carry
        k, sub = jax.random.split(k)
        perm = jax.random.permutation(sub, n)
        # The valid rows first, in a uniformly random order; padded to whole minibatches.
        order = perm[jnp.argsort(~mask[perm], stable=True)]
        order = jnp.pad(order, (0, padded - n))

        def step(b: Array, inner: tuple[Any, Any, Array]) -> tuple[Any, Any, Array]:
            p, state, total = inner
            start = b * batch
            idx = jax.lax.dynamic_slice(order, (start,), (batch,))
            w = (start + jnp.arange(batch) < count).astype(jnp.float32)
            loss, grads = grad_fn(p, x[idx], y[idx], w)
            updates, state = optimizer.update(grads, state, p)
            return optax.apply_updates(p, updates), state, total + loss * jnp.sum(w)

        p, state, total = jax.lax.fori_loop(
            0, num_batches, step, (p, state, jnp.zeros((), jnp.float32))
        )
        loss = total / jnp.maximum(count, 1).astype(jnp.float32)
        return p, state, done + 1, loss, losses.at[done].set(loss), k

    def more(carry: tuple[Any, ...]) -> Array:
        _, _, done, loss, _, _ = carry
        return (done < config.epochs) & (loss > config.cutoff_loss)

    init = (
        params,
        opt_state,
        jnp.zeros((), jnp.int32),
        jnp.asarray(jnp.inf, jnp.float32),
        jnp.full((config.epochs,), jnp.nan, jnp.float32),
        key,
    )
    params, opt_state, done, _, losses, _ = jax.lax.while_loop(more, epoch, init)
    return FitResult(params=params, opt_state=opt_state, epochs=done, losses=losses)
