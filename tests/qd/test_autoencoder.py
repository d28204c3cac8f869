"""AURORA's autoencoder: it learns, encodes, normalises, ignores invalid rows, jits, repeats."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.autoencoder import Autoencoder, AutoencoderState, make_autoencoder

STEPS, FEATURES, LATENT = 25, 2, 5
# Learning rates above QDax's 1e-4 so that a few hundred steps show the learning.
RATES = {"lstm": 1e-2, "mlp": 1e-3}


def trajectories(key: jax.Array, n: int) -> jax.Array:
    """(n, STEPS, FEATURES) smooth sequences: sines of random amplitude, frequency and phase per feature."""
    k1, k2, k3 = jax.random.split(key, 3)
    amplitude = jax.random.uniform(k1, (n, 1, FEATURES), minval=0.5, maxval=2.0)
    frequency = jax.random.uniform(k2, (n, 1, FEATURES), minval=0.5, maxval=2.0)
    phase = jax.random.uniform(k3, (n, 1, FEATURES), maxval=2 * np.pi)
    t = jnp.linspace(0.0, 1.0, STEPS)[None, :, None]
    return amplitude * jnp.sin(2 * np.pi * frequency * t + phase)


def autoencoder(kind: str, batch_size: int = 32) -> Autoencoder:
    return make_autoencoder(
        kind, STEPS, FEATURES, LATENT, learning_rate=RATES[kind], batch_size=batch_size
    )


def finite(tree: object) -> bool:
    return all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in jax.tree_util.tree_leaves(tree))


def assert_identical(a: object, b: object) -> None:
    """Two pytrees of the same structure, equal leaf for leaf, bit for bit."""
    assert str(jax.tree_util.tree_structure(a)) == str(jax.tree_util.tree_structure(b))
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("kind", ["lstm", "mlp"])
def test_training_halves_the_reconstruction_loss(kind: str) -> None:
    """50 epochs of 8 steps on 256 sequences: the loss falls under half of the untrained one."""
    ae = autoencoder(kind)
    obs = trajectories(jax.random.PRNGKey(0), 256)
    valid = jnp.ones(256, bool)
    train = jax.jit(ae.train)
    untrained = train(ae.init(jax.random.PRNGKey(1)), obs, valid, jax.random.PRNGKey(2), 0)
    before = float(jnp.mean(ae.reconstruction_loss(untrained, obs)))
    trained = train(untrained, obs, valid, jax.random.PRNGKey(3), 50)
    after = float(jnp.mean(ae.reconstruction_loss(trained, obs)))
    # Sines normalised to unit variance: an untrained network reconstructs about nothing.
    assert 0.7 < before < 1.5
    assert after < 0.5 * before, (kind, before, after)
    # The state's loss is the last epoch's mean over minibatches, close to the full-batch one.
    assert float(trained.loss) == pytest.approx(after, rel=0.3)
    assert int(trained.steps) == 50 * (256 // 32)


def test_state_before_training() -> None:
    state = autoencoder("lstm").init(jax.random.PRNGKey(0))
    assert isinstance(state, AutoencoderState)
    assert np.isnan(float(state.loss)) and int(state.steps) == 0
    np.testing.assert_array_equal(state.mean, np.zeros(FEATURES))
    np.testing.assert_array_equal(state.std, np.ones(FEATURES))


@pytest.mark.parametrize("kind", ["lstm", "mlp"])
def test_encode_shape_and_dependence_on_the_input(kind: str) -> None:
    ae = autoencoder(kind)
    obs = trajectories(jax.random.PRNGKey(0), 64)
    state = jax.jit(ae.train)(
        ae.init(jax.random.PRNGKey(1)), obs, jnp.ones(64, bool), jax.random.PRNGKey(2), 2
    )
    codes = jax.jit(ae.encode)(state, obs[:10])
    assert codes.shape == (10, LATENT) and codes.dtype == jnp.float32
    assert finite(codes)
    # Ten different trajectories, ten different codes, each apart from every other.
    gaps = jnp.linalg.norm(codes[:, None] - codes[None], axis=-1) + jnp.eye(10)
    assert float(jnp.min(gaps)) > 1e-4
    # The code of a sequence does not depend on the others of its batch.
    np.testing.assert_allclose(ae.encode(state, obs[3:4])[0], codes[3], rtol=1e-5, atol=1e-6)
    assert ae.reconstruction_loss(state, obs[:10]).shape == (10,)


def test_normalisation_uses_the_valid_rows_and_leaves_constant_features_unscaled() -> None:
    """mean/std by hand over valid rows and steps; a constant feature gets std 1, not NaN."""
    ae = autoencoder("mlp")
    obs = np.array(trajectories(jax.random.PRNGKey(0), 40))
    obs[:, :, 1] = 0.3  # a feature that never varies
    valid = np.arange(40) % 3 != 0
    state = jax.jit(ae.train)(ae.init(jax.random.PRNGKey(1)), obs, valid, jax.random.PRNGKey(2), 3)
    kept = obs[valid].reshape(-1, FEATURES)
    np.testing.assert_allclose(state.mean, kept.mean(axis=0), rtol=1e-5, atol=1e-6)
    assert float(state.std[0]) == pytest.approx(kept[:, 0].std(), rel=1e-5)
    assert float(state.std[1]) == 1.0
    assert finite(state) and finite(ae.encode(state, jnp.asarray(obs)))
    normalised = ae.normalise(state, jnp.asarray(obs))
    assert float(jnp.max(jnp.abs(normalised[:, :, 1]))) < 1e-6  # centred, not blown up


@pytest.mark.parametrize("filler", [np.nan, 1e6])
def test_invalid_rows_are_ignored(filler: float) -> None:
    """Whatever the invalid rows hold, the trained state is the one with zeros there, bit for bit."""
    ae = autoencoder("lstm")
    obs = np.array(trajectories(jax.random.PRNGKey(0), 96))
    valid = np.arange(96) < 40
    obs[~valid] = 0.0
    train = jax.jit(ae.train)
    state = ae.init(jax.random.PRNGKey(1))
    clean = train(state, obs, valid, jax.random.PRNGKey(2), 4)
    obs[~valid] = filler
    dirty = train(state, obs, valid, jax.random.PRNGKey(2), 4)
    assert finite(dirty) and np.isfinite(float(dirty.loss))
    assert_identical(clean, dirty)


def test_no_valid_row_leaves_the_state_as_it_was() -> None:
    ae = autoencoder("mlp")
    state = ae.init(jax.random.PRNGKey(1))
    obs = jnp.full((64, STEPS, FEATURES), jnp.nan)
    after = jax.jit(ae.train)(state, obs, jnp.zeros(64, bool), jax.random.PRNGKey(2), 5)
    assert_identical(state, after)


def test_fewer_rows_than_a_batch_still_train() -> None:
    """K < batch_size: one step per epoch on all K rows (K // batch_size would be none)."""
    ae = autoencoder("mlp", batch_size=128)
    obs = trajectories(jax.random.PRNGKey(0), 20)
    state = jax.jit(ae.train)(
        ae.init(jax.random.PRNGKey(1)), obs, jnp.ones(20, bool), jax.random.PRNGKey(2), 3
    )
    assert int(state.steps) == 3 and np.isfinite(float(state.loss))


def test_traced_epochs_compile_once_and_the_same_key_repeats_bit_for_bit() -> None:
    ae = autoencoder("lstm")
    obs = trajectories(jax.random.PRNGKey(0), 64)
    valid = jnp.arange(64) < 50
    traces: list[None] = []

    @jax.jit
    def train(state: AutoencoderState, key: jax.Array, epochs: jax.Array) -> AutoencoderState:
        traces.append(None)
        return ae.train(state, obs, valid, key, epochs)

    state = ae.init(jax.random.PRNGKey(1))
    one = train(state, jax.random.PRNGKey(2), jnp.int32(1))
    three = train(state, jax.random.PRNGKey(2), jnp.int32(3))
    again = train(state, jax.random.PRNGKey(2), jnp.int32(3))
    other = train(state, jax.random.PRNGKey(3), jnp.int32(3))
    assert len(traces) == 1
    assert (int(one.steps), int(three.steps)) == (64 // 32, 3 * (64 // 32))
    assert_identical(three, again)
    assert float(other.loss) != float(three.loss)  # another key, other minibatches
    # Training continues from the state handed in: 1 epoch then 2 more is 3 in all.
    more = train(one, jax.random.PRNGKey(4), jnp.int32(2))
    assert int(more.steps) == int(three.steps)


def test_the_autoencoder_is_a_static_hashable_value() -> None:
    ae = autoencoder("lstm")
    assert hash(ae) == hash(autoencoder("lstm")) and ae == autoencoder("lstm")
    codes = jax.jit(lambda a, s, x: a.encode(s, x), static_argnums=0)(
        ae, ae.init(jax.random.PRNGKey(0)), jnp.zeros((3, STEPS, FEATURES))
    )
    assert codes.shape == (3, LATENT)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"kind": "gru"}, "kind"),
        ({"sequence_length": 0}, "sequence_length"),
        ({"observation_size": -1}, "observation_size"),
        ({"latent_size": 2.5}, "latent_size"),
        ({"hidden": (64, 0)}, "hidden"),
        ({"hidden": 64}, "hidden"),
        ({"learning_rate": 0.0}, "learning_rate"),
        ({"learning_rate": float("nan")}, "learning_rate"),
        ({"batch_size": 0}, "batch_size"),
    ],
)
def test_bad_arguments_name_themselves(kwargs: dict[str, object], name: str) -> None:
    args: dict[str, object] = {
        "kind": "mlp",
        "sequence_length": STEPS,
        "observation_size": FEATURES,
        "latent_size": LATENT,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        make_autoencoder(**args)  # type: ignore[arg-type]


def test_bad_shapes_say_what_was_expected() -> None:
    ae = autoencoder("mlp")
    state = ae.init(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match=r"observations: expected shape \(n, 25, 2\)"):
        ae.encode(state, jnp.zeros((4, STEPS, FEATURES + 1)))
    with pytest.raises(ValueError, match=r"observations: expected shape"):
        ae.reconstruction_loss(state, jnp.zeros((STEPS, FEATURES)))
    with pytest.raises(ValueError, match=r"valid: expected shape \(4,\)"):
        ae.train(
            state, jnp.zeros((4, STEPS, FEATURES)), jnp.ones(5, bool), jax.random.PRNGKey(1), 1
        )
