"""Benchmarks kept runnable as tests (`pytest -m slow`): SAC and TD3 learn halfcheetah.

A tiny version of the README's learning figures: 60k environment steps with the
literature settings (a few minutes each on a 2-core CPU). A random policy scores
about -250 to 0 over an episode; both agents pass 300 within these steps (in the
recorded runs, benchmarks/results/*_halfcheetah_150k.csv, SAC was at 564 and TD3
at 508 after 50k steps).
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from qdrl.experiment import run_spec

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["sac", "td3"])
def test_learns_halfcheetah(tmp_path: Path, algorithm: str) -> None:
    overrides = [
        "train.total_env_steps=60000",
        "train.eval_every=10000",
        "train.learning_starts=10000",
        "train.buffer_size=100000",
        "log.progress=false",
        "log.plots=false",
    ]
    run_spec(ROOT / "agents" / f"{algorithm}_halfcheetah.toml", overrides, tmp_path / "run")
    with (tmp_path / "run" / "metrics.csv").open() as f:
        returns = [float(row["eval_return"]) for row in csv.DictReader(f)]
    assert returns[0] < 100.0  # before updates start: about a random policy
    assert max(returns[-3:]) > 300.0, returns
