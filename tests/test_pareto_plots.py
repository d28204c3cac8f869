"""Pareto-front plots in the objectives' own view: ZDT and DTLZ2 minimise, qdrl scores them negated."""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from qdrl import plotting
from qdrl.tasks import make_task


def test_minimised_tasks_are_drawn_as_the_literature_draws_them() -> None:
    assert make_task("zdt1").minimised and make_task("dtlz2").minimised
    assert not make_task("mo_rastrigin").minimised  # two rastrigins, maximised as scored
    fitnesses = np.array([[-0.1, -0.8], [-0.5, -0.3], [-0.9, -0.05]])  # ZDT1 scores: minus (f1, f2)
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    assert plotting.plot_pareto_front({"nsga2": fitnesses}, reference=(-1.0, -1.0), ax=ax, minimised=True) is ax
    np.testing.assert_allclose(ax.collections[0].get_offsets(), -fitnesses)
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("f1 (minimised)", "f2 (minimised)")
    lines = {line.get_label(): line for line in ax.get_lines()}
    np.testing.assert_allclose(lines["reference point"].get_xydata(), [[1.0, 1.0]])
    staircase = next(line for line in ax.get_lines() if line.get_label().startswith("_"))
    xy = staircase.get_xydata()
    assert xy.min() >= 0.05 - 1e-12 and xy.max() <= 1.0 + 1e-12  # inside the minimisation box


def test_maximised_fronts_are_drawn_as_scored() -> None:
    fitnesses = np.array([[-100.0, -20.0], [-30.0, -90.0]])
    ax = plotting.plot_pareto_front({"mome": fitnesses}, reference=(-150.0, -150.0))
    np.testing.assert_allclose(ax.collections[0].get_offsets(), fitnesses)
    assert ax.get_xlabel() == "objective 0"
