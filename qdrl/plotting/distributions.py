"""How an archive's objective values are distributed: a histogram of one or several archives, and
their empirical CDF, several seeds of a spec aggregated into a median and a band.

Both read plain arrays of fitnesses (empty cells, -inf, and any other non-finite value are left
out), e.g. `np.asarray(repertoire.fitnesses)` or a repertoire.csv's `fitness` column. Descriptors
of any dimension in parallel axes: `plot_parallel_axes` (`qdrl.plotting.summary`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, overload

import numpy as np
from matplotlib.axes import Axes

from qdrl.plotting._common import _one_panel

__all__ = ["plot_fitness_ecdf", "plot_fitness_histogram"]

Fitnesses = Any  # an array-like of fitnesses (C,)


def _finite(fitnesses: Fitnesses) -> np.ndarray:
    """The finite entries of `fitnesses`, flattened, as float64."""
    values = np.asarray(fitnesses, dtype=np.float64).ravel()
    return values[np.isfinite(values)]


def _draw_histogram(ax: Axes, archives: Mapping[str, np.ndarray], bins: int) -> None:
    shown = [v for v in archives.values() if v.size]
    if not shown:
        ax.text(0.5, 0.5, "no elites", ha="center", va="center", transform=ax.transAxes)
    else:
        pooled = np.concatenate(shown)
        lo, hi = float(pooled.min()), float(pooled.max())
        # One set of edges for every archive, so that their counts compare bin by bin.
        edges = np.linspace(lo, hi, bins + 1) if hi > lo else np.array([lo - 0.5, hi + 0.5])
        single = len(archives) == 1
        for index, (name, values) in enumerate(archives.items()):
            ax.hist(
                values, bins=edges.tolist(), color=f"C{index % 10}",
                label=f"{name} ({values.size} elites)" if name else f"{values.size} elites",
                histtype="stepfilled" if single else "step", alpha=0.8 if single else 1.0, linewidth=1.5,
            )
        ax.legend(fontsize=8)
    ax.set_xlabel("fitness")
    ax.set_ylabel("elites")
    ax.grid(True, alpha=0.3)


@overload
def plot_fitness_histogram(
    fitnesses: Fitnesses | Mapping[str, Fitnesses], path: str | Path, bins: int = ..., title: str = ...,
    *, ax: None = None,
) -> Path: ...
@overload
def plot_fitness_histogram(
    fitnesses: Fitnesses | Mapping[str, Fitnesses], path: str | Path | None = ..., bins: int = ...,
    title: str = ..., *, ax: Axes,
) -> Axes: ...
@overload
def plot_fitness_histogram(
    fitnesses: Fitnesses | Mapping[str, Fitnesses], path: None = ..., bins: int = ..., title: str = ...,
    *, ax: None = None,
) -> Axes: ...
def plot_fitness_histogram(
    fitnesses: Fitnesses | Mapping[str, Fitnesses],
    path: str | Path | None = None,
    bins: int = 30,
    title: str = "",
    *,
    ax: Axes | None = None,
) -> Path | Axes:
    """A histogram of an archive's objective values: how many elites reach each fitness.

    Args:
      fitnesses: one archive's fitnesses (C,) (-inf where empty; non-finite values are left
        out), or name -> fitnesses for several archives, drawn as outlines over common bins.
      path: PNG to write (its directory is created), or None.
      bins: the number of bins over the range of every finite fitness.
      title: the title (the figure's; with `ax`, the panel's).
      ax: an Axes to draw on.

    Returns:
      `ax` when given, else `path` when given, else the Axes of a new figure.
    """
    if bins < 1:
        raise ValueError(f"bins: expected a positive int, got {bins}")
    if isinstance(fitnesses, Mapping):
        if not fitnesses:
            raise ValueError("fitnesses is empty; nothing to draw")
        archives = {str(name): _finite(values) for name, values in fitnesses.items()}
    else:
        archives = {"": _finite(fitnesses)}

    return _one_panel(lambda panel: _draw_histogram(panel, archives, bins), path, ax, title, size=(6.0, 4.0))


def _ecdf_at(values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The empirical CDF of `values` at each point of `grid`: the share of values <= it."""
    return np.searchsorted(np.sort(values), grid, side="right") / values.size


def _draw_ecdf(ax: Axes, runs: Mapping[str, list[np.ndarray]], band: tuple[float, float]) -> None:
    pooled = [v for seeds in runs.values() for v in seeds if v.size]
    if not pooled:
        ax.text(0.5, 0.5, "no elites", ha="center", va="center", transform=ax.transAxes)
    ends = np.concatenate(pooled) if pooled else np.zeros(1)
    lo, hi = float(np.min(ends)), float(np.max(ends))
    for index, (name, seeds) in enumerate(runs.items()):
        colour = f"C{index % 10}"
        filled = [v for v in seeds if v.size]
        if not filled:
            ax.plot([], [], color=colour, label=f"{name} (no elites)")
            continue
        # Every seed's step function is exact at the union of its values: the median and
        # the band change only there.
        grid = np.unique(np.concatenate([*filled, [lo, hi]]))
        curves = np.stack([_ecdf_at(v, grid) for v in filled])
        label = name if len(filled) == 1 else f"{name} (median of {len(filled)} seeds)"
        ax.step(grid, np.median(curves, axis=0), where="post", color=colour, linewidth=1.5, label=label)
        if len(filled) > 1:
            low, high = np.quantile(curves, band, axis=0)
            ax.fill_between(grid, low, high, step="post", color=colour, alpha=0.2, linewidth=0)
    ax.set_xlabel("fitness")
    ax.set_ylabel("share of elites with fitness ≤ x")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(True, alpha=0.3)
    if runs:
        ax.legend(fontsize=8)


@overload
def plot_fitness_ecdf(
    runs: Mapping[str, Sequence[Fitnesses] | np.ndarray], path: str | Path, title: str = ...,
    band: tuple[float, float] = ..., *, ax: None = None,
) -> Path: ...
@overload
def plot_fitness_ecdf(
    runs: Mapping[str, Sequence[Fitnesses] | np.ndarray], path: str | Path | None = ..., title: str = ...,
    band: tuple[float, float] = ..., *, ax: Axes,
) -> Axes: ...
@overload
def plot_fitness_ecdf(
    runs: Mapping[str, Sequence[Fitnesses] | np.ndarray], path: None = ..., title: str = ...,
    band: tuple[float, float] = ..., *, ax: None = None,
) -> Axes: ...
def plot_fitness_ecdf(
    runs: Mapping[str, Sequence[Fitnesses] | np.ndarray],
    path: str | Path | None = None,
    title: str = "",
    band: tuple[float, float] = (0.0, 1.0),
    *,
    ax: Axes | None = None,
) -> Path | Axes:
    """The empirical CDF of archives' objective values: the share of elites at or below each
    fitness, one colour per name.

    A name with one seed is its archive's step function; with several, the median over seeds
    of their step functions (each exact at every fitness that one of them holds) and a band
    between the `band` quantiles over seeds (default min to max).

    Args:
      runs: name -> one array of fitnesses per seed, or one 1-D array for a single seed (-inf
        and other non-finite values left out; a seed without elites is left out of its
        name's median).
      path: PNG to write (its directory is created), or None.
      title: the title (the figure's; with `ax`, the panel's).
      band: the (low, high) quantiles over seeds that bound the band, in [0, 1].
      ax: an Axes to draw on.

    Returns:
      `ax` when given, else `path` when given, else the Axes of a new figure.
    """
    if not runs:
        raise ValueError("runs is empty; nothing to draw")
    if not (0.0 <= band[0] <= band[1] <= 1.0):
        raise ValueError(f"band: expected quantiles 0 <= low <= high <= 1, got {band}")
    seeds = {
        # A bare 1-D array is one seed's fitnesses.
        str(name): [_finite(values)] if getattr(values, "ndim", None) == 1 else [_finite(v) for v in values]
        for name, values in runs.items()
    }

    return _one_panel(lambda panel: _draw_ecdf(panel, seeds, band), path, ax, title, size=(6.0, 4.0))
