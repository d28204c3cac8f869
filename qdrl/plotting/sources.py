"""What the repertoire plots accept: a repertoire, a loaded run, or a DataFrame of elites.

`elites_of(source, low, high, labels)` turns any of them into what the drawing code
reads (`fitnesses` (C,), `descriptors` (C, D), and for cell repertoires `centroids`,
`grid_shape`, `low`, `high`) with the descriptor bounds and names filled in from the
source where the caller gave none.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["Elites", "elites_of"]


class Elites:
    """Elites as plain arrays: `fitnesses` (C,) (-inf where empty), `descriptors` (C, D), and
    optionally `centroids` (C, D) and a grid's `grid_shape`, `low`, `high`."""

    def __init__(
        self,
        fitnesses: np.ndarray,
        descriptors: np.ndarray,
        centroids: np.ndarray | None = None,
        grid_shape: tuple[int, ...] | None = None,
        low: np.ndarray | None = None,
        high: np.ndarray | None = None,
    ) -> None:
        self.fitnesses, self.descriptors, self.centroids = fitnesses, descriptors, centroids
        self.grid_shape, self.low, self.high = grid_shape, low, high


def _is_frame(source: Any) -> bool:
    return hasattr(source, "columns") and hasattr(source, "to_numpy")


def _is_run(source: Any) -> bool:
    """A loaded run (`qdrl.runs.LoadedRun`; not imported here: plotting stays below runs)."""
    return hasattr(source, "repertoire") and hasattr(source, "summary") and hasattr(source, "metrics")


def _from_frame(frame: Any) -> tuple[Elites, list[str]]:
    """The elites of a table with `fitness` and `descriptor_*` columns (`to_table`'s)."""
    columns = [str(c) for c in frame.columns]
    names = [c for c in columns if c.startswith("descriptor_")]
    if "fitness" not in columns or not names:
        raise ValueError(
            "a DataFrame of elites needs a `fitness` column and `descriptor_*` columns "
            f"(as `run.table` or `qdrl.load_repertoires` give), got columns {columns}"
        )
    fitnesses = frame["fitness"].to_numpy(dtype=np.float64)
    descriptors = frame[names].to_numpy(dtype=np.float64)
    labels = [n.removeprefix("descriptor_").replace("_", " ") for n in names]
    if all(label.isdigit() for label in labels):
        labels = []
    return Elites(fitnesses, descriptors), labels


def elites_of(
    source: Any,
    low: float | Sequence[float] | None,
    high: float | Sequence[float] | None,
    labels: Sequence[str] | None,
) -> tuple[Any, Any, Any, Sequence[str] | None]:
    """(elites, low, high, labels) of a repertoire, loaded run or DataFrame of elites.

    Bounds default to the run's (summary.json), the grid's own, else the range of the
    stored descriptors; labels to the run's descriptor names (or the table's columns).
    """
    found_low = found_high = None
    found_labels: Sequence[str] | None = None
    if _is_run(source):
        summary = source.summary or {}
        found_low, found_high = summary.get("descriptor_low"), summary.get("descriptor_high")
        found_labels = summary.get("descriptor_names") or None
        source = source.repertoire
    elif _is_frame(source):
        source, found_labels = _from_frame(source)
    if not (hasattr(source, "fitnesses") and hasattr(source, "descriptors")):
        raise ValueError(
            "expected a repertoire (fitnesses and descriptors), a loaded run (qdrl.load_run) or "
            f"a DataFrame of elites, got {type(source).__name__}"
        )
    if found_low is None and getattr(source, "grid_shape", None) is not None:
        found_low, found_high = getattr(source, "low", None), getattr(source, "high", None)
    if found_low is None or found_high is None:
        fitnesses = np.asarray(source.fitnesses, dtype=np.float64)
        descriptors = np.asarray(source.descriptors, dtype=np.float64)
        filled = descriptors[fitnesses > -np.inf]
        points = filled if len(filled) else np.zeros((1, descriptors.shape[1]))
        lo, hi = points.min(axis=0), points.max(axis=0)
        pad = np.where(hi > lo, 0.05 * (hi - lo), 0.5)
        found_low, found_high = lo - pad, hi + pad
    return (
        source,
        found_low if low is None else low,
        found_high if high is None else high,
        labels if labels else (list(found_labels) if found_labels else None),
    )
