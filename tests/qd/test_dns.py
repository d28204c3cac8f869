"""Dominated Novelty Search: survival against a NumPy reference, both tie rules, slots, errors.

The hypothesis test draws one-dimensional integer descriptors and integer
fitnesses: every competition fitness is an integer sum of at most 3 distances
divided by their number, so float32 and the float64 reference order them alike,
ties included.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qdrl.qd.base import AddResult
from qdrl.qd.repertoires.dns import DNSPopulation, competition_fitness, dns_population

SETTINGS = settings(max_examples=25, deadline=None, database=None, derandomize=True)
C, N = 4, 5  # population size, candidates per batch
ID = jnp.zeros((), jnp.int32)  # a genotype is the candidate's id


@jax.jit
def _add(pop: DNSPopulation, ids: Any, d: Any, f: Any) -> tuple[DNSPopulation, AddResult]:
    return pop.add(ids, d, f)


class Reference:
    """DNS survival with the documented tie rules, in NumPy (float64)."""

    def __init__(self, k: int, rule: str) -> None:
        self.d = np.zeros((C, 1))
        self.f = np.full(C, -np.inf)
        self.ids = np.zeros(C, np.int64)
        self.k, self.rule = k, rule

    def add(self, ids: np.ndarray, d: np.ndarray, f: np.ndarray) -> dict[str, np.ndarray]:
        n = len(f)
        valid = np.isfinite(f) & np.all(np.isfinite(d), axis=1)
        pool_f = np.concatenate([self.f, np.where(valid, f, -np.inf)])
        pool_d = np.concatenate([self.d, np.where(valid[:, None], d, 0.0)])
        members = np.flatnonzero(pool_f > -np.inf)
        comp = np.full(C + n, -np.inf)
        for i in members:
            fitter = [
                j for j in members
                if j != i and (pool_f[j] >= pool_f[i] if self.rule == "qdax" else pool_f[j] > pool_f[i])
            ]
            dist = sorted(float(np.linalg.norm(pool_d[j] - pool_d[i])) for j in fitter)[: self.k]
            comp[i] = np.mean(dist) if dist else np.inf
        ranked = sorted(members, key=lambda i: (-comp[i], -pool_f[i], i))[:C]
        keep = np.isin(np.arange(C), ranked)
        free = iter(np.flatnonzero(~keep).tolist())
        cell = np.full(n, -1)
        for c in range(n):
            if C + c in ranked:
                cell[c] = next(free)
        was_empty = ~(self.f > -np.inf)
        self.f = np.where(keep, self.f, -np.inf)
        for i in np.flatnonzero(cell >= 0):
            self.d[cell[i]], self.f[cell[i]], self.ids[cell[i]] = d[i], f[i], ids[i]
        added = cell >= 0
        return {
            "added": added,
            "new_cell": added & was_empty[np.maximum(cell, 0)],
            "cell": cell,
            "status": np.where(added, 2, 0),
            "value": comp[C:],
        }


@st.composite
def batches(draw: st.DrawFn) -> tuple[int, str, list[tuple[np.ndarray, np.ndarray]]]:
    k = draw(st.integers(1, 3))
    rule = draw(st.sampled_from(["qdax", "strict"]))
    out = []
    for _ in range(draw(st.integers(1, 3))):
        x = draw(st.lists(st.integers(0, 6), min_size=N, max_size=N))
        d = np.array(x, np.float64)[:, None]
        d[draw(st.lists(st.sampled_from([False] * 5 + [True]), min_size=N, max_size=N))] = math.nan
        f = np.array(draw(st.lists(st.sampled_from([math.nan, math.inf, 0.0, 1.0, 2.0]), min_size=N, max_size=N)))
        out.append((d, f))
    return k, rule, out


@SETTINGS
@given(batches())
def test_survival_matches_the_numpy_reference(case: tuple[int, str, list[tuple[np.ndarray, np.ndarray]]]) -> None:
    k, rule, batch_list = case
    pop = dns_population(ID, C, 1, k, tie_rule=rule)  # type: ignore[arg-type]
    ref = Reference(k, rule)
    for b, (d, f) in enumerate(batch_list):
        ids = np.arange(N) + 100 * b
        pop, r = _add(pop, jnp.asarray(ids, jnp.int32), jnp.asarray(d, jnp.float32), jnp.asarray(f, jnp.float32))
        want = ref.add(ids, d, f)
        assert r.status is not None and r.value is not None and r.info is not None
        got = {"added": r.added, "new_cell": r.new_cell, "cell": r.cell, "status": r.status, "value": r.value}
        for name, expected in want.items():
            np.testing.assert_allclose(np.asarray(got[name], np.float64), expected, rtol=1e-6, err_msg=name)
        np.testing.assert_array_equal(np.asarray(r.info["competition_fitness"]), np.asarray(r.value))
        np.testing.assert_array_equal(np.asarray(pop.fitnesses), ref.f.astype(np.float32))
        filled = np.asarray(pop.filled)
        np.testing.assert_array_equal(np.asarray(pop.genotypes)[filled], ref.ids[filled])
        np.testing.assert_array_equal(np.asarray(pop.descriptors)[filled], ref.d[filled])


def test_competition_fitness_by_hand() -> None:
    # 2-D pool; fitnesses 3, 1, 1, 2, 0 (row 4 not a member), k = 2
    d = jnp.array([[0.0, 0.0], [3.0, 4.0], [0.0, 1.0], [6.0, 8.0], [1.0, 1.0]])
    f = jnp.array([3.0, 1.0, 1.0, 2.0, 0.0])
    members = jnp.array([True, True, True, True, False])
    score = jax.jit(competition_fitness, static_argnums=(3, 4))
    qdax = score(d, f, members, 2, "qdax")
    strict = score(d, f, members, 2, "strict")
    # row 0: nobody fitter -> inf; row 3: only row 0 (distance 10);
    # row 1: fitter 0 (5), 3 (5), and with equal fitness row 2 (sqrt(18) = 4.243):
    #   qdax: mean(4.243, 5) ; strict: mean(5, 5)
    # row 2: fitter 0 (1), 3 (sqrt(85) = 9.22), equal row 1 (4.243):
    #   qdax: mean(1, 4.243) ; strict: mean(1, 9.22)
    np.testing.assert_allclose(
        np.asarray(qdax), [np.inf, (math.sqrt(18) + 5) / 2, (1 + math.sqrt(18)) / 2, 10.0, -np.inf], rtol=1e-6
    )
    np.testing.assert_allclose(
        np.asarray(strict), [np.inf, 5.0, (1 + math.sqrt(85)) / 2, 10.0, -np.inf], rtol=1e-6
    )


def test_the_two_tie_rules_keep_different_survivors_on_a_plateau() -> None:
    # equal fitnesses at 0, 0.1 and 5, room for two
    d = jnp.array([[0.0], [0.1], [5.0]])
    f = jnp.zeros(3)
    qdax, r_qdax = _add(dns_population(ID, 2, 1, 1, tie_rule="qdax"), jnp.arange(3), d, f)
    strict, r_strict = _add(dns_population(ID, 2, 1, 1, tie_rule="strict"), jnp.arange(3), d, f)
    assert r_qdax.info is not None and r_strict.info is not None
    # qdax: equal counts as fitter, so it is novelty: 5 (4.9) and then 0 (0.1, first of the tie)
    np.testing.assert_allclose(np.asarray(r_qdax.info["competition_fitness"]), [0.1, 0.1, 4.9], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(r_qdax.added), [True, False, True])
    np.testing.assert_array_equal(np.asarray(qdax.genotypes), [0, 2])
    # strict: nobody is fitter, all +inf; the first two in batch order survive
    assert np.isinf(np.asarray(r_strict.info["competition_fitness"])).all()
    np.testing.assert_array_equal(np.asarray(r_strict.added), [True, True, False])
    np.testing.assert_array_equal(np.asarray(strict.genotypes), [0, 1])


def test_survivors_keep_their_slots_and_newcomers_fill_the_free_ones() -> None:
    pop = dns_population(ID, 4, 1, 1)
    pop, r = _add(pop, jnp.arange(3), jnp.array([[0.0], [10.0], [20.0]]), jnp.array([1.0, 1.0, 1.0]))
    np.testing.assert_array_equal(np.asarray(r.cell), [0, 1, 2])
    assert np.asarray(r.new_cell).all() and int(pop.num_filled) == 3
    # two fitter candidates: one fills the empty slot 3, the other evicts the member at 10
    # (the nearest to a fitter one: 11 is 1 away), whose slot 1 it takes
    pop, r = _add(pop, jnp.array([3, 4]), jnp.array([[11.0], [30.0]]), jnp.array([5.0, 5.0]))
    np.testing.assert_array_equal(np.asarray(r.added), [True, True])
    np.testing.assert_array_equal(np.asarray(r.cell), [1, 3])
    np.testing.assert_array_equal(np.asarray(r.new_cell), [False, True])
    np.testing.assert_array_equal(np.asarray(pop.genotypes), [0, 3, 2, 4])
    np.testing.assert_array_equal(np.asarray(r.status), [2, 2])


def test_non_finite_candidates_never_survive_and_a_small_pool_survives_whole() -> None:
    pop = dns_population(ID, 5, 2, 3)
    d = jnp.array([[0.0, 0.0], [jnp.nan, 0.0], [1.0, 1.0], [2.0, jnp.inf]])
    f = jnp.array([1.0, 2.0, jnp.nan, 0.0])
    pop, r = _add(pop, jnp.arange(4), d, f)
    assert r.value is not None
    np.testing.assert_array_equal(np.asarray(r.added), [True, False, False, False])
    np.testing.assert_array_equal(np.asarray(r.cell), [0, -1, -1, -1])
    np.testing.assert_array_equal(np.asarray(r.improvement), [1.0, -np.inf, -np.inf, -np.inf])
    np.testing.assert_array_equal(np.asarray(r.value), [np.inf, -np.inf, -np.inf, -np.inf])
    assert int(pop.num_filled) == 1


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"capacity": 0}, "capacity"),
        ({"descriptor_dim": 0}, "descriptor_dim"),
        ({"k": 0}, "k"),
        ({"k": 1.5}, "k"),
        ({"tie_rule": "pyribs"}, "tie_rule"),
    ],
)
def test_bad_parameters_raise_naming_the_parameter(kwargs: dict[str, Any], name: str) -> None:
    args: dict[str, Any] = {"capacity": 4, "descriptor_dim": 2, "k": 3}
    args.update(kwargs)
    with pytest.raises(ValueError, match=f"dns_population: {name} must be"):
        dns_population(ID, **args)


def test_add_compiles_once_and_sample_draws_members() -> None:
    traces = []

    @jax.jit
    def add(pop: DNSPopulation, ids: Any, d: Any, f: Any) -> tuple[DNSPopulation, AddResult]:
        traces.append(1)
        return pop.add(ids, d, f)

    pop = dns_population(ID, 8, 2, 3)
    assert pop.num_cells == 8 and bool(pop.is_empty)
    rng = np.random.default_rng(0)
    for b in range(4):
        pop, _ = add(pop, jnp.arange(5) + 5 * b, rng.uniform(size=(5, 2)), rng.uniform(size=5))
    assert len(traces) == 1 and int(pop.num_filled) == 8
    drawn = np.asarray(pop.sample(jax.random.key(0), 100))
    assert set(drawn.tolist()) <= set(np.asarray(pop.genotypes).tolist())
    own = np.asarray(pop.competition_fitness())
    assert own.shape == (8,) and not np.isnan(own).any() and (own > 0).all()
    assert np.isnan(np.asarray(dns_population(jnp.zeros(2), 3, 1, 1).sample(jax.random.key(0), 2))).all()
