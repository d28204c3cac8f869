"""Mistakes of a first MAP-Elites script get a message saying what was expected, where it is made."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

from qdrl.qd.base import Evaluation
from qdrl.qd.emitters import isoline_emitter
from qdrl.qd.map_elites import MapElites, QDState
from qdrl.qd.repertoires import grid_repertoire

REPERTOIRE = grid_repertoire(jnp.zeros(4), grid_shape=(4, 4), low=0.0, high=1.0)
EMITTER = isoline_emitter(8, 0.05, 0.1, 0.0, 1.0)


def good_score(x: jax.Array, key: jax.Array) -> Evaluation:
    return Evaluation(-jnp.sum(x**2, axis=1), x[:, :2], {}, jnp.int32(0))


def qdax_score(x: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array, dict]:
    return -jnp.sum(x**2, axis=1), x[:, :2], {}


def test_a_scoring_function_returning_a_tuple_is_named_at_init() -> None:
    me = MapElites(qdax_score, EMITTER, REPERTOIRE)
    with pytest.raises(TypeError, match=r"scoring_fn returned: expected qdrl.qd.base.Evaluation\(fitnesses") as e:
        jax.jit(me.init)(jnp.zeros((8, 4)), jax.random.PRNGKey(0))
    assert "got a tuple of 3 (a QDax scoring function returns (fitnesses, descriptors, extras)" in str(e.value)
    with pytest.raises(TypeError, match="got dict"):
        MapElites(lambda x, k: {"f": x}, EMITTER, REPERTOIRE).init(jnp.zeros((8, 4)), jax.random.PRNGKey(0))


ME = MapElites(good_score, EMITTER, REPERTOIRE)


@pytest.fixture(scope="module")
def state() -> QDState:
    return jax.jit(ME.init)(jnp.zeros((8, 4)), jax.random.PRNGKey(0))


def test_tell_and_the_constructor_check_what_they_are_given(state: QDState) -> None:
    with pytest.raises(TypeError, match=r"tell: evaluation: expected qdrl.qd.base.Evaluation"):
        ME.tell(state, jnp.zeros((8, 4)), (jnp.zeros(8), jnp.zeros((8, 2))))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"scoring_fn: expected a function \(genotypes, key\) -> Evaluation"):
        MapElites("score", EMITTER, REPERTOIRE)  # type: ignore[arg-type]


def test_run_jitted_without_its_static_length_says_how_to_jit_it(state: QDState) -> None:
    with pytest.raises(TypeError, match=r"num_steps: expected a Python int .*jax.jit\(me.run, static_argnums=1\)"):
        jax.jit(ME.run)(state, 3)
    after, metrics = jax.jit(ME.run, static_argnums=1)(state, 3)
    assert int(after.iteration) == 3 and metrics["qd_score"].shape == (3,)
