"""Tests for qdrl.plotting: PNGs written, gaps skipped, bad keys rejected, no figure leak."""

from __future__ import annotations

import itertools
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


# --- the researcher's figures: ticks, seeds, descriptor names, maze walls -------------


def _extents(ax: object, fig: object) -> list[tuple[float, float]]:
    """The horizontal pixel extent of each visible x tick label of `ax`, after drawing."""
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    labels = [t for t in ax.get_xticklabels() if t.get_text() and t.get_visible()]  # type: ignore[attr-defined]
    return sorted((b.x0, b.x1) for b in (t.get_window_extent(renderer) for t in labels))


@pytest.mark.parametrize("top", [150_000.0, 3.2e6, 12.5, 1_000_000_000.0])
def test_x_tick_labels_never_overlap(top: float) -> None:
    fig = plotting._new_figure(2)  # the width of a panel of plot_curves
    ax = fig.subplots(1, 2)[0]
    xs = np.linspace(0.0, top, 40)
    ax.plot(xs, np.sqrt(xs))
    plotting._tidy_x(ax)
    fig.canvas.draw()
    extents = _extents(ax, fig)
    assert 2 <= len(extents) <= 7
    for (_, right), (left, _) in itertools.pairwise(extents):
        assert right < left, extents


def test_compact_tick_labels() -> None:
    assert [plotting._compact(v) for v in (0.0, 12.5, 150_000.0, 2_500_000.0, -3000.0)] == [
        "0", "12.5", "150k", "2.5M", "-3k"
    ]


def test_default_x_keys_leave_out_columns_that_are_zero_everywhere() -> None:
    qd_function = [{"evaluations": 100 * i, "env_steps": 0, "wall_s": 0.1 * i} for i in range(1, 4)]
    rl = [{"env_steps": 1000 * i, "wall_s": 0.1 * i} for i in range(1, 4)]
    assert plotting.default_x_keys(qd_function) == ["evaluations", "wall_s"]
    assert plotting.default_x_keys(rl) == ["env_steps", "wall_s"]


def test_seeds_are_drawn_as_their_mean_and_a_band(tmp_path: Path) -> None:
    seeds = [run_rows(10, scale=s) for s in (1.0, 2.0, 3.0)]
    fig = plotting._new_figure(1)
    ax = fig.subplots()
    plotting._draw_comparison(ax, {"sac": seeds, "td3": [run_rows(10, scale=5.0)]}, "env_steps", "eval_return", 0.95)
    mean_line, single_line = ax.lines
    np.testing.assert_allclose(mean_line.get_ydata(), [2.0 * math.sqrt(i) for i in range(10)])
    assert mean_line.get_label() == "sac (3 seeds)" and single_line.get_label() == "td3"
    (band,) = ax.collections  # one band: the single run has none
    lows = band.get_paths()[0].vertices[:, 1]
    assert lows.min() <= 0.0 and lows.max() >= 3.0 * math.sqrt(9) - 1e-6
    path = plotting.plot_comparison(
        {"sac": seeds}, "eval_return", ["env_steps", "wall_s"], tmp_path / "seeds.png"
    )
    assert_png(path)
    assert imread(path).shape[1] > 2 * imread(path).shape[0]  # two panels side by side


def sac_rows(n: int = 6) -> list[dict]:
    """An RL run's metrics.csv rows: counters, the evaluation, the archive's QD metrics, losses."""
    return [
        {
            "log_point": i, "env_steps": 200 * (i + 1), "grad_steps": 50 * i, "eval_return": -30.0 + i,
            "eval_return_std": 0.5 * (i + 1), "actor_loss": 1.0 / (i + 1), "alpha": 1.0 - 0.1 * i,
            "coverage": 0.01 * i, "critic_loss": 3.0 - 0.4 * i, "qd_score": 10.0 * i,
            "train_return": float("nan") if i < 2 else -31.0 + i, "wall_s": 0.5 * i,
        }
        for i in range(n)
    ]


def _titles(fig: object) -> list[str]:
    return [a.get_title() for a in fig.axes if a.get_label() != "<colorbar>"]  # type: ignore[attr-defined]


def test_the_rl_summary_draws_the_return_first_and_largest_then_the_archive_and_every_metric(
    tmp_path: Path,
) -> None:
    from matplotlib.collections import PolyCollection, QuadMesh
    from matplotlib.figure import Figure

    rows = sac_rows()
    fig = Figure()
    archive = _grid_rep(np.where(np.arange(16) % 5 == 0, np.arange(16.0), -np.inf))
    assert plotting.plot_rl_summary(rows, archive, None, (0.0, 0.0), (1.0, 1.0), ["x", "y"], fig=fig) is fig
    # the archive's curves, then the losses, then the rest in metrics.csv's order; no counters
    assert _titles(fig) == [
        "evaluation return", "qd score", "coverage", "actor loss", "critic loss", "alpha", "train return",
        "passive archive",
    ]
    main, *small, heatmap = (a for a in fig.axes if a.get_label() != "<colorbar>")
    assert main.get_xlabel() == "environment steps"
    np.testing.assert_allclose(main.get_lines()[0].get_xdata(), [200.0 * (i + 1) for i in range(6)])
    np.testing.assert_allclose(main.get_lines()[0].get_ydata(), [-30.0 + i for i in range(6)])
    (band,) = [c for c in main.collections if isinstance(c, PolyCollection)]  # return ± std
    ys = band.get_paths()[0].vertices[:, 1]
    assert math.isclose(ys.min(), -30.5) and math.isclose(ys.max(), -25.0 + 3.0)
    area = [a.get_position().width * a.get_position().height for a in (main, *small)]
    assert area[0] > 3 * max(area[1:])
    np.testing.assert_allclose(small[-1].get_lines()[0].get_ydata(), [-29.0, -28.0, -27.0, -26.0])  # NaN skipped
    (mesh,) = [c for c in heatmap.collections if isinstance(c, QuadMesh)]
    assert int(np.ma.masked_invalid(mesh.get_array()).count()) == 4  # the filled cells
    assert (heatmap.get_xlabel(), heatmap.get_ylabel()) == ("x", "y")
    path = plotting.plot_rl_summary(rows, archive, tmp_path / "plots" / "summary.png", (0.0, 0.0), (1.0, 1.0))
    assert path == tmp_path / "plots" / "summary.png"
    assert_png(path)


def test_the_rl_summary_of_a_loaded_run_a_dataframe_and_a_population() -> None:
    import types

    import pandas as pd
    from matplotlib.figure import Figure

    archive = _grid_rep(np.arange(16.0))
    run = types.SimpleNamespace(
        metrics=pd.DataFrame(sac_rows()), repertoire=archive, algorithm="td3", task_name="point",
        summary={"descriptor_low": [0.0, 0.0], "descriptor_high": [1.0, 1.0], "descriptor_names": ["a", "b"]},
    )
    new = plotting.plot_rl_summary(run)
    assert new._suptitle.get_text() == "td3 on point" and _titles(new)[-1] == "passive archive"
    assert new.axes[-2].get_xlabel() == "a"  # the run's descriptor names
    # a DataFrame without an archive: the curves only
    assert "passive archive" not in _titles(plotting.plot_rl_summary(run.metrics))
    # PBT: the best member's return beside the population's median and mean; members on one panel
    rows = [
        {**row, "eval_return_m0": row["eval_return"], "eval_return_m1": row["eval_return"] - 2.0,
         "eval_return_median": row["eval_return"] - 1.0, "eval_return_mean": row["eval_return"] - 1.0,
         "member_env_steps": row["env_steps"] // 2}
        for row in sac_rows()
    ]
    fig = plotting.plot_rl_summary(rows, archive, low=0.0, high=1.0, fig=Figure())
    assert _titles(fig)[:4] == ["evaluation return", "qd score", "coverage", "members' eval return"]
    assert "member env steps" not in _titles(fig)  # a counter
    main, _, _, members = fig.axes[:4]
    assert main.get_legend_handles_labels()[1] == [
        "best member", "± std over episodes", "population median", "population mean"
    ]
    assert [line.get_label() for line in members.get_lines()] == ["m0", "m1"]


def test_heatmap_axes_carry_the_descriptor_names(tmp_path: Path) -> None:
    import types

    fitnesses = np.full(16, -np.inf)
    fitnesses[[1, 14]] = [1.0, 2.0]  # a 4 x 4 grid, read by duck typing
    rep = types.SimpleNamespace(
        fitnesses=fitnesses, descriptors=np.zeros((16, 2)), centroids=np.zeros((16, 2)),
        grid_shape=(4, 4), low=(0.0, 0.0), high=(1.0, 1.0),
    )
    fig = plotting._new_figure(1)
    ax = fig.subplots()
    norm, colours = plotting._colour_scale([rep], None, None, "viridis")
    plotting._draw_repertoire(ax, rep, 0.0, 1.0, (0, 1), norm, colours, ["back foot contact", "front foot contact"])
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("back foot contact", "front foot contact")
    with pytest.raises(ValueError, match=r"labels: expected 2 names"):
        plotting.plot_repertoire(rep, tmp_path / "x.png", 0.0, 1.0, labels=["x"])
    both = plotting.plot_repertoires({"a": rep, "b": rep}, tmp_path / "both.png", 0.0, 1.0, labels=["x", "y"])
    assert_png(both)


def test_tasks_name_their_descriptors() -> None:
    from qdrl.envs.brax import FEET, FEET_NAMES
    from qdrl.tasks import Task, make_task

    assert make_task("arm", num_dofs=4).descriptor_names == ("end-effector x", "end-effector y")
    plain = Task("t", make_task("arm").scoring_fn, (0.0, 0.0), (1.0, 1.0), 4, 0.0, 1.0, 0.0)
    assert plain.descriptor_names == ("descriptor 0", "descriptor 1")  # the default
    with pytest.raises(ValueError, match=r"t: expected 2 descriptor names, got \['x'\]"):
        Task("t", plain.scoring_fn, (0.0, 0.0), (1.0, 1.0), 4, 0.0, 1.0, 0.0, descriptor_names=("x",))
    assert {k: len(v) for k, v in FEET_NAMES.items()} == {k: len(v) for k, v in FEET.items()}
    assert FEET_NAMES["halfcheetah"] == ("back foot contact", "front foot contact")


def test_the_skills_plot_draws_the_maze_walls(tmp_path: Path) -> None:
    from qdrl.envs.point_maze import QDAX_WALLS, PointMazeEnv

    walls = plotting.env_walls(PointMazeEnv(episode_length=5))
    np.testing.assert_allclose([[*a, *b, r] for a, b, r in walls], [[*a, *b, 0.0] for a, b in QDAX_WALLS])
    assert plotting.env_walls(object()) == []
    t = np.linspace(0.0, 1.0, 6)
    traj = np.stack([np.stack([t * 0.5 - 0.9, t * 0.2 - 0.9], -1)] * 2, axis=1)  # (T, 2, 2), away from the walls
    args = (traj, np.array([0, 1]), np.ones((6, 2)))
    # The whole maze in view (the default fits the axes to the paths, far from the walls).
    plain = plotting.plot_skills(*args, tmp_path / "plain.png", (-1.0, -1.0), (1.0, 1.0), bounds="task")
    walled = plotting.plot_skills(
        *args, tmp_path / "walls.png", (-1.0, -1.0), (1.0, 1.0), walls=walls, bounds="task"
    )
    a, b = imread(plain)[..., :3], imread(walled)[..., :3]
    assert a.shape == b.shape
    dark = (b.max(axis=-1) < 0.35) & (a.min(axis=-1) > 0.9)  # wall pixels: grey where white was
    assert dark.sum() > 500


def _paths(num_episodes: int, offset: float = 0.0) -> np.ndarray:
    """(6, B, 2) straight paths in [-0.6, -0.1] x [-0.5, 0.0]: episode b heads its own way."""
    t = np.linspace(0.0, 1.0, 6)[:, None]
    angle = np.linspace(0.0, np.pi / 2, num_episodes)[None]
    return np.stack([-0.6 + 0.5 * t * np.cos(angle) + offset, -0.5 + 0.5 * t * np.sin(angle)], axis=-1)


def test_the_skills_plot_names_the_skills_and_shows_several_evaluations() -> None:
    from matplotlib.figure import Figure
    from matplotlib.legend import Legend

    skills = np.arange(8) % 4
    evaluations = {f"{n} env steps": _paths(8, 0.05 * i) for i, n in enumerate((320, 640, 960))}
    masks = {k: np.ones((6, 8)) for k in evaluations}
    fig = plotting.plot_skills(
        evaluations, skills, masks, None, (-1.0, -1.0), (1.0, 1.0), archive=_grid_rep(np.arange(16.0)), fig=Figure(),
    )
    panels, heatmap, heat_bar = fig.axes[:3], fig.axes[3], fig.axes[4]
    assert len(fig.axes) == 5  # three evaluations, the archive and its colour bar; a legend names the skills
    assert [a.get_title() for a in panels] == [f"{k}: trajectories" for k in evaluations]
    assert heatmap.get_title().startswith("passive archive") and heat_bar.get_ylabel() == "fitness (return)"
    (legend,) = [c for c in panels[-1].get_children() if isinstance(c, Legend)]
    assert legend.get_title().get_text() == "skill"
    assert [t.get_text() for t in legend.get_texts()] == ["0", "1", "2", "3"]
    # Episodes of one skill share its colour, skills differ; the legend's colours are theirs.
    paths = [line for line in panels[0].lines if line.get_linestyle() == "-"]
    colours = [tuple(line.get_color()) for line in paths]
    assert colours[:4] == colours[4:] and len(set(colours[:4])) == 4
    assert [tuple(h.get_color()) for h in legend.legend_handles] == colours[:4]  # type: ignore[union-attr]
    # The axes fit the paths of every panel (x from -0.6 to 0.0 over the three, 5% margins), or the task's bounds.
    x0, x1 = panels[0].get_xlim()
    assert x0 == pytest.approx(-0.6 - 0.03) and x1 == pytest.approx(0.0 + 0.03)
    assert panels[2].get_xlim() == panels[0].get_xlim()
    task = plotting.plot_skills(_paths(8), skills, np.ones((6, 8)), None, (-1.0, -1.0), (1.0, 1.0), bounds="task", fig=Figure())
    assert task.axes[0].get_xlim() == (-1.0, 1.0) and task.axes[0].get_ylim() == (-1.0, 1.0)


def test_many_skills_get_a_colour_bar_of_skill_ids() -> None:
    from matplotlib.figure import Figure

    fig = plotting.plot_skills(_paths(32), np.arange(32) % 16, np.ones((6, 32)), None, (-1.0, -1.0), (1.0, 1.0), fig=Figure())
    panel, bar = fig.axes
    assert panel.get_legend() is None and bar.get_ylabel() == "skill"
    ticks = [float(t) for t in bar.get_yticks()]
    assert ticks[0] == 0 and ticks[-1] == 15 and all(t == int(t) for t in ticks)  # skill ids, not fractions
    assert len({tuple(line.get_color()) for line in panel.lines}) == 16


def test_the_skills_plot_refuses_what_it_cannot_draw() -> None:
    from matplotlib.figure import Figure

    ones = np.ones((6, 2))
    with pytest.raises(ValueError, match="same evaluations"):
        plotting.plot_skills({"a": _paths(2)}, np.arange(2), {"b": ones}, None, (-1.0, -1.0), (1.0, 1.0))
    with pytest.raises(ValueError, match=r"skills \(B,\) expected"):
        plotting.plot_skills(_paths(2), np.arange(3), ones, None, (-1.0, -1.0), (1.0, 1.0))
    with pytest.raises(ValueError, match="several evaluations are several panels"):
        plotting.plot_skills(
            {"a": _paths(2), "b": _paths(2)}, np.arange(2), {"a": ones, "b": ones}, None, (-1.0, -1.0), (1.0, 1.0),
            ax=Figure().subplots(),
        )
    with pytest.raises(ValueError, match="bounds: expected 'data' or 'task'"):
        plotting.plot_skills(_paths(2), np.arange(2), ones, None, (-1.0, -1.0), (1.0, 1.0), bounds="box")  # type: ignore[call-overload]


# --- drawing into the caller's Axes / Figure (notebooks) ------------------------------


def _artists(*axes: object) -> int:
    return sum(len(a.collections) + len(a.images) + len(a.lines) + len(a.patches) for a in axes)  # type: ignore[attr-defined]


@pytest.fixture
def no_writes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """Fails a test that saves any figure, and checks its working directory stays empty."""
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("a figure was saved")

    monkeypatch.setattr(Figure, "savefig", refuse)
    monkeypatch.chdir(tmp_path)
    yield
    plt.close("all")
    assert list(tmp_path.iterdir()) == []


def _grid_rep(fitnesses: np.ndarray, grid_shape: tuple[int, int] = (4, 4)) -> object:
    import types

    cells = int(np.prod(grid_shape))
    return types.SimpleNamespace(
        fitnesses=fitnesses, descriptors=np.zeros((cells, 2)), centroids=np.zeros((cells, 2)),
        grid_shape=grid_shape, low=(0.0, 0.0), high=(1.0, 1.0),
    )


def _mo_inputs() -> tuple[np.ndarray, np.ndarray, object]:
    rng = np.random.default_rng(0)
    fitnesses = rng.uniform(size=(16, 5, 2))
    fitnesses[3] = -np.inf  # an empty cell
    hypervolumes = rng.uniform(size=16)
    hypervolumes[3] = 0.0
    layout = _grid_rep(np.zeros(16))
    return fitnesses, hypervolumes, layout


SINGLE_PANEL = {
    "plot_comparison": lambda ax: plotting.plot_comparison(
        {"a": [run_rows(10, s) for s in (1.0, 2.0)], "b": run_rows(8)}, "eval_return", "env_steps", ax=ax
    ),
    "plot_repertoire": lambda ax: plotting.plot_repertoire(
        _grid_rep(np.where(np.arange(16) % 3 == 0, np.arange(16.0), -np.inf)), None, 0.0, 1.0, ax=ax
    ),
    "plot_pareto_front": lambda ax: plotting.plot_pareto_front(
        {"a": np.random.default_rng(1).uniform(size=(10, 2))}, reference=(0.0, 0.0), ax=ax
    ),
    "plot_cell_hypervolumes": lambda ax: plotting.plot_cell_hypervolumes(
        _mo_inputs()[2], _mo_inputs()[1], None, 0.0, 1.0, ax=ax
    ),
    "plot_cell_fronts": lambda ax: plotting.plot_cell_fronts(*_mo_inputs()[:2], reference=(0.0, 0.0), ax=ax),
    "plot_skills": lambda ax: plotting.plot_skills(
        np.random.default_rng(2).uniform(-1, 1, size=(6, 3, 2)), np.arange(3), np.ones((6, 3)),
        None, (-1.0, -1.0), (1.0, 1.0), walls=[((0.0, -0.5), (0.0, 0.5), 0.1)], ax=ax,
    ),
    "draw_walls": lambda ax: plotting.draw_walls(ax, [((0.0, -0.5), (0.0, 0.5), 0.1), ((-1, 0), (1, 0), 0.0)]),
}


@pytest.mark.parametrize("name", sorted(SINGLE_PANEL))
def test_single_panel_functions_draw_into_the_given_axes(name: str, no_writes: None) -> None:
    import matplotlib.pyplot as plt

    _, (ax, other) = plt.subplots(1, 2)
    assert _artists(ax) == 0
    assert SINGLE_PANEL[name](ax) is ax
    assert _artists(ax) > 0
    assert _artists(other) == 0  # the neighbouring panel is left alone


def test_a_3d_front_needs_a_3d_axes(no_writes: None) -> None:
    import matplotlib.pyplot as plt

    front = {"a": np.random.default_rng(3).uniform(size=(10, 3))}
    fig = plt.figure()
    with pytest.raises(ValueError, match="projection='3d'"):
        plotting.plot_pareto_front(front, ax=fig.add_subplot())
    ax3 = fig.add_subplot(projection="3d")
    assert plotting.plot_pareto_front(front, ax=ax3) is ax3
    assert _artists(ax3) > 0


MULTI_PANEL = {
    # name: (call, the number of Axes it adds, colour bars included)
    "plot_curves": (lambda fig: plotting.plot_curves(run_rows(10), fig=fig), 4),  # 2 metrics x 2 x keys
    "plot_comparison": (
        lambda fig: plotting.plot_comparison({"a": run_rows(10)}, "eval_return", ["env_steps", "wall_s"], fig=fig), 2
    ),
    "plot_repertoires": (
        lambda fig: plotting.plot_repertoires(
            {"a": _grid_rep(np.arange(16.0)), "b": _grid_rep(np.full(16, -np.inf))}, None, 0.0, 1.0, fig=fig
        ),
        3,  # two panels and the shared colour bar
    ),
    "plot_skills": (
        lambda fig: plotting.plot_skills(
            np.random.default_rng(2).uniform(-1, 1, size=(6, 3, 2)), np.arange(3), np.ones((6, 3)),
            None, (-1.0, -1.0), (1.0, 1.0), archive=_grid_rep(np.arange(16.0)), fig=fig,
        ),
        3,  # trajectories, archive and its colour bar
    ),
    "plot_rl_summary": (
        lambda fig: plotting.plot_rl_summary(run_rows(10), _grid_rep(np.arange(16.0)), None, 0.0, 1.0, fig=fig),
        4,  # the return, actor loss, the archive and its colour bar
    ),
}


@pytest.mark.parametrize("name", sorted(MULTI_PANEL))
def test_multi_panel_functions_draw_into_the_given_figure(name: str, no_writes: None) -> None:
    import matplotlib.pyplot as plt

    call, panels = MULTI_PANEL[name]
    fig = plt.figure()
    left, right = fig.subfigures(1, 2)
    assert call(left) is left  # a SubFigure, so the plot composes with others
    assert len(left.axes) == panels and not right.axes
    assert _artists(*left.axes) > 0
    whole = plt.figure()
    assert call(whole) is whole


def test_ax_with_several_x_keys_or_an_archive_is_refused(no_writes: None) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    with pytest.raises(ValueError, match="pass fig"):
        plotting.plot_comparison({"a": run_rows(5)}, "eval_return", ["env_steps", "wall_s"], ax=ax)
    with pytest.raises(ValueError, match="not both"):
        plotting.plot_comparison({"a": run_rows(5)}, "eval_return", "env_steps", ax=ax, fig=fig)
    with pytest.raises(ValueError, match="second panel"):
        plotting.plot_skills(
            np.zeros((3, 1, 2)), np.zeros(1), np.ones((3, 1)), None, (-1.0, -1.0), (1.0, 1.0),
            archive=_grid_rep(np.zeros(16)), ax=ax,
        )
    assert _artists(ax) == 0


def test_grid_heatmap_in_an_axes_shows_every_filled_cell() -> None:
    from matplotlib.collections import QuadMesh
    from matplotlib.figure import Figure

    from qdrl.qd.repertoires import grid_repertoire

    rng = np.random.default_rng(4)
    descriptors = rng.uniform(size=(40, 2)).astype(np.float32)
    rep = grid_repertoire(None, (10, 8), 0.0, 1.0).add(None, descriptors, descriptors.sum(-1))[0]
    fitnesses = np.asarray(rep.fitnesses)
    num_filled = int(np.sum(fitnesses > -np.inf))
    assert 10 < num_filled < 40  # some cells hit twice, most of the grid empty

    ax = Figure().subplots()
    assert plotting.plot_repertoire(rep, None, 0.0, 1.0, ax=ax) is ax
    (mesh,) = [c for c in ax.collections if isinstance(c, QuadMesh)]
    shown = np.ma.masked_invalid(mesh.get_array())
    assert shown.shape == (8, 10)  # y rows, x columns
    assert int(shown.count()) == num_filled
    np.testing.assert_allclose(np.sort(shown.compressed()), np.sort(fitnesses[fitnesses > -np.inf]), rtol=1e-6)


def test_the_return_rule(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt
    from matplotlib.axes import Axes
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rep = _grid_rep(np.arange(16.0))
    before = plt.get_fignums()
    # No path, no ax: a new figure's Axes, on the Agg canvas and unknown to pyplot.
    ax = plotting.plot_repertoire(rep, None, 0.0, 1.0, title="r")
    assert isinstance(ax, Axes) and isinstance(ax.figure.canvas, FigureCanvasAgg)
    assert isinstance(plotting.plot_repertoires({"a": rep}, None, 0.0, 1.0), Figure)
    assert isinstance(plotting.plot_curves(run_rows(5)), Figure)
    assert plt.get_fignums() == before
    # A path and an ax: the file is written as without the ax, and the ax returned.
    mine = Figure().subplots()
    assert plotting.plot_repertoire(rep, tmp_path / "both.png", 0.0, 1.0, ax=mine) is mine
    alone = plotting.plot_repertoire(rep, tmp_path / "alone.png", 0.0, 1.0)
    assert alone == tmp_path / "alone.png"
    assert (tmp_path / "both.png").read_bytes() == alone.read_bytes()
    fig = Figure()
    assert plotting.plot_curves(run_rows(5), tmp_path / "curves", fig=fig) is fig
    assert sorted(p.name for p in (tmp_path / "curves").iterdir()) == ["actor_loss.png", "eval_return.png"]
