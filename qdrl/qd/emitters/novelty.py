"""Novelty against an archive of descriptors, and the D-PG emitter of QD-PG built on it.

Pierrot et al. 2022, "Diversity Policy Gradient for Sample Efficient
Quality-Diversity Optimization" (GECCO): the diversity policy gradient (D-PG)
trains a critic on a novelty reward, the mean distance of the next state's
descriptor to its k nearest neighbours in an archive of descriptors already
visited (Lehman & Stanley 2011), and applies TD3 actor steps against that critic
to elites. QD-PG is MAP-Elites with GA, Q-PG and D-PG emitters side by side.

The archive follows QDax's `qdax.core.containers.archive.Archive`: a fixed
number of slots, filled in order; a candidate enters only if it is farther than
`acceptance_threshold` from every descriptor already stored (candidates of one
update are examined one after the other, so they also screen each other).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import haiku as hk
import jax
import jax.numpy as jnp

from qdrl.config import PositiveFloat, PositiveInt, check_fields
from qdrl.qd.base import Emitter, Evaluation
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.emitters.multi import MultiEmitter, split_batch
from qdrl.qd.emitters.pg import PGConfig, PGEmitter, flatten_valid
from qdrl.qd.neighbours import nearest_in_prefix
from qdrl.types import Array, PRNGKey, Transition


class DescriptorArchive(NamedTuple):
    """Descriptors visited so far: slots (max_size, D), the first `size` of them valid."""

    data: Array
    size: Array  # int32


def init_archive(max_size: int, descriptor_size: int) -> DescriptorArchive:
    """An empty archive."""
    if max_size < 1 or descriptor_size < 1:
        raise ValueError(f"archive: expected max_size and descriptor_size >= 1, got {max_size}, {descriptor_size}")
    return DescriptorArchive(jnp.zeros((max_size, descriptor_size), jnp.float32), jnp.zeros((), jnp.int32))


def add_to_archive(
    archive: DescriptorArchive, candidates: Array, acceptance_threshold: float
) -> DescriptorArchive:
    """Offer (n, D) candidates in order; each enters if farther than the threshold from all stored.

    A full archive accepts nothing more.
    """
    max_size = archive.data.shape[0]
    slots = jnp.arange(max_size)

    def offer(a: DescriptorArchive, c: Array) -> tuple[DescriptorArchive, None]:
        dist = jnp.linalg.norm(a.data - c, axis=-1)
        nearest = jnp.min(jnp.where(slots < a.size, dist, jnp.inf))
        accept = (nearest > acceptance_threshold) & (a.size < max_size)
        data = jnp.where(accept & (slots == a.size)[:, None], c, a.data)
        return DescriptorArchive(data, a.size + accept.astype(jnp.int32)), None

    archive, _ = jax.lax.scan(offer, archive, candidates.astype(jnp.float32))
    return archive


def novelty(archive: DescriptorArchive, descriptors: Array, num_neighbours: int) -> Array:
    """(n,) mean Euclidean distance of each descriptor to its k nearest archive entries.

    With fewer than k entries stored, the mean is over those there are (0 when empty).
    """
    k = min(num_neighbours, archive.data.shape[0])
    sq, _ = nearest_in_prefix(descriptors, archive.data, archive.size, k)
    finite = jnp.isfinite(sq)
    nearest = jnp.sqrt(jnp.where(finite, sq, 0.0))
    count = jnp.maximum(jnp.sum(finite, axis=-1), 1)
    return jnp.sum(jnp.where(finite, nearest, 0.0), axis=-1) / count


@dataclasses.dataclass(frozen=True)
class NoveltyConfig:
    """The novelty reward of D-PG (the `[dpg]` section's archive keys); defaults: QDax's
    `DiversityPGConfig` (threshold 0.1, 10000 slots, 5 neighbours)."""

    # A descriptor enters the archive if farther than this from all stored (QDax: 0.1).
    acceptance_threshold: PositiveFloat = 0.1
    archive_max_size: PositiveInt = 10_000
    # k of the k-nearest-neighbour novelty reward (QDax: 5).
    num_neighbours: PositiveInt = 5
    # Visited descriptors offered to the archive per update.
    candidates_per_update: PositiveInt = 256
    novelty_scale: PositiveFloat = 1.0

    def check(self, section: str = "dpg") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value."""
        check_fields(self, section)


@dataclasses.dataclass(frozen=True)
class NoveltyReward:
    """D-PG's reward hook (`qdrl.qd.emitters.pg.RewardRelabel`): novelty of `next_desc`.

    Each update offers `candidates_per_update` descriptors, drawn uniformly from
    the valid steps of the evaluated episodes, to the archive (QDax offers every
    step, a sequential scan too slow for 1000-step episodes).
    """

    descriptor_size: int
    config: NoveltyConfig = NoveltyConfig()

    def init(self, evaluation: Evaluation, key: PRNGKey) -> DescriptorArchive:
        archive = init_archive(self.config.archive_max_size, self.descriptor_size)
        return self.update(archive, evaluation, key)

    def update(self, state: DescriptorArchive, evaluation: Evaluation, key: PRNGKey) -> DescriptorArchive:
        transitions: Transition = evaluation.extras["transitions"]
        items, num_valid = flatten_valid(transitions, evaluation.extras["mask"])
        picks = jax.random.randint(key, (self.config.candidates_per_update,), 0, jnp.maximum(num_valid, 1))
        return add_to_archive(state, items.next_desc[picks], self.config.acceptance_threshold)

    def relabel(self, state: DescriptorArchive, transitions: Transition) -> Transition:
        reward = self.config.novelty_scale * novelty(state, transitions.next_desc, self.config.num_neighbours)
        return transitions._replace(reward=reward.astype(transitions.reward.dtype))

    def log_metrics(self, state: DescriptorArchive) -> dict[str, Array]:
        """The archive's size."""
        return {"novelty_archive_size": state.size}


def qdpg_emitter(
    batch_size: int,
    policy_network: hk.Transformed,
    obs_size: int,
    action_size: int,
    descriptor_size: int,
    config: PGConfig | None = None,
    shares: tuple[float, float, float] = (0.34, 0.33, 0.33),
    novelty_reward: NoveltyReward | None = None,
    make_ga: Callable[[int], Emitter] | None = None,
) -> MultiEmitter:
    """QD-PG's emitter (Pierrot et al. 2022): GA, Q-PG and D-PG share one batch by `shares`.

    Q-PG and D-PG are the same `PGEmitter` (same TD3 settings, each its own critic,
    greedy actor and replay buffer); D-PG's critic learns the novelty reward.
    """
    ga_size, q_size, d_size = split_batch(batch_size, shares)
    if min(ga_size, q_size, d_size) < 1:
        raise ValueError(
            f"batch_size: expected room for GA, Q-PG and D-PG with shares {shares}, got {batch_size}"
        )
    config = config or PGConfig()
    reward = novelty_reward or NoveltyReward(descriptor_size)
    ga = make_ga(ga_size) if make_ga is not None else isoline_emitter(ga_size, 0.005, 0.05)
    qpg = PGEmitter(q_size, policy_network, obs_size, action_size, config)
    dpg = PGEmitter(d_size, policy_network, obs_size, action_size, config, relabel=reward)
    return MultiEmitter((ga, qpg, dpg))


__all__ = [
    "DescriptorArchive",
    "NoveltyConfig",
    "NoveltyReward",
    "add_to_archive",
    "init_archive",
    "novelty",
    "qdpg_emitter",
]
