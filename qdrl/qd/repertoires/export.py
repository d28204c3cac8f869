"""Exports of a repertoire's elites: a column table, a CSV file, an NPZ file.

They run on the host (NumPy), between log points, never inside jitted code.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import jax
import numpy as np

__all__ = ["export_npz", "to_table", "write_csv"]


def to_table(repertoire: Any) -> dict[str, np.ndarray]:
    """One row per elite, as columns: `cell`, `fitness`, `descriptor_0..D-1` and, for cell
    repertoires, `centroid_0..D-1`. Rows are in increasing cell (slot) order."""
    fitnesses = np.asarray(repertoire.fitnesses)
    cells = np.flatnonzero(fitnesses > -np.inf)
    table: dict[str, np.ndarray] = {
        "cell": cells.astype(np.int64),
        "fitness": fitnesses[cells],
    }
    descriptors = np.asarray(repertoire.descriptors)[cells]
    for i in range(descriptors.shape[1]):
        table[f"descriptor_{i}"] = descriptors[:, i]
    centroids = getattr(repertoire, "centroids", None)
    if centroids is not None:
        centroids = np.asarray(centroids)[cells]
        for i in range(centroids.shape[1]):
            table[f"centroid_{i}"] = centroids[:, i]
    return table


def write_csv(repertoire: Any, path: str | Path) -> Path:
    """Writes `to_table(repertoire)` as a CSV file with a header row (loads with
    `pandas.read_csv`); floats are written with full precision. Returns the path."""
    table = to_table(repertoire)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    columns = list(table.values())
    with out.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(table.keys())
        for row in zip(*columns, strict=True):
            writer.writerow([repr(v.item()) for v in row])
    return out


def export_npz(repertoire: Any, path: str | Path) -> Path:
    """Writes the whole repertoire (all cells, empty ones included) to an `.npz` file.

    Arrays: `fitnesses`, `descriptors`, `filled`, `centroids` (cell repertoires),
    `grid_shape`, `low`, `high` (grids), `l_value` (unstructured), and one array per
    genotype leaf named `genotypes` + its key path (e.g. `genotypes['linear']['w']`).
    Returns the path.
    """
    arrays: dict[str, Any] = {
        "fitnesses": np.asarray(repertoire.fitnesses),
        "descriptors": np.asarray(repertoire.descriptors),
        "filled": np.asarray(repertoire.fitnesses) > -np.inf,
    }
    for name in ("centroids", "grid_shape", "low", "high", "l_value"):
        value = getattr(repertoire, name, None)
        if value is not None:
            arrays[name] = np.asarray(value)
    for key_path, leaf in jax.tree_util.tree_flatten_with_path(repertoire.genotypes)[0]:
        arrays["genotypes" + jax.tree_util.keystr(key_path)] = np.asarray(leaf)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("wb") as f:
        np.savez(f, **arrays)
    return out
