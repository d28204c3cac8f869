"""Aggregates over seeds: bootstrap confidence intervals and the interquartile mean.

Agarwal et al. 2021, "Deep reinforcement learning at the edge of the statistical
precipice" (rliable): report the interquartile mean (IQM, the mean of the middle
50% of runs) with a percentile bootstrap confidence interval rather than a mean
alone, which few seeds make fragile.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["bootstrap_ci", "iqm"]


def _trim_mean(x: np.ndarray, cut: float, axis: int) -> np.ndarray:
    """The mean along `axis` of what is left after dropping `int(cut * n)` of the n values at
    each end, as `scipy.stats.trim_mean` (not imported: scipy.stats alone takes ~1 s)."""
    n = x.shape[axis]
    k = int(cut * n)
    return np.mean(np.take(np.sort(x, axis=axis), np.arange(k, n - k), axis=axis), axis=axis)


def iqm(values: np.ndarray, axis: int = 0) -> np.ndarray:
    """The interquartile mean along `axis`: the mean after cutting 25% of the values at each
    end (`scipy.stats.trim_mean(x, 0.25)`, as rliable computes it)."""
    return np.asarray(_trim_mean(np.asarray(values, dtype=np.float64), 0.25, axis))


def bootstrap_ci(
    values: np.ndarray,
    statistic: str = "mean",
    confidence: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile bootstrap interval of the mean (or IQM) over axis 0 (the runs).

    `values` is (n, ...) with one row per run; NaN entries are left out of each
    resample's statistic. Runs are resampled with replacement `resamples` times
    (seeded, so the band of a figure does not change between two reports). With
    one run, the interval is that run's value.

    Returns:
      (low, high), each of shape `values.shape[1:]`.
    """
    if statistic not in ("mean", "iqm"):
        raise ValueError(f"statistic: expected 'mean' or 'iqm', got {statistic!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: expected a number in (0, 1), got {confidence}")
    x = np.asarray(values, dtype=np.float64)
    n = x.shape[0]
    if n == 0:
        raise ValueError("values: expected at least one run, got none")
    if n == 1:
        return x[0].copy(), x[0].copy()
    picks = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    samples = x[picks]  # (resamples, n, ...)
    with warnings.catch_warnings():  # all-NaN slices give NaN, as wanted
        warnings.simplefilter("ignore", RuntimeWarning)
        stats = np.nanmean(samples, axis=1) if statistic == "mean" else _trim_mean(samples, 0.25, 1)
        tail = 100.0 * (1.0 - confidence) / 2.0
        low, high = np.nanpercentile(stats, [tail, 100.0 - tail], axis=0)
    return np.asarray(low), np.asarray(high)
