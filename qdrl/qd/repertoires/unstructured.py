"""Unstructured (distance-threshold) repertoire of fixed capacity, as in novelty search and AURORA.

The container has no predefined cells: an elite is kept when it lies far enough
from the others (Cully & Demiris 2018, "Quality and diversity optimization: a
unifying modular framework", unstructured archive; Cully 2019, AURORA, which also
adapts the threshold `l_value` to control the container's size).

Insertion rule, candidate by candidate (the batch is processed sequentially with
`jax.lax.scan`, so later candidates of a batch see the earlier ones):

- a fitness or descriptor that is not finite (NaN, +inf, -inf): rejected, never
  stored; subnormal fitnesses are flushed to 0 before comparing (as in every
  repertoire, `qdrl.qd.repertoires.cells.flush_subnormals`);
- NOVEL (distance to the nearest stored descriptor >= `l_value`, or the repertoire
  is empty): stored in the first free slot; rejected when the container is full;
- otherwise it competes with its nearest elite and REPLACES it only if strictly
  fitter AND its second-nearest elite is at distance >= `l_value`.

The second-nearest condition keeps the invariant that all stored descriptors are
pairwise at least `l_value` apart, so replacements never compress the archive.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult
from qdrl.qd.repertoires.cells import (
    Slots,
    check_batch,
    init_storage,
    valid_candidates,
    write_rows,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype

__all__ = ["UnstructuredRepertoire", "unstructured_repertoire"]


@dataclasses.dataclass(frozen=True, eq=False)
class UnstructuredRepertoire(Slots):
    """Fixed-capacity archive of elites kept at least `l_value` apart in descriptor space.

    Attributes:
      genotypes: pytree of stored genotypes, every leaf (K, ...); zeros in free
        slots; `None` for no genotype.
      fitnesses: (K,) float32, -inf in free slots.
      descriptors: (K, D) float32 (zeros in free slots).
      l_value: () float32 distance threshold; a leaf, so it can be adapted during a
        run (AURORA's container-size control) without recompiling.
    """

    genotypes: Genotype
    fitnesses: Array
    descriptors: Array
    l_value: Array

    def with_l_value(self, l_value: float | Array) -> UnstructuredRepertoire:
        """The same archive with a new threshold (stored elites are kept as they are)."""
        return dataclasses.replace(self, l_value=jnp.asarray(l_value, jnp.float32))

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[UnstructuredRepertoire, AddResult]:
        """Offers n candidates one after the other (see the module docstring for the rule).

        Returns:
          The new repertoire and an `AddResult`: `added`, `new_cell` (stored in a free
          slot as a novel elite), `improvement` (fitness minus the nearest elite's when
          it competed with it, the fitness itself when novel, -inf when rejected for
          a non-finite value), `cell` (the slot it was stored in or competed for; -1
          when rejected for a non-finite value or novel with no free slot).
        """
        descriptors, fitnesses = check_batch(
            self.genotypes, self.descriptor_dim, genotypes, descriptors, fitnesses, "add"
        )
        valid = valid_candidates(descriptors, fitnesses)
        capacity = self.capacity
        sq_l = self.l_value**2

        def step(
            store: tuple[Genotype, Array, Array], cand: tuple[Genotype, Array, Array, Array]
        ) -> tuple[tuple[Genotype, Array, Array], tuple[Array, Array, Array, Array]]:
            store_g, store_f, store_d = store
            g, d, f, ok = cand
            filled = store_f > -jnp.inf
            sq_dist = jnp.where(filled, jnp.sum((store_d - d) ** 2, axis=-1), jnp.inf)
            nearest = jnp.argmin(sq_dist).astype(jnp.int32)
            sq_second = jnp.min(sq_dist.at[nearest].set(jnp.inf))
            novel = sq_dist[nearest] >= sq_l
            free_slot = jnp.argmin(filled).astype(jnp.int32)  # first free slot, if any
            has_space = ~filled[free_slot]
            rival = store_f[nearest]
            add_new = ok & novel & has_space
            replace = ok & ~novel & (f > rival) & (sq_second >= sq_l)
            added = add_new | replace
            slot = jnp.where(novel, jnp.where(has_space, free_slot, -1), nearest)
            target = jnp.where(added, slot, capacity)[None]
            store = (
                write_rows(store_g, target, jax.tree_util.tree_map(lambda x: x[None], g)),
                store_f.at[target].set(f, mode="drop"),
                store_d.at[target].set(d[None], mode="drop"),
            )
            improvement = jnp.where(ok, jnp.where(novel, f, f - rival), -jnp.inf)
            return store, (added, add_new, improvement, jnp.where(ok, slot, -1))

        (new_g, new_f, new_d), (added, new_cell, improvement, cell) = jax.lax.scan(
            step,
            (self.genotypes, self.fitnesses, self.descriptors),
            (genotypes, descriptors, fitnesses, valid),
        )
        new = dataclasses.replace(self, genotypes=new_g, fitnesses=new_f, descriptors=new_d)
        return new, AddResult(
            added=added,
            new_cell=new_cell,
            improvement=improvement.astype(jnp.float32),
            cell=cell.astype(jnp.int32),
        )


jax.tree_util.register_dataclass(
    UnstructuredRepertoire,
    data_fields=["genotypes", "fitnesses", "descriptors", "l_value"],
    meta_fields=[],
)


def unstructured_repertoire(
    genotype_example: Genotype, capacity: int, descriptor_dim: int, l_value: float
) -> UnstructuredRepertoire:
    """An empty unstructured repertoire of `capacity` slots and distance threshold `l_value`.

    Args:
      genotype_example: one genotype, without batch axis (any pytree; `None` for no
        genotype).
      capacity: maximum number of elites K.
      descriptor_dim: descriptor dimension D.
      l_value: distance threshold (> 0) under which two descriptors compete.
    """
    if capacity <= 0 or descriptor_dim <= 0:
        raise ValueError(
            f"capacity and descriptor_dim must be positive, got {capacity}, {descriptor_dim}"
        )
    if not l_value > 0:
        raise ValueError(f"l_value must be > 0, got {l_value}")
    return UnstructuredRepertoire(
        genotypes=init_storage(genotype_example, capacity),
        fitnesses=jnp.full((capacity,), -jnp.inf, jnp.float32),
        descriptors=jnp.zeros((capacity, descriptor_dim), jnp.float32),
        l_value=jnp.asarray(l_value, jnp.float32),
    )
