"""The autoencoder of AURORA: a learned descriptor from each policy's sequence of observations.

Cully 2019, "Autonomous skill discovery with Quality-Diversity and Unsupervised
Descriptors" (GECCO); Grillotti & Cully 2022, "Unsupervised Behaviour Discovery With
Quality-Diversity Optimisation" (IEEE TEVC). A policy's descriptor is the latent code of
an autoencoder trained to reconstruct the M observations of size O that the policy
visited; the archive that calls `Autoencoder.train` and `Autoencoder.encode` is AURORA's.

Two architectures:
- "lstm", the sequence-to-sequence LSTM autoencoder of QDax's AURORA: an encoder LSTM of
  L units reads the normalised sequence and its final hidden state is the latent; a
  decoder LSTM starts from the encoder's final state, is fed the sequence shifted right by
  one step behind a start token (teacher forcing), and a linear layer maps each of its
  outputs to an observation. The decoder carries its own state from step to step; QDax's
  hands every step the encoder's final state again, discarding the cell's update.
- "mlp": the flattened sequence (M*O) -> ReLU MLP -> linear L latent -> the mirrored MLP
  -> M*O.

Both minimise the mean squared error of the reconstruction in the normalised scale, with
Adam. Training is one `lax.fori_loop` over epochs (the count may be traced) of a
`lax.scan` over minibatches, in fixed shapes, so it runs inside a jitted QD loop.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any, Literal, NamedTuple, cast

import haiku as hk
import jax
import jax.numpy as jnp
import optax

from qdrl.types import Array, Params, PRNGKey

__all__ = ["START_TOKEN", "Autoencoder", "AutoencoderState", "make_autoencoder"]

Kind = Literal["lstm", "mlp"]
KINDS: tuple[Kind, ...] = ("lstm", "mlp")

# The decoder's input before the first observation, in the normalised scale. 0 is the
# data's mean, so the first step's gates stay in their working range; QDax's -1000
# saturates them and sends the first step's gradient through a huge input weight.
START_TOKEN = 0.0


class AutoencoderState(NamedTuple):
    """The trained autoencoder: a pytree carried by the archive.

    Attributes:
      params: haiku parameters of the encoder and the decoder.
      opt_state: Adam's state, carried from one `train` to the next.
      mean: (O,) float32 per-feature mean of the last training's valid observations.
      std: (O,) float32 their standard deviation; 1 where a feature does not vary, so
        that it passes unscaled.
      loss: () float32 mean normalised reconstruction MSE over the last epoch's
        minibatches of the last training (NaN before any training).
      steps: () int32 gradient steps done so far.
    """

    params: Params
    opt_state: Any
    mean: Array
    std: Array
    loss: Array
    steps: Array


@dataclasses.dataclass(frozen=True)
class Autoencoder:
    """An autoencoder of sequences (M, O) to latents (L,): static configuration, hashable.

    Attributes:
      kind: "lstm" (sequence-to-sequence LSTM) or "mlp" (on the flattened sequence).
      sequence_length: M, observations per sequence.
      observation_size: O, features per observation.
      latent_size: L, the descriptor's size (the LSTM's units; 5 in Grillotti & Cully).
      hidden: the MLP encoder's hidden layers, mirrored in its decoder; unused by "lstm".
      learning_rate: Adam's step size (1e-4, QDax's `lstm_ae_train`).
      batch_size: sequences per minibatch (128, QDax's AURORA).
    """

    kind: Kind
    sequence_length: int
    observation_size: int
    latent_size: int
    hidden: tuple[int, ...] = (64, 64)
    learning_rate: float = 1e-4
    batch_size: int = 128

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: expected one of {KINDS}, got {self.kind!r}")
        for name in ("sequence_length", "observation_size", "latent_size", "batch_size"):
            value = getattr(self, name)
            if not _is_int(value) or value <= 0:
                raise ValueError(f"{name}: expected a positive integer, got {value!r}")
        if not isinstance(self.hidden, tuple) or not all(_is_int(h) and h > 0 for h in self.hidden):
            raise ValueError(f"hidden: expected a tuple of positive integers, got {self.hidden!r}")
        rate = self.learning_rate
        if (
            isinstance(rate, bool)
            or not isinstance(rate, (int, float))
            or not (math.isfinite(rate) and rate > 0)
        ):
            raise ValueError(f"learning_rate: expected a finite number > 0, got {rate!r}")

    @property
    def networks(self) -> hk.MultiTransformed:
        """haiku's `(init, apply)` with `apply = (encode, reconstruct)`, both (n, M, O) in.

        `encode` gives (n, L) latents, `reconstruct` (n, M, O) reconstructions, both of
        normalised sequences. Rebuilt on each access, which costs nothing at run time.
        """
        return _networks(self)

    @property
    def optimizer(self) -> optax.GradientTransformation:
        """optax's Adam at `learning_rate`."""
        return optax.adam(self.learning_rate)

    def init(self, key: PRNGKey) -> AutoencoderState:
        """Fresh parameters and Adam state; identity normalisation, NaN loss, no steps."""
        dummy = jnp.zeros((1, self.sequence_length, self.observation_size), jnp.float32)
        params = self.networks.init(key, dummy)
        size = self.observation_size
        return AutoencoderState(
            params=params,
            opt_state=self.optimizer.init(params),
            mean=jnp.zeros((size,), jnp.float32),
            std=jnp.ones((size,), jnp.float32),
            loss=jnp.asarray(jnp.nan, jnp.float32),
            steps=jnp.zeros((), jnp.int32),
        )

    def normalise(self, state: AutoencoderState, observations: Array) -> Array:
        """(n, M, O) observations -> (n, M, O) float32 (x - mean) / std with `state`'s statistics."""
        x = self._sequences(observations)
        return (x - state.mean) / state.std

    def encode(self, state: AutoencoderState, observations: Array) -> Array:
        """(n, M, O) observations -> (n, L) float32 latents: the learned descriptors."""
        encode, _ = self.networks.apply
        return encode(state.params, self.normalise(state, observations))

    def reconstruction_loss(self, state: AutoencoderState, observations: Array) -> Array:
        """(n, M, O) observations -> (n,) float32 mean squared error of each reconstruction.

        The error is taken in the normalised scale, averaged over the M steps and O features.
        """
        return _sequence_losses(self.networks, state.params, self.normalise(state, observations))

    def train(
        self,
        state: AutoencoderState,
        observations: Array,
        valid: Array,
        key: PRNGKey,
        num_epochs: int | Array,
    ) -> AutoencoderState:
        """Recomputes the normalisation on the valid rows, then trains `num_epochs` epochs; jittable.

        The mean and standard deviation are taken per feature over the valid rows and
        their M steps. An epoch is max(1, K // batch_size) Adam steps on minibatches of
        min(batch_size, K) sequences: a uniformly random order of the valid rows, repeated
        as often as needed to fill them, so each valid row is seen equally often, give or
        take one, however few they are. Rows where `valid` is False never enter a statistic or a
        step, and may hold anything (NaN included). With no valid row, `state` comes back
        unchanged; with `num_epochs` 0, only the normalisation changes.

        Args:
          state: the autoencoder to train on from (parameters and Adam state carry on).
          observations: (K, M, O) the stored sequences.
          valid: (K,) bool, the rows that hold a sequence.
          key: the shuffles' key (split once per epoch).
          num_epochs: epochs to run; a Python int or a traced () int32.

        Returns:
          The new state; its `loss` is the mean minibatch loss of the last epoch.
        """
        x = self._sequences(observations)
        rows = x.shape[0]
        valid = jnp.asarray(valid)
        if valid.shape != (rows,):
            raise ValueError(f"valid: expected shape ({rows},), got {valid.shape}")
        valid = valid.astype(bool)
        count = jnp.sum(valid, dtype=jnp.int32)
        # Invalid rows are zeroed: a NaN there would reach the statistics through 0 * NaN.
        x = jnp.where(valid[:, None, None], x, 0.0)
        mean, std = _statistics(x, valid, count)
        x = (x - mean) / std

        batch = min(self.batch_size, rows)
        steps_per_epoch = max(1, rows // self.batch_size)
        networks, optimizer = self.networks, self.optimizer
        grad_fn = jax.value_and_grad(lambda p, xb: jnp.mean(_sequence_losses(networks, p, xb)))

        def step(carry: tuple[Params, Any], idx: Array) -> tuple[tuple[Params, Any], Array]:
            params, opt_state = carry
            loss, grads = grad_fn(params, x[idx])
            updates, opt_state = optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), loss

        def epoch(_: Array, carry: tuple[Any, ...]) -> tuple[Any, ...]:
            params, opt_state, k, _ = carry
            k, sub = jax.random.split(k)
            perm = jax.random.permutation(sub, rows)
            # The valid rows first, in a uniformly random order, then cycled over the epoch.
            order = perm[jnp.argsort(~valid[perm], stable=True)]
            draws = jnp.arange(steps_per_epoch * batch) % jnp.maximum(count, 1)
            idx = order[draws].reshape(steps_per_epoch, batch)
            (params, opt_state), losses = jax.lax.scan(step, (params, opt_state), idx)
            return params, opt_state, k, jnp.mean(losses)

        def run(s: AutoencoderState) -> AutoencoderState:
            epochs = jnp.asarray(num_epochs, jnp.int32)
            params, opt_state, _, loss = jax.lax.fori_loop(
                0, epochs, epoch, (s.params, s.opt_state, key, s.loss)
            )
            return AutoencoderState(
                params=params,
                opt_state=opt_state,
                mean=mean,
                std=std,
                loss=loss,
                steps=s.steps + epochs * steps_per_epoch,
            )

        return jax.lax.cond(count > 0, run, lambda s: s, state)

    def _sequences(self, observations: Array) -> Array:
        """`observations` as float32 (n, M, O), or a ValueError that says the expected shape."""
        x = jnp.asarray(observations, jnp.float32)
        expected = (self.sequence_length, self.observation_size)
        if x.ndim != 3 or x.shape[1:] != expected:
            raise ValueError(
                f"observations: expected shape (n, {expected[0]}, {expected[1]}) "
                f"(sequences, sequence_length, observation_size), got {x.shape}"
            )
        return x


def make_autoencoder(
    kind: str,
    sequence_length: int,
    observation_size: int,
    latent_size: int,
    hidden: Sequence[int] = (64, 64),
    learning_rate: float = 1e-4,
    batch_size: int = 128,
) -> Autoencoder:
    """An `Autoencoder`, its values checked (ValueError naming the argument); `hidden` as a tuple."""
    if isinstance(hidden, (str, bytes)) or not isinstance(hidden, Sequence):
        raise ValueError(f"hidden: expected a sequence of positive integers, got {hidden!r}")
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    return Autoencoder(
        kind=cast(Kind, kind),
        sequence_length=sequence_length,
        observation_size=observation_size,
        latent_size=latent_size,
        hidden=tuple(hidden),
        learning_rate=learning_rate,
        batch_size=batch_size,
    )


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _statistics(x: Array, valid: Array, count: Array) -> tuple[Array, Array]:
    """Per-feature mean and std (O,) of the valid rows of x (K, M, O), whose invalid rows are 0."""
    n = jnp.maximum(count * x.shape[1], 1).astype(jnp.float32)
    mean = jnp.sum(x, axis=(0, 1)) / n
    centred = jnp.where(valid[:, None, None], x - mean, 0.0)
    std = jnp.sqrt(jnp.sum(centred * centred, axis=(0, 1)) / n)
    # A constant feature leaves a rounding residue, not zero, in std: a spread under a
    # millionth of the feature's scale counts as none, lest the residue be blown up to 1.
    spread = std > 1e-6 * jnp.maximum(1.0, jnp.abs(mean))
    return mean, jnp.where(spread, std, 1.0)


def _sequence_losses(networks: hk.MultiTransformed, params: Params, x: Array) -> Array:
    """(n,) mean squared error of the reconstruction of each normalised sequence x (n, M, O)."""
    _, reconstruct = networks.apply
    err = reconstruct(params, x) - x
    return jnp.mean(err * err, axis=(1, 2))


def _networks(ae: Autoencoder) -> hk.MultiTransformed:
    """The haiku pair (encode, reconstruct) of `ae`'s kind, sharing one set of parameters."""
    steps, size, latent = ae.sequence_length, ae.observation_size, ae.latent_size

    def lstm() -> tuple[Callable[[Array], Array], Callable[[Array], Array]]:
        encoder = hk.LSTM(latent, name="encoder")
        decoder = hk.LSTM(latent, name="decoder")
        readout = hk.Linear(size, name="readout")

        def final_state(x: Array) -> hk.LSTMState:
            initial = encoder.initial_state(x.shape[0])
            _, state = hk.dynamic_unroll(encoder, x, initial, time_major=False)
            return state

        def encode(x: Array) -> Array:
            return final_state(x).hidden

        def reconstruct(x: Array) -> Array:
            # Teacher forcing: step t is fed observation t-1 and predicts observation t.
            start = jnp.full_like(x[:, :1], START_TOKEN)
            shifted = jnp.concatenate([start, x[:, :-1]], axis=1)
            outputs, _ = hk.dynamic_unroll(decoder, shifted, final_state(x), time_major=False)
            return readout(outputs)

        return encode, reconstruct

    def mlp() -> tuple[Callable[[Array], Array], Callable[[Array], Array]]:
        encoder = hk.nets.MLP([*ae.hidden, latent], activation=jax.nn.relu, name="encoder")
        decoder = hk.nets.MLP(
            [*reversed(ae.hidden), steps * size], activation=jax.nn.relu, name="decoder"
        )

        def encode(x: Array) -> Array:
            return encoder(x.reshape(x.shape[0], steps * size))

        def reconstruct(x: Array) -> Array:
            return decoder(encode(x)).reshape(x.shape[0], steps, size)

        return encode, reconstruct

    def pair() -> tuple[Callable[[Array], Array], tuple[Callable[[Array], Array], ...]]:
        encode, reconstruct = lstm() if ae.kind == "lstm" else mlp()
        return reconstruct, (encode, reconstruct)

    return hk.without_apply_rng(hk.multi_transform(pair))
