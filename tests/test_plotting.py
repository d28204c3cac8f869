"""Tests for qdrl.plotting: PNGs written, gaps skipped, bad keys rejected, no figure leak."""

from __future__ import annotations

import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from matplotlib.image import imread

from qdrl import plotting

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > 5_000  # axes, ticks and a curve, not an empty canvas
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    # Not a blank image: some pixels differ from the background.
    assert float(np.ptp(image[..., :3])) > 0.5


def run_rows(n: int = 20, scale: float = 1.0) -> list[dict]:
    return [
        {
            "iteration": i,
            "env_steps": 1000 * i,
            "wall_s": 0.5 * i,
            "eval_return": scale * math.sqrt(i),
            "actor_loss": 1.0 / (i + 1),
        }
        for i in range(n)
    ]


def test_plot_curves_writes_one_png_per_metric(tmp_path: Path) -> None:
    out = tmp_path / "plots" / "run0"  # created, parents included
    paths = plotting.plot_curves(run_rows(), out, title="sac / halfcheetah")
    assert paths == [out / "eval_return.png", out / "actor_loss.png"]
    for p in paths:
        assert_png(p)
    # Two panels side by side (vs env steps, vs wall time): wider than tall.
    height, width = imread(paths[0]).shape[:2]
    assert width > 2 * height


def test_nan_missing_and_non_numeric_values_are_skipped(tmp_path: Path) -> None:
    rows = run_rows(10)
    rows[2]["eval_return"] = float("nan")
    del rows[3]["eval_return"]
    rows[4]["eval_return"] = None
    rows[5]["eval_return"] = float("inf")
    rows[6]["wall_s"] = float("nan")  # missing x drops the point from that panel only
    rows[7]["eval_return"] = jnp.float32(2.5)  # 0-d jax arrays are numbers
    rows[8]["note"] = "restarted"  # a string column is not a metric
    rows[9]["sps"] = np.float64(123.0)  # a column appearing late is still plotted
    assert plotting.default_y_keys(rows) == ["eval_return", "actor_loss", "sps"]
    assert plotting._points(rows, "wall_s", "eval_return")[0] == [0.0, 0.5, 3.5, 4.0, 4.5]

    paths = plotting.plot_curves(rows, tmp_path)
    assert [p.name for p in paths] == ["eval_return.png", "actor_loss.png", "sps.png"]
    for p in paths:
        assert_png(p)


def test_metric_without_any_finite_value_still_gives_a_png(tmp_path: Path) -> None:
    rows = [{"env_steps": i, "wall_s": i, "q": float("nan")} for i in range(3)]
    (path,) = plotting.plot_curves(rows, tmp_path, y_keys=["q"])
    assert path.read_bytes()[:8] == PNG_SIGNATURE


def test_plot_curves_explicit_keys_and_file_names(tmp_path: Path) -> None:
    rows = [{"env_steps": i, "wall_s": i, "evaluations": 2 * i, "eval/return": i} for i in range(5)]
    paths = plotting.plot_curves(rows, tmp_path, x_keys=("evaluations",), y_keys=["eval/return"])
    assert paths == [tmp_path / "eval_return.png"]  # no subdirectory from "/"
    assert_png(paths[0])
    with pytest.raises(ValueError, match=r"y keys \['nope'\] appear in no row"):
        plotting.plot_curves(rows, tmp_path, y_keys=["nope"])
    with pytest.raises(ValueError, match=r"x key 'frames' appears in no row"):
        plotting.plot_curves(rows, tmp_path, x_keys=("frames",))


def test_plot_comparison(tmp_path: Path) -> None:
    runs = {"sac": run_rows(30), "td3": run_rows(25, scale=1.5), "pbt": run_rows(1)}
    runs["td3"][4]["eval_return"] = float("nan")
    path = plotting.plot_comparison(runs, "eval_return", "env_steps", tmp_path / "cmp" / "ret.png")
    assert path == tmp_path / "cmp" / "ret.png"
    assert_png(path)


def test_plot_comparison_rejects_unknown_keys(tmp_path: Path) -> None:
    runs = {"sac": run_rows(5)}
    with pytest.raises(ValueError, match=r"y_key 'qd_score' appears in no row"):
        plotting.plot_comparison(runs, "qd_score", "env_steps", tmp_path / "x.png")
    with pytest.raises(ValueError, match=r"x_key 'frames'"):
        plotting.plot_comparison(runs, "eval_return", "frames", tmp_path / "x.png")
    with pytest.raises(ValueError, match="empty"):
        plotting.plot_comparison({}, "eval_return", "env_steps", tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_no_pyplot_figures_left_open(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    for _ in range(3):
        plotting.plot_curves(run_rows(5), tmp_path)
        plotting.plot_comparison({"a": run_rows(5)}, "eval_return", "wall_s", tmp_path / "c.png")
    assert plt.get_fignums() == before
