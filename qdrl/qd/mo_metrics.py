"""Metrics of multi-objective runs: MOQD score, global hypervolume, coverage, maxima per objective.

MOME (Pierrot et al. 2022) measures a repertoire of fronts by its MOQD score, the
sum over filled cells of the hypervolume of the cell's front w.r.t. a reference
point fixed by the task, and by the hypervolume of the global front (the
non-dominated set of every stored solution). NSGA-II and SPEA2 populations are
measured by the hypervolume of their population (that of its first front).

`mo_metrics` runs under jit (inside the QD loop's scan). Hypervolumes there are
exact for two objectives (`qdrl.qd.pareto.hypervolume_2d`); for more, they are
left out and `exact_hypervolumes` computes them on the host with moocore at each
log point. Both read the same containers.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import moocore
import numpy as np

from qdrl.qd.pareto import hypervolume_2d, hypervolume_exact, non_dominated
from qdrl.qd.populations import ParetoPopulation
from qdrl.qd.repertoires.mome import MOMERepertoire
from qdrl.types import Array

__all__ = ["exact_hypervolumes", "global_front", "mo_metrics"]


def _maxima(points: Array, members: Array) -> dict[str, Array]:
    best = jnp.max(jnp.where(members[:, None], points, -jnp.inf), axis=0)
    out = {f"max_objective_{k}": best[k] for k in range(points.shape[1])}
    out["max_sum_objectives"] = jnp.max(jnp.where(members, jnp.sum(points, axis=1), -jnp.inf))
    return out


def mo_metrics(container: Any, reference: Sequence[float]) -> dict[str, Array]:
    """Metrics of a `MOMERepertoire` or a `ParetoPopulation`; jittable.

    MOME: `moqd_score` (sum of the cells' front hypervolumes), `max_hypervolume`
    (the best cell's), `global_hypervolume`, `coverage` (filled cells / C),
    `num_solutions`. Populations: `global_hypervolume` (the population's),
    `front_size` (members of the first front), `num_solutions`. Both:
    `max_objective_k` per objective and `max_sum_objectives`. Hypervolume keys only
    for two objectives (see the module docstring).
    """
    ref = jnp.asarray(reference, jnp.float32)
    two = container.num_objectives == 2
    if isinstance(container, MOMERepertoire):
        members = container.members  # (C, P)
        flat = container.fitnesses.reshape(-1, container.num_objectives)
        out: dict[str, Array] = {
            "coverage": jnp.mean(container.filled.astype(jnp.float32)),
            "num_solutions": jnp.sum(members, dtype=jnp.int32),
            **_maxima(flat, members.reshape(-1)),
        }
        if two:
            cell_hv = jax.vmap(hypervolume_2d, in_axes=(0, None, 0))(container.fitnesses, ref, members)
            out["moqd_score"] = jnp.sum(cell_hv)
            out["max_hypervolume"] = jnp.max(cell_hv)
            out["global_hypervolume"] = hypervolume_2d(flat, ref, members.reshape(-1))
        return out
    if isinstance(container, ParetoPopulation):
        members = container.members
        out = {
            "num_solutions": jnp.sum(members, dtype=jnp.int32),
            "front_size": jnp.sum(non_dominated(container.fitnesses, members), dtype=jnp.int32),
            **_maxima(container.fitnesses, members),
        }
        if two:
            out["global_hypervolume"] = hypervolume_2d(container.fitnesses, ref, members)
        return out
    raise TypeError(f"mo_metrics: expected a MOMERepertoire or a ParetoPopulation, got {type(container)}")


def global_front(container: Any) -> np.ndarray:
    """(k, M) fitnesses of the non-dominated set of every solution a container holds (host)."""

    f = np.asarray(container.fitnesses, np.float64).reshape(-1, int(container.num_objectives))
    f = f[np.all(np.isfinite(f), axis=1)]
    if len(f) == 0:
        return f
    return f[moocore.is_nondominated(f, maximise=True, keep_weakly=True)]


def exact_hypervolumes(container: Any, reference: Sequence[float]) -> dict[str, Any]:
    """Exact hypervolumes on the host (moocore), any number of objectives.

    `global_hypervolume` for both kinds; for MOME also `moqd_score`,
    `max_hypervolume` and `cell_hypervolumes` ((C,) array, 0 for empty cells).
    """
    f = np.asarray(container.fitnesses, np.float64)
    m = int(container.num_objectives)
    flat = f.reshape(-1, m)
    out: dict[str, Any] = {"global_hypervolume": hypervolume_exact(flat, reference)}
    if isinstance(container, MOMERepertoire):
        cells = np.array([hypervolume_exact(front, reference) for front in f])
        out.update(moqd_score=float(cells.sum()), max_hypervolume=float(cells.max()), cell_hypervolumes=cells)
    return out
