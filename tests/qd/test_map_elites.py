"""The one QD loop: improves a repertoire, compiles once, and drives outside evaluations via ask/tell."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import cvt_centroids, cvt_repertoire, grid_repertoire
from qdrl.tasks import make_task

TASK = make_task("arm", num_dofs=8)


def _me(repertoire) -> MapElites:  # type: ignore[no-untyped-def]
    emitter = isoline_emitter(64, 0.05, 0.1, TASK.genotype_low, TASK.genotype_high)
    return MapElites(TASK.scoring_fn, emitter, repertoire, qd_offset=TASK.qd_offset)


def _start(me: MapElites, seed: int = 0):  # type: ignore[no-untyped-def]
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    return me.init(TASK.init_genotypes(k1, 64), k2)


class Loop(NamedTuple):
    """A MapElites and its jitted 25-step `run`, with the traces of that run."""

    me: MapElites
    run: Callable[[Any], Any]
    traces: list[int]


def _loop(kind: str) -> Loop:
    example = jnp.zeros((8,))
    if kind == "grid":
        rep = grid_repertoire(example, (16, 16), TASK.descriptor_low, TASK.descriptor_high)
    else:
        centroids = cvt_centroids(jax.random.PRNGKey(1), 128, 5_000, TASK.descriptor_low, TASK.descriptor_high)
        rep = cvt_repertoire(example, centroids)
    me = _me(rep)
    traces: list[int] = []

    def run(s):  # type: ignore[no-untyped-def]
        traces.append(1)
        return me.run(s, 25)

    return Loop(me, jax.jit(run), traces)


@pytest.fixture(scope="module")
def grid_loop() -> Loop:
    """Shared by the tests that run the grid loop, so that it compiles once for the module."""
    return _loop("grid")


# CVT MAP-Elites learns through the same loop (tests/test_qd_run.py runs it end to end): -m slow.
@pytest.mark.parametrize("kind", ["grid", pytest.param("cvt", marks=pytest.mark.slow)])
def test_map_elites_improves_qd_score_and_coverage(kind: str, request: pytest.FixtureRequest) -> None:
    loop = request.getfixturevalue("grid_loop") if kind == "grid" else _loop(kind)
    state = _start(loop.me)
    first = None
    for _ in range(4):
        state, metrics = loop.run(state)
        first = metrics if first is None else first
    assert len(loop.traces) == 1
    assert int(state.iteration) == 100
    assert int(state.evaluations) == 64 + 100 * 64
    qd = np.asarray(metrics["qd_score"])
    assert float(qd[-1]) > 1.5 * float(np.asarray(first["qd_score"])[0])
    assert np.all(np.diff(qd) >= 0)  # adding never loses a better elite
    assert float(metrics["coverage"][-1]) > 0.25


def test_ask_tell_with_a_numpy_objective_matches_step() -> None:
    rep = grid_repertoire(jnp.zeros((8,)), (16, 16), TASK.descriptor_low, TASK.descriptor_high)
    me = _me(rep)

    def numpy_arm(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        angles = np.cumsum(2 * np.pi * np.clip(g, 0, 1) - np.pi, axis=1)
        desc = np.stack([np.cos(angles).sum(1), np.sin(angles).sum(1)], 1) / (2 * g.shape[1]) + 0.5
        return -np.std(np.clip(g, 0, 1), axis=1), desc

    state = _start(me)
    stepped, _ = me.step(state)
    # ask / evaluate in NumPy / tell: the same as one `step` (the step's evaluation
    # key is split off the state's key, exactly as here)
    offspring, asked = me.ask(state)
    key, _ = jax.random.split(asked.key)
    fit, desc = numpy_arm(np.asarray(offspring))
    told, metrics = me.tell_values(asked._replace(key=key), offspring, fit, desc)
    np.testing.assert_allclose(told.repertoire.fitnesses, stepped.repertoire.fitnesses, atol=1e-5)
    assert int(told.evaluations) == int(stepped.evaluations) == 128
    assert float(metrics["num_elites"]) == float(np.sum(np.isfinite(np.asarray(told.repertoire.fitnesses))))


def test_tell_checks_shapes() -> None:
    rep = grid_repertoire(jnp.zeros((8,)), (4, 4), TASK.descriptor_low, TASK.descriptor_high)
    me = _me(rep)
    state = _start(me)
    offspring, state = me.ask(state)
    with pytest.raises(ValueError, match=r"descriptors: expected shape \(64, 2\), got \(64, 3\)"):
        me.tell_values(state, offspring, np.zeros(64), np.zeros((64, 3)))
    with pytest.raises(ValueError, match=r"fitnesses: expected shape \(64,\), got \(63,\)"):
        me.tell_values(state, offspring, np.zeros(63), np.zeros((64, 2)))


def test_an_empty_repertoire_is_an_error_outside_jit_and_stays_empty_under_jit(
    grid_loop: Loop,
) -> None:
    me = grid_loop.me
    key = jax.random.PRNGKey(0)
    genotypes = TASK.init_genotypes(key, 64)
    fitnesses = np.full(64, np.nan, np.float32)
    fitnesses[:3] = [np.inf, -np.inf, 1.0]
    descriptors = np.full((64, 2), 0.5, np.float32)
    descriptors[2] = [np.inf, 0.5]  # the one finite fitness has an infinite descriptor
    with pytest.raises(
        ValueError,
        match=r"init: expected at least one initial evaluation with a finite fitness and a "
        r"finite descriptor, got none of 64 \(63 non-finite fitnesses, 1 non-finite descriptors\)",
    ):
        me.init_values(genotypes, fitnesses, descriptors, key)
    # Under jit nothing can raise: the repertoire is empty, and ask says so outside jit.
    state = jax.jit(me.init_values)(genotypes, fitnesses, descriptors, key)
    assert bool(state.repertoire.is_empty)
    with pytest.raises(ValueError, match="ask: the repertoire is empty"):
        me.ask(state)
    # Jitted steps sample NaN parents, whose offspring are rejected: still empty, and the
    # metrics show it (not a search silently restarted from zero genotypes).
    state, metrics = grid_loop.run(state)
    assert len(grid_loop.traces) == 1
    assert bool(state.repertoire.is_empty) and int(state.evaluations) == 64 + 25 * 64
    np.testing.assert_array_equal(np.asarray(metrics["coverage"]), 0.0)
    np.testing.assert_array_equal(np.asarray(metrics["qd_score"]), 0.0)


def test_scanned_metrics_travel_packed_and_come_back_exact() -> None:
    """`run` packs the scalar metrics of an iteration into one vector: nothing is lost."""
    from qdrl.qd.map_elites import _pack_scalars, _unpack_scalars

    layout: list = []

    def body(carry: None, i: jax.Array):  # type: ignore[no-untyped-def]
        metrics = {
            "count": jnp.int32(2**31 - 1) - i,  # not exact as a float32 value
            "vector": jnp.ones(2) * i,  # not a scalar: stacked apart
            "score": jnp.float32(np.nan) * i,
            "low": jnp.float32(-np.inf) + i,
            "unsigned": jnp.uint32(2**32 - 1) - i.astype(jnp.uint32),
        }
        return carry, _pack_scalars(metrics, layout)

    _, (packed, rest) = jax.jit(lambda: jax.lax.scan(body, None, jnp.arange(3)))()
    assert packed.shape == (3, 4) and packed.dtype == jnp.float32
    out = _unpack_scalars(packed, rest, layout)
    assert list(out) == ["count", "vector", "score", "low", "unsigned"]
    assert out["count"].dtype == jnp.int32 and out["unsigned"].dtype == jnp.uint32
    np.testing.assert_array_equal(np.asarray(out["count"]), [2**31 - 1, 2**31 - 2, 2**31 - 3])
    np.testing.assert_array_equal(np.asarray(out["unsigned"]), [2**32 - 1, 2**32 - 2, 2**32 - 3])
    np.testing.assert_array_equal(np.asarray(out["vector"]), [[0, 0], [1, 1], [2, 2]])
    assert np.all(np.isnan(np.asarray(out["score"])))
    np.testing.assert_array_equal(np.asarray(out["low"]), -np.inf)


def test_run_gives_the_same_metrics_whether_they_travel_packed_or_apart(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On a CPU `run` stacks each metric apart; traced for an accelerator it packs them
    into one vector per iteration. Both give the same names, dtypes and values."""
    import qdrl.qd.map_elites as map_elites

    rep = grid_repertoire(jnp.zeros((8,)), (8, 8), TASK.descriptor_low, TASK.descriptor_high)
    me = _me(rep)
    state = _start(me)
    _, apart = jax.jit(lambda s: me.run(s, 3))(state)
    monkeypatch.setattr(map_elites.jax, "default_backend", lambda: "gpu")
    _, packed = jax.jit(lambda s: me.run(s, 3))(state)
    assert list(apart) == list(packed) and "num_elites" in apart and "added" in apart
    for name in apart:
        assert apart[name].dtype == packed[name].dtype and apart[name].shape == (3,), name
        np.testing.assert_array_equal(np.asarray(apart[name]), np.asarray(packed[name]), err_msg=name)
