"""MOME's repertoire: fronts stay non-dominated, equal the brute-force fronts, overflow rules, sampling."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.repertoires import grid_repertoire
from qdrl.qd.repertoires.mome import MOMERepertoire, mome_repertoire

BATCH, ROUNDS = 6, 3


def _dominates(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(a >= b) and np.any(a > b))


def _front(points: list[np.ndarray]) -> list[tuple[float, ...]]:
    return sorted(
        tuple(p.tolist()) for p in points if not any(_dominates(q, p) for q in points)
    )


def _empty(front_length: int, overflow: str = "crowding") -> MOMERepertoire:
    cells = grid_repertoire(jnp.zeros(3), (2, 1), 0.0, 1.0)  # two cells: x < 0.5 and x >= 0.5
    return mome_repertoire(cells, jnp.zeros(3), 2, front_length, overflow)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def add() -> object:
    return jax.jit(lambda rep, g, d, f: rep.add(g, d, f))


def _batches() -> st.SearchStrategy[list[tuple[np.ndarray, np.ndarray]]]:
    fit = st.lists(st.integers(0, 5), min_size=2 * BATCH, max_size=2 * BATCH)
    cells = st.lists(st.sampled_from([0.25, 0.75, np.nan]), min_size=BATCH, max_size=BATCH)
    batch = st.tuples(fit, cells).map(
        lambda t: (np.asarray(t[0], np.float32).reshape(BATCH, 2), np.asarray(t[1], np.float32))
    )
    return st.lists(batch, min_size=ROUNDS, max_size=ROUNDS)


@settings(max_examples=40, deadline=None)
@given(batches=_batches())
def test_fronts_equal_brute_force_without_overflow_and_stay_non_dominated_with_it(
    batches: list[tuple[np.ndarray, np.ndarray]], add: object
) -> None:
    big, small = _empty(BATCH * ROUNDS), _empty(3)
    offered: dict[int, list[np.ndarray]] = {0: [], 1: []}
    for fit, x in batches:
        desc = np.stack([x, np.zeros_like(x)], axis=1)
        genotypes = np.concatenate([fit, x[:, None]], axis=1)  # genotype carries its own fitness
        big, result = add(big, genotypes, desc, fit)  # type: ignore[operator]
        small, _ = add(small, genotypes, desc, fit)  # type: ignore[operator]
        for i in range(BATCH):
            if not np.isnan(x[i]):
                offered[int(x[i] > 0.5)].append(fit[i])
        cell = np.asarray(result.cell)
        assert np.all((cell == -1) == np.isnan(x))
    for rep in (big, small):
        f, g = np.asarray(rep.fitnesses), np.asarray(rep.genotypes)
        members = np.all(np.isfinite(f), axis=-1)
        for c in (0, 1):
            front = f[c][members[c]]
            # members fill the first slots, carry their own genotype and dominate nothing
            assert members[c].tolist() == sorted(members[c].tolist(), reverse=True)
            np.testing.assert_array_equal(g[c][members[c]][:, :2], front)
            assert not any(_dominates(a, b) for a in front for b in front)
            expected = _front(offered[c])
            if rep is big:
                assert sorted(tuple(p) for p in front.tolist()) == expected
            else:
                # A bounded front forgets what its overflows dropped: a point dropped early
                # (or a copy of a kept one) can be on the brute-force front at the end, and a
                # later point that only a dropped one dominated can be kept. What always holds:
                # at most 3 members, each one offered to this cell, and both extremes kept (the
                # best of each objective is never dominated and crowding never drops it).
                assert len(front) <= 3
                assert {tuple(p) for p in front.tolist()} <= {tuple(p.tolist()) for p in offered[c]}
                if expected:
                    best = np.array(expected)
                    assert front[:, 0].max() == best[:, 0].max()
                    assert front[:, 1].max() == best[:, 1].max()


def test_index_overflow_keeps_the_members_first_as_qdax_does(add: object) -> None:
    line = np.array(
        [[0.0, 4.0], [1.0, 3.0], [1.25, 2.75], [3.0, 1.0], [4.0, 0.0], [0.0, 0.0]], np.float32
    )
    desc = np.full((BATCH, 2), 0.25, np.float32)
    genotypes = np.concatenate([line, line[:, :1]], axis=1)
    # crowding distances: (1, 3) 0.6, (1.25, 2.75) 1.0, (3, 1) 1.375, the extremes inf
    for overflow, kept in (
        ("index", [[0, 4], [1, 3], [1.25, 2.75]]),
        ("crowding", [[0, 4], [3, 1], [4, 0]]),
    ):
        rep, result = add(_empty(3, overflow), genotypes, desc, line)  # type: ignore[operator]
        f = np.asarray(rep.fitnesses[0])
        assert sorted(f[np.all(np.isfinite(f), -1)].tolist()) == kept, overflow
        assert int(np.sum(result.added)) == 3
        assert bool(result.new_cell[0])


def test_sampling_draws_a_cell_then_a_member_uniformly(add: object) -> None:
    fit = np.array([[1.0, 1.0], [0.0, 3.0], [1.0, 2.0], [3.0, 0.0], [9, 9], [9, 9]], np.float32)
    x = np.array([0.25, 0.75, 0.75, 0.75, np.nan, np.nan], np.float32)  # the last two rejected
    rep, _ = add(_empty(3), np.concatenate([fit, x[:, None]], 1), np.stack([x, x], 1), fit)  # type: ignore[operator]
    samples = np.asarray(jax.jit(rep.sample, static_argnums=1)(jax.random.PRNGKey(0), 60_000))
    cell_0 = samples[:, 2] < 0.5
    assert cell_0.mean() == pytest.approx(0.5, abs=0.01)
    for f in fit[1:4]:
        share = np.mean(np.all(samples[:, :2] == f, axis=1))
        assert share == pytest.approx(1 / 6, abs=0.01)


def test_rejects_bad_shapes_and_arguments() -> None:
    rep = _empty(2)
    with pytest.raises(ValueError, match=r"fitnesses must have shape \(n, 2\)"):
        rep.add(np.zeros((2, 3)), np.zeros((2, 2)), np.zeros((2,)))
    cells = grid_repertoire(jnp.zeros(3), (2, 1), 0.0, 1.0)
    with pytest.raises(ValueError, match="pareto_front_max_length: expected a positive integer, got 0"):
        mome_repertoire(cells, jnp.zeros(3), 2, 0)
    with pytest.raises(ValueError, match="num_objectives: expected at least 2, got 1"):
        mome_repertoire(cells, jnp.zeros(3), 1, 5)
