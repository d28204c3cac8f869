"""Plots of feature-space skills: each skill's average feature beside its target, and the
distance and performance profiles of QDAC's analysis (Grillotti et al. 2024)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from qdrl.plotting._common import _figure, _names, _save


def plot_feature_skills(
    targets: np.ndarray,
    achieved: np.ndarray,
    returns: np.ndarray,
    path: str | Path,
    low: Sequence[float],
    high: Sequence[float],
    labels: Sequence[str] | None = None,
    title: str = "",
) -> Path:
    """Each skill's average feature (dot, coloured by its return) joined to its target (cross).

    Two features or more: the first two in the plane; one feature: the average feature
    against the target, beside the line where they are equal. Writes `path`.
    """
    targets, achieved = np.asarray(targets, float), np.asarray(achieved, float)
    returns = np.asarray(returns, float)
    if targets.shape != achieved.shape or targets.ndim != 2 or returns.shape != targets.shape[:1]:
        raise ValueError(
            f"targets, achieved, returns: expected shapes (n, D), (n, D), (n,), got "
            f"{targets.shape}, {achieved.shape}, {returns.shape}"
        )
    d = targets.shape[1]
    names = _names(labels, d)
    fig = _figure(5.6, 4.6)
    ax = fig.add_subplot()
    if d == 1:
        xs, ys = targets[:, 0], achieved[:, 0]
        ax.plot([low[0], high[0]], [low[0], high[0]], color="0.6", lw=1, label="reached exactly")
        sc = ax.scatter(xs, ys, c=returns, cmap="viridis", s=22, zorder=3)
        ax.set_xlabel(f"target {names[0]}")
        ax.set_ylabel(f"average {names[0]}")
        ax.legend(loc="upper left", fontsize=8)
    else:
        for t, a in zip(targets, achieved, strict=True):
            ax.plot([t[0], a[0]], [t[1], a[1]], color="0.7", lw=0.8, zorder=1)
        ax.scatter(targets[:, 0], targets[:, 1], marker="x", color="0.3", s=18, label="target", zorder=2)
        sc = ax.scatter(achieved[:, 0], achieved[:, 1], c=returns, cmap="viridis", s=22, label="average feature", zorder=3)
        ax.set_xlabel(names[0])
        ax.set_ylabel(names[1])
        ax.legend(loc="upper left", fontsize=8)
    margin = 0.05 * (np.asarray(high, float) - np.asarray(low, float))
    ax.set_xlim(low[0] - margin[0], high[0] + margin[0])
    if d > 1:
        ax.set_ylim(low[1] - margin[1], high[1] + margin[1])
    fig.colorbar(sc, ax=ax, label="return")
    return _save(fig, path, title)


def plot_profiles(profiles: Mapping[str, Mapping[str, Any]], path: str | Path, title: str = "") -> Path:
    """Distance and performance profiles of one or several runs (`profiles.json` contents by label).

    Left: the share of skills whose distance to target is below d, against d. Right: the share
    of skills that reach their target with a return above R, against R. Writes `path`.
    """
    fig = _figure(10.0, 3.8)
    left, right = fig.subplots(1, 2)
    for label, prof in profiles.items():
        dp, pp = prof["distance_profile"], prof["performance_profile"]
        left.plot(dp["distance"], dp["share"], marker=".", label=label)
        right.plot(pp["return"], pp["share"], marker=".", label=label)
    left.set_xlabel("distance to skill d")
    left.set_ylabel("share of skills closer than d")
    right.set_xlabel("return R")
    right.set_ylabel("share of skills reached with return > R")
    for ax in (left, right):
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    left.legend(fontsize=8)
    return _save(fig, path, title)
