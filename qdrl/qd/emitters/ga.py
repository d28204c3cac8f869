"""Genetic variation operators and the GA emitter of MAP-Elites.

Operators act on pytrees of genotypes whose leaves carry a leading batch axis;
each individual is treated independently. The emitter is QDax's `MixingEmitter`:
part of the batch comes from a two-parent variation (crossover), the rest from a
one-parent mutation, all parents drawn uniformly from the repertoire.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, Literal

import jax
import jax.numpy as jnp

from qdrl.config import NonNegativeFloat, PositiveInt, UnitFloat, check_fields
from qdrl.qd.base import AddResult, Evaluation, Repertoire
from qdrl.qd.emitters.multi import concat_batches
from qdrl.types import Array, Genotype, PRNGKey

VariationFn = Callable[[Genotype, Genotype, PRNGKey], Genotype]
"""(parents_1, parents_2, key) -> offspring, all with the same batch size."""
MutationFn = Callable[[Genotype, PRNGKey], Genotype]
"""(parents, key) -> offspring of the same shape."""


def _batch_size(x: Genotype) -> int:
    leaves = jax.tree.leaves(x)
    if not leaves:
        raise ValueError("genotypes: expected a pytree with at least one array leaf")
    return int(leaves[0].shape[0])


def _same_structure_leaves(treedef: Any, x2: Genotype) -> list[Array]:
    if jax.tree.structure(x2) != treedef:
        raise ValueError(f"parents differ in structure: {treedef} vs {jax.tree.structure(x2)}")
    return list(jax.tree.leaves(x2))


def _per_individual(leaf: Array) -> Array:
    """A leaf (n, ...) flattened to (n, d): operators pick genes over all of an individual's entries."""
    return leaf.reshape(leaf.shape[0], -1)


def isoline_variation(
    x1: Genotype,
    x2: Genotype,
    key: PRNGKey,
    iso_sigma: float,
    line_sigma: float,
    minval: float | None = None,
    maxval: float | None = None,
) -> Genotype:
    """Iso+LineDD: x = x1 + iso_sigma N(0, I) + line_sigma N(0, 1) (x2 - x1), optionally clipped.

    Vassiliades & Mouret 2018, "Discovering the elite hypervolume by leveraging
    interspecies correlation" (GECCO). The line coefficient is one scalar per
    individual, shared by all leaves of its pytree (as QDax 0.5.0 draws it; one per
    gene would lose the "line" direction). All the noise is one flat draw,
    `normal(key, (n * (1 + d),))` with d the number of entries of an individual over
    all its leaves: its first n values are the line coefficients, then each leaf in
    flattening order takes the next n * size values, reshaped to the leaf's (n, ...).
    One random-number program instead of one per leaf and one for the line (a policy
    of six leaves compiles six fewer; on a GPU, launches six fewer kernel groups), and
    a flat one: XLA's code for a one-dimensional draw is smaller than for an (n, d) one.
    """
    leaves_1, treedef = jax.tree.flatten(x1)
    leaves_2 = _same_structure_leaves(treedef, x2)
    n = _batch_size(x1)
    sizes = [math.prod(a.shape[1:]) for a in leaves_1]
    noise = jax.random.normal(key, (n * (1 + sum(sizes)),))
    line = noise[:n]
    children = []
    start = n
    for a, b, size in zip(leaves_1, leaves_2, sizes, strict=True):
        if a.shape != b.shape:
            raise ValueError(f"isoline_variation: parents differ in shape, {a.shape} vs {b.shape}")
        coeff = line.reshape((n,) + (1,) * (a.ndim - 1)).astype(a.dtype)
        iso = noise[start : start + n * size].reshape(a.shape).astype(a.dtype)
        start += n * size
        child = a + iso_sigma * iso + line_sigma * coeff * (b - a)
        if minval is not None or maxval is not None:
            child = jnp.clip(child, minval, maxval)
        children.append(child)
    return jax.tree.unflatten(treedef, children)


def _gene_masks(key: PRNGKey, n: int, d: int, num: int) -> Array:
    """(n, d) bool, each row with exactly `num` True entries at uniformly random positions."""
    if num == 0:
        return jnp.zeros((n, d), bool)
    if num == d:
        return jnp.ones((n, d), bool)
    # the `num` smallest of d iid uniforms are a uniform subset; one batched argsort compiles
    # much faster than a vmapped jax.random.permutation
    ranks = jnp.argsort(jnp.argsort(jax.random.uniform(key, (n, d)), axis=1), axis=1)
    return ranks < num


def _polynomial_mutation_leaf(
    x: Array, key: PRNGKey, eta: float, num_to_mutate: int, minval: float, maxval: float
) -> Array:
    """Mutates `num_to_mutate` entries of each row of x (n, d)."""
    mask_key, rand_key = jax.random.split(key)
    mask = _gene_masks(mask_key, x.shape[0], x.shape[1], num_to_mutate)
    return _polynomial_step(x, mask, rand_key, eta, minval, maxval)


def _polynomial_step(
    x: Array, mask: Array, rand_key: PRNGKey, eta: float, minval: float, maxval: float
) -> Array:
    """Deb's bounded polynomial mutation of the entries of x (n, d) where `mask` is True."""
    span = maxval - minval
    x = jnp.clip(x, minval, maxval)
    delta_1 = (x - minval) / span
    delta_2 = (maxval - x) / span
    rand = jax.random.uniform(rand_key, x.shape, x.dtype)
    power = 1.0 / (eta + 1.0)
    low_side = (2.0 * rand + (1.0 - 2.0 * rand) * (1.0 - delta_1) ** (eta + 1.0)) ** power - 1.0
    high_side = (
        1.0 - (2.0 * (1.0 - rand) + 2.0 * (rand - 0.5) * (1.0 - delta_2) ** (eta + 1.0)) ** power
    )
    delta_q = jnp.where(rand < 0.5, low_side, high_side)
    mutated = jnp.where(mask, x + delta_q * span, x)
    return jnp.clip(mutated, minval, maxval)


def polynomial_mutation(
    x: Genotype,
    key: PRNGKey,
    eta: float,
    proportion_to_mutate: float,
    minval: float,
    maxval: float,
) -> Genotype:
    """Deb's bounded polynomial mutation of `floor(proportion_to_mutate * d)` genes per individual.

    Deb & Goyal 1996, "A combined genetic adaptive search (GeneAS) for engineering
    design"; the bounded form of NSGA-II / pymoo. For a chosen gene x in
    [minval, maxval] with delta_1 = (x - minval) / (maxval - minval), delta_2 =
    (maxval - x) / (maxval - minval), u ~ U(0, 1) and p = 1 / (eta + 1):
    delta_q = (2u + (1 - 2u)(1 - delta_1)^(eta+1))^p - 1 if u < 0.5, else
    1 - (2(1 - u) + 2(u - 0.5)(1 - delta_2)^(eta+1))^p; x' = x + delta_q
    (maxval - minval), which stays in the bounds. Larger eta, smaller steps. The
    genes are chosen without replacement, as in QDax; QDax writes delta_i where
    Deb writes 1 - delta_i (and clips the result). The whole output is clipped to
    [minval, maxval]; d counts all entries of an individual in each leaf. Keys:
    leaf i uses `mask_key, rand_key = split(split(key, num_leaves)[i])`, with
    u = `uniform(rand_key, (n, d))`.
    """
    if not 0.0 <= proportion_to_mutate <= 1.0:
        raise ValueError(f"proportion_to_mutate must be in [0, 1], got {proportion_to_mutate}")
    if not minval < maxval:
        raise ValueError(f"minval ({minval}) must be below maxval ({maxval})")
    leaves, treedef = jax.tree.flatten(x)
    _batch_size(x)
    leaf_keys = jax.random.split(key, len(leaves))
    children = []
    for leaf, leaf_key in zip(leaves, leaf_keys, strict=True):
        flat = _per_individual(leaf)
        num = int(proportion_to_mutate * flat.shape[1])
        child = _polynomial_mutation_leaf(flat, leaf_key, eta, num, minval, maxval)
        children.append(child.reshape(leaf.shape))
    return jax.tree.unflatten(treedef, children)


def polynomial_crossover(
    x1: Genotype,
    x2: Genotype,
    key: PRNGKey,
    proportion_var_to_change: float,
) -> Genotype:
    """QDax's "polynomial crossover": x1 with `floor(proportion_var_to_change * d)` genes taken from x2.

    Despite its name this is a uniform gene exchange (QDax
    `mutation_operators.polynomial_crossover`): per individual, that many gene
    positions, drawn uniformly without replacement (QDax draws with replacement,
    so it may change fewer), are copied from the second parent.
    """
    if not 0.0 <= proportion_var_to_change <= 1.0:
        raise ValueError(
            f"proportion_var_to_change must be in [0, 1], got {proportion_var_to_change}"
        )
    leaves_1, treedef = jax.tree.flatten(x1)
    leaves_2 = _same_structure_leaves(treedef, x2)
    n = _batch_size(x1)
    leaf_keys = jax.random.split(key, len(leaves_1))
    children = []
    for a, b, leaf_key in zip(leaves_1, leaves_2, leaf_keys, strict=True):
        if a.shape != b.shape:
            raise ValueError(
                f"polynomial_crossover: parents differ in shape, {a.shape} vs {b.shape}"
            )
        flat_a, flat_b = _per_individual(a), _per_individual(b)
        d = flat_a.shape[1]
        masks = _gene_masks(leaf_key, n, d, int(proportion_var_to_change * d))
        children.append(jnp.where(masks, flat_b, flat_a).reshape(a.shape))
    return jax.tree.unflatten(treedef, children)


def bernoulli_polynomial_mutation(
    x: Genotype, key: PRNGKey, eta: float, mutation_prob: float, minval: float, maxval: float
) -> Genotype:
    """Deb's bounded polynomial mutation of each gene independently with probability `mutation_prob`.

    The mutation of NSGA-II (Deb et al. 2002) and pymoo's `PM` (`prob_var`, usually
    1/d): the same step as `polynomial_mutation`, but every gene is mutated with
    probability `mutation_prob` rather than a fixed number of genes per individual.
    Keys: leaf i uses `mask_key, rand_key = split(split(key, num_leaves)[i])`.
    """
    if not 0.0 <= mutation_prob <= 1.0:
        raise ValueError(f"mutation_prob must be in [0, 1], got {mutation_prob}")
    if not minval < maxval:
        raise ValueError(f"minval ({minval}) must be below maxval ({maxval})")
    leaves, treedef = jax.tree.flatten(x)
    leaf_keys = jax.random.split(key, len(leaves))
    children = []
    for leaf, leaf_key in zip(leaves, leaf_keys, strict=True):
        flat = _per_individual(leaf)
        mask_key, rand_key = jax.random.split(leaf_key)
        mask = jax.random.bernoulli(mask_key, mutation_prob, flat.shape)
        child = _polynomial_step(flat, mask, rand_key, eta, minval, maxval)
        children.append(child.reshape(leaf.shape))
    return jax.tree.unflatten(treedef, children)


def _sbx_leaf(
    a: Array, b: Array, key: PRNGKey, eta: float, minval: float, maxval: float,
    crossover_prob: float, prob_var: float,
) -> Array:
    """One SBX child of each pair of rows of a, b (n, d) (see `sbx_crossover`)."""
    pair_key, var_key, u_key, swap_key = jax.random.split(key, 4)
    n, d = a.shape
    crossed = jax.random.bernoulli(pair_key, crossover_prob, (n, 1)) & jax.random.bernoulli(
        var_key, prob_var, (n, d)
    )
    crossed = crossed & (jnp.abs(a - b) > 1e-14)
    y1, y2 = jnp.minimum(a, b), jnp.maximum(a, b)
    gap = jnp.where(crossed, y2 - y1, 1.0)
    u = jax.random.uniform(u_key, (n, d), a.dtype)
    power = 1.0 / (eta + 1.0)

    def spread(beta: Array) -> Array:
        alpha = 2.0 - beta ** -(eta + 1.0)
        return jnp.where(
            u <= 1.0 / alpha, (u * alpha) ** power, (1.0 / (2.0 - u * alpha)) ** power
        )

    c1 = 0.5 * (y1 + y2 - spread(1.0 + 2.0 * (y1 - minval) / gap) * (y2 - y1))
    c2 = 0.5 * (y1 + y2 + spread(1.0 + 2.0 * (maxval - y2) / gap) * (y2 - y1))
    c1, c2 = jnp.clip(c1, minval, maxval), jnp.clip(c2, minval, maxval)
    child = jnp.where(jax.random.bernoulli(swap_key, 0.5, (n, d)), c2, c1)
    return jnp.where(crossed, child, a)


def sbx_crossover(
    x1: Genotype,
    x2: Genotype,
    key: PRNGKey,
    eta: float,
    minval: float,
    maxval: float,
    crossover_prob: float = 0.9,
    prob_var: float = 0.5,
) -> Genotype:
    """Simulated binary crossover, bounded (Deb & Agrawal 1995; NSGA-II, Deb et al. 2002).

    Each pair crosses with probability `crossover_prob` (else the child is x1), and
    then each gene with probability `prob_var` (and only where the parents differ).
    For parents y1 <= y2 in [minval, maxval] and u ~ U(0, 1), with
    beta = 1 + 2 (y1 - minval) / (y2 - y1) on the low side (1 + 2 (maxval - y2) /
    (y2 - y1) on the high side), alpha = 2 - beta^-(eta+1) and
    beta_q = (u alpha)^(1/(eta+1)) if u <= 1/alpha else (1 / (2 - u alpha))^(1/(eta+1)),
    the two children are (y1 + y2 -/+ beta_q (y2 - y1)) / 2, clipped to the bounds;
    the bounded form of Deb's NSGA-II code and pymoo's `SBX`. pymoo keeps both
    children of a pair (swapping each gene between them with probability 1/2);
    here each pair gives one child, one of the two values at random per gene, so
    that a batch of n pairs gives n offspring. Larger eta, children closer to the
    parents.
    """
    for name, p in (("crossover_prob", crossover_prob), ("prob_var", prob_var)):
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"{name} must be in [0, 1], got {p}")
    if not minval < maxval:
        raise ValueError(f"minval ({minval}) must be below maxval ({maxval})")
    leaves_1, treedef = jax.tree.flatten(x1)
    leaves_2 = _same_structure_leaves(treedef, x2)
    leaf_keys = jax.random.split(key, len(leaves_1))
    children = []
    for a, b, k in zip(leaves_1, leaves_2, leaf_keys, strict=True):
        if a.shape != b.shape:
            raise ValueError(f"sbx_crossover: parents differ in shape, {a.shape} vs {b.shape}")
        child = _sbx_leaf(
            _per_individual(a), _per_individual(b), k, eta, minval, maxval, crossover_prob, prob_var
        )
        children.append(child.reshape(a.shape))
    return jax.tree.unflatten(treedef, children)


@dataclasses.dataclass(eq=False)
class GAEmitter:
    """MAP-Elites' genetic emitter: variation of two parents and mutation of one (QDax `MixingEmitter`).

    Mouret & Clune 2015, "Illuminating search spaces by mapping elites". The first
    `num_variation = floor(batch_size * variation_percentage)` offspring are
    `variation_fn(p1, p2, key)` of parents drawn uniformly from the repertoire, the
    remaining `num_mutation` are `mutation_fn(p, key)`. Stateless (state None).
    """

    batch_size: int
    variation_fn: VariationFn | None
    mutation_fn: MutationFn | None
    variation_percentage: float

    def __post_init__(self) -> None:
        if self.batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {self.batch_size}")
        if not 0.0 <= self.variation_percentage <= 1.0:
            raise ValueError(
                f"variation_percentage must be in [0, 1], got {self.variation_percentage}"
            )
        if self.num_variation > 0 and self.variation_fn is None:
            raise ValueError(
                f"{self.num_variation} offspring per batch come from variation but variation_fn is None"
            )
        if self.num_mutation > 0 and self.mutation_fn is None:
            raise ValueError(
                f"{self.num_mutation} offspring per batch come from mutation but mutation_fn is None"
            )

    @property
    def num_variation(self) -> int:
        """Offspring per batch made by `variation_fn` (the first ones)."""
        # the epsilon keeps e.g. 0.29 * 100 = 28.999999999999996 at 29
        return min(self.batch_size, math.floor(self.batch_size * self.variation_percentage + 1e-9))

    @property
    def num_mutation(self) -> int:
        """Offspring per batch made by `mutation_fn` (the last ones)."""
        return self.batch_size - self.num_variation

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> None:
        """No state."""
        del key, repertoire, evaluation, genotypes
        return None

    def emit(self, state: None, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """`batch_size` offspring: variations first, then mutations.

        Keys: `sample_key, key_variation, key_mutation = split(key, 3)`. All parents
        come from ONE `repertoire.sample(sample_key, 2 * num_variation +
        num_mutation)`: the first `num_variation` are the first parents of the
        variations, the next `num_variation` their second parents, the rest the
        mutated ones (one draw instead of three: fewer kernels on a GPU).
        """
        del state
        sample_key, key_variation, key_mutation = jax.random.split(key, 3)
        nv, nm = self.num_variation, self.num_mutation
        parents = repertoire.sample(sample_key, 2 * nv + nm)

        def rows(start: int, stop: int) -> Genotype:
            return jax.tree.map(lambda x: x[start:stop], parents)

        parts = []
        if nv > 0:
            assert self.variation_fn is not None
            parts.append(self.variation_fn(rows(0, nv), rows(nv, 2 * nv), key_variation))
        if nm > 0:
            assert self.mutation_fn is not None
            parts.append(self.mutation_fn(rows(2 * nv, 2 * nv + nm), key_mutation))
        return concat_batches(parts)

    def update(
        self,
        state: None,
        repertoire: Repertoire,
        genotypes: Genotype,
        evaluation: Evaluation,
        added: AddResult,
        key: PRNGKey,
    ) -> None:
        """No state to update."""
        del repertoire, genotypes, evaluation, added, key
        return state


def gaussian_mutation(
    x: Genotype,
    key: PRNGKey,
    sigma: float,
    minval: float | None = None,
    maxval: float | None = None,
) -> Genotype:
    """x + sigma N(0, I) on every leaf, optionally clipped: Iso+LineDD of a parent with itself."""
    leaves, treedef = jax.tree.flatten(x)
    keys = jax.random.split(key, len(leaves))
    children = []
    for leaf, k in zip(leaves, keys, strict=True):
        child = leaf + sigma * jax.random.normal(k, leaf.shape, leaf.dtype)
        if minval is not None or maxval is not None:
            child = jnp.clip(child, minval, maxval)
        children.append(child)
    return jax.tree.unflatten(treedef, children)


def isoline_emitter(
    batch_size: int,
    iso_sigma: float,
    line_sigma: float,
    minval: float | None = None,
    maxval: float | None = None,
    variation_percentage: float = 1.0,
) -> GAEmitter:
    """The emitter of (CVT-)MAP-Elites with Iso+LineDD (QDax's MAP-Elites examples).

    A `variation_percentage` share of the offspring comes from `isoline_variation`;
    the rest (none by default, as in QDax) from `gaussian_mutation` with
    `iso_sigma`. QDax's examples use iso_sigma 0.005 to 0.05 and line_sigma 0.05 to
    0.1 (in units of the genotype's range).
    """
    variation = functools.partial(
        isoline_variation, iso_sigma=iso_sigma, line_sigma=line_sigma, minval=minval, maxval=maxval
    )
    mutation = functools.partial(gaussian_mutation, sigma=iso_sigma, minval=minval, maxval=maxval)
    return GAEmitter(batch_size, variation, mutation, variation_percentage=variation_percentage)


def polynomial_emitter(
    batch_size: int,
    eta: float,
    proportion_to_mutate: float,
    minval: float,
    maxval: float,
    variation_percentage: float = 0.0,
    proportion_var_to_change: float = 0.5,
) -> GAEmitter:
    """Polynomial mutation, and a `variation_percentage` share of `polynomial_crossover` (QDax MOME / NSGA-II setup)."""
    variation: VariationFn = functools.partial(
        polynomial_crossover, proportion_var_to_change=proportion_var_to_change
    )
    mutation: MutationFn = functools.partial(
        polynomial_mutation,
        eta=eta,
        proportion_to_mutate=proportion_to_mutate,
        minval=minval,
        maxval=maxval,
    )
    return GAEmitter(batch_size, variation, mutation, variation_percentage=variation_percentage)


GAKind = Literal["isoline", "polynomial"]


@dataclasses.dataclass(frozen=True)
class GAConfig:
    """The `[emitter]` section of a GA emitter (`kind` = "isoline" or "polynomial").

    MAP-Elites' own emitter; PGA-ME, QD-PG and DCRL-ME make part of their batch
    with it. Plain Gaussian mutation (the DQD paper's MAP-Elites) is "isoline"
    with `variation_percentage = 0`.
    """

    kind: GAKind = "isoline"
    batch_size: PositiveInt = 1024  # offspring per iteration (of each instance)
    # Copies of this GA: arms of the bandit in a pool ([[emitters]]); alone, they make
    # num_instances x batch_size offspring together.
    num_instances: PositiveInt = 1
    iso_sigma: NonNegativeFloat = 0.05  # isoline: isotropic Gaussian noise (Vassiliades & Mouret 2018)
    line_sigma: NonNegativeFloat = 0.1  # isoline: noise along the line between two parents
    variation_percentage: UnitFloat = 1.0  # share of the batch made by crossover/variation
    eta: NonNegativeFloat = 0.05  # polynomial mutation: distribution index
    proportion_to_mutate: UnitFloat = 0.5  # polynomial mutation: share of genes mutated
    crossover_proportion: UnitFloat = 0.5  # polynomial crossover: share of genes exchanged

    def check(self, section: str = "emitter") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value."""
        check_fields(self, section)

    @property
    def offspring(self) -> int:
        """Offspring per iteration: num_instances x batch_size."""
        return self.num_instances * self.batch_size

    @property
    def instance_size(self) -> int:
        """Offspring of one instance per iteration (every arm of a pool emits as many)."""
        return self.batch_size


def ga_emitter(
    config: GAConfig, genotype_low: float, genotype_high: float, batch_size: int | None = None
) -> GAEmitter:
    """The GA of `config` with `batch_size` offspring (default: num_instances x batch_size).

    Offspring are clipped to finite genotype bounds (an infinite bound clips
    nothing); polynomial mutation needs finite bounds.
    """
    n = config.offspring if batch_size is None else batch_size
    if config.kind == "isoline":
        lo = genotype_low if math.isfinite(genotype_low) else None
        hi = genotype_high if math.isfinite(genotype_high) else None
        return isoline_emitter(
            n, config.iso_sigma, config.line_sigma, lo, hi,
            variation_percentage=config.variation_percentage,
        )
    if not (math.isfinite(genotype_low) and math.isfinite(genotype_high)):
        raise ValueError(
            "emitter.kind: 'polynomial' mutates within the genotype bounds, which must be "
            f"finite; the task's are [{genotype_low}, {genotype_high}] (use 'isoline')"
        )
    return polynomial_emitter(
        n, config.eta, config.proportion_to_mutate, genotype_low, genotype_high,
        variation_percentage=config.variation_percentage,
        proportion_var_to_change=config.crossover_proportion,
    )


def sbx_emitter(
    batch_size: int,
    crossover_eta: float,
    mutation_eta: float,
    mutation_prob: float,
    minval: float,
    maxval: float,
    crossover_prob: float = 0.9,
    redraws: int = 0,
) -> GAEmitter:
    """NSGA-II's and SPEA2's variation: every child is SBX of two parents, then polynomially mutated.

    Deb et al. 2002: `sbx_crossover` (probability `crossover_prob` per pair, 0.5 per
    gene) followed by `bernoulli_polynomial_mutation` (each gene with probability
    `mutation_prob`, usually 1/d); the parents are what `repertoire.sample` draws
    (a binary tournament for the Pareto populations). With `redraws` > 0, a child
    equal to one of its parents (no gene crossed or mutated: about 4% of them with
    30 genes and mutation 1/30) is drawn again, up to `redraws` times, so that few
    evaluations go to copies, as pymoo's duplicate elimination does against the
    whole population. The 1 + `redraws` draws of every child are made at once, as
    one variation of the parents repeated 1 + `redraws` times (rows k n .. (k + 1) n
    - 1 are the k-th draws), and each child is its first draw that copies neither
    parent, else its last. The draw splits its key into crossover and mutation keys.
    """
    if not (isinstance(redraws, int) and redraws >= 0):
        raise ValueError(f"redraws: expected an integer >= 0, got {redraws!r}")

    def draw(x1: Genotype, x2: Genotype, key: PRNGKey) -> Genotype:
        cross_key, mutation_key = jax.random.split(key)
        child = sbx_crossover(x1, x2, cross_key, crossover_eta, minval, maxval, crossover_prob)
        return bernoulli_polynomial_mutation(
            child, mutation_key, mutation_eta, mutation_prob, minval, maxval
        )

    def is_copy(child: Genotype, parent: Genotype) -> Array:
        same = [jnp.all(_per_individual(c) == _per_individual(p), axis=1)
                for c, p in zip(jax.tree.leaves(child), jax.tree.leaves(parent), strict=True)]
        return functools.reduce(jnp.logical_and, same)

    def variation(x1: Genotype, x2: Genotype, key: PRNGKey) -> Genotype:
        if redraws == 0:
            return draw(x1, x2, key)
        # All 1 + redraws draws at once, as one batch of (1 + redraws) n pairs (one large
        # variation costs little more than one small one); each child is its first draw that
        # copies neither parent, or its last draw.
        reps = 1 + redraws
        n = _batch_size(x1)
        p1 = jax.tree.map(lambda x: jnp.concatenate([x] * reps), x1)
        p2 = jax.tree.map(lambda x: jnp.concatenate([x] * reps), x2)
        drawn = draw(p1, p2, key)
        fresh = ~(is_copy(drawn, p1) | is_copy(drawn, p2)).reshape(reps, n)[:-1]
        pick = jnp.where(jnp.any(fresh, axis=0), jnp.argmax(fresh, axis=0), reps - 1)
        rows = pick * n + jnp.arange(n)
        return jax.tree.map(lambda x: x[rows], drawn)

    return GAEmitter(batch_size, variation, None, variation_percentage=1.0)


__all__: list[str] = [
    "GAConfig",
    "GAEmitter",
    "MutationFn",
    "VariationFn",
    "bernoulli_polynomial_mutation",
    "ga_emitter",
    "gaussian_mutation",
    "isoline_emitter",
    "isoline_variation",
    "polynomial_crossover",
    "polynomial_emitter",
    "polynomial_mutation",
    "sbx_crossover",
    "sbx_emitter",
]
