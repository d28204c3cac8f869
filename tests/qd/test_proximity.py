"""ProximityArchive: novelty search and NSLC insertion against a NumPy reference, decay, capacity, errors.

The hypothesis test draws one-dimensional integer descriptors, integer fitnesses
and thresholds that are odd multiples of 1/8: every distance is an integer and a
novelty is an integer sum over at most 4 neighbours divided by their number, so
float32 and the float64 reference agree exactly on every comparison (a novelty
never equals such a threshold). Hand-computed 2-D examples check the rest.
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
from qdrl.qd.repertoires.proximity import ProximityArchive, proximity_archive

SETTINGS = settings(max_examples=25, deadline=None, database=None, derandomize=True)
N = 6  # candidates per batch
CAPACITY = 5  # smaller than two batches: the hypothesis test fills it
SUBNORMAL = 4e-41
FITNESS_VALUES = [math.nan, math.inf, -math.inf, -1.0, 0.0, 1.0, 2.0, 3.0, SUBNORMAL]
TINY = np.finfo(np.float32).tiny
ID = jnp.zeros((), jnp.int32)  # a genotype is the candidate's id


@jax.jit
def _add(archive: ProximityArchive, ids: Any, d: Any, f: Any) -> tuple[ProximityArchive, AddResult]:
    return archive.add(ids, d, f)


class Reference:
    """pyribs' ProximityArchive rules with a capacity, in NumPy (float64)."""

    def __init__(self, dim: int, k: int, threshold: float, local_competition: bool) -> None:
        self.d = np.zeros((CAPACITY, dim))
        self.f = np.full(CAPACITY, -np.inf)
        self.ids = np.zeros(CAPACITY, np.int64)
        self.count = 0
        self.k, self.threshold, self.lc = k, threshold, local_competition

    def add(self, ids: np.ndarray, d: np.ndarray, f: np.ndarray) -> dict[str, np.ndarray]:
        n = len(f)
        f = np.where(np.abs(f) < TINY, 0.0, f)
        valid = np.isfinite(f) & np.all(np.isfinite(d), axis=1)
        novelty = np.full(n, -np.inf)
        local = np.zeros(n, np.int64)
        nearest = np.full(n, -1)
        for i in np.flatnonzero(valid):
            if self.count == 0:
                novelty[i] = self.threshold
                continue
            sq = np.sum((self.d[: self.count] - d[i]) ** 2, axis=1)
            near = np.argsort(sq, kind="stable")[: self.k]
            novelty[i] = np.mean(np.sqrt(sq[near]))
            local[i] = np.sum(self.f[near] < f[i])
            nearest[i] = near[0]
        novel = valid & (novelty >= self.threshold)
        by_novelty = sorted(np.flatnonzero(novel), key=lambda i: (-novelty[i], i))
        admit = np.zeros(n, bool)
        admit[by_novelty[: CAPACITY - self.count]] = True
        rival = np.where(nearest >= 0, self.f[np.maximum(nearest, 0)], -np.inf)
        beats = self.lc & valid & ~novel & (f > rival)
        replace = np.zeros(n, bool)
        for slot in set(nearest[beats].tolist()):
            rivals = np.flatnonzero(beats & (nearest == slot))
            best = np.max(f[rivals])
            replace[rivals[f[rivals] == best][0]] = True
        slot_of = np.full(n, -1)
        slot_of[admit] = self.count + np.arange(admit.sum())
        for i in np.flatnonzero(replace | admit):
            s = slot_of[i] if admit[i] else nearest[i]
            self.d[s], self.f[s], self.ids[s] = d[i], f[i], ids[i]
        self.count += int(admit.sum())
        with np.errstate(invalid="ignore"):
            margin = np.where(rival > -np.inf, f - rival, f)
        value = np.where(valid, np.where(admit, f, margin), -np.inf)
        return {
            "added": admit | replace,
            "new_cell": admit,
            "cell": np.where(admit, slot_of, np.where(valid & ~novel, nearest, -1)),
            "status": np.where(admit, 2, np.where(beats, 1, 0)),
            "value": value,
            "novelty": novelty,
            "local_competition": local if self.lc else np.zeros(n, np.int64),
        }


def _check(result: AddResult, expected: dict[str, np.ndarray]) -> None:
    assert result.status is not None and result.value is not None and result.info is not None
    got = {
        "added": result.added,
        "new_cell": result.new_cell,
        "cell": result.cell,
        "status": result.status,
        "value": result.value,
        "novelty": result.info["novelty"],
        "local_competition": result.info["local_competition"],
    }
    for name, want in expected.items():
        np.testing.assert_allclose(np.asarray(got[name], np.float64), want, rtol=1e-6, err_msg=name)
    np.testing.assert_array_equal(np.asarray(result.improvement), np.asarray(result.value))


@st.composite
def batches(draw: st.DrawFn) -> tuple[int, float, bool, list[tuple[np.ndarray, np.ndarray]]]:
    k = draw(st.sampled_from([1, 2, 4]))
    threshold = (2 * draw(st.integers(0, 15)) + 1) / 8
    lc = draw(st.booleans())
    out = []
    for _ in range(draw(st.integers(1, 3))):
        x = draw(st.lists(st.integers(0, 8), min_size=N, max_size=N))
        bad = draw(st.lists(st.sampled_from([None] * 8 + [math.nan, math.inf]), min_size=N, max_size=N))
        d = np.array([[b if b is not None else float(v)] for v, b in zip(x, bad, strict=True)])
        f = np.array(draw(st.lists(st.sampled_from(FITNESS_VALUES), min_size=N, max_size=N)))
        out.append((d, f))
    return k, threshold, lc, out


@SETTINGS
@given(batches())
def test_insertion_matches_the_numpy_reference(
    case: tuple[int, float, bool, list[tuple[np.ndarray, np.ndarray]]],
) -> None:
    k, threshold, lc, batch_list = case
    archive = proximity_archive(ID, CAPACITY, 1, k, threshold, local_competition=lc)
    ref = Reference(1, k, threshold, lc)
    for b, (d, f) in enumerate(batch_list):
        ids = np.arange(N) + 100 * b
        archive, result = _add(
            archive, jnp.asarray(ids, jnp.int32), jnp.asarray(d, jnp.float32), jnp.asarray(f, jnp.float32)
        )
        _check(result, ref.add(ids, d, f))
        filled = np.asarray(archive.filled)
        assert int(archive.num_filled) == ref.count and filled[: ref.count].all()
        np.testing.assert_array_equal(np.asarray(archive.fitnesses), ref.f.astype(np.float32))
        np.testing.assert_array_equal(np.asarray(archive.genotypes)[filled], ref.ids[: ref.count])
        np.testing.assert_array_equal(np.asarray(archive.descriptors)[filled], ref.d[: ref.count])


def test_novelty_by_hand_fewer_than_k_members_and_an_empty_archive() -> None:
    archive = proximity_archive(ID, 8, 2, 3, 1.0, local_competition=True)
    # empty: every candidate gets novelty = threshold, local competition 0, and enters
    archive, r = _add(archive, jnp.array([0, 1]), jnp.array([[0.0, 0.0], [3.0, 4.0]]), jnp.array([1.0, 5.0]))
    assert r.info is not None and r.status is not None
    np.testing.assert_allclose(np.asarray(r.info["novelty"]), [1.0, 1.0])
    np.testing.assert_array_equal(np.asarray(r.status), [2, 2])
    # two members, k = 3: the mean over both. (0, 4): distances 4 and 3 -> 3.5;
    # (3, 3.5): 4.61 and 0.5 -> 2.555; fitness 2 beats member 0 (1) but not member 1 (5)
    cand = jnp.array([[0.0, 4.0], [3.0, 3.5]])
    archive, r = _add(archive, jnp.array([2, 3]), cand, jnp.array([2.0, 2.0]))
    assert r.info is not None
    np.testing.assert_allclose(
        np.asarray(r.info["novelty"]), [3.5, (math.hypot(3.0, 3.5) + 0.5) / 2], rtol=1e-6
    )
    np.testing.assert_array_equal(np.asarray(r.info["local_competition"]), [1, 1])
    assert int(archive.num_filled) == 4


def test_candidates_of_one_batch_do_not_see_each_other() -> None:
    archive = proximity_archive(ID, 8, 1, 1, 1.0)
    archive, _ = _add(archive, jnp.array([0]), jnp.array([[0.0]]), jnp.array([0.0]))
    # two copies of a novel point both enter (pyribs' batch semantics)
    archive, r = _add(archive, jnp.array([1, 2]), jnp.array([[5.0], [5.0]]), jnp.zeros(2))
    np.testing.assert_array_equal(np.asarray(r.added), [True, True])
    np.testing.assert_array_equal(np.asarray(r.cell), [1, 2])
    assert int(archive.num_filled) == 3


def test_local_competition_replaces_the_nearest_member_once_per_batch() -> None:
    archive = proximity_archive(ID, 4, 1, 2, 10.0, local_competition=True)
    archive, _ = _add(archive, jnp.array([0, 1]), jnp.array([[0.0], [4.0]]), jnp.array([1.0, 1.0]))
    # all near member 0 (not novel); 2 and 3 tie at the best fitness, 2 (first) wins;
    # 4 is not fitter; 5 beats member 1 alone
    d = jnp.array([[0.5], [0.2], [0.1], [0.3], [3.0]])
    f = jnp.array([2.0, 3.0, 3.0, 1.0, 1.5])
    archive, r = _add(archive, jnp.arange(2, 7), d, f)
    assert r.status is not None and r.value is not None
    np.testing.assert_array_equal(np.asarray(r.status), [1, 1, 1, 0, 1])
    np.testing.assert_array_equal(np.asarray(r.added), [False, True, False, False, True])
    np.testing.assert_array_equal(np.asarray(r.cell), [0, 0, 0, 0, 1])
    np.testing.assert_allclose(np.asarray(r.value), [1.0, 2.0, 2.0, 0.0, 0.5])
    np.testing.assert_array_equal(np.asarray(archive.genotypes)[:2], [3, 6])
    np.testing.assert_allclose(np.asarray(archive.fitnesses)[:2], [3.0, 1.5])


def test_without_local_competition_a_non_novel_candidate_is_never_stored() -> None:
    archive = proximity_archive(ID, 4, 1, 1, 10.0)
    archive, _ = _add(archive, jnp.array([0]), jnp.array([[0.0]]), jnp.array([0.0]))
    archive, r = _add(archive, jnp.array([1]), jnp.array([[1.0]]), jnp.array([9.0]))
    assert r.status is not None and r.info is not None
    assert int(r.status[0]) == 0 and not bool(r.added[0])
    assert int(r.info["local_competition"][0]) == 0
    assert float(archive.fitnesses[0]) == 0.0


def test_a_full_archive_keeps_its_members_and_admits_the_most_novel() -> None:
    archive = proximity_archive(ID, 3, 1, 1, 1.0, local_competition=True)
    archive, _ = _add(archive, jnp.array([0]), jnp.array([[0.0]]), jnp.array([0.0]))
    # novelties 2, 8, 5 (all novel), two free slots: 8 and 5 enter, in batch order
    archive, r = _add(archive, jnp.array([1, 2, 3]), jnp.array([[2.0], [8.0], [-5.0]]), jnp.zeros(3))
    assert r.status is not None
    np.testing.assert_array_equal(np.asarray(r.added), [False, True, True])
    np.testing.assert_array_equal(np.asarray(r.status), [0, 2, 2])
    np.testing.assert_array_equal(np.asarray(r.cell), [-1, 1, 2])
    np.testing.assert_array_equal(np.asarray(archive.genotypes), [0, 2, 3])
    # full: a novel one is rejected, a fitter non-novel one still replaces its neighbour
    archive, r = _add(archive, jnp.array([4, 5]), jnp.array([[20.0], [8.2]]), jnp.array([0.0, 1.0]))
    np.testing.assert_array_equal(np.asarray(r.added), [False, True])
    np.testing.assert_array_equal(np.asarray(r.cell), [-1, 1])
    np.testing.assert_array_equal(np.asarray(archive.genotypes), [0, 5, 3])


def test_the_threshold_decays_every_n_adds_down_to_its_floor() -> None:
    archive = proximity_archive(
        ID, 4, 1, 1, 1.0, threshold_decay=0.5, decay_every=2, threshold_min=0.3
    )
    thresholds, counts = [], []
    for i in range(6):
        archive, _ = _add(archive, jnp.array([i]), jnp.array([[0.1 * i]]), jnp.array([0.0]))
        thresholds.append(float(archive.novelty_threshold))
        counts.append(int(archive.iterations))
    np.testing.assert_allclose(thresholds, [1.0, 0.5, 0.5, 0.3, 0.3, 0.3], rtol=1e-6)
    assert counts == [1, 2, 3, 4, 5, 6]
    # 0.1, 0.2 and 0.3 were too close to 0.0; 0.4 enters once the threshold is 0.3
    np.testing.assert_array_equal(np.asarray(archive.genotypes), [0, 4, 0, 0])
    assert int(archive.num_filled) == 2


def test_non_finite_candidates_are_rejected() -> None:
    archive = proximity_archive(ID, 4, 2, 1, 0.5, local_competition=True)
    d = jnp.array([[0.0, 0.0], [jnp.nan, 1.0], [2.0, jnp.inf], [3.0, 3.0]])
    f = jnp.array([jnp.nan, 1.0, 1.0, jnp.inf])
    archive, r = _add(archive, jnp.arange(4), d, f)
    assert r.status is not None and r.info is not None and r.value is not None
    assert not np.asarray(r.added).any() and (np.asarray(r.cell) == -1).all()
    assert (np.asarray(r.status) == 0).all() and (np.asarray(r.value) == -np.inf).all()
    assert (np.asarray(r.info["novelty"]) == -np.inf).all()
    assert bool(archive.is_empty)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"capacity": 0}, "capacity"),
        ({"descriptor_dim": 0}, "descriptor_dim"),
        ({"k_neighbors": 0}, "k_neighbors"),
        ({"novelty_threshold": 0.0}, "novelty_threshold"),
        ({"novelty_threshold": -1.0}, "novelty_threshold"),
        ({"novelty_threshold": math.nan}, "novelty_threshold"),
        ({"novelty_threshold": math.inf}, "novelty_threshold"),
        ({"threshold_decay": 0.0}, "threshold_decay"),
        ({"threshold_decay": 1.5}, "threshold_decay"),
        ({"decay_every": 0}, "decay_every"),
        ({"threshold_min": -0.1}, "threshold_min"),
        ({"threshold_min": 2.0}, "threshold_min"),
    ],
)
def test_bad_parameters_raise_naming_the_parameter(kwargs: dict[str, Any], name: str) -> None:
    args: dict[str, Any] = {"capacity": 4, "descriptor_dim": 2, "k_neighbors": 3, "novelty_threshold": 1.0}
    args.update(kwargs)
    with pytest.raises(ValueError, match=f"proximity_archive: {name} must be"):
        proximity_archive(ID, **args)


def test_add_compiles_once_and_runs_under_scan() -> None:
    traces = []

    @jax.jit
    def add(archive: ProximityArchive, ids: Any, d: Any, f: Any) -> tuple[ProximityArchive, AddResult]:
        traces.append(1)
        return archive.add(ids, d, f)

    archive = proximity_archive(ID, 16, 2, 3, 0.2, local_competition=True, threshold_decay=0.9)
    rng = np.random.default_rng(0)
    for b in range(3):
        archive, _ = add(archive, jnp.arange(4) + 4 * b, rng.uniform(size=(4, 2)), jnp.ones(4) * b)
        archive = archive.with_threshold(0.1 * (b + 1))  # a leaf: no new compilation
    assert len(traces) == 1

    def body(a: ProximityArchive, xs: Any) -> tuple[ProximityArchive, None]:
        return a.add(*xs)[0], None

    xs = (jnp.arange(12).reshape(3, 4), jnp.asarray(rng.uniform(size=(3, 4, 2))), jnp.ones((3, 4)))
    scanned, _ = jax.jit(lambda a, x: jax.lax.scan(body, a, x))(archive, xs)
    assert isinstance(scanned, ProximityArchive) and int(scanned.iterations) == 6


def test_sample_draws_only_members_and_properties() -> None:
    archive = proximity_archive(ID, 6, 1, 1, 1.0)
    assert archive.num_cells == 6 and bool(archive.is_empty)
    sample = jax.jit(lambda a, key: a.sample(key, 200))
    assert np.isnan(np.asarray(sample(proximity_archive(jnp.zeros(2), 3, 1, 1, 1.0), jax.random.key(0)))).all()
    archive, _ = _add(archive, jnp.array([7, 8]), jnp.array([[0.0], [5.0]]), jnp.zeros(2))
    drawn = np.asarray(sample(archive, jax.random.key(1)))
    assert set(drawn.tolist()) == {7, 8}
    np.testing.assert_array_equal(np.asarray(archive.filled), [True, True, False, False, False, False])
    assert int(archive.num_filled) == 2 and archive.descriptors.shape == (6, 1)
