"""Tests for qdrl.plotting.distributions (fitness histogram, empirical CDF over seeds), parallel
axes from plain arrays, and their place in `qdrl report`. No run is compiled: the runs are
directories written here by hand."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.axes import Axes

from qdrl import plotting
from qdrl.plotting import Elites
from qdrl.qd.repertoires import export_npz, grid_repertoire, write_csv
from qdrl.report import report

RNG = np.random.default_rng(0)


def test_the_histogram_of_one_archive_and_of_several(tmp_path: Path) -> None:
    fitnesses = np.concatenate([RNG.normal(size=200), np.full(50, -np.inf)])  # empty cells left out
    path = plotting.plot_fitness_histogram(fitnesses, tmp_path / "sub" / "hist.png", title="one")
    assert path == tmp_path / "sub" / "hist.png" and path.stat().st_size > 10_000
    ax = plotting.plot_fitness_histogram({"a": [0.0, 1.0, 1.0, 2.0, 3.0, -np.inf], "b": [1.0, 2.0]}, bins=3)
    assert isinstance(ax, Axes)
    # One outline per archive on common bins [0, 1), [1, 2), [2, 3]; a step outline's
    # vertices hold each bin's count at every other point.
    counts = [patch.get_xy()[1:-1:2, 1].tolist() for patch in ax.patches]
    assert counts == [[1, 2, 2], [0, 1, 1]]
    assert [text.get_text() for text in ax.get_legend().get_texts()] == ["a (5 elites)", "b (2 elites)"]
    empty = plotting.plot_fitness_histogram(np.full(4, -np.inf), tmp_path / "empty.png")
    assert empty.stat().st_size > 5_000


def test_the_ecdf_of_several_seeds_is_their_median_with_a_min_max_band(tmp_path: Path) -> None:
    seeds = [np.array([1.0, 2.0]), np.array([2.0, 3.0, -np.inf]), np.array([0.0, 4.0])]
    ax = plotting.plot_fitness_ecdf({"spec": seeds, "one": np.array([1.5])})
    (median, single) = ax.lines
    # At each value any seed holds, the share of each seed's elites at or below it, then the median.
    np.testing.assert_array_equal(median.get_xdata(), [0.0, 1.0, 2.0, 3.0, 4.0])
    by_seed = np.array([[0, 0.5, 1, 1, 1], [0, 0, 0.5, 1, 1], [0.5, 0.5, 0.5, 0.5, 1]])
    np.testing.assert_allclose(median.get_ydata(), np.median(by_seed, axis=0))
    assert median.get_label() == "spec (median of 3 seeds)" and single.get_label() == "one"
    band = ax.collections[0].get_paths()[0].vertices
    assert band[:, 1].min() == 0.0 and band[:, 1].max() == 1.0
    path = plotting.plot_fitness_ecdf({"spec": seeds, "nothing": [np.full(3, -np.inf)]}, tmp_path / "ecdf.png")
    assert path.stat().st_size > 10_000
    with pytest.raises(ValueError, match="band"):
        plotting.plot_fitness_ecdf({"spec": seeds}, band=(0.9, 0.1))


def test_parallel_axes_from_plain_arrays(tmp_path: Path) -> None:
    descriptors, fitnesses = RNG.uniform(size=(30, 4)), RNG.normal(size=30)
    path = plotting.plot_parallel_axes(
        Elites(fitnesses, descriptors), tmp_path / "parallel.png", 0.0, 1.0, labels=["a", "b", "c", "d"]
    )
    assert path.stat().st_size > 10_000


def qd_run(path: Path, seed: int, scale: float, csv_only: bool = False) -> None:
    """A finished QD run of the arm: config.toml, metrics.csv, summary.json and its repertoire."""
    path.mkdir(parents=True)
    (path / "config.toml").write_text(
        f'[experiment]\nalgorithm = "map_elites"\nseed = {seed}\nname = "{path.parent.name}"\n\n[task]\nname = "arm"\n'
    )
    rows = [{"log_point": i, "evaluations": 100 * (i + 1), "qd_score": scale * i, "wall_s": 1.0 + i} for i in range(3)]
    with (path / "metrics.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (path / "summary.json").write_text(json.dumps({"descriptor_low": [0, 0], "descriptor_high": [1, 1], **rows[-1]}))
    rep = grid_repertoire(None, (5, 5), 0.0, 1.0)
    rep, _ = rep.add(None, RNG.uniform(size=(40, 2)), scale * RNG.normal(size=40))
    write_csv(rep, path / "repertoire.csv")
    if not csv_only:
        export_npz(rep, path / "repertoire.npz")


def test_the_report_draws_the_fitness_distributions_of_qd_runs(tmp_path: Path) -> None:
    for seed in range(3):
        qd_run(tmp_path / "runs" / "me" / f"seed_{seed}", seed, 1.0)
    qd_run(tmp_path / "runs" / "other" / "seed_0", 0, 2.0, csv_only=True)
    result = report([tmp_path / "runs"], tmp_path / "report", resamples=100)
    found = result["groups"]["arm"]["distributions"]
    assert set(found) == {"histogram", "ecdf"}
    for name in ("fitness_histogram", "fitness_ecdf"):
        path = tmp_path / "report" / "arm" / f"{name}.png"
        assert path.stat().st_size > 10_000 and str(path) in found.values()
    table = (tmp_path / "report" / "report.md").read_text()
    assert "(arm/fitness_histogram.png)" in table and "(arm/fitness_ecdf.png)" in table
    assert "(arm/repertoires.png)" in table  # the existing figures stay
