"""`qdrl run` on QD specs: artefacts, exports, resume after SIGKILL, and bad specs."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from qdrl import checkpoint
from qdrl.cli import main
from qdrl.experiment import run_spec

SPEC = """
[experiment]
algorithm = "{algorithm}"
seed = 1

[task]
name = "arm"
num_dofs = 10

[repertoire]
grid_shape = [16, 16]
num_centroids = 64
cvt_samples = 2000

[emitter]
batch_size = 32

[qd]
num_iterations = {iterations}
log_every = 10
init_batch_size = 32

[log]
progress = false
plots = false  # the test that reads plots turns them on
"""


def write_spec(tmp_path: Path, algorithm: str = "map_elites", iterations: int = 40) -> Path:
    path = tmp_path / f"{algorithm}.toml"
    path.write_text(SPEC.format(algorithm=algorithm, iterations=iterations))
    return path


@pytest.mark.parametrize("algorithm", ["map_elites", "cvt_map_elites"])
def test_qd_run_writes_metrics_plots_and_exports(
    tmp_path: Path, algorithm: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    summary = run_spec(write_spec(tmp_path, algorithm), ["log.plots=true", "log.progress=true"], out)
    lines = capsys.readouterr().err.splitlines()
    kmeans = [i for i, line in enumerate(lines) if "CVT cells (k-means of" in line]
    compiling = next(i for i, line in enumerate(lines) if line.startswith(f"compiling {algorithm} on arm"))
    if algorithm == "cvt_map_elites":  # the cells' k-means has a line of its own, before compiling
        assert len(kmeans) == 2 and kmeans[1] < compiling and " s" in lines[kmeans[1]]
    else:
        assert kmeans == []
    for key in ("qd_score", "coverage", "max_fitness", "evaluations", "wall_s", "compile_s"):
        assert key in summary, key
    assert summary["evaluations"] == 32 + 40 * 32
    assert summary["evaluations_per_s"] > 0
    rows = pd.read_csv(out / "metrics.csv")
    assert list(rows["iteration"]) == [10, 20, 30, 40]
    assert {"qd_score", "coverage", "max_fitness", "evaluations", "env_steps", "wall_s"} <= set(rows)
    assert rows["qd_score"].is_monotonic_increasing
    table = pd.read_csv(out / "repertoire.csv")
    assert len(table) == summary["num_elites"]
    # columns named from the task's descriptor names (summary.json's descriptor_names)
    assert list(table)[:4] == ["cell", "fitness", "descriptor_end_effector_x", "descriptor_end_effector_y"]
    assert summary["descriptor_names"] == ["end-effector x", "end-effector y"]
    npz = np.load(out / "repertoire.npz")
    assert int(np.isfinite(npz["fitnesses"]).sum()) == len(table)
    assert (out / "plots" / "repertoire.png").stat().st_size > 1000
    assert (out / "plots" / "qd_score.png").exists()
    assert (out / "plots" / "summary.png").stat().st_size > 1000  # the one-figure summary
    assert json.loads((out / "summary.json").read_text())["task"] == "arm"


def test_qd_resume_after_sigkill_matches_an_uninterrupted_run(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, iterations=600)  # 60 log points
    full = run_spec(spec, [], tmp_path / "full")
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "qdrl.cli", "run", str(spec), "--out", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline:
        latest = checkpoint.latest(out / "checkpoints")
        if latest is not None and json.loads((latest / "meta.json").read_text())["metadata"]["chunk"] >= 3:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "summary.json").exists()
    resumed = run_spec(spec, [], out, resume=True)
    for key in ("qd_score", "coverage", "max_fitness", "mean_fitness", "evaluations", "num_elites"):
        assert resumed[key] == full[key], key
    a = np.load(out / "repertoire.npz")
    b = np.load(tmp_path / "full" / "repertoire.npz")
    np.testing.assert_array_equal(a["fitnesses"], b["fitnesses"])
    assert len(pd.read_csv(out / "metrics.csv")) == 60


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ('task.name="arms"', "task.name: expected one of ["),
        ("task.num_joints=3", "task.num_joints: unknown key for task 'arm'"),
        ("task.num_dofs=0", "task.num_dofs: expected a positive integer, got 0"),
        ("repertoire.grid_shape=[4, 4, 4]", "repertoire.grid_shape: expected 2 entries"),
        ('repertoire.kind="hex"', "repertoire.kind: expected one of 'grid', 'cvt'"),
        ("emitter.batch_size=0", "emitter.batch_size: expected a positive integer, got 0"),
        ("emitter.variation_percentage=1.5", "emitter.variation_percentage: expected a number in [0, 1]"),
        ("qd.num_iterations=45", "qd.num_iterations: expected a multiple of qd.log_every=10"),
    ],
)
def test_bad_qd_spec_fails_fast(
    tmp_path: Path, override: str, message: str, capsys: pytest.CaptureFixture[str], compilations: Any
) -> None:
    with compilations() as compiled:
        assert main(["run", str(write_spec(tmp_path)), "--set", override, "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err
    assert compiled.count == 0  # refused before anything compiled


def test_cvt_cells_follow_the_seed_unless_a_cvt_seed_shares_them() -> None:
    import dataclasses

    from qdrl.algorithms.qd import RepertoireConfig, cvt_cells, make_repertoire
    from qdrl.tasks import make_task

    task = make_task("arm", num_dofs=4)
    example = task.example_genotype()
    own = RepertoireConfig(kind="cvt", num_centroids=16, cvt_samples=200, kmeans_iters=5)
    a, b = (np.asarray(make_repertoire(own, task, example, seed).centroids) for seed in (0, 1))
    assert a.shape == (16, 2) and not np.array_equal(a, b)  # each seed its own cells, as in QDax
    shared = dataclasses.replace(own, cvt_seed=7)
    misses = cvt_cells.cache_info().misses
    c, d = (np.asarray(make_repertoire(shared, task, example, seed).centroids) for seed in (0, 1))
    np.testing.assert_array_equal(c, d)
    assert cvt_cells.cache_info().misses == misses + 1  # k-means ran once for both seeds
    np.testing.assert_array_equal(c, np.asarray(make_repertoire(own, task, example, 7).centroids))
