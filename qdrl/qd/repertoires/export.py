"""Exports of a repertoire's elites: a column table, a CSV file, an NPZ file.

They run on the host (NumPy), between log points, never inside jitted code.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

__all__ = ["descriptor_columns", "export_npz", "export_solutions", "to_table", "write_csv", "write_front"]


def descriptor_columns(names: Sequence[str], size: int) -> list[str]:
    """The column suffixes of `size` descriptor dimensions: each name made an identifier
    ("front foot contact" -> `front_foot_contact`), else (no names, or the default names
    "descriptor i") the dimension's index. Suffixes that two names share fall back to indices."""
    suffixes = []
    for i in range(size):
        name = names[i] if i < len(names) else ""
        slug = re.sub(r"[^0-9a-zA-Z]+", "_", name).strip("_").lower()
        suffixes.append(str(i) if not slug or slug == f"descriptor_{i}" else slug)
    return suffixes if len(set(suffixes)) == size else [str(i) for i in range(size)]


def to_table(repertoire: Any, names: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """One row per elite, as columns: `cell`, `fitness`, `descriptor_<d>` and, for cell
    repertoires, `centroid_<d>`, where `<d>` is each dimension's name as an identifier
    (`descriptor_front_foot_contact`; `descriptor_columns`) or, without `names`, its index
    (`descriptor_0..D-1`). Rows are in increasing cell (slot) order."""
    fitnesses = np.asarray(repertoire.fitnesses)
    cells = np.flatnonzero(fitnesses > -np.inf)
    table: dict[str, np.ndarray] = {
        "cell": cells.astype(np.int64),
        "fitness": fitnesses[cells],
    }
    descriptors = np.asarray(repertoire.descriptors)[cells]
    suffixes = descriptor_columns(names, descriptors.shape[1])
    for i, suffix in enumerate(suffixes):
        table[f"descriptor_{suffix}"] = descriptors[:, i]
    centroids = getattr(repertoire, "centroids", None)
    if centroids is not None:
        centroids = np.asarray(centroids)[cells]
        for i, suffix in enumerate(suffixes):
            table[f"centroid_{suffix}"] = centroids[:, i]
    return table


def write_csv(repertoire: Any, path: str | Path, names: Sequence[str] = ()) -> Path:
    """Writes `to_table(repertoire, names)` as a CSV file with a header row (loads with
    `pandas.read_csv`); floats are written with full precision. Returns the path."""
    table = to_table(repertoire, names)
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


def write_front(front: np.ndarray, path: Path) -> None:
    """A Pareto front (k, M) as a CSV file, one row per point (`objective_0..M-1`)."""
    header = ",".join(f"objective_{k}" for k in range(front.shape[1]))
    np.savetxt(path, front, delimiter=",", header=header, comments="")


def export_solutions(container: Any, out_dir: Path, name: str, names: Sequence[str] = ()) -> None:
    """A multi-objective container's solutions (a MOME repertoire's fronts, a Pareto population):
    `<name>.npz` (as `export_npz`: fitnesses, descriptors, genotype leaves named `genotypes` +
    key path, centroids) and `<name>.csv`, one row per stored solution (cell and slot, or slot),
    its descriptor columns named as `to_table`'s."""
    fit = np.asarray(container.fitnesses)
    desc = np.asarray(container.descriptors)
    arrays: dict[str, np.ndarray] = {"fitnesses": fit, "descriptors": desc}
    for key_path, leaf in jax.tree_util.tree_flatten_with_path(container.genotypes)[0]:
        arrays["genotypes" + jax.tree_util.keystr(key_path)] = np.asarray(leaf)
    if hasattr(container, "centroids"):
        arrays["centroids"] = np.asarray(container.centroids)
    np.savez_compressed(out_dir / f"{name}.npz", **arrays)  # type: ignore[arg-type]
    m, d = fit.shape[-1], desc.shape[-1]
    flat_f, flat_d = fit.reshape(-1, m), desc.reshape(-1, d)
    keep = np.all(np.isfinite(flat_f), axis=1)
    slots = fit.shape[1] if fit.ndim == 3 else len(fit)
    index = np.arange(len(flat_f))
    cols = [index // slots, index % slots, *flat_f.T, *flat_d.T]
    header = ["cell", "slot", *(f"objective_{k}" for k in range(m))]
    header += [f"descriptor_{suffix}" for suffix in descriptor_columns(names, d)]
    table = np.stack(cols, axis=1)[keep]
    fmt = ["%d", "%d", *(["%.9g"] * (m + d))]
    np.savetxt(out_dir / f"{name}.csv", table, delimiter=",", header=",".join(header), comments="", fmt=fmt)
