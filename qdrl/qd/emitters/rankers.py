"""Rankers of CMA-ME and its family: how an emitter orders its evaluated offspring for CMA-ES.

Fontaine, Togelius, Nikolaidis & Hoover 2020, "Covariance Matrix Adaptation for
the Rapid Illumination of Behavior Space" (improvement, optimizing and
random-direction emitters); pyribs' rankers (`ribs.emitters.rankers`) give the
names. A ranker is a pure function of an `Outcome` (what the archive said about
each offspring) and, for the random-direction rankers, a direction in descriptor
space; it returns the offspring's order, best first, and the values it ranked by.

| name | ranks by |
|---|---|
| `imp` | improvement over the cell's elite or threshold (CMA-MAE) |
| `2imp` | new cell first, then improved cell, then the rest; each by improvement (CMA-ME) |
| `obj` | fitness (the optimizing emitter) |
| `2obj` | added first (new, improved, rest), each by fitness |
| `rd` | projection of the descriptor on the direction |
| `2rd` | added first (new, improved, rest), each by projection (the random-direction emitter) |
| `nov` | `info["novelty"]`, highest first (novelty search; `ProximityArchive`) |
| `nslc` | non-dominated fronts of (`info["novelty"]`, `info["local_competition"]`), each front by crowding distance (NSLC; `ProximityArchive` with local competition) |
| `density` | `info["density"]`, lowest first (a density archive) |

`outcome` turns a repertoire's `AddResult` into pyribs' per-candidate status
(0 not added, 1 improved an occupied cell, 2 found an empty cell), judged against
the archive BEFORE the batch, for every candidate (several offspring may beat
the same cell; only one of them becomes its elite).

The last three read the fields an archive judges its candidates by
(`AddResult.info`, passed on by `outcome`; `INFO_FIELDS` names them) and raise a
`ValueError` at trace time when the archive gives none. Ties keep batch order,
except in `nslc`, which orders ties as pyribs' `NSLCRanker` does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.qd.base import AddResult
from qdrl.qd.pareto import crowding_distance, dominance_matrix, front_ranks
from qdrl.types import Array, PRNGKey

__all__ = [
    "INFO_FIELDS",
    "RANKERS",
    "Outcome",
    "check_ranker",
    "outcome",
    "random_direction",
    "rank",
    "uses_direction",
]

NOT_ADDED, IMPROVED, NEW = 0, 1, 2


class Outcome(NamedTuple):
    """What the archive said about each of b offspring (leading axes may be batched)."""

    fitnesses: Array  # (b,)
    descriptors: Array  # (b, D)
    status: Array  # (b,) int32: 0 not added, 1 improved an occupied cell, 2 new cell
    value: Array  # (b,) improvement over the cell's elite or threshold (-inf when rejected)
    info: dict[str, Array] | None = None  # (b,) fields of the archive's own judgement (`AddResult.info`)


def outcome(repertoire: Any, fitnesses: Array, descriptors: Array, added: AddResult) -> Outcome:
    """Per-candidate status and improvement of a WHOLE batch just offered to `repertoire`.

    `repertoire` is the cell repertoire after the `add` that returned `added`. A
    candidate's cell was empty before the batch when it is still empty, or when
    the batch's winner there filled a new cell. A candidate in an empty cell
    counts as new when its cell's threshold was -inf (CMA-ME) or it beats
    `threshold_min` (CMA-MAE: `value` is then fitness - threshold_min); in an
    occupied cell it improved when `value` > 0. Pass the whole batch: a slice
    cannot see a cell that another part of the batch filled. An archive that sets
    `added.status` (proximity, density, discount archives) is taken at its word, and its
    `added.info` is passed on for the rankers that read it.
    """
    if added.status is not None:  # an archive that judges its candidates itself
        value = added.value if added.value is not None else jnp.where(added.added, 0.0, -jnp.inf)
        return Outcome(
            fitnesses=jnp.asarray(fitnesses, jnp.float32),
            descriptors=jnp.asarray(descriptors, jnp.float32),
            status=added.status.astype(jnp.int32),
            value=jnp.asarray(value, jnp.float32),
            info=added.info,
        )
    cell = added.cell
    valid = cell >= 0
    fit = repertoire.fitnesses
    num_cells = fit.shape[0]
    safe = jnp.clip(cell, 0, num_cells - 1)
    filled_now = jnp.zeros((num_cells,), bool).at[jnp.where(added.new_cell, cell, num_cells)].set(
        True, mode="drop"
    )
    was_empty = (fit[safe] == -jnp.inf) | filled_now[safe]
    value = jnp.where(valid, added.improvement, -jnp.inf).astype(jnp.float32)
    threshold_min = float(getattr(repertoire, "threshold_min", -jnp.inf))
    beats_empty = value > 0 if threshold_min > -jnp.inf else jnp.ones_like(valid)
    status = jnp.where(
        ~valid,
        NOT_ADDED,
        jnp.where(
            was_empty,
            jnp.where(beats_empty, NEW, NOT_ADDED),
            jnp.where(value > 0, IMPROVED, NOT_ADDED),
        ),
    ).astype(jnp.int32)
    return Outcome(
        fitnesses=jnp.asarray(fitnesses, jnp.float32),
        descriptors=jnp.asarray(descriptors, jnp.float32),
        status=status,
        value=value,
    )


def _finite_or_worst(x: Array) -> Array:
    return jnp.where(jnp.isnan(x), -jnp.inf, x)


def _one_stage(key: Array) -> tuple[Array, Array]:
    key = _finite_or_worst(key)
    # ascending sort of -key: best first; a stable sort keeps ties in batch order
    return jnp.argsort(-key, stable=True), key


def _two_stage(status: Array, key: Array) -> tuple[Array, Array]:
    key = _finite_or_worst(key)
    order = jnp.lexsort((-key, -status))
    return order, jnp.stack([status.astype(jnp.float32), key], axis=-1)


def _projection(out: Outcome, direction: Array) -> Array:
    return out.descriptors @ direction


def _info(out: Outcome, name: str, field: str) -> Array:
    """`out.info[field]` as float32; a ValueError (at trace time) when the archive gave none."""
    if out.info is None or field not in out.info:
        given = sorted(out.info) if out.info is not None else []
        raise ValueError(
            f"ranker {name!r}: needs info[{field!r}] from the archive's add (as "
            f"ProximityArchive or a density archive give), got info fields {given}"
        )
    return jnp.asarray(out.info[field], jnp.float32)


def _novelty(out: Outcome) -> tuple[Array, Array]:
    """pyribs' NoveltyRanker: novelty, highest first (NaN last)."""
    return _one_stage(_info(out, "nov", "novelty"))


def _density(out: Outcome) -> tuple[Array, Array]:
    """pyribs' DensityRanker: density, lowest first (NaN last)."""
    density = _info(out, "density", "density")
    density = jnp.where(jnp.isnan(density), jnp.inf, density)
    return jnp.argsort(density, stable=True), density


def _front_discovery_order(points: Array, valid: Array, ranks: Array) -> Array:
    """(b,) int32 position of each row when fronts are listed as NSGA-II's fast sort finds them.

    The first front in batch order; a member of front L + 1 is found when the last
    of its dominators in front L is processed, so front L + 1 is ordered by the
    position of that dominator, then by batch index. pyribs' NSLCRanker breaks
    equal crowding distances by this position. Invalid rows come after, in batch order.
    """
    b = points.shape[0]
    dom = dominance_matrix(points, valid)
    index = jnp.arange(b, dtype=jnp.int32)
    first = valid & (ranks == 0)
    seq0 = jnp.where(first, jnp.cumsum(first, dtype=jnp.int32) - 1, 2 * b + index)

    def cond(carry: tuple[Array, Array]) -> Array:
        _, level = carry
        return jnp.any(valid & (ranks == level + 1))

    def body(carry: tuple[Array, Array]) -> tuple[Array, Array]:
        seq, level = carry
        prev = valid & (ranks == level)
        cur = valid & (ranks == level + 1)
        key = jnp.max(jnp.where(dom & prev[:, None], seq[:, None], -1), axis=0)
        before = (key[None, :] < key[:, None]) | (
            (key[None, :] == key[:, None]) & (index[None, :] < index[:, None])
        )
        pos = jnp.sum(before & cur[None, :], axis=1, dtype=jnp.int32)
        done = jnp.sum(valid & (ranks <= level), dtype=jnp.int32)
        return jnp.where(cur, done + pos, seq), level + 1

    seq, _ = jax.lax.while_loop(cond, body, (seq0, jnp.zeros((), jnp.int32)))
    return seq


def _nslc(out: Outcome) -> tuple[Array, Array]:
    """pyribs' NSLCRanker (diversity_field None): fronts of (novelty, local competition), then crowding.

    Lehman & Stanley 2011b; NSGA-II's non-dominated sorting and crowding distance
    (Deb et al. 2002) on the two objectives, both maximised. Within a front, the
    larger crowding distance first; equal distances, and equal values inside the
    crowding computation, keep the order in which the fast sort lists the front
    (`_front_discovery_order`), as pyribs. Candidates with a non-finite novelty
    (rejected by the archive) come last.
    """
    novelty = _info(out, "nslc", "novelty")
    local = _info(out, "nslc", "local_competition")
    valid = jnp.isfinite(novelty) & jnp.isfinite(local)
    points = jnp.where(valid[:, None], jnp.stack([novelty, local], axis=-1), 0.0)
    ranks = front_ranks(points, valid)
    perm = jnp.argsort(_front_discovery_order(points, valid, ranks))
    # In the listing order, index order is pyribs' order: crowding_distance's and
    # lexsort's index tie-breaks then match its stable sorts (on the costs, -points).
    crowd = crowding_distance(-points[perm], valid[perm], ranks[perm])
    order = perm[jnp.lexsort((-crowd, ranks[perm]))]
    return order, jnp.stack([_finite_or_worst(novelty), _finite_or_worst(local)], axis=-1)


Ranker = Callable[[Outcome, Array], tuple[Array, Array]]

RANKERS: dict[str, Ranker] = {
    "imp": lambda out, d: _one_stage(out.value),
    "2imp": lambda out, d: _two_stage(out.status, out.value),
    "obj": lambda out, d: _one_stage(out.fitnesses),
    "2obj": lambda out, d: _two_stage(out.status, out.fitnesses),
    "rd": lambda out, d: _one_stage(_projection(out, d)),
    "2rd": lambda out, d: _two_stage(out.status, _projection(out, d)),
    "nov": lambda out, d: _novelty(out),
    "nslc": lambda out, d: _nslc(out),
    "density": lambda out, d: _density(out),
}

# The `Outcome.info` fields each ranker reads (an archive's own judgement of its candidates).
INFO_FIELDS: dict[str, tuple[str, ...]] = {
    "nov": ("novelty",),
    "nslc": ("novelty", "local_competition"),
    "density": ("density",),
}


def check_ranker(name: str, where: str = "emitter.ranker") -> None:
    """Raises `ValueError("<where>: expected one of ..., got ...")` for an unknown ranker name."""
    if name not in RANKERS:
        raise ValueError(f"{where}: expected one of {', '.join(sorted(RANKERS))}, got {name!r}")


def uses_direction(name: str) -> bool:
    """Whether the ranker needs a descriptor-space direction (`rd`, `2rd`; no other ranker reads it)."""
    return name in ("rd", "2rd")


def rank(name: str, out: Outcome, direction: Array) -> tuple[Array, Array]:
    """(order (b,), values in that order): the offspring best first, and what they were ranked by.

    `values` is (b,) for one-stage rankers (`nov`: novelty, `density`: density),
    (b, 2) (status, key) for two-stage ones and (b, 2) (novelty, local
    competition) for `nslc`; CMA-ES's flat-ranking stop reads it (the first and
    the last row differ by less than 1e-12: every candidate looked alike). NaN keys
    rank last.
    """
    check_ranker(name)
    order, values = RANKERS[name](out, direction)
    return order, values[order]


def random_direction(key: PRNGKey, low: Array, high: Array) -> Array:
    """A standard-normal direction in descriptor space scaled by the archive's ranges (pyribs)."""
    low = jnp.asarray(low, jnp.float32)
    high = jnp.asarray(high, jnp.float32)
    return jax.random.normal(key, low.shape) * (high - low)
