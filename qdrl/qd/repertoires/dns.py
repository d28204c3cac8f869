"""Dominated Novelty Search: a fixed-size population kept by distance to fitter solutions.

Bahlous-Boldi, Faldor, Grillotti, Janmohamed, Coiffard, Spector & Cully 2025,
"Dominated Novelty Search: Rethinking Local Competition in Quality-Diversity".
No grid and no threshold: on `add`, the pool is the population and the
candidates together, and each member of the pool gets a competition fitness, the
mean descriptor-space (Euclidean) distance to its k nearest FITTER members of the
pool; the C members with the highest competition fitness survive.

- Fewer than k fitter members: the mean over those there are. None: +inf (the
  locally best solutions always survive, unless more than C of them compete).
- Who is fitter, `tie_rule`:
  - "qdax" (the default): a member of EQUAL fitness counts as fitter, as QDax's
    `DominatedNoveltyRepertoire` compares (f_j >= f_i) and as pyribs'
    `DNSArchive.compute_dns` code does too (its test expects equal fitnesses to
    count). The default because, on a fitness plateau (pure diversity search,
    pyribs' default objective 0), it turns DNS into novelty selection, where the
    strict rule gives every member of the plateau +inf and no pressure to spread.
  - "strict": only a strictly higher fitness counts (f_j > f_i), as the paper
    defines the fitter set and as pyribs 0.12's `DNSArchive` docstring states (its code
    compares with >=, the "qdax" rule); members tied at the best fitness all get +inf.
- Invalid: empty slots and candidates with a non-finite fitness or descriptor
  are not members (no neighbour of anyone) and never survive (competition -inf);
  subnormal fitnesses are flushed to 0 first (`flush_subnormals`).
- Equal competition fitness (several +inf, duplicates): the higher fitness
  survives first, then pool order (the population by slot, then the candidates
  in batch order), so an incumbent keeps its place against an equal newcomer.
- Fewer than C valid members in the pool: all survive and the rest stay empty.
- Slots: a surviving member keeps its slot; the surviving candidates fill the
  free slots (evicted or empty) lowest first, in batch order.
"""

from __future__ import annotations

import dataclasses
import numbers
from typing import Literal

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult
from qdrl.qd.neighbours import smallest_k, squared_distances
from qdrl.qd.repertoires.cells import (
    Slots,
    check_batch,
    init_storage,
    valid_candidates,
    write_rows,
)
from qdrl.types import Array, Descriptor, Fitness, Genotype

__all__ = ["TIE_RULES", "DNSPopulation", "TieRule", "competition_fitness", "dns_population"]

TieRule = Literal["qdax", "strict"]
TIE_RULES: tuple[str, ...] = ("qdax", "strict")


def competition_fitness(
    descriptors: Array, fitnesses: Array, members: Array, k: int, tie_rule: TieRule = "qdax"
) -> Array:
    """(P,) DNS competition fitness of each member of a pool; -inf for non-members.

    The mean distance to the min(k, number fitter) nearest fitter members of the
    pool (`tie_rule` says whether equal fitness counts as fitter; see the module
    docstring), +inf when no member is fitter.

    Args:
      descriptors: (P, D) descriptors of the pool (any finite value for non-members).
      fitnesses: (P,) fitnesses.
      members: (P,) bool, the rows that belong to the pool.
      k: neighbours (>= 1, static).
      tie_rule: "qdax" (f_j >= f_i counts as fitter) or "strict" (f_j > f_i).
    """
    if tie_rule not in TIE_RULES:
        raise ValueError(f"tie_rule must be one of {', '.join(TIE_RULES)}, got {tie_rule!r}")
    p = fitnesses.shape[0]
    sq = squared_distances(descriptors, descriptors)
    if tie_rule == "qdax":
        fitter = fitnesses[None, :] >= fitnesses[:, None]
    else:
        fitter = fitnesses[None, :] > fitnesses[:, None]
    fitter = fitter & members[:, None] & members[None, :] & ~jnp.eye(p, dtype=bool)
    k_eff = min(k, p - 1)
    if k_eff < 1:  # a pool of one row: nobody has a neighbour
        return jnp.where(members, jnp.inf, -jnp.inf)
    # The k smallest distances to fitter members, nearest first (+inf: fewer fitter).
    nearest, _ = smallest_k(jnp.where(fitter, sq, jnp.inf), k_eff)
    near = jnp.isfinite(nearest)
    dist = jnp.sqrt(jnp.where(near, nearest, 0.0))
    count = jnp.sum(near, axis=1)
    mean = jnp.sum(dist, axis=1) / jnp.maximum(count, 1).astype(dist.dtype)
    return jnp.where(members, jnp.where(count > 0, mean, jnp.inf), -jnp.inf)


@dataclasses.dataclass(frozen=True, eq=False)
class DNSPopulation(Slots):
    """Fixed-size Dominated Novelty Search population (see the module docstring for the rules).

    Attributes:
      genotypes: pytree of the members' genotypes, every leaf (C, ...); zeros in
        slots never filled; `None` for no genotype.
      fitnesses: (C,) float32, -inf in empty slots.
      descriptors: (C, D) float32 (zeros in slots never filled).
      k: fitter neighbours averaged by the competition fitness (static).
      tie_rule: "qdax" or "strict", whether equal fitness counts as fitter (static).
    """

    genotypes: Genotype
    fitnesses: Array
    descriptors: Array
    k: int = 3
    tie_rule: TieRule = "qdax"

    def competition_fitness(self) -> Array:
        """(C,) competition fitness of the members among themselves (-inf in empty slots)."""
        return competition_fitness(self.descriptors, self.fitnesses, self.filled, self.k, self.tie_rule)

    def add(
        self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness
    ) -> tuple[DNSPopulation, AddResult]:
        """Merges n candidates with the population and keeps the C of highest competition fitness.

        Returns:
          The new population and an `AddResult`: `added` (the candidate survived),
          `new_cell` (it survived into a slot that was empty before the batch),
          `improvement` (1.0 for a survivor, 0.0 otherwise, -inf when rejected as
          non-finite, as `ParetoPopulation`), `cell` (its slot, -1 if it did not
          survive), `status` (2 survived, 0 not, as pyribs' `DNSArchive`), `value`
          and `info["competition_fitness"]` (its competition fitness in the pool,
          -inf when rejected as non-finite).
        """
        descriptors, fitnesses = check_batch(
            self.genotypes, self.descriptor_dim, genotypes, descriptors, fitnesses, "add"
        )
        valid = valid_candidates(descriptors, fitnesses)
        c, n = self.capacity, fitnesses.shape[0]
        total = c + n
        pool_f = jnp.concatenate([self.fitnesses, jnp.where(valid, fitnesses, -jnp.inf)])
        pool_d = jnp.concatenate([self.descriptors, jnp.where(valid[:, None], descriptors, 0.0)])
        members = jnp.concatenate([self.filled, valid])
        comp = competition_fitness(pool_d, pool_f, members, self.k, self.tie_rule)

        order = jnp.lexsort((jnp.arange(total), -pool_f, -comp))  # best first
        rank = jnp.zeros((total,), jnp.int32).at[order].set(jnp.arange(total, dtype=jnp.int32))
        survive = members & (rank < c)
        keep, chosen = survive[:c], survive[c:]

        # The j-th surviving candidate (batch order) takes the j-th free slot.
        free = ~keep
        free_slots = jnp.full((c,), c, jnp.int32).at[
            jnp.where(free, jnp.cumsum(free, dtype=jnp.int32) - 1, c)
        ].set(jnp.arange(c, dtype=jnp.int32), mode="drop")
        cell = jnp.where(chosen, free_slots[jnp.clip(jnp.cumsum(chosen) - 1, 0, c - 1)], -1)
        target = jnp.where(chosen, cell, c)

        new = dataclasses.replace(
            self,
            genotypes=write_rows(self.genotypes, target, genotypes),
            fitnesses=jnp.where(keep, self.fitnesses, -jnp.inf).at[target].set(fitnesses, mode="drop"),
            descriptors=self.descriptors.at[target].set(descriptors, mode="drop"),
        )
        cand_comp = comp[c:].astype(jnp.float32)
        return new, AddResult(
            added=chosen,
            new_cell=chosen & ~self.filled[jnp.clip(cell, 0, c - 1)],
            improvement=jnp.where(valid, chosen.astype(jnp.float32), -jnp.inf),
            cell=cell.astype(jnp.int32),
            status=jnp.where(chosen, 2, 0).astype(jnp.int32),
            value=cand_comp,
            info={"competition_fitness": cand_comp},
        )


jax.tree_util.register_dataclass(
    DNSPopulation,
    data_fields=["genotypes", "fitnesses", "descriptors"],
    meta_fields=["k", "tie_rule"],
)


def dns_population(
    genotype_example: Genotype,
    capacity: int,
    descriptor_dim: int,
    k: int,
    tie_rule: TieRule = "qdax",
) -> DNSPopulation:
    """An empty Dominated Novelty Search population of `capacity` slots.

    Args:
      genotype_example: one genotype, without batch axis (any pytree; `None` for no
        genotype).
      capacity: population size C (>= 1).
      descriptor_dim: descriptor dimension D (>= 1).
      k: fitter neighbours averaged by the competition fitness (>= 1).
      tie_rule: "qdax" (default: equal fitness counts as fitter) or "strict"
        (strictly fitter only); see the module docstring.

    Raises:
      ValueError: naming the parameter, for a value outside its range.
    """
    for name, value in (("capacity", capacity), ("descriptor_dim", descriptor_dim), ("k", k)):
        if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < 1:
            raise ValueError(f"dns_population: {name} must be an int >= 1, got {value!r}")
    if tie_rule not in TIE_RULES:
        raise ValueError(
            f"dns_population: tie_rule must be one of {', '.join(TIE_RULES)}, got {tie_rule!r}"
        )
    return DNSPopulation(
        genotypes=init_storage(genotype_example, capacity),
        fitnesses=jnp.full((capacity,), -jnp.inf, jnp.float32),
        descriptors=jnp.zeros((capacity, descriptor_dim), jnp.float32),
        k=int(k),
        tie_rule=tie_rule,
    )
