"""What a run with learnt descriptors (AURORA) reports of its archive: the autoencoder's
reconstruction loss, the number of elites against container size control's target, and the
distance threshold the controller moves."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import FigureBase

from qdrl.plotting._common import Rows, _draw, _panels, _points, _tidy_x


def plot_learnt_descriptors(
    rows: Rows, target_size: int, path: str | Path | None = None, fig: FigureBase | None = None,
    title: str = "", x_key: str = "iteration",
) -> Path | FigureBase:
    """Three panels against `x_key`: `autoencoder_loss` (log scale), `aurora_elites` with the
    `target_size` as a dashed line, and the threshold `l_value`; returns by the package's rule
    (`qdrl.plotting`)."""

    def draw(figure: FigureBase) -> None:
        loss, elites, threshold = figure.subplots(1, 3)
        _draw(loss, *_points(rows, x_key, "autoencoder_loss"))
        loss.set_yscale("log")
        loss.set_title("reconstruction loss")
        _draw(elites, *_points(rows, x_key, "aurora_elites"), label="elites")
        elites.axhline(target_size, linestyle="--", color="grey", label=f"target {target_size:,}")
        elites.set_title("elites of the learnt archive")
        elites.legend()
        _draw(threshold, *_points(rows, x_key, "l_value"))
        threshold.set_title("distance threshold l")
        for ax in (loss, elites, threshold):
            ax.set_xlabel(x_key)
            _tidy_x(ax)

    return _panels(draw, path, fig, title, (15.0, 3.8))
