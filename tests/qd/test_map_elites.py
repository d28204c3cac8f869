"""The one QD loop: improves a repertoire, compiles once, and drives outside evaluations via ask/tell."""

from __future__ import annotations

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


@pytest.mark.parametrize("kind", ["grid", "cvt"])
def test_map_elites_improves_qd_score_and_coverage(kind: str) -> None:
    example = jnp.zeros((8,))
    if kind == "grid":
        rep = grid_repertoire(example, (16, 16), TASK.descriptor_low, TASK.descriptor_high)
    else:
        centroids = cvt_centroids(jax.random.PRNGKey(1), 128, 5_000, TASK.descriptor_low, TASK.descriptor_high)
        rep = cvt_repertoire(example, centroids)
    me = _me(rep)
    state = _start(me)
    traces = []

    def run(s):  # type: ignore[no-untyped-def]
        traces.append(1)
        return me.run(s, 25)

    run_jit = jax.jit(run)
    first = None
    for _ in range(4):
        state, metrics = run_jit(state)
        first = metrics if first is None else first
    assert len(traces) == 1
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
