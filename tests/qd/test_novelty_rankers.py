"""Rankers `nov`, `nslc` and `density`: hand-computed orders, NSLC against a NumPy NSGA-II, CMA use.

The NSLC reference lists each front as NSGA-II's fast non-dominated sort finds it
and breaks equal crowding distances by that listing, as pyribs' NSLCRanker; the
drawn novelty and local-competition values are 0, 1 or 2, so every crowding
distance is a sum of halves (exact in float32) and ties are real ties.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.base import Evaluation
from qdrl.qd.cma_es import CMAES
from qdrl.qd.emitters.cma import CMAEmitter, CMAEmitterConfig
from qdrl.qd.emitters.rankers import (
    INFO_FIELDS,
    RANKERS,
    Outcome,
    check_ranker,
    outcome,
    rank,
    uses_direction,
)
from qdrl.qd.repertoires.proximity import proximity_archive

SETTINGS = settings(max_examples=40, deadline=None, database=None, derandomize=True)
NO_DIRECTION = jnp.zeros(2)
_rank = jax.jit(rank, static_argnums=0)


def _outcome(**info: list[float]) -> Outcome:
    b = len(next(iter(info.values())))
    return Outcome(
        fitnesses=jnp.zeros(b),
        descriptors=jnp.zeros((b, 2)),
        status=jnp.zeros(b, jnp.int32),
        value=jnp.zeros(b),
        info={name: jnp.asarray(v, jnp.float32) for name, v in info.items()},
    )


def test_novelty_ranker_highest_first_nan_last() -> None:
    order, values = _rank("nov", _outcome(novelty=[0.5, 2.0, math.nan, 1.0, 2.0]), NO_DIRECTION)
    np.testing.assert_array_equal(np.asarray(order), [1, 4, 3, 0, 2])  # ties in batch order
    np.testing.assert_array_equal(np.asarray(values), [2.0, 2.0, 1.0, 0.5, -np.inf])


def test_density_ranker_lowest_first_nan_last() -> None:
    order, values = _rank("density", _outcome(density=[0.3, 0.1, math.nan, 0.1, 0.5]), NO_DIRECTION)
    np.testing.assert_array_equal(np.asarray(order), [1, 3, 0, 4, 2])
    np.testing.assert_allclose(np.asarray(values), [0.1, 0.1, 0.3, 0.5, np.inf])


def test_nslc_fronts_then_crowding_by_hand() -> None:
    # (novelty, local competition): front 0 = {1: (1, 2), 3: (2, 1), 4: (3, 0)}, front 1 =
    # {0: (1, 1)}, front 2 = {2: (0, 0)}, 5 rejected. In front 0, 1 and 4 are the extremes
    # (+inf); 3 gets (3 - 1) / 2 + (2 - 0) / 2 = 2.
    out = _outcome(novelty=[1, 1, 0, 2, 3, -math.inf], local_competition=[1, 2, 0, 1, 0, 0])
    order, values = _rank("nslc", out, NO_DIRECTION)
    np.testing.assert_array_equal(np.asarray(order), [1, 4, 3, 0, 2, 5])
    np.testing.assert_array_equal(
        np.asarray(values), [[1, 2], [3, 0], [2, 1], [1, 1], [0, 0], [-np.inf, 0]]
    )


def test_nslc_breaks_ties_in_the_order_the_fast_sort_finds_a_front() -> None:
    # Front 0 = [1: (4, 0), 3: (0, 4)]. Front 1 holds 0: (0, 3), dominated by 3 only, and
    # 4: (3, 0), dominated by 1 only: the sort reaches 4 first (its dominator comes
    # first), and both are extremes (+inf), so 4 ranks before 0.
    out = _outcome(novelty=[0, 4, 0, 0, 3], local_competition=[3, 0, 0, 4, 0])
    order, _ = _rank("nslc", out, NO_DIRECTION)
    np.testing.assert_array_equal(np.asarray(order), [1, 3, 4, 0, 2])


def _reference_nslc(novelty: np.ndarray, local: np.ndarray) -> list[int]:
    """NSGA-II's fast non-dominated sort and crowding distance on (novelty, local competition)."""
    valid = [i for i in range(len(novelty)) if np.isfinite(novelty[i])]
    pts = {i: (float(novelty[i]), float(local[i])) for i in valid}

    def dominates(a: int, b: int) -> bool:
        return all(x >= y for x, y in zip(pts[a], pts[b], strict=True)) and pts[a] != pts[b]

    count = {i: sum(dominates(j, i) for j in valid) for i in valid}
    fronts = [[i for i in valid if count[i] == 0]]
    while fronts[-1]:
        found = []
        for i in fronts[-1]:
            for j in valid:
                if dominates(i, j):
                    count[j] -= 1
                    if count[j] == 0:
                        found.append(j)
        fronts.append(found)
    order: list[int] = []
    for front in fronts[:-1]:
        crowd = np.zeros(len(front))
        for m in range(2):
            cost = np.array([-pts[i][m] for i in front])
            s = np.argsort(cost, kind="stable")
            crowd[s[0]] = crowd[s[-1]] = np.inf
            span = cost[s[-1]] - cost[s[0]]
            for t in range(1, len(front) - 1):
                if span > 0:
                    crowd[s[t]] += (cost[s[t + 1]] - cost[s[t - 1]]) / span
        order += [front[t] for t in np.argsort(-crowd, kind="stable")]
    return order + [i for i in range(len(novelty)) if i not in pts]


_nslc_jit = jax.jit(lambda out: rank("nslc", out, NO_DIRECTION))


@SETTINGS
@given(
    st.lists(
        st.tuples(st.sampled_from([0.0, 1.0, 2.0, -math.inf]), st.sampled_from([0.0, 1.0, 2.0])),
        min_size=8,
        max_size=8,
    )
)
def test_nslc_matches_a_numpy_nsga2(rows: list[tuple[float, float]]) -> None:
    novelty = np.array([r[0] for r in rows])
    local = np.array([r[1] for r in rows])
    order, values = _nslc_jit(_outcome(novelty=novelty.tolist(), local_competition=local.tolist()))
    want = _reference_nslc(novelty, local)
    np.testing.assert_array_equal(np.asarray(order), want)
    np.testing.assert_array_equal(np.asarray(values), np.stack([novelty, local], axis=-1)[want])


def test_rankers_that_need_archive_fields_say_which() -> None:
    plain = Outcome(jnp.zeros(3), jnp.zeros((3, 2)), jnp.zeros(3, jnp.int32), jnp.zeros(3))
    for name, fields in INFO_FIELDS.items():
        with pytest.raises(ValueError, match=rf"ranker '{name}': needs info\['{fields[0]}'\]"):
            rank(name, plain, NO_DIRECTION)
    with pytest.raises(ValueError, match=r"needs info\['local_competition'\]"):
        _rank("nslc", _outcome(novelty=[1.0, 2.0]), NO_DIRECTION)


def test_the_new_rankers_are_registered_and_need_no_direction() -> None:
    for name in ("nov", "nslc", "density"):
        check_ranker(name)
        assert name in RANKERS and not uses_direction(name)
    assert CMAEmitterConfig(ranker="nslc").ranker == "nslc"
    with pytest.raises(ValueError, match=r"expected one of .*nslc"):
        check_ranker("novelty")


def test_rank_under_vmap_and_jit_as_the_cma_emitter_calls_it() -> None:
    rng = np.random.default_rng(0)
    novelty = rng.integers(0, 3, size=(3, 6)).astype(np.float32)
    local = rng.integers(0, 3, size=(3, 6)).astype(np.float32)
    batched = Outcome(
        jnp.zeros((3, 6)), jnp.zeros((3, 6, 2)), jnp.zeros((3, 6), jnp.int32), jnp.zeros((3, 6)),
        {"novelty": jnp.asarray(novelty), "local_competition": jnp.asarray(local)},
    )
    for name in ("nov", "nslc"):
        orders, values = jax.jit(jax.vmap(lambda o, name=name: rank(name, o, NO_DIRECTION)))(batched)
        for i in range(3):
            one = jax.tree.map(lambda x, i=i: x[i], batched)
            o, v = _rank(name, one, NO_DIRECTION)
            np.testing.assert_array_equal(np.asarray(orders[i]), np.asarray(o))
            np.testing.assert_array_equal(np.asarray(values[i]), np.asarray(v))


def test_cma_stop_reads_two_objective_values_as_a_flat_ranking() -> None:
    es = CMAES(3, 4, 0.5)
    state = es.init(jnp.zeros(3))
    _, same = _rank("nslc", _outcome(novelty=[1.0] * 4, local_competition=[2.0] * 4), NO_DIRECTION)
    _, spread = _rank("nslc", _outcome(novelty=[1.0, 2.0, 0.0, 1.0], local_competition=[2.0] * 4), NO_DIRECTION)
    assert same.shape == (4, 2)
    assert bool(es.stop(state, same)) and not bool(es.stop(state, spread))
    _, density = _rank("density", _outcome(density=[0.1, 0.2, 0.3, 0.4]), NO_DIRECTION)
    assert not bool(es.stop(state, density))


def test_a_cma_emitter_ranks_by_nslc_on_a_proximity_archive() -> None:
    config = CMAEmitterConfig(ranker="nslc", num_instances=2, batch_size=4, sigma0=0.3)
    emitter = CMAEmitter(config, jnp.zeros(3))
    archive = proximity_archive(jnp.zeros(3), 32, 2, 3, 0.05, local_competition=True)

    def evaluate(x: jax.Array) -> Evaluation:
        return Evaluation(-jnp.sum(x**2, axis=-1), x[:, :2], {}, jnp.zeros((), jnp.int32))

    x0 = jax.random.normal(jax.random.key(0), (4, 3))
    archive, _ = archive.add(x0, x0[:, :2], evaluate(x0).fitnesses)
    state = emitter.init(jax.random.key(1), archive, evaluate(x0), x0)

    @jax.jit
    def step(state, archive, key):  # type: ignore[no-untyped-def]
        offspring = emitter.emit(state, archive, key)
        ev = evaluate(offspring)
        archive, added = archive.add(offspring, ev.descriptors, ev.fitnesses)
        out = outcome(archive, ev.fitnesses, ev.descriptors, added)
        return emitter.update(state, archive, offspring, ev, added, key), archive, out

    for i in range(3):
        state, archive, out = step(state, archive, jax.random.key(2 + i))
    assert out.info is not None and set(out.info) == {"novelty", "local_competition"}
    assert int(archive.num_filled) > 4
    assert (np.asarray(state.es.generation) + np.asarray(state.restarts) >= 1).all()
