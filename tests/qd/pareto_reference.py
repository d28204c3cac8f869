"""Brute-force NumPy references of the Pareto utilities, written from their definitions (shared by tests)."""

from __future__ import annotations

import itertools
import math

import numpy as np


def dominates(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(a >= b) and np.any(a > b))


def ranks(p: np.ndarray, mask: np.ndarray) -> np.ndarray:
    ranks = np.full(len(p), len(p))
    left = [i for i in range(len(p)) if mask[i]]
    level = 0
    while left:
        front = [i for i in left if not any(dominates(p[j], p[i]) for j in left)]
        ranks[front] = level
        left = [i for i in left if i not in front]
        level += 1
    return ranks


def crowding(p: np.ndarray, mask: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    dist = np.full(len(p), -np.inf)
    for r in set(ranks[mask].tolist()):
        front = np.flatnonzero(mask & (ranks == r))
        d = np.zeros(len(front))
        for k in range(p.shape[1]):
            v = p[front, k]
            order = np.argsort(v, kind="stable")
            span = v.max() - v.min()
            d[order[0]] = d[order[-1]] = np.inf
            for a in range(1, len(front) - 1):
                if span > 0:
                    d[order[a]] += (v[order[a + 1]] - v[order[a - 1]]) / span
        dist[front] = d
    return dist


def hypervolume(p: np.ndarray, ref: np.ndarray) -> float:
    """Union volume by coordinate compression: each grid box counts if some point covers it."""
    p = p[np.all(p > ref, axis=1)]
    if len(p) == 0:
        return 0.0
    axes = [np.unique(np.concatenate([[ref[k]], p[:, k]])) for k in range(p.shape[1])]
    total = 0.0
    for idx in itertools.product(*(range(len(a) - 1) for a in axes)):
        upper = np.array([axes[k][i + 1] for k, i in enumerate(idx)])
        if np.any(np.all(p >= upper, axis=1)):
            total += math.prod(axes[k][i + 1] - axes[k][i] for k, i in enumerate(idx))
    return total
