"""QDAC's distance-to-skill metrics against hand computations."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import skill_metrics as sm
from qdrl.envs.skills import SkillSpace

SKILLS = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], np.float32)
# Each skill's average features: distances 0, 0.5, 0.25 and 1 (exact in float32).
FEATURES = np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 0.75], [1.0, 0.0]], np.float32)
DISTANCES = np.array([0.0, 0.5, 0.25, 1.0])


def test_distance_to_skill_per_skill_and_over_replicates() -> None:
    np.testing.assert_allclose(sm.distance_to_skill(FEATURES, SKILLS), DISTANCES, atol=1e-6)
    # Two episodes per skill: the distances are averaged (not the features).
    replicated = np.stack([FEATURES, SKILLS], axis=1)  # the second episode hits its target
    np.testing.assert_allclose(sm.distance_to_skill(replicated, SKILLS), DISTANCES / 2, atol=1e-6)
    # Averaging the features first would give |mean - z| = distance / 2 too here, so also
    # check episodes on opposite sides of the target: features average to the target itself.
    shift = np.array([0.2, 0.0], np.float32)
    opposite = np.stack([SKILLS + shift, SKILLS - shift], axis=1)
    np.testing.assert_allclose(sm.distance_to_skill(opposite, SKILLS), np.full(4, 0.2), atol=1e-6)


def test_angles_take_the_shorter_arc() -> None:
    skills = np.array([[0.1], [3.0], [-3.0]], np.float32)
    feats = np.array([[2 * math.pi - 0.1], [-3.0], [3.0]], np.float32)
    # 0.1 and 2 pi - 0.1 are 0.2 apart along the circle; 3 and -3 are 2 pi - 6 apart.
    expected = [0.2, 2 * math.pi - 6.0, 2 * math.pi - 6.0]
    np.testing.assert_allclose(sm.distance_to_skill(feats, skills, angles=True), expected, atol=1e-5)
    np.testing.assert_allclose(sm.distance_to_skill(feats, skills), [2 * math.pi - 0.2, 6.0, 6.0], atol=1e-5)


def test_distance_profile() -> None:
    profile = sm.distance_profile(DISTANCES, max_distance=1.0, num_bins=5)
    np.testing.assert_allclose(profile.thresholds, [0.0, 0.25, 0.5, 0.75, 1.0])
    # below 0: none; below 0.25: d=0 (0.25 is not below 0.25); below 0.5: 0 and 0.25; below
    # 0.75 and 1: all but d=1
    np.testing.assert_allclose(profile.share, [0.0, 0.25, 0.5, 0.75, 0.75])
    assert sm.distance_profile(DISTANCES, 1.0).share.shape == (21,)


def test_performance_profile_counts_reached_skills_over_all_skills() -> None:
    returns = np.array([10.0, 50.0, 90.0, 100.0], np.float32)
    profile = sm.performance_profile(returns, DISTANCES, threshold=0.5, min_return=0.0, max_return=100.0, num_bins=5)
    np.testing.assert_allclose(profile.thresholds, [0.0, 25.0, 50.0, 75.0, 100.0])
    # Reached (distance <= 0.5): the first three. Returns above 0: 3 of 4; above 25: 50 and 90;
    # above 50: 90 only; above 75: 90; above 100: none. The last skill (return 100) never counts.
    np.testing.assert_allclose(profile.share, [0.75, 0.5, 0.25, 0.25, 0.0])


def test_skill_qd_score_and_distance_score() -> None:
    returns = np.array([-20.0, 50.0, 90.0, 100.0], np.float32)
    # Reached: the first three, normalised by (0, 100) and clipped: 0 + 0.5 + 0.9.
    assert float(sm.skill_qd_score(returns, DISTANCES, 0.5, 0.0, 100.0)) == pytest.approx(1.4)
    # A wider threshold lets the last one in: + 1.0.
    assert float(sm.skill_qd_score(returns, DISTANCES, 1.0, 0.0, 100.0)) == pytest.approx(2.4)
    # 1 - d / 2 over the four skills: 1 + 0.75 + 0.875 + 0.5; with max_distance 0.5 the last
    # two are clipped at 0 and 0.5: 1 + 0 + 0.5 + 0.
    assert float(sm.distance_score(DISTANCES, 2.0)) == pytest.approx(3.125)
    assert float(sm.distance_score(DISTANCES, 0.5)) == pytest.approx(1.5)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: sm.distance_profile(DISTANCES, 0.0), "max_distance"),
        (lambda: sm.distance_profile(DISTANCES, 1.0, num_bins=1), "num_bins"),
        (lambda: sm.performance_profile(DISTANCES, DISTANCES, -1.0, 0.0, 1.0), "threshold"),
        (lambda: sm.performance_profile(DISTANCES, DISTANCES, 0.5, 1.0, 1.0), "min_return < max_return"),
        (lambda: sm.skill_qd_score(DISTANCES[:3], DISTANCES, 0.5, 0.0, 1.0), "returns and distances"),
        (lambda: sm.distance_to_skill(FEATURES[:, :1], SKILLS), "mean_features"),
        (lambda: sm.distance_to_skill(FEATURES, SKILLS[0]), "skills"),
    ],
)
def test_bad_values_are_refused_with_the_name(call, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=message):
        call()


def test_cells_visited_counts_distinct_unit_cells_of_the_valid_steps() -> None:
    # one episode visiting (0.5, 0.5) -> (1.5, 0.5) -> (1.7, 0.2) (same cell) -> (-0.5, 0.1),
    # a second episode whose last step is masked out (it would add cell (5, 5))
    positions = jnp.array([
        [[0.5, 0.5], [0.2, 0.3]],
        [[1.5, 0.5], [0.9, 0.9]],
        [[1.7, 0.2], [5.5, 5.5]],
        [[-0.5, 0.1], [5.5, 5.5]],
    ])
    mask = jnp.array([[1, 1], [1, 1], [1, 0], [1, 0]])
    assert int(sm.cells_visited(positions, mask)) == 3  # (0, 0), (1, 0), (-1, 0)
    assert int(jax.jit(sm.cells_visited)(positions, jnp.ones((4, 2)))) == 4  # and (5, 5)
    assert int(sm.cells_visited(positions, mask, cell_size=10.0)) == 2  # (0, 0) and (-1, 0)
    assert int(sm.cells_visited(positions[..., :1], mask)) == 3  # x alone: 0, 1, -1
    with pytest.raises(ValueError, match="positions, mask"):
        sm.cells_visited(positions[0], mask)


def test_nearest_elites_reads_a_repertoire_as_a_library_of_skills() -> None:
    descriptors = jnp.array([[0.0, 0.0], [1.0, 1.0], [0.9, 0.0], [5.0, 5.0]])
    fitnesses = jnp.array([1.0, 2.0, 3.0, -jnp.inf])  # the last cell is empty
    targets = jnp.array([[1.0, 0.9], [1.0, 0.0], [4.0, 4.0]])
    dist, ret = sm.nearest_elites(descriptors, fitnesses, targets)
    np.testing.assert_allclose(dist, [0.1, 0.1, np.hypot(3.0, 3.0)], rtol=1e-5)
    np.testing.assert_allclose(ret, [2.0, 3.0, 2.0])  # never the empty cell
    # the archive metrics: the same reading, over the space's fixed 256 evaluation targets
    box = SkillSpace((0.0, 0.0), (1.0, 1.0))
    m = sm.archive_skill_metrics(descriptors, fitnesses, box, threshold=0.2)
    want, _ = sm.nearest_elites(descriptors, fitnesses, sm.evaluation_targets(box, sm.ARCHIVE_TARGETS))
    assert float(m["archive_distance_to_skill"]) == pytest.approx(float(np.mean(want)), rel=1e-6)
    assert float(m["archive_reached"]) == pytest.approx(float(np.mean(np.asarray(want) <= 0.2)))
    assert float(sm.archive_skill_metrics(descriptors, fitnesses, box)["archive_reached"]) == pytest.approx(
        float(np.mean(np.asarray(want) <= sm.default_threshold(box)))
    )
    empty, ret = sm.nearest_elites(descriptors, jnp.full((4,), -jnp.inf), targets)
    assert np.all(np.isinf(np.asarray(empty))) and np.all(np.asarray(ret) == -np.inf)


def test_picked_elites_are_chosen_by_their_stored_descriptor_and_judged_by_their_replays() -> None:
    """QDAC's reading of a QD baseline: each target picks the elite stored nearest to it (A at
    (0, 0) for targets with x + y < 1, B at (1, 1) beyond), and is judged by that elite's
    re-evaluations: their distance to the target, the share within the threshold, their return."""
    box = SkillSpace((0.0, 0.0), (1.0, 1.0))
    targets = sm.evaluation_targets(box, sm.ARCHIVE_TARGETS)
    near_a = targets.sum(axis=1) < 1.0
    stored = np.array([[0.0, 0.0], [1.0, 1.0]])
    fit = np.array([1.0, 3.0])
    returns = np.array([[1.0, 3.0], [1.0, 5.0]])  # (S=2, n=2): A returns 1, B 3 then 5
    replays_in_place = np.stack([stored, stored])  # (S, n, D): each elite lands where it was stored
    m = sm.picked_elite_metrics(stored, fit, replays_in_place, returns, box, threshold=0.5)
    d_a, d_b = np.linalg.norm(targets, axis=1), np.linalg.norm(targets - 1.0, axis=1)
    want = np.where(near_a, d_a, d_b)
    assert m["picked_distance_to_skill"] == pytest.approx(float(np.mean(want)), rel=1e-6)
    assert m["picked_reached"] == pytest.approx(float(np.mean(want <= 0.5)))
    assert m["picked_return"] == pytest.approx(float(np.mean(np.where(near_a, 1.0, 4.0))))
    # B's replays land at (0, 0): the targets that picked B are now judged from (0, 0)
    moved = np.stack([np.zeros((2, 2)), np.zeros((2, 2))])
    m = sm.picked_elite_metrics(stored, fit, moved, returns, box)
    assert m["picked_distance_to_skill"] == pytest.approx(float(np.mean(d_a)), rel=1e-6)
    none = sm.picked_elite_metrics(np.zeros((0, 2)), np.zeros(0), np.zeros((2, 0, 2)), np.zeros((2, 0)), box)
    assert all(math.isnan(v) for v in none.values())


def test_evaluation_targets_are_one_fixed_set() -> None:
    box = SkillSpace((0.0, -5.0), (1.0, 5.0))
    a, b = sm.evaluation_targets(box, 32), sm.evaluation_targets(box, 32)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (32, 2) and a[:, 0].min() >= 0.0 and a[:, 1].max() <= 5.0
    grid = sm.evaluation_targets(box, 9, "grid")
    assert sorted(set(grid[:, 1].tolist())) == [-5.0, 0.0, 5.0]
    with pytest.raises(ValueError, match=r"train\.num_eval_envs: expected k\^2"):
        sm.evaluation_targets(box, 8, "grid")
    circle = sm.evaluation_targets(SkillSpace((-1.0, -1.0), (1.0, 1.0), "angular"), 8)
    np.testing.assert_allclose(np.linalg.norm(circle, axis=1), 1.0, rtol=1e-6)
    assert sm.default_threshold(box) == pytest.approx(0.05 * np.hypot(1.0, 10.0))
