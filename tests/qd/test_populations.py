"""NSGA-II and SPEA2 survival against NumPy references written from the papers; tournaments."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pareto_reference import crowding as _crowding
from pareto_reference import dominates as _dominates
from pareto_reference import pruned as _pruned
from pareto_reference import ranks as _ranks

from qdrl.qd.populations import ParetoPopulation, pareto_population, tournament_pool

SIZE, BATCH = 6, 6


def _nsga2_survivors(f: np.ndarray, pruning: bool = False) -> list[int]:
    """Deb et al. 2002: whole fronts, the last cut by crowding (stable: lower index first);
    copies of an earlier member's objectives after the distinct members of their front.
    With `pruning`, the distinct members of the front that does not fit whole are thinned
    to the room left one at a time (Kukkonen & Deb 2006), the removed ones last."""
    mask = np.ones(len(f), bool)
    ranks = _ranks(f, mask)
    crowd = _crowding(f, mask, ranks)
    clone = np.array([any(np.array_equal(f[i], f[j]) for j in range(i)) for i in range(len(f))])
    if pruning:
        counts = np.array([np.sum(ranks == r) for r in range(len(f) + 1)])
        before = np.cumsum(counts) - counts
        over = np.flatnonzero(before + counts > SIZE)
        if len(over):
            split = over[0]
            front = (ranks == split) & ~clone
            kept, dist = _pruned(f, front, SIZE - before[split])
            crowd = np.where(front, np.where(kept, dist, -1.0), crowd)
    order = sorted(range(len(f)), key=lambda i: (ranks[i], clone[i], -crowd[i], i))
    return sorted(order[:SIZE])


def _spea2_survivors(f: np.ndarray) -> list[int]:
    """Zitzler et al. 2001: F = R + D, non-dominated first, truncation by sorted distances."""
    n = len(f)
    strength = [sum(_dominates(f[i], f[j]) for j in range(n)) for i in range(n)]
    raw = np.array([sum(strength[j] for j in range(n) if _dominates(f[j], f[i])) for i in range(n)])
    dist = np.sqrt(((f[:, None] - f[None]) ** 2).sum(-1))
    np.fill_diagonal(dist, np.inf)
    k = int(math.sqrt(n))
    fitness = raw + 1.0 / (np.sort(dist, axis=1)[:, k - 1] + 2.0)
    alive = [i for i in range(n) if raw[i] == 0]
    if len(alive) <= SIZE:
        return sorted(sorted(range(n), key=lambda i: (fitness[i], i))[:SIZE])
    while len(alive) > SIZE:
        rows = {i: sorted(dist[i, j] for j in alive if j != i) for i in alive}
        alive.remove(min(alive, key=lambda i: (rows[i], i)))
    return sorted(alive)


@pytest.fixture(scope="module")
def add() -> object:
    return jax.jit(lambda pop, g, d, f: pop.add(g, d, f))


def _merge(pop: ParetoPopulation, batch: np.ndarray) -> np.ndarray:
    return np.concatenate([np.asarray(pop.fitnesses), batch])


@settings(max_examples=40, deadline=None)
@given(
    rounds=st.lists(
        st.lists(st.integers(0, 6), min_size=2 * BATCH, max_size=2 * BATCH), min_size=2, max_size=2
    ),
    survival=st.sampled_from(["nsga2", "nsga2_pruning", "spea2"]),
)
def test_survivors_match_the_papers_rules(rounds: list[list[int]], survival: str, add: object) -> None:
    pruning = survival == "nsga2_pruning"
    pop = pareto_population(
        jnp.zeros(2), SIZE, 2, 1, "nsga2" if pruning else survival, "pruning" if pruning else "distance"  # type: ignore[arg-type]
    )
    reference = {
        "nsga2": _nsga2_survivors, "nsga2_pruning": lambda f: _nsga2_survivors(f, pruning=True),
        "spea2": _spea2_survivors,
    }[survival]
    for r, values in enumerate(rounds):
        batch = np.asarray(values, np.float32).reshape(BATCH, 2)
        merged = _merge(pop, batch)
        if r == 0:  # the first round fills the empty population: only the batch competes
            expected = sorted(merged[SIZE:][i].tolist() for i in reference(batch))
        else:
            expected = sorted(merged[i].tolist() for i in reference(merged))
        pop, result = add(pop, batch, np.zeros((BATCH, 1)), batch)  # type: ignore[operator]
        assert sorted(np.asarray(pop.fitnesses).tolist()) == expected
        assert int(np.sum(result.added)) == sum(int(c >= 0) for c in np.asarray(result.cell))
        np.testing.assert_array_equal(np.asarray(pop.genotypes), np.asarray(pop.fitnesses))


def test_tournament_prefers_the_lower_front_then_the_larger_score(add: object) -> None:
    f = np.array([[3, 3], [1, 1], [0, 0], [-1, -1], [np.nan, 0], [np.nan, 0]], np.float32)
    pop = pareto_population(jnp.zeros(2), SIZE, 2, 1, "nsga2")
    pop, _ = add(pop, f, np.zeros((BATCH, 1)), f)  # type: ignore[operator]
    assert int(np.sum(np.asarray(pop.members))) == 4  # NaN offspring never survive
    samples = np.asarray(jax.jit(pop.sample, static_argnums=1)(jax.random.PRNGKey(1), 40_000))
    # Tournaments pair neighbours of shuffled orders of the 4 members: each member is in
    # half of them and meets each rival equally often, so the i-th best wins the share
    # (1/2) P(its rival is worse) = (3 - i) / 6 of them: 1/2, 1/3, 1/6, 0.
    for i in range(4):
        share = np.mean(np.all(samples == f[i], axis=1))
        assert share == pytest.approx((3 - i) / 6, abs=0.01)


@pytest.mark.parametrize("seed", range(5))
def test_every_member_of_a_full_population_competes_in_exactly_two_tournaments(
    add: object, seed: int
) -> None:
    # N parents from N members: 2N tournament places, two per member, so the best
    # member (which wins every tournament it is in) is drawn exactly twice and the
    # worst never, whatever the draw (with independent draws both counts vary by seed).
    n = 8
    f = np.stack([np.arange(n, dtype=np.float32)] * 2, axis=1)  # a chain: member i dominates i - 1
    pop = pareto_population(jnp.zeros(2), n, 2, 1, "nsga2")
    pop, _ = add(pop, f, np.zeros((n, 1)), f)  # type: ignore[operator]
    samples = np.asarray(pop.sample(jax.random.PRNGKey(seed), n))
    counts = [int(np.sum(np.all(samples == f[i], axis=1))) for i in range(n)]
    assert counts[n - 1] == 2 and counts[0] == 0
    assert sum(counts) == n


def test_tournament_pool_spreads_the_members_evenly() -> None:
    members = jnp.array([True, False, True, True, False, True, True])  # 5 of 7 slots
    pool = np.asarray(tournament_pool(jax.random.PRNGKey(0), members, 23))
    assert set(pool.tolist()) <= {0, 2, 3, 5, 6}
    counts = np.bincount(pool, minlength=7)[[0, 2, 3, 5, 6]]
    assert counts.max() - counts.min() <= 1  # 23 = 4 x 5 + 3
    # each run of 5 entries is one order of the 5 members
    for start in range(0, 20, 5):
        assert sorted(pool[start : start + 5].tolist()) == [0, 2, 3, 5, 6]


def test_invalid_offspring_never_survive(add: object) -> None:
    pop = pareto_population(jnp.zeros(2), SIZE, 2, 1, "spea2")
    f = np.array([[np.nan, 5], [1, 1], [np.inf, 0], [0, 2], [2, 0], [-np.inf, 9]], np.float32)
    pop, result = add(pop, np.zeros((BATCH, 2)), np.zeros((BATCH, 1)), f)  # type: ignore[operator]
    assert np.asarray(result.added).tolist() == [False, True, False, True, True, False]
    assert int(np.sum(np.asarray(pop.members))) == 3
