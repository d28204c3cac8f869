"""Live dashboards for runs: TensorBoard and Weights & Biases, chosen in the spec's `[log]`.

    [log]
    tensorboard = true        # <run>/tensorboard/, `tensorboard --logdir runs`
    wandb = true              # pip install "qdrl[wandb]"; wandb_mode = "offline" to sync later
    wandb_project = "qdrl"

metrics.csv stays the source of truth: a logger receives each row the driver
writes there, as scalars at the step the progress bar counts (iterations for QD
runs, environment steps for RL runs). Rows are logged as they come, so a long run
can be watched live; a resumed run continues the same W&B run (its id is kept in
`<run>/wandb_id.txt`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, Protocol

from qdrl.config import ConfigError

__all__ = ["Logger", "Loggers", "TensorBoardLogger", "WandbLogger", "WandbMode", "scalars"]

WandbMode = Literal["online", "offline", "disabled"]


def scalars(row: Mapping[str, Any]) -> dict[str, float]:
    """The finite numeric values of a metrics row (bools and strings left out)."""
    out = {}
    for key, value in row.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            continue
        if math.isfinite(value):
            out[key] = value
    return out


class Logger(Protocol):
    """Receives the rows of a run as they are written to metrics.csv."""

    def log(self, row: Mapping[str, float], step: int) -> None: ...

    def close(self) -> None: ...


class TensorBoardLogger:
    """Writes each row's values as TensorBoard scalars (tensorboardX, which brax installs)."""

    def __init__(self, log_dir: Path, config_toml: str = "") -> None:
        from tensorboardX import SummaryWriter

        self.log_dir = log_dir
        self.writer = SummaryWriter(logdir=str(log_dir))
        if config_toml:
            # Indented: TensorBoard's text panel renders Markdown.
            self.writer.add_text("config", "    " + config_toml.replace("\n", "\n    "), 0)

    def log(self, row: Mapping[str, float], step: int) -> None:
        for key, value in scalars(row).items():
            self.writer.add_scalar(key, value, step)
        self.writer.flush()  # visible in a running TensorBoard at once

    def close(self) -> None:
        self.writer.close()


class WandbLogger:
    """Logs each row to a Weights & Biases run (one W&B run per qdrl run; seeds share a group)."""

    def __init__(
        self,
        out_dir: Path,
        config: Mapping[str, Any],
        name: str,
        group: str,
        project: str = "qdrl",
        entity: str = "",
        mode: WandbMode = "online",
    ) -> None:
        try:
            import wandb
        except ImportError:
            raise ConfigError(
                "log.wandb: expected the wandb package to be installed (pip install \"qdrl[wandb]\"), "
                "got none; set log.wandb = false to run without it"
            ) from None
        id_file = out_dir / "wandb_id.txt"
        run_id = id_file.read_text().strip() if id_file.is_file() else None
        self.run = wandb.init(
            project=project,
            entity=entity or None,
            group=group or None,
            name=name,
            dir=str(out_dir),
            mode=mode,
            config=dict(config),
            id=run_id,
            resume="allow",
        )
        id_file.write_text(f"{self.run.id}\n")  # a resumed run continues this W&B run

    def log(self, row: Mapping[str, float], step: int) -> None:
        self.run.log(scalars(row), step=step)

    def close(self) -> None:
        self.run.finish()


class Loggers:
    """Every logger of a run, as one; closing closes them all."""

    def __init__(self, loggers: Sequence[Logger] = ()) -> None:
        self.loggers = list(loggers)

    def log(self, row: Mapping[str, float], step: int) -> None:
        for logger in self.loggers:
            logger.log(row, step)

    def close(self) -> None:
        for logger in self.loggers:
            logger.close()
        self.loggers = []

    def __enter__(self) -> Loggers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
