"""TensorBoard and W&B loggers: what a run logs is read back from their own files."""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from qdrl.config import ConfigError
from qdrl.experiment import run_spec
from qdrl.loggers import TensorBoardLogger, scalars

SPEC = """
[experiment]
algorithm = "map_elites"

[task]
name = "arm"
num_dofs = 8

[repertoire]
grid_shape = [8, 8]

[emitter]
batch_size = 32

[qd]
num_iterations = 6
log_every = 2
init_batch_size = 32

[log]
progress = false
plots = false
"""


def tensorboard_scalars(log_dir: Path) -> dict[str, dict[int, float]]:
    """tag -> {step: value} of every event file under `log_dir` (TFRecord framing, read by hand)."""
    from tensorboardX.proto import event_pb2

    out: dict[str, dict[int, float]] = {}
    for path in sorted(log_dir.glob("events.out.tfevents.*")):
        data = path.read_bytes()
        pos = 0
        while pos < len(data):
            (length,) = struct.unpack("<Q", data[pos : pos + 8])
            event = event_pb2.Event.FromString(data[pos + 12 : pos + 12 + length])
            pos += 12 + length + 4  # length, its crc, the record, its crc
            for value in event.summary.value:
                if value.HasField("simple_value"):
                    out.setdefault(value.tag, {})[event.step] = value.simple_value
    return out


def wandb_history(run_dir: Path) -> tuple[Any, list[dict[str, Any]]]:
    """The run record and the history rows of an offline W&B run (its .wandb log file: W&B's
    7-byte header, then records framed as in LevelDB's log: crc, length, type; 32 KiB blocks)."""
    from wandb.proto import wandb_internal_pb2 as pb

    (path,) = run_dir.glob("wandb/offline-run-*/run-*.wandb")
    data = path.read_bytes()
    assert data[:4] == b":W&B"
    pos, block, chunks, partial = 7, 32768, [], b""
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # a block's tail too short for a header is padding
            pos += block - pos % block
            continue
        length, kind = int.from_bytes(data[pos + 4 : pos + 6], "little"), data[pos + 6]
        partial += data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        if kind in (1, 4):  # FULL, or LAST of a record split across blocks
            chunks.append(partial)
            partial = b""
    run, history = None, []
    for raw in chunks:
        record = pb.Record.FromString(raw)
        kind = record.WhichOneof("record_type")
        if kind == "run":
            run = record.run
        elif kind == "history":
            history.append({"/".join(i.nested_key) or i.key: json.loads(i.value_json) for i in record.history.item})
    return run, history


def test_scalars_keeps_finite_numbers_only() -> None:
    row = {"a": 1, "b": 2.5, "c": float("nan"), "d": True, "e": "text", "f": float("inf")}
    assert scalars(row) == {"a": 1, "b": 2.5}


def test_tensorboard_logger_writes_what_it_is_given(tmp_path: Path) -> None:
    logger = TensorBoardLogger(tmp_path / "tb", "[experiment]\nalgorithm = \"sac\"\n")
    logger.log({"eval_return": 1.5, "env_steps": 100, "note": "x"}, step=100)
    logger.log({"eval_return": -2.0, "env_steps": 200}, step=200)
    logger.close()
    assert tensorboard_scalars(tmp_path / "tb") == {
        "eval_return": {100: 1.5, 200: -2.0},
        "env_steps": {100: 100.0, 200: 200.0},
    }


def test_a_run_logs_every_row_to_tensorboard_and_wandb(tmp_path: Path) -> None:
    """One run with both loggers; each holds metrics.csv's rows at the run's iteration counts."""
    pytest.importorskip("wandb")
    spec = tmp_path / "arm_logged.toml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    run_spec(spec, ["log.tensorboard=true", "log.wandb=true", 'log.wandb_mode="offline"'], out)
    rows = pd.read_csv(out / "metrics.csv")
    assert list(rows.iteration) == [2, 4, 6]

    logged = tensorboard_scalars(out / "tensorboard")
    for key in ("qd_score", "coverage", "evaluations", "wall_s"):
        assert logged[key] == pytest.approx(dict(zip(rows.iteration, rows[key], strict=True)), rel=1e-6), key

    run, history = wandb_history(out)
    assert run.display_name == "arm_logged seed 0" and run.run_group == "arm_logged"
    assert run.run_id == (out / "wandb_id.txt").read_text().strip()
    assert [h["_step"] for h in history] == [2, 4, 6]
    assert [h["qd_score"] for h in history] == pytest.approx(list(rows.qd_score))
    assert [h["evaluations"] for h in history] == list(rows.evaluations)


def test_wandb_without_the_package_fails_before_compiling(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "wandb", None)  # `import wandb` raises ImportError
    spec = tmp_path / "arm.toml"
    spec.write_text(SPEC)
    with pytest.raises(ConfigError, match=r"log.wandb: expected the wandb package .*qdrl\[wandb\]"):
        run_spec(spec, ["log.wandb=true"], tmp_path / "out")
    assert not (tmp_path / "out" / "metrics.csv").exists()


def test_a_bad_wandb_mode_is_refused_with_the_key(tmp_path: Path) -> None:
    spec = tmp_path / "arm.toml"
    spec.write_text(SPEC)
    with pytest.raises(ConfigError, match=r"log\.wandb_mode: expected one of"):
        run_spec(spec, ['log.wandb_mode="sometimes"'], tmp_path / "out")
