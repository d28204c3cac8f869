"""`qdrl run SPEC --seeds`: one run per seed in seed_<n>/, equal to the seed run alone; resume;
and `qdrl report` on the real sweep. On a tiny MAP-Elites arm run (compiles in seconds)."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

import qdrl
from qdrl.cli import main
from qdrl.config import ConfigError
from qdrl.experiment import run_spec
from qdrl.report import report
from qdrl.sweeps import parse_seeds, run_seeds

SPEC = """# A tiny MAP-Elites on the arm, for the sweep tests.
[experiment]
algorithm = "map_elites"

[task]
name = "arm"
num_dofs = 8

[repertoire]
kind = "grid"
grid_shape = [8, 8]

[emitter]
batch_size = 32
iso_sigma = 0.01

[qd]
num_iterations = 8
log_every = 2
init_batch_size = 32

[log]
progress = false
plots = false
"""


@pytest.mark.parametrize(
    ("text", "seeds"),
    [("0-4", [0, 1, 2, 3, 4]), ("0,3,7", [0, 3, 7]), ("0-2,7", [0, 1, 2, 7]), ("5", [5]), (" 1, 1-2", [1, 2])],
)
def test_seeds_are_ranges_and_lists(text: str, seeds: list[int]) -> None:
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize("text", ["", "a", "3-1", "0-2-4", "-1", "1,,2"])
def test_bad_seeds_are_refused_in_one_line(text: str) -> None:
    with pytest.raises(ConfigError, match=r"^--seeds: expected seeds as \"0-4\""):
        parse_seeds(text)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Seeds 0 and 1 through the command line, and seed 1 run alone."""
    root = tmp_path_factory.mktemp("sweep")
    spec = root / "arm_tiny.toml"
    spec.write_text(SPEC)
    out = root / "arm_tiny"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["run", str(spec), "--seeds", "0-1", "--out", str(out)]) == 0
    single = run_spec(spec, ["experiment.seed=1"], root / "single")
    return {"spec": spec, "out": out, "printed": json.loads(stdout.getvalue()), "single": single, "root": root}


def test_each_seed_is_a_run_identical_to_that_seed_run_alone(sweep: dict[str, Any]) -> None:
    out = sweep["out"]
    assert sorted(p.name for p in out.iterdir()) == ["seed_0", "seed_1"]
    printed = sweep["printed"]
    assert printed["out"] == str(out) and sorted(printed["runs"]) == ["0", "1"]
    s0, s1 = printed["runs"]["0"], printed["runs"]["1"]
    assert (s0["seed"], s1["seed"]) == (0, 1) and s0["qd_score"] != s1["qd_score"]
    single = sweep["single"]
    for key in ("qd_score", "coverage", "max_fitness", "evaluations", "iteration"):
        assert s1[key] == single[key], key
    with np.load(out / "seed_1" / "repertoire.npz") as a, np.load(sweep["root"] / "single" / "repertoire.npz") as b:
        np.testing.assert_array_equal(a["fitnesses"], b["fitnesses"])
    # A function task steps no environment: no env-steps throughput, evaluations instead.
    assert "env_steps_per_s" not in s0 and s0["evaluations_per_s"] > 0
    assert s0["descriptor_names"] == ["end-effector x", "end-effector y"]


def test_an_interrupted_sweep_resumes_where_it_stopped(
    sweep: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "arm_tiny"
    shutil.copytree(sweep["out"], out)
    # Seed 1 stopped after its third log point: no summary, its last checkpoint gone.
    (out / "seed_1" / "summary.json").unlink()
    shutil.rmtree(sorted((out / "seed_1" / "checkpoints").glob("step_*"))[-1])
    assert main(["run", str(sweep["spec"]), "--seeds", "0-2", "--out", str(out), "--resume"]) == 0
    captured = capsys.readouterr()
    assert "seed 0 (1 of 3): finished in" in captured.err and "skipped" in captured.err
    printed = json.loads(captured.out)
    assert printed["runs"]["1"]["qd_score"] == sweep["printed"]["runs"]["1"]["qd_score"]
    assert printed["runs"]["2"]["seed"] == 2 and (out / "seed_2" / "summary.json").is_file()


def test_a_sweep_over_existing_runs_is_refused_before_anything_runs(sweep: dict[str, Any]) -> None:
    with pytest.raises(ConfigError, match="seed_0 already holds a run with checkpoints; pass --resume"):
        run_seeds(sweep["spec"], [0, 1], out_dir=sweep["out"])
    with pytest.raises(ConfigError, match="--seeds: expected at least one seed"):
        run_seeds(sweep["spec"], [], out_dir=sweep["out"])


def test_metrics_and_repertoires_of_a_sweep_load_in_one_call(sweep: dict[str, Any]) -> None:
    metrics = qdrl.load_metrics(sweep["out"], sweep["root"] / "single")
    assert list(metrics.columns[:5]) == ["spec", "algorithm", "task", "seed", "run"]
    assert sorted(metrics.groupby(["spec", "seed"]).size().items()) == [
        (("arm_tiny", 0), 4), (("arm_tiny", 1), 8)  # seed 1: the sweep's and the single run's
    ]
    final = metrics[metrics.iteration == 8].set_index("run").qd_score
    assert final[str(sweep["out"] / "seed_1")] == final[str(sweep["root"] / "single")]
    elites = qdrl.load_repertoires(sweep["out"])
    assert isinstance(elites, pd.DataFrame) and set(elites.seed) == {0, 1}
    assert (elites.groupby("seed").size() == [sweep["printed"]["runs"][s]["num_elites"] for s in "01"]).all()


def test_report_of_the_sweep_and_the_single_run(sweep: dict[str, Any], tmp_path: Path) -> None:
    result = report([sweep["out"], sweep["root"] / "single"], tmp_path / "report")
    (group,) = result["groups"].values()
    # one spec in two folders: the one named after it, and "single" (named beside the spec)
    assert group["labels"] == {"arm_tiny": [0, 1], "arm_tiny (single)": [1]}
    figures = {Path(f["path"]).stem: f for f in group["figures"]}
    assert figures["qd_score"]["x"] == ["evaluations", "wall_s"]  # the arm counts no env steps
    assert Path(figures["qd_score"]["path"]).stat().st_size > 10_000
    assert Path(group["repertoires"]).stat().st_size > 10_000
    table = (tmp_path / "report" / "report.md").read_text()
    assert "| arm_tiny | 0, 1 | " in table and "| arm_tiny (single) | 1 | " in table
    final = pd.read_csv(tmp_path / "report" / "final.csv")
    row = final[(final.spec == "arm_tiny") & (final.metric == "qd_score")].iloc[0]
    scores = [sweep["printed"]["runs"][s]["qd_score"] for s in "01"]
    assert row.seeds == 2 and row["mean"] == pytest.approx(np.mean(scores))
    assert row["std"] == pytest.approx(np.std(scores, ddof=1))
