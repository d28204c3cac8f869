"""A finished tiny run copied as the run a stop after its first checkpoint leaves, and the check
that resuming it ends bit for bit where the uninterrupted run ended (imported by the run tests)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from qdrl import checkpoint

TIMING = {"wall_s", "compile_s", "startup_s", "run_s", "env_steps_per_s"}


def stopped_copy(full: Path, out: Path, episodes_per_log_point: int) -> None:
    """`out`: `full` (2 log points, a checkpoint after each) as a stop after its first checkpoint
    leaves it: that checkpoint, its config, one metrics row and that log point's skills.csv rows."""
    shutil.copytree(full, out)
    shutil.rmtree(checkpoint.latest(out / "checkpoints"))  # type: ignore[arg-type]
    (out / "summary.json").unlink()
    rows = (out / "metrics.csv").read_text().splitlines()
    (out / "metrics.csv").write_text("\n".join(rows[:2]) + "\n")
    episodes = (out / "skills.csv").read_text().splitlines()
    (out / "skills.csv").write_text("\n".join(episodes[: 1 + episodes_per_log_point]) + "\n")
    assert checkpoint.step_of(checkpoint.latest(out / "checkpoints")) == 1  # type: ignore[arg-type]


def assert_resumed_as_uninterrupted(
    full_summary: dict[str, Any], resumed_summary: dict[str, Any], full: Path, resumed: Path, expected: set[str]
) -> None:
    """Every non-timing summary figure equal (and `expected` among them), the final checkpoints'
    arrays bit-identical, skills.csv equal."""
    keys = sorted(k for k, v in full_summary.items() if isinstance(v, int | float) and k not in TIMING)
    assert expected <= set(keys)
    for key in keys:
        assert resumed_summary[key] == full_summary[key], key
    final = checkpoint.latest(full / "checkpoints")
    assert final is not None
    with np.load(final / "state.npz") as a, np.load(resumed / "checkpoints" / final.name / "state.npz") as b:
        assert a.files == b.files and len(a.files) > 20
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert (resumed / "skills.csv").read_text() == (full / "skills.csv").read_text()
