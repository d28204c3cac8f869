"""Repertoire plots from a repertoire, a loaded run or a DataFrame; parallel axes for N-D
descriptors; the one-figure summary of a QD run."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.image import imread

from qdrl import plotting
from qdrl.qd.repertoires import to_table


def _axes() -> tuple[Figure, object]:
    fig = Figure()
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def grid() -> plotting.Elites:
    """A 4 x 4 grid of [0, 1] x [0, 2] (host arrays: nothing to compile) with three elites."""
    fitnesses = np.full(16, -np.inf)
    descriptors = np.zeros((16, 2))
    for cell, d, f in ((0, [0.1, 0.1], 1.0), (6, [0.6, 1.1], 2.0), (15, [0.9, 1.9], 3.0)):
        fitnesses[cell], descriptors[cell] = f, d
    centroids = np.stack(np.meshgrid(np.arange(4) / 4 + 0.125, np.arange(4) / 2 + 0.25, indexing="ij"), -1)
    return plotting.Elites(
        fitnesses, descriptors, centroids.reshape(16, 2), (4, 4), np.array([0.0, 0.0]), np.array([1.0, 2.0])
    )


def archive_4d(descriptors: np.ndarray, fitnesses: list[float]) -> plotting.Elites:
    """An unstructured archive of 8 slots, the first ones filled."""
    f = np.full(8, -np.inf)
    d = np.zeros((8, 4))
    f[: len(fitnesses)], d[: len(fitnesses)] = fitnesses, descriptors
    return plotting.Elites(f, d)


def test_a_heatmap_from_a_loaded_run_takes_its_bounds_and_names() -> None:
    run = SimpleNamespace(
        repertoire=grid(), metrics=pd.DataFrame(), summary={
            "descriptor_low": [0.0, 0.0], "descriptor_high": [1.0, 2.0], "descriptor_names": ["speed", "height"],
        },
    )
    ax = plotting.plot_repertoire(run)
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("speed", "height")
    assert ax.get_xlim() == (0.0, 1.0) and ax.get_ylim() == (0.0, 2.0)


def test_a_heatmap_from_a_dataframe_draws_its_elites_as_points() -> None:
    table = pd.DataFrame(to_table(grid(), ("speed", "height")))
    _, ax = _axes()
    assert plotting.plot_repertoire(table, ax=ax) is ax
    np.testing.assert_allclose(ax.collections[0].get_offsets(), [[0.1, 0.1], [0.6, 1.1], [0.9, 1.9]], rtol=1e-6)
    assert ax.get_xlabel() == "speed"  # from the column descriptor_speed
    lo, hi = ax.get_xlim()
    assert lo < 0.1 and hi > 0.9  # the elites' range, padded
    with pytest.raises(ValueError, match="needs a `fitness` column and `descriptor_\\*` columns"):
        plotting.plot_repertoire(pd.DataFrame({"x": [1.0]}))


def test_parallel_axes_draw_every_elite_of_a_4d_archive(tmp_path: Path) -> None:
    descriptors = np.array([[0.0, 0.5, 1.0, 0.25], [1.0, 0.0, 0.5, 0.75], [0.5, 0.5, 0.5, 0.5]])
    rep = archive_4d(descriptors, [3.0, 1.0, 2.0])
    _, ax = _axes()
    assert plotting.plot_parallel_axes(rep, low=0.0, high=1.0, labels=["a", "b", "c", "d"], ax=ax) is ax
    (lines,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    segments = lines.get_segments()
    assert len(segments) == 3
    np.testing.assert_allclose(lines.get_array(), [1.0, 2.0, 3.0])  # fittest drawn last
    np.testing.assert_allclose(segments[-1][:, 1], descriptors[0])  # scaled to [low, high] = [0, 1]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a", "b", "c", "d"]
    path = plotting.plot_parallel_axes(rep, tmp_path / "p.png", 0.0, 1.0)
    assert imread(path).shape[0] > 100


def test_the_qd_summary_is_one_figure_of_four_panels(tmp_path: Path) -> None:
    rows = [
        {"iteration": 10 * i, "evaluations": 100 * i, "env_steps": 0, "qd_score": 1.0 * i, "coverage": 0.1 * i,
         "max_fitness": 0.5 * i} for i in range(1, 5)
    ]
    fig = Figure()
    FigureCanvasAgg(fig)
    assert plotting.plot_qd_summary(rows, grid(), low=(0.0, 0.0), high=(1.0, 2.0), fig=fig) is fig
    panels = [a for a in fig.axes if a.get_label() != "<colorbar>"]
    assert [a.get_title() for a in panels] == ["qd score", "coverage", "max fitness", "final repertoire"]
    assert panels[0].get_xlabel() == "evaluations"  # the run's cost (no env steps)
    np.testing.assert_allclose(panels[0].get_lines()[0].get_ydata(), [1.0, 2.0, 3.0, 4.0])
    # a loaded run gives both; a 4-D repertoire is drawn in parallel axes
    rep = archive_4d(np.full((1, 4), 0.5), [1.0])
    run = SimpleNamespace(repertoire=rep, metrics=pd.DataFrame(rows), summary=None, algorithm="me", task_name="t")
    path = plotting.plot_qd_summary(run, path=tmp_path / "summary.png")
    assert imread(path).shape[1] > 1000
    new = plotting.plot_qd_summary(run)
    assert new._suptitle.get_text() == "me on t"
    assert any(isinstance(c, LineCollection) for c in new.axes[3].collections)
