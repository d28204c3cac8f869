"""Plots of runs: learning curves, QD repertoire heatmaps, Pareto fronts and skills.

Modules by what they draw: `curves` (one run's metrics, runs compared), `repertoires`
(fitness heatmaps), `pareto` (fronts, MOME's cells), `skills` (trajectories, maze
walls); `_common` holds the shared helpers.

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

# The `_name as _name` imports are helpers the tests reach as `plotting._name`, not public API.
from qdrl.plotting._common import COUNTER_KEYS, X_KEYS
from qdrl.plotting._common import _compact as _compact
from qdrl.plotting._common import _new_figure as _new_figure
from qdrl.plotting._common import _points as _points
from qdrl.plotting._common import _tidy_x as _tidy_x
from qdrl.plotting.curves import _draw_comparison as _draw_comparison
from qdrl.plotting.curves import default_x_keys, default_y_keys, plot_comparison, plot_curves
from qdrl.plotting.pareto import plot_cell_fronts, plot_cell_hypervolumes, plot_pareto_front
from qdrl.plotting.repertoires import _colour_scale as _colour_scale
from qdrl.plotting.repertoires import _draw_repertoire as _draw_repertoire
from qdrl.plotting.repertoires import plot_repertoire, plot_repertoires
from qdrl.plotting.skills import Wall, draw_walls, env_walls, plot_skills

__all__ = [
    "COUNTER_KEYS",
    "X_KEYS",
    "Wall",
    "default_x_keys",
    "default_y_keys",
    "draw_walls",
    "env_walls",
    "plot_cell_fronts",
    "plot_cell_hypervolumes",
    "plot_comparison",
    "plot_curves",
    "plot_pareto_front",
    "plot_repertoire",
    "plot_repertoires",
    "plot_skills",
]
