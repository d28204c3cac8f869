"""Proximity (novelty) archive of fixed capacity: novelty search, optionally with local competition.

Novelty search (Lehman & Stanley 2011, "Abandoning objectives: evolution through
the search for novelty alone"): a candidate's novelty is the mean Euclidean
distance, in descriptor space, to its k nearest archive members, and it enters
the archive when its novelty reaches the threshold. With `local_competition`
(NSLC: Lehman & Stanley 2011b, "Evolving a diversity of virtual creatures through
novelty search and local competition") its local competition is the number of
those k neighbours it is strictly fitter than, and a candidate that is not novel
enough replaces its nearest member when strictly fitter. pyribs'
`ProximityArchive` is the reference; the rules below are its rules, with a fixed
capacity (JAX needs static shapes) and an optional threshold decay added.

Rules for a batch of n candidates (jittable, fixed shapes):

- Batch semantics (pyribs'): every candidate is judged against the archive as it
  was BEFORE the batch, then the admitted ones are written together. Two
  candidates of one batch never see each other: both may enter even when they lie
  next to each other (where `UnstructuredRepertoire` inserts one after the other).
- Fewer than k members: the novelty is the mean distance to all of them
  (k_eff = min(k, members), as pyribs). An EMPTY archive gives every candidate
  novelty = the threshold (so all enter, capacity permitting) and local
  competition 0, as pyribs.
- A fitness or descriptor that is not finite: rejected (status 0, cell -1,
  novelty -inf); subnormal fitnesses are flushed to 0 first (`flush_subnormals`).
- Novel (novelty >= threshold): stored in a free slot (status 2). Slots fill in
  order, so the members are always slots [0, num_filled).
- Capacity: when the batch holds more novel candidates than free slots, the MOST
  novel ones take them (equal novelty: batch order); the others are rejected
  (status 0, cell -1) and members are never evicted. Evicting a member would need
  the novelty of every member among the others (C x C distances per add), and an
  archive that forgets admitted points would let the search return to them; a
  full archive still improves under local competition (next rule).
- Local competition only, not novel: the candidate competes with its nearest
  member (lowest slot on equal distance) and beats it when strictly fitter
  (status 1). When several candidates of the batch beat the same member, the
  fittest replaces it (equal fitness: the first in the batch); the others keep
  status 1 (as pyribs: they beat the member) but are not stored (`added` False).
  Without local competition a non-novel candidate is never stored.
- Threshold decay: after each call of `add` (one iteration) the counter
  `iterations` increases, and every `decay_every` iterations the threshold becomes
  max(threshold x `threshold_decay`, `threshold_min`). The default decay 1.0 keeps
  the threshold fixed, as pyribs.

`value` (and `improvement`) is pyribs' local-competition value: the fitness for a
stored novel candidate, fitness minus the nearest member's fitness otherwise, -inf
for a rejected non-finite one. pyribs returns it only with local competition; here
it is filled in both modes, so the `imp` / `2imp` rankers work on either.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult
from qdrl.qd.neighbours import nearest_in_prefix
from qdrl.qd.repertoires.cells import (
    Slots,
    check_batch,
    init_storage,
    valid_candidates,
    write_rows,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype

__all__ = ["ProximityArchive", "proximity_archive"]

NEIGHBOUR_BLOCK = 4096  # slots compared with a batch at once in the nearest-neighbour search

NOT_ADDED, IMPROVED, NEW = 0, 1, 2


@dataclasses.dataclass(frozen=True, eq=False)
class ProximityArchive(Slots):
    """Fixed-capacity novelty archive (see the module docstring for the rules).

    Attributes:
      genotypes: pytree of stored genotypes, every leaf (C, ...); zeros in free
        slots; `None` for no genotype.
      fitnesses: (C,) float32, -inf in free slots.
      descriptors: (C, D) float32 (zeros in free slots).
      novelty_threshold: () float32, the novelty a candidate needs to enter.
      iterations: () int32, calls of `add` so far (they drive the threshold decay).
      k_neighbors: neighbours k of the novelty (static).
      local_competition: NSLC's replacement rule and local-competition scores (static).
      threshold_decay: factor applied to the threshold every `decay_every` adds
        (static; 1.0: no decay).
      decay_every: adds between two decays (static).
      threshold_min: floor of the decayed threshold (static).
    """

    genotypes: Genotype
    fitnesses: Array
    descriptors: Array
    novelty_threshold: Array
    iterations: Array
    k_neighbors: int = 15
    local_competition: bool = False
    threshold_decay: float = 1.0
    decay_every: int = 1
    threshold_min: float = 0.0

    def with_threshold(self, novelty_threshold: float | Array) -> ProximityArchive:
        """The same archive with a new threshold (members are kept as they are)."""
        return dataclasses.replace(
            self, novelty_threshold=jnp.asarray(novelty_threshold, jnp.float32)
        )

    def _neighbours(self, descriptors: Array) -> tuple[Array, Array, Array]:
        """(distances (n, k), slots (n, k), is_member (n, k)) of the k nearest slots, nearest first.

        Members fill the slots in order and are never removed, so they are the first
        `num_filled` slots: the search (`qdrl.qd.neighbours.nearest_in_prefix`) reads only the
        blocks of NEIGHBOUR_BLOCK slots that hold members, so its cost grows with the archive,
        not with its capacity. On equal distance the lower slot comes first; free slots (+inf)
        come after every member.
        """
        k = min(self.k_neighbors, self.capacity)
        sq, slots = nearest_in_prefix(descriptors, self.descriptors, self.num_filled, k, NEIGHBOUR_BLOCK)
        member = jnp.isfinite(sq) & self.filled[slots]
        return jnp.sqrt(jnp.where(member, sq, 0.0)), slots, member

    def _scores(self, descriptors: Array, fitnesses: Array | None) -> tuple[Array, Array, Array]:
        """(novelty (n,), local competition (n,) int32, nearest slot (n,)); see `novelty`."""
        dist, slots, member = self._neighbours(descriptors)
        count = jnp.sum(member, axis=1)
        novelty = jnp.where(
            count > 0,
            jnp.sum(dist, axis=1) / jnp.maximum(count, 1).astype(jnp.float32),
            self.novelty_threshold,
        )
        if fitnesses is None:
            local = jnp.zeros(novelty.shape, jnp.int32)
        else:
            beaten = member & (self.fitnesses[slots] < fitnesses[:, None])
            local = jnp.sum(beaten, axis=1, dtype=jnp.int32)
        return novelty, local, slots[:, 0]

    def novelty(self, descriptors: Descriptor, fitnesses: Fitness | None = None) -> tuple[Array, Array]:
        """(novelty (n,), local competition (n,) int32) of descriptors against the archive as it is.

        Novelty: mean distance to the min(k, num_filled) nearest members; the
        threshold when the archive is empty. Local competition: how many of those
        members have a strictly lower fitness than `fitnesses` (zeros without
        `fitnesses` or when the archive is empty). No finiteness check: `add` does it.
        """
        f = None if fitnesses is None else jnp.asarray(fitnesses, jnp.float32)
        novelty, local, _ = self._scores(jnp.asarray(descriptors, jnp.float32), f)
        return novelty, local

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[ProximityArchive, AddResult]:
        """Offers n candidates, judged against the archive before the batch (module docstring).

        Returns:
          The new archive (its threshold decayed when due) and an `AddResult`:
          `added` (stored), `new_cell` (stored in a free slot as novel),
          `improvement` = `value`, `cell` (the slot it was stored in or competed for;
          -1 when rejected as non-finite or novel without a free slot), `status`
          (2 novel and stored, 1 beat its nearest member (local competition), 0
          otherwise), `value` (see the module docstring) and `info` with
          "novelty" (n,) float32 (-inf when rejected as non-finite) and
          "local_competition" (n,) int32 (zeros without local competition).
        """
        descriptors, fitnesses = check_batch(
            self.genotypes, self.descriptor_dim, genotypes, descriptors, fitnesses, "add"
        )
        valid = valid_candidates(descriptors, fitnesses)
        n, capacity = fitnesses.shape[0], self.capacity
        index = jnp.arange(n, dtype=jnp.int32)
        # Rejected rows get a harmless descriptor so that nothing NaN enters the sums.
        safe_d = jnp.where(valid[:, None], descriptors, 0.0)
        novelty, local, nearest = self._scores(safe_d, fitnesses)
        rival = self.fitnesses[nearest]  # -inf when the archive is empty

        novel = valid & (novelty >= self.novelty_threshold)
        # The most novel candidates take the free slots (equal novelty: batch order).
        free = capacity - self.num_filled
        order = jnp.argsort(-jnp.where(novel, novelty, -jnp.inf), stable=True)
        rank = jnp.zeros((n,), jnp.int32).at[order].set(index)
        admit = novel & (rank < free)
        slot = self.num_filled + jnp.cumsum(admit, dtype=jnp.int32) - 1  # batch order

        if self.local_competition:
            beats = valid & ~novel & (fitnesses > rival)
            # One winner per member: the fittest of those that beat it, then the first.
            seg = jnp.where(beats, nearest, capacity)
            best = jax.ops.segment_max(
                jnp.where(beats, fitnesses, -jnp.inf), seg, num_segments=capacity + 1
            )
            top = beats & (fitnesses == best[seg])
            first = jax.ops.segment_min(
                jnp.where(top, index, n), seg, num_segments=capacity + 1
            )
            replace = top & (index == first[seg])
        else:
            beats = jnp.zeros((n,), bool)
            replace = beats
            local = jnp.zeros((n,), jnp.int32)

        target = jnp.where(admit, slot, jnp.where(replace, nearest, capacity))
        new_g = write_rows(self.genotypes, target, genotypes)
        new_f = self.fitnesses.at[target].set(fitnesses, mode="drop")
        new_d = self.descriptors.at[target].set(descriptors, mode="drop")

        iterations = self.iterations + 1
        due = iterations % self.decay_every == 0
        decayed = jnp.maximum(
            self.novelty_threshold * jnp.float32(self.threshold_decay),
            jnp.float32(self.threshold_min),
        )
        new = dataclasses.replace(
            self,
            genotypes=new_g,
            fitnesses=new_f,
            descriptors=new_d,
            novelty_threshold=jnp.where(due, decayed, self.novelty_threshold),
            iterations=iterations,
        )

        status = jnp.where(admit, NEW, jnp.where(beats, IMPROVED, NOT_ADDED)).astype(jnp.int32)
        margin = jnp.where(rival > -jnp.inf, fitnesses - rival, fitnesses)
        value = jnp.where(valid, jnp.where(admit, fitnesses, margin), -jnp.inf).astype(jnp.float32)
        cell = jnp.where(admit, slot, jnp.where(valid & ~novel, nearest, -1)).astype(jnp.int32)
        return new, AddResult(
            added=admit | replace,
            new_cell=admit,
            improvement=value,
            cell=cell,
            status=status,
            value=value,
            info={
                "novelty": jnp.where(valid, novelty, -jnp.inf).astype(jnp.float32),
                "local_competition": jnp.where(valid, local, 0).astype(jnp.int32),
            },
        )


jax.tree_util.register_dataclass(
    ProximityArchive,
    data_fields=["genotypes", "fitnesses", "descriptors", "novelty_threshold", "iterations"],
    meta_fields=[
        "k_neighbors", "local_competition", "threshold_decay", "decay_every", "threshold_min",
    ],
)


def _is_int(x: object) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


def _is_real(x: object) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def proximity_archive(
    genotype_example: Genotype,
    capacity: int,
    descriptor_dim: int,
    k_neighbors: int,
    novelty_threshold: float,
    local_competition: bool = False,
    threshold_decay: float = 1.0,
    decay_every: int = 1,
    threshold_min: float = 0.0,
) -> ProximityArchive:
    """An empty proximity archive (novelty search; NSLC with `local_competition`).

    Args:
      genotype_example: one genotype, without batch axis (any pytree; `None` for no
        genotype).
      capacity: maximum number of members C (>= 1).
      descriptor_dim: descriptor dimension D (>= 1).
      k_neighbors: neighbours k of the novelty (>= 1).
      novelty_threshold: novelty a candidate needs to enter (finite, > 0).
      local_competition: NSLC: non-novel candidates may replace their nearest
        member, and `info["local_competition"]` is computed.
      threshold_decay: factor in (0, 1] applied to the threshold every
        `decay_every` calls of `add` (1.0: a fixed threshold, as pyribs).
      decay_every: calls of `add` between two decays (>= 1).
      threshold_min: floor of the decayed threshold, in [0, novelty_threshold].

    Raises:
      ValueError: naming the parameter, for a value outside its range.
    """

    def bad(name: str, expected: str, got: object) -> ValueError:
        return ValueError(f"proximity_archive: {name} must be {expected}, got {got!r}")

    if not _is_int(capacity) or capacity < 1:
        raise bad("capacity", "an int >= 1", capacity)
    if not _is_int(descriptor_dim) or descriptor_dim < 1:
        raise bad("descriptor_dim", "an int >= 1", descriptor_dim)
    if not _is_int(k_neighbors) or k_neighbors < 1:
        raise bad("k_neighbors", "an int >= 1", k_neighbors)
    if not (_is_real(novelty_threshold) and 0 < novelty_threshold < math.inf):
        raise bad("novelty_threshold", "a finite number > 0", novelty_threshold)
    if not (_is_real(threshold_decay) and 0 < threshold_decay <= 1):
        raise bad("threshold_decay", "a number in (0, 1]", threshold_decay)
    if not _is_int(decay_every) or decay_every < 1:
        raise bad("decay_every", "an int >= 1", decay_every)
    if not (_is_real(threshold_min) and 0 <= threshold_min <= novelty_threshold):
        raise bad("threshold_min", f"a number in [0, novelty_threshold={novelty_threshold}]", threshold_min)
    return ProximityArchive(
        genotypes=init_storage(genotype_example, capacity),
        fitnesses=jnp.full((capacity,), -jnp.inf, jnp.float32),
        descriptors=jnp.zeros((capacity, descriptor_dim), jnp.float32),
        novelty_threshold=jnp.asarray(novelty_threshold, jnp.float32),
        iterations=jnp.zeros((), jnp.int32),
        k_neighbors=int(k_neighbors),
        local_competition=bool(local_competition),
        threshold_decay=float(threshold_decay),
        decay_every=int(decay_every),
        threshold_min=float(threshold_min),
    )
