"""Tests for qdrl.plotting.plot_repertoire: valid PNGs for every kind of repertoire."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import pytest
from matplotlib.image import imread

from qdrl.plotting import plot_repertoire
from qdrl.qd.repertoires import cvt_repertoire, grid_repertoire, unstructured_repertoire

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path) -> np.ndarray:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    assert float(np.ptp(image[..., :3])) > 0.5  # not a blank canvas
    return image


def filled(repertoire, num: int = 60, seed: int = 0):
    """The repertoire after `num` random candidates in [0, 1]^D with fitness = sum of descriptors."""
    dim = repertoire.descriptors.shape[1]
    descriptors = np.random.default_rng(seed).uniform(size=(num, dim)).astype(np.float32)
    return jit_add(repertoire, descriptors, descriptors.sum(-1))


@jax.jit
def jit_add(repertoire, descriptors, fitnesses):
    return repertoire.add(None, descriptors, fitnesses)[0]


def colourful_fraction(image: np.ndarray) -> float:
    """Share of pixels that are neither white nor grey (the colour-mapped ones)."""
    rgb = image[..., :3]
    return float(np.mean(np.ptp(rgb, axis=-1) > 0.1))


CENTROIDS_2D = np.random.default_rng(1).uniform(size=(40, 2)).astype(np.float32)
CENTROIDS_3D = np.random.default_rng(2).uniform(size=(60, 3)).astype(np.float32)


@pytest.mark.parametrize(
    ("name", "make", "dims"),
    [
        ("grid_2d", lambda: grid_repertoire(None, (10, 8), 0.0, 1.0), (0, 1)),
        ("cvt_2d", lambda: cvt_repertoire(None, CENTROIDS_2D), (0, 1)),
        ("grid_3d", lambda: grid_repertoire(None, (5, 4, 3), 0.0, 1.0), (2, 0)),
        ("cvt_3d", lambda: cvt_repertoire(None, CENTROIDS_3D), (0, 2)),
        ("unstructured", lambda: unstructured_repertoire(None, 64, 2, 0.05), (0, 1)),
        ("grid_1d", lambda: grid_repertoire(None, (10,), 0.0, 1.0), (0, 1)),
    ],
)
def test_plot_repertoire_writes_png(tmp_path: Path, name, make, dims):
    repertoire = filled(make())
    path = plot_repertoire(
        repertoire, tmp_path / "plots" / f"{name}.png", 0.0, 1.0, title=name, dims=dims
    )
    assert path == tmp_path / "plots" / f"{name}.png"
    image = assert_png(path)
    assert colourful_fraction(image) > 0.02


def test_empty_cells_are_white(tmp_path: Path):
    # One elite in a 4 x 4 grid: the plot area is mostly white, with one coloured square.
    one = grid_repertoire(None, (4, 4), 0.0, 1.0)
    fitnesses = np.full(60, np.nan, np.float32)
    fitnesses[0] = 1.0
    one = jit_add(one, np.full((60, 2), 0.1, np.float32), fitnesses)
    full = grid_repertoire(None, (4, 4), 0.0, 1.0)
    centres = np.resize(np.asarray(full.centroids), (60, 2))  # every cell, some twice
    full = jit_add(full, centres, centres.sum(-1))
    assert bool(full.num_filled == 16)
    sparse = assert_png(plot_repertoire(one, tmp_path / "one.png", 0.0, 1.0))
    dense = assert_png(plot_repertoire(full, tmp_path / "full.png", 0.0, 1.0))
    assert colourful_fraction(dense) > colourful_fraction(sparse) + 0.2


def test_empty_repertoire_and_fixed_colour_range(tmp_path: Path):
    empty = grid_repertoire(None, (4, 4), 0.0, 1.0)
    assert_png(plot_repertoire(empty, tmp_path / "empty.png", 0.0, 1.0, title="empty"))
    cvt = filled(cvt_repertoire(None, CENTROIDS_2D))
    assert_png(
        plot_repertoire(cvt, tmp_path / "fixed.png", 0.0, 1.0, vmin=0.0, vmax=2.0, cmap="magma")
    )


def test_plot_repertoire_rejects_bad_dims_and_bounds(tmp_path: Path):
    repertoire = grid_repertoire(None, (4, 4, 4), 0.0, 1.0)
    with pytest.raises(ValueError, match="dims"):
        plot_repertoire(repertoire, tmp_path / "x.png", 0.0, 1.0, dims=(1, 1))
    with pytest.raises(ValueError, match="dims"):
        plot_repertoire(repertoire, tmp_path / "x.png", 0.0, 1.0, dims=(0, 3))
    with pytest.raises(ValueError, match="3 entries"):
        plot_repertoire(repertoire, tmp_path / "x.png", (0.0, 0.0), 1.0)
    with pytest.raises(ValueError, match="low < high"):
        plot_repertoire(repertoire, tmp_path / "x.png", 1.0, 0.0)


def test_plot_accepts_device_arrays(tmp_path: Path):
    repertoire = jax.device_put(filled(grid_repertoire(None, (6, 6), 0.0, 1.0)))
    assert_png(plot_repertoire(repertoire, tmp_path / "device.png", 0.0, 1.0))
