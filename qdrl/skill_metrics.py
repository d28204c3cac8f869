"""How well skills reach their targets in a feature space: QDAC's distance-to-skill metrics.

A feature-space skill z is a target for the episode's average feature vector phi-bar
(Grillotti, Faldor, González León & Cully 2024, "Quality-Diversity Actor-Critic", ICML).
Evaluated over a fixed set of skills, a method is judged by

- the **distance to skill** ||phi-bar - z||_2 of each skill (averaged over replicated
  episodes when given several),
- its **distance profile**: for each of `num_bins` distances d evenly spaced in
  [0, max_distance], the share of skills whose distance is below d,
- its **performance profile**: for each of `num_bins` returns R evenly spaced in
  [min_return, max_return], the share of ALL skills that both reach their target (distance
  at most `threshold`) and return more than R,
- the **skill QD score**: the sum, over the skills that reach their target, of the return
  normalised to [0, 1] by (min_return, max_return) and clipped,
- the **distance score**: the sum over skills of 1 - d / max_distance, clipped to [0, 1].

The profiles use 21 bins, as QDAC's analysis code does; the thresholds are returned with the
shares so that plots need not rebuild them. Angle features (a heading) use the wrapped
distance min(|a - b|, 2 pi - |a - b|) with `angles=True`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from qdrl.envs.skills import SkillSpace
from qdrl.types import Array

# The key every run draws its evaluation targets from: one set for every method and seed.
EVAL_TARGETS_SEED = 0
# The targets an archive is read against (`archive_skill_metrics`), the same for every method.
ARCHIVE_TARGETS = 256

NUM_BINS = 21  # QDAC's analysis code


class Profile(NamedTuple):
    """`share[i]`: the share of skills that pass `thresholds[i]`."""

    thresholds: Array
    share: Array


def _check_finite_range(low: float, high: float, low_name: str, high_name: str) -> None:
    if not (math.isfinite(low) and math.isfinite(high) and high > low):
        raise ValueError(f"{low_name} < {high_name} (finite) expected, got {low_name}={low}, {high_name}={high}")


def _check_bins(num_bins: int) -> None:
    if num_bins < 2:
        raise ValueError(f"num_bins: expected at least 2, got {num_bins}")


def _check_positive(value: float, name: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name}: expected a finite value > 0, got {value}")


def _check_same_length(returns: Array, distances: Array) -> None:
    if returns.ndim != 1 or returns.shape != distances.shape:
        raise ValueError(
            f"returns and distances: expected two arrays of shape (n,), got {returns.shape} and {distances.shape}"
        )


def distance_to_skill(mean_features: Array, skills: Array, angles: bool = False) -> Array:
    """(n,) distance of each skill's average features (n, D), or (n, r, D) over r episodes, to its target (n, D).

    With replicated episodes the distance is computed per episode, then averaged (QDAC's
    `mean_distance_to_goal`). `angles`: features are angles in radians, each compared along
    the circle (the shorter arc), and the distance is the Euclidean norm of those arcs.
    """
    mean_features = jnp.asarray(mean_features, jnp.float32)
    skills = jnp.asarray(skills, jnp.float32)
    if skills.ndim != 2:
        raise ValueError(f"skills: expected shape (n, D), got {skills.shape}")
    replicated = mean_features.ndim == 3
    if mean_features.ndim not in (2, 3) or (mean_features.shape[0], mean_features.shape[-1]) != skills.shape:
        raise ValueError(
            f"mean_features: expected shape {skills.shape} or ({skills.shape[0]}, r, {skills.shape[1]}) "
            f"to match skills {skills.shape}, got {mean_features.shape}"
        )
    targets = skills[:, None, :] if replicated else skills
    diff = mean_features - targets
    if angles:  # the shorter arc between two angles, in [0, pi]
        diff = jnp.abs(jnp.mod(diff + jnp.pi, 2 * jnp.pi) - jnp.pi)
    dist = jnp.linalg.norm(diff, axis=-1)
    return jnp.mean(dist, axis=1) if replicated else dist


def distance_profile(distances: Array, max_distance: float, num_bins: int = NUM_BINS) -> Profile:
    """For d evenly spaced in [0, max_distance]: the share of skills whose distance is below d."""
    _check_positive(max_distance, "max_distance")
    _check_bins(num_bins)
    distances = jnp.asarray(distances, jnp.float32)
    if distances.ndim != 1:
        raise ValueError(f"distances: expected shape (n,), got {distances.shape}")
    thresholds = jnp.linspace(0.0, max_distance, num_bins)
    share = jnp.mean(distances[None, :] < thresholds[:, None], axis=1)
    return Profile(thresholds, share)


def performance_profile(
    returns: Array,
    distances: Array,
    threshold: float,
    min_return: float,
    max_return: float,
    num_bins: int = NUM_BINS,
) -> Profile:
    """For R evenly spaced in [min_return, max_return]: the share of all skills within
    `threshold` of their target whose return is above R."""
    _check_positive(threshold, "threshold")
    _check_finite_range(min_return, max_return, "min_return", "max_return")
    _check_bins(num_bins)
    returns = jnp.asarray(returns, jnp.float32)
    distances = jnp.asarray(distances, jnp.float32)
    _check_same_length(returns, distances)
    reached = distances <= threshold
    thresholds = jnp.linspace(min_return, max_return, num_bins)
    share = jnp.mean(reached[None, :] & (returns[None, :] > thresholds[:, None]), axis=1)
    return Profile(thresholds, share)


def skill_qd_score(
    returns: Array, distances: Array, threshold: float, min_return: float, max_return: float
) -> Array:
    """() sum, over the skills within `threshold` of their target, of their return
    normalised by (min_return, max_return) and clipped to [0, 1]."""
    _check_positive(threshold, "threshold")
    _check_finite_range(min_return, max_return, "min_return", "max_return")
    returns = jnp.asarray(returns, jnp.float32)
    distances = jnp.asarray(distances, jnp.float32)
    _check_same_length(returns, distances)
    normalised = jnp.clip((returns - min_return) / (max_return - min_return), 0.0, 1.0)
    return jnp.sum(jnp.where(distances <= threshold, normalised, 0.0))


def distance_score(distances: Array, max_distance: float) -> Array:
    """() sum over skills of 1 - distance / max_distance, clipped to [0, 1]."""
    _check_positive(max_distance, "max_distance")
    distances = jnp.asarray(distances, jnp.float32)
    return jnp.sum(jnp.clip(1.0 - distances / max_distance, 0.0, 1.0))


def cells_visited(positions: Array, mask: Array, cell_size: float = 1.0) -> Array:
    """() the number of distinct cells of side `cell_size` that the positions (T, B, D) of the
    valid steps (`mask` (T, B) > 0) fall in: METRA's state coverage (Park et al. 2024, the
    count of 1x1 x-y bins the evaluation skills' trajectories visit). Jittable.
    """
    _check_positive(cell_size, "cell_size")
    positions = jnp.asarray(positions, jnp.float32)
    if positions.ndim != 3 or jnp.shape(mask) != positions.shape[:2]:
        raise ValueError(
            f"positions, mask: expected shapes (T, B, D) and (T, B), got {positions.shape} and {jnp.shape(mask)}"
        )
    cells = jnp.floor(positions / cell_size).astype(jnp.int32).reshape(-1, positions.shape[-1])
    valid = jnp.asarray(mask).reshape(-1) > 0
    # invalid steps take the first valid step's cell, which is counted anyway
    first = cells[jnp.argmax(valid)]
    cells = jnp.where(valid[:, None], cells, first)
    order = jnp.lexsort(tuple(cells[:, i] for i in reversed(range(cells.shape[-1]))))
    ordered = cells[order]
    new = jnp.any(ordered[1:] != ordered[:-1], axis=-1)
    return jnp.where(jnp.any(valid), 1 + jnp.sum(new), 0)


def evaluation_targets(space: SkillSpace, n: int, kind: str = "sample") -> np.ndarray:
    """The (n, D) raw skills every feature-space evaluation plays, the same for every method and
    seed: "sample" draws them from the space's prior with a fixed key (heading spaces: evenly
    spaced angles), "grid" lays them on a regular k^D grid (ValueError naming
    `train.num_eval_envs` unless n = k^D, k >= 2)."""
    if space.kind == "angular":
        theta = -np.pi + 2.0 * np.pi * (np.arange(n) + 0.5) / n
        return np.stack([np.cos(theta), np.sin(theta)], axis=-1).astype(np.float32)
    d = space.size
    if kind == "grid":
        k = round(n ** (1.0 / d))
        if k < 2 or k**d != n:
            raise ValueError(
                f"train.num_eval_envs: expected k^{d} skills (k >= 2) for evaluation.skills = 'grid' "
                f"over {d} feature dimensions, got {n}"
            )
        axes = [np.linspace(lo, hi, k) for lo, hi in zip(space.low, space.high, strict=True)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(n, d).astype(np.float32)
    with jax.ensure_compile_time_eval():
        return np.asarray(space.sample(jax.random.PRNGKey(EVAL_TARGETS_SEED), (n,)), np.float32)


def nearest_elites(descriptors: Array, fitnesses: Array, targets: Array) -> tuple[Array, Array]:
    """A repertoire read as a library of skills: for each target (n, D), the distance from it to
    the nearest elite's descriptor (C, D) and that elite's fitness, the elites being the cells
    whose fitness is finite (an empty repertoire gives inf and -inf). What a method without
    target-conditioned skills (SMERL, DOMiNO, QD) offers for a target. Jittable."""
    nearest, best = nearest_elites_index(descriptors, fitnesses, targets)
    return nearest, jnp.where(jnp.isfinite(nearest), jnp.asarray(fitnesses)[best], -jnp.inf)


def nearest_elites_index(descriptors: Array, fitnesses: Array, targets: Array) -> tuple[Array, Array]:
    """For each target (n, D): the distance to the nearest elite (cells of finite fitness among
    `descriptors` (C, D)) and that elite's index. Jittable."""
    descriptors = jnp.asarray(descriptors, jnp.float32)
    targets = jnp.asarray(targets, jnp.float32)
    filled = jnp.isfinite(fitnesses)
    dist = jnp.linalg.norm(targets[:, None, :] - descriptors[None, :, :], axis=-1)
    dist = jnp.where(filled[None, :], dist, jnp.inf)
    best = jnp.argmin(dist, axis=1)
    return jnp.take_along_axis(dist, best[:, None], axis=1)[:, 0], best


def picked_elite_metrics(
    descriptors: ArrayLike, fitnesses: ArrayLike, descriptor_samples: ArrayLike, fitness_samples: ArrayLike,
    space: SkillSpace, threshold: float | None = None,
) -> dict[str, float]:
    """A repertoire read as QDAC's paper reads a QD baseline: for each of the `ARCHIVE_TARGETS`
    evaluation targets, the elite whose stored descriptor is nearest is picked and played
    again. `descriptors` (n, D) and `fitnesses` (n,) are the n elites' stored figures,
    `descriptor_samples` (S, n, D) and `fitness_samples` (S, n) their S re-evaluations
    (`qdrl.qd.reevaluate`). Returns the mean over targets and re-evaluations of the picked
    elite's distance to its target (`picked_distance_to_skill`), the share of those episodes
    within `threshold` (`picked_reached`, default `default_threshold`) and their mean return
    (`picked_return`); NaN where there is no elite."""
    threshold = default_threshold(space) if threshold is None else threshold
    stored = jnp.asarray(descriptors, jnp.float32)
    if stored.shape[0] == 0:
        return {"picked_distance_to_skill": math.nan, "picked_reached": math.nan, "picked_return": math.nan}
    targets = np.asarray(evaluation_targets(space, ARCHIVE_TARGETS), np.float32)
    _, best = nearest_elites_index(stored, jnp.asarray(fitnesses), jnp.asarray(targets))
    picked = np.asarray(best)
    samples = np.asarray(descriptor_samples, np.float32)[:, picked]  # (S, targets, D)
    dist = np.linalg.norm(samples - targets[None], axis=-1)  # (S, targets)
    return {
        "picked_distance_to_skill": float(np.mean(dist)),
        "picked_reached": float(np.mean(dist <= threshold)),
        "picked_return": float(np.mean(np.asarray(fitness_samples)[:, picked])),
    }


def default_threshold(space: SkillSpace) -> float:
    """The distance under which a skill counts as reached when none is given: 5% of the feature
    space's diagonal (its largest distance)."""
    return 0.05 * float(np.linalg.norm(np.subtract(space.high, space.low)))


def archive_skill_metrics(
    descriptors: Array, fitnesses: Array, space: SkillSpace, threshold: float | None = None
) -> dict[str, Array]:
    """`archive_distance_to_skill` (the mean, over `ARCHIVE_TARGETS` evaluation targets of
    `space`, of the distance to the nearest elite, `nearest_elites`) and `archive_reached` (the
    share of targets with an elite within `threshold`, default `default_threshold`): the same
    figures for every method that fills an archive over a feature space. Jittable."""
    threshold = default_threshold(space) if threshold is None else threshold
    targets = jnp.asarray(evaluation_targets(space, ARCHIVE_TARGETS))
    dist, _ = nearest_elites(descriptors, fitnesses, targets)
    return {
        "archive_distance_to_skill": jnp.mean(dist),
        "archive_reached": jnp.mean((dist <= threshold).astype(jnp.float32)),
    }
