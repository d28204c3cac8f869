"""Plots of runs: learning curves, QD repertoire heatmaps, Pareto fronts and skills.

Modules by what they draw: `curves` (one run's metrics, runs compared), `repertoires`
(fitness heatmaps), `distributions` (fitness histograms and empirical CDFs), `pareto`
(fronts, MOME's cells), `skills` (trajectories, maze walls); `_common` holds the shared
helpers.

Every plotting function writes a PNG, draws into the caller's matplotlib objects, or
both. Single-panel functions take `ax` (an Axes), multi-panel ones `fig` (an empty
Figure or SubFigure, in which they lay out their panels); `plot_comparison` and
`plot_skills` take either. The return value follows one rule:

- `ax` / `fig` given: it is drawn on and returned (the file at `path`, when given
  too, is still written from a figure of its own, exactly as without `ax` / `fig`);
- else a path given: the file is written and its path returned (`plot_curves`: the
  list of paths), as before;
- else: the new figure's Axes (single panel) or the new Figure (multi-panel).

A path is positional and accepts None. The figures this package creates are built
with matplotlib's object API on the Agg canvas, never through `pyplot`: no display is
needed, the caller's backend (e.g. a notebook's inline one) is left alone and no
figure is registered globally, so nothing accumulates across calls.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# Where each name lives. The package loads a submodule (and matplotlib, ~1-2 s) on the first
# use of one of its names, not on `from qdrl import plotting`: the algorithms import this
# package at the top, and a run that plots nothing (a test, `qdrl validate`) never pays for it.
# The `_name`s are helpers the tests reach as `plotting._name`, not public API.
_WHERE = {
    "COUNTER_KEYS": "_common",
    "X_KEYS": "_common",
    "_compact": "_common",
    "_new_figure": "_common",
    "_points": "_common",
    "_tidy_x": "_common",
    "_draw_comparison": "curves",
    "default_x_keys": "curves",
    "default_y_keys": "curves",
    "plot_comparison": "curves",
    "plot_curves": "curves",
    "plot_fitness_ecdf": "distributions",
    "plot_fitness_histogram": "distributions",
    "plot_learnt_descriptors": "learnt",
    "plot_cell_fronts": "pareto",
    "plot_cell_hypervolumes": "pareto",
    "plot_pareto_front": "pareto",
    "_colour_scale": "repertoires",
    "_draw_repertoire": "repertoires",
    "plot_repertoire": "repertoires",
    "plot_repertoires": "repertoires",
    "Wall": "skills",
    "draw_walls": "skills",
    "env_walls": "skills",
    "plot_skills": "skills",
    "plot_feature_skills": "feature_skills",
    "plot_profiles": "feature_skills",
    "Elites": "sources",
    "elites_of": "sources",
    "plot_parallel_axes": "summary",
    "plot_qd_summary": "summary",
    "plot_rl_summary": "summary",
}

if TYPE_CHECKING:
    from qdrl.plotting._common import COUNTER_KEYS, X_KEYS
    from qdrl.plotting._common import _compact as _compact
    from qdrl.plotting._common import _new_figure as _new_figure
    from qdrl.plotting._common import _points as _points
    from qdrl.plotting._common import _tidy_x as _tidy_x
    from qdrl.plotting.curves import _draw_comparison as _draw_comparison
    from qdrl.plotting.curves import default_x_keys, default_y_keys, plot_comparison, plot_curves
    from qdrl.plotting.distributions import plot_fitness_ecdf, plot_fitness_histogram
    from qdrl.plotting.feature_skills import plot_feature_skills, plot_profiles
    from qdrl.plotting.learnt import plot_learnt_descriptors
    from qdrl.plotting.pareto import plot_cell_fronts, plot_cell_hypervolumes, plot_pareto_front
    from qdrl.plotting.repertoires import _colour_scale as _colour_scale
    from qdrl.plotting.repertoires import _draw_repertoire as _draw_repertoire
    from qdrl.plotting.repertoires import plot_repertoire, plot_repertoires
    from qdrl.plotting.skills import Wall, draw_walls, env_walls, plot_skills
    from qdrl.plotting.sources import Elites, elites_of
    from qdrl.plotting.summary import plot_parallel_axes, plot_qd_summary, plot_rl_summary


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    globals()[name] = value  # found once, then an ordinary attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})


__all__ = [
    "COUNTER_KEYS",
    "X_KEYS",
    "Elites",
    "Wall",
    "default_x_keys",
    "default_y_keys",
    "draw_walls",
    "elites_of",
    "env_walls",
    "plot_cell_fronts",
    "plot_cell_hypervolumes",
    "plot_comparison",
    "plot_curves",
    "plot_feature_skills",
    "plot_fitness_ecdf",
    "plot_fitness_histogram",
    "plot_learnt_descriptors",
    "plot_parallel_axes",
    "plot_pareto_front",
    "plot_profiles",
    "plot_qd_summary",
    "plot_repertoire",
    "plot_repertoires",
    "plot_rl_summary",
    "plot_skills",
]
