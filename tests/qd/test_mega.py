"""Differentiable QD: OMG-MEGA, CMA-MEGA (gradient ascent, Adam), CMA-MAEGA on the LP sphere."""

from __future__ import annotations

import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.qd.dqd import jacobian
from qdrl.qd.emitters.mega import (
    CMAMegaConfig,
    CMAMegaEmitter,
    OMGMegaConfig,
    OMGMegaEmitter,
    normalise_rows,
)
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire
from qdrl.tasks import make_task

N = 8
TASK = make_task("lp_sphere", num_dims=N)
SCORE = TASK.gradient_scoring_fn
assert SCORE is not None


def _grid(alpha: float | None = None):  # type: ignore[no-untyped-def]
    rep = grid_repertoire(TASK.example_genotype(), (16, 16), TASK.descriptor_low, TASK.descriptor_high)
    return rep if alpha is None else rep.with_learning_rate(alpha, threshold_min=0.0)


def _run(emitter, rep, init, iterations: int = 30):  # type: ignore[no-untyped-def]
    me = MapElites(SCORE, emitter, rep, qd_offset=TASK.qd_offset)
    state = me.init(init, jax.random.PRNGKey(0))
    return jax.jit(lambda s: me.run(s, iterations))(state)


def test_omg_mega_steps_elites_along_their_stored_gradients() -> None:
    em = OMGMegaEmitter(OMGMegaConfig(batch_size=16, sigma_g=1.0))
    init = jax.random.normal(jax.random.PRNGKey(5), (6, N))
    rep = _grid()
    ev = SCORE(init, None)
    rep, added = rep.add(init, ev.descriptors, ev.fitnesses)
    store = em.init(jax.random.PRNGKey(0), rep, ev, init)
    # each elite's row holds its own Jacobian; the other cells are zeros
    jac = np.asarray(jacobian(ev.extras))
    for i in np.flatnonzero(np.asarray(added.added)):
        np.testing.assert_allclose(np.asarray(store[int(added.cell[i])]), jac[i], rtol=1e-6)
    assert int(np.sum(np.any(np.asarray(store) != 0, axis=(1, 2)))) == int(rep.num_filled)
    # an offspring minus its parent lies in the span of the parent's normalised gradients
    offspring = np.asarray(em.emit(store, rep, jax.random.PRNGKey(1)))
    parents = np.asarray(init)
    for child in offspring[:4]:
        residuals = []
        for p, j in zip(parents, np.asarray(normalise_rows(jnp.asarray(jac))), strict=True):
            coeffs, *_ = np.linalg.lstsq(j.T, child - p, rcond=None)
            residuals.append((np.linalg.norm(j.T @ coeffs - (child - p)), coeffs[0]))
        best = min(residuals, key=lambda r: r[0])
        assert best[0] < 1e-4 and best[1] >= 0.0  # the objective's coefficient is |c_0|


def test_omg_mega_improves_the_qd_score() -> None:
    em = OMGMegaEmitter(OMGMegaConfig(batch_size=32, sigma_g=2.0))
    _, metrics = _run(em, _grid(), jax.random.normal(jax.random.PRNGKey(2), (8, N)))
    qd = np.asarray(metrics["qd_score"])
    assert qd[-1] > 3 * qd[0] and np.all(np.diff(np.asarray(metrics["coverage"])) >= 0)


@pytest.mark.parametrize(
    ("optimizer", "lr", "ranker", "restart", "alpha"),
    [
        # CMA-MEGA and its Adam variant learn through the same step: -m slow
        pytest.param("gradient_ascent", 1.0, "2imp", "no_improvement", None, marks=pytest.mark.slow),
        pytest.param("adam", 0.01, "2imp", "no_improvement", None, marks=pytest.mark.slow),
        ("gradient_ascent", 1.0, "imp", "basic", 0.01),  # CMA-MAEGA
    ],
)
def test_cma_mega_variants_improve_the_qd_score(
    optimizer: str, lr: float, ranker: str, restart: str, alpha: float | None
) -> None:
    config = CMAMegaConfig(
        num_instances=3, batch_size=7, sigma0=2.0, learning_rate=lr, optimizer=optimizer,
        ranker=ranker, restart_rule=restart,
    )
    em = CMAMegaEmitter(config, SCORE, N)
    state, metrics = _run(em, _grid(alpha), jnp.zeros((1, N)))
    qd = np.asarray(metrics["qd_score"])
    assert qd[-1] > 5 * qd[0] and np.all(np.diff(np.asarray(metrics["coverage"])) >= 0)
    assert int(state.evaluations) == 1 + 30 * 3 * 8  # lambda offspring + theta per instance
    es = state.emitter_state
    # theta moved away from x0 and its stored gradients are those of the task at theta
    assert float(jnp.max(jnp.abs(es.theta))) > 0.1
    expected = normalise_rows(jacobian(SCORE(es.theta, None).extras))
    np.testing.assert_allclose(np.asarray(es.jacobian), np.asarray(expected), rtol=1e-4, atol=1e-6)


def test_mega_rejects_bad_options_and_tasks_without_gradients() -> None:
    for kw, message in (
        ({"optimizer": "sgd"}, "emitter.optimizer: expected one of 'gradient_ascent', 'adam', got 'sgd'"),
        ({"learning_rate": 0.0}, "emitter.learning_rate: expected a number > 0, got 0.0"),
        ({"sigma0": -1.0}, "emitter.sigma0: expected a number > 0, got -1.0"),
        ({"ranker": "nope"}, "emitter.ranker: expected one of"),
    ):
        with pytest.raises(ValueError, match=re.escape(message)):
            CMAMegaConfig(**kw).check()  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=re.escape("emitter.sigma_g: expected a number > 0, got nan")):
        OMGMegaConfig(sigma_g=math.nan).check()
    with pytest.raises(ValueError, match="evaluate with the task's gradient_scoring_fn"):
        jacobian(TASK.scoring_fn(jnp.zeros((1, N)), None).extras)
