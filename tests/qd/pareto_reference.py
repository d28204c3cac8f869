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


def pruned(p: np.ndarray, members: np.ndarray, keep: int) -> tuple[np.ndarray, np.ndarray]:
    """Kukkonen & Deb 2006 (pymoo's "pcd"): scale by the members' ranges, keep each objective's
    first lowest and first highest member, remove the member of smallest crowding distance
    (lowest index on ties) one at a time, recomputing the distances."""
    idx = np.flatnonzero(members)
    lo, hi = p[idx].min(axis=0), p[idx].max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    x = (p - lo) / span
    extremes = {int(idx[np.argmin(p[idx, k])]) for k in range(p.shape[1])}
    extremes |= {int(idx[np.argmax(p[idx, k])]) for k in range(p.shape[1])}

    def distances(alive: list[int]) -> dict[int, float]:
        d = dict.fromkeys(alive, 0.0)
        for k in range(p.shape[1]):
            order = sorted(alive, key=lambda i: (x[i, k], i))
            for a, i in enumerate(order):
                inner = 0 < a < len(order) - 1
                d[i] += x[order[a + 1], k] - x[order[a - 1], k] if inner else np.inf
        return {i: (np.inf if i in extremes else v) for i, v in d.items()}

    alive = idx.tolist()
    while len(alive) > keep and any(i not in extremes for i in alive):
        d = distances(alive)
        alive.remove(min((i for i in alive if i not in extremes), key=lambda i: (d[i], i)))
    kept = np.zeros(len(p), bool)
    kept[alive] = True
    dist = np.full(len(p), -np.inf)
    for i, v in distances(alive).items():
        dist[i] = v
    return kept, dist
