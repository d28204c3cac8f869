"""`qdrl run` on MOME, NSGA-II and SPEA2 specs: artefacts, exact resume, bad specs refused early."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from qdrl.cli import main
from qdrl.config import ConfigError, load_toml
from qdrl.experiment import check_spec, run_spec
from qdrl.runs import load_run

AGENTS = Path(__file__).resolve().parents[1] / "agents"

SPECS = {
    "mome": """
[experiment]
algorithm = "mome"
seed = 3
[task]
name = "mo_rastrigin"
num_dims = 6
[repertoire]
kind = "cvt"
num_centroids = 8
cvt_samples = 500
[mome]
pareto_front_max_length = 4
[emitter]
kind = "polynomial"
batch_size = 16
eta = 1.0
proportion_to_mutate = 0.5
variation_percentage = 0.5
[qd]
num_iterations = 10
log_every = 5
init_batch_size = 16
[log]
progress = false
""",
    "nsga2": """
[experiment]
algorithm = "nsga2"
seed = 1
[task]
name = "zdt1"
num_dims = 8
[population]
size = 12
[qd]
num_iterations = 10
log_every = 5
[log]
progress = false
""",
    "spea2": """
[experiment]
algorithm = "spea2"
seed = 2
[task]
name = "dtlz2"
num_dims = 5
[population]
size = 12
[qd]
num_iterations = 10
log_every = 5
[log]
progress = false
""",
}


# NSGA-II shares SPEA2's run class (only the survival rule differs): its end-to-end run is slow-only.
@pytest.mark.parametrize("algorithm", ["mome", "spea2", pytest.param("nsga2", marks=pytest.mark.slow)])
def test_mo_run_writes_fronts_and_resumes_bit_identically(tmp_path: Path, algorithm: str) -> None:
    spec = tmp_path / f"{algorithm}.toml"
    spec.write_text(SPECS[algorithm])
    out = tmp_path / "out"
    summary = run_spec(spec, [], out)
    rows = pd.read_csv(out / "metrics.csv")
    assert list(rows["iteration"]) == [5, 10]
    assert summary["evaluations"] == (16 if algorithm == "mome" else 12) * 11
    # the hypervolume of the log point equals the exact host computation of the final state
    assert summary["global_hypervolume"] == pytest.approx(summary["exact_global_hypervolume"], rel=1e-5)
    front = np.loadtxt(out / "front.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(front) == summary["global_front_size"] > 0
    name = "repertoire" if algorithm == "mome" else "population"
    npz = np.load(out / f"{name}.npz")
    stored = np.all(np.isfinite(npz["fitnesses"]), axis=-1)
    assert int(stored.sum()) == summary["num_solutions"] == len(pd.read_csv(out / f"{name}.csv"))
    loaded = load_run(out).repertoire  # the container comes back (MOME: from the export)
    np.testing.assert_array_equal(np.asarray(loaded.fitnesses), npz["fitnesses"])
    plots = {p.name for p in (out / "plots").glob("*.png")}
    assert "front.png" in plots and "global_hypervolume.png" in plots
    if algorithm == "mome":
        assert {"cell_hypervolumes.png", "cell_fronts.png"} <= plots
        assert summary["moqd_score"] == pytest.approx(summary["exact_moqd_score"], rel=1e-5)
        assert summary["moqd_score"] >= summary["max_hypervolume"] > 0
    else:
        assert summary["true_front_hypervolume"] > 0 and 0 <= summary["hypervolume_ratio"] < 1
    # drop the newest checkpoint and resume: fronts, populations and metrics come back exactly
    checkpoints = sorted((out / "checkpoints").glob("step_*"))
    assert len(checkpoints) == 2
    shutil.rmtree(checkpoints[-1])
    resumed = run_spec(spec, [], out, resume=True)
    for key in ("global_hypervolume", "num_solutions", "evaluations", "exact_global_hypervolume"):
        assert resumed[key] == summary[key], key
    again = np.load(out / f"{name}.npz")
    for name in npz.files:
        np.testing.assert_array_equal(again[name], npz[name])
    assert json.loads((out / "summary.json").read_text())["global_hypervolume"] == summary["global_hypervolume"]


def _spec(name: str) -> dict[str, object]:
    return load_toml(AGENTS / name)


@pytest.mark.parametrize(
    ("spec", "section", "key", "value", "message"),
    [
        ("mome_mo_rastrigin_cpu.toml", "task", "reference_point", [-150.0],
         "task.reference_point: expected 2 numbers (one per objective of 'mo_rastrigin'), got [-150.0]"),
        ("nsga2_dtlz2.toml", "task", "reference_point", [1.0, 1.0],
         "task.reference_point: expected 3 numbers (one per objective of 'dtlz2'), got [1.0, 1.0]"),
        ("mome_mo_rastrigin_cpu.toml", "mome", "pareto_front_max_length", 0,
         "mome.pareto_front_max_length: expected a positive integer, got 0"),
        ("mome_mo_rastrigin_cpu.toml", "task", "name", "rastrigin",
         "task.name: expected a multi-objective task for mome (one of ["),
        ("spea2_zdt1.toml", "task", "name", "arm", "task.name: expected a multi-objective task for spea2"),
        ("nsga2_zdt1.toml", "task", "name", "halfcheetah_multi",
         "task.name: expected a task with bounded genotypes for nsga2"),
        ("mome_mo_rastrigin_cpu.toml", "qd", "reevaluate_samples", 2,
         "qd.reevaluate_samples: expected 0 for a multi-objective run, got 2"),
        ("nsga2_zdt1.toml", "population", "mutation_prob", 1.5,
         "population.mutation_prob: expected a number in [0, 1], got 1.5"),
        ("nsga2_zdt1.toml", "population", "crowding", "close",
         "population.crowding: expected one of 'distance', 'pruning', got 'close'"),
        ("spea2_zdt1.toml", "population", "crowding", "pruning",
         "population.crowding: expected \"distance\" for spea2 (pruning is NSGA-II's cut of its last front)"),
    ],
)
def test_bad_mo_specs_are_refused_naming_the_key(
    spec: str, section: str, key: str, value: object, message: str, compilations: Any
) -> None:
    data = _spec(spec)
    table = {} if key == "name" else dict(data.get(section, {}))  # type: ignore[call-overload]
    table[key] = value
    check_spec(data)  # the spec itself is valid (and the imports are done)
    with compilations() as compiled, pytest.raises(ConfigError) as err:
        check_spec({**data, section: table})
    assert str(err.value).startswith(message)
    assert compiled.count == 0  # nothing built, nothing compiled


def test_a_bad_reference_point_fails_in_one_line_through_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["run", str(AGENTS / "mome_halfcheetah_multi_cpu.toml"), "--set", "task.reference_point=[0, 0, 0]",
            "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert capsys.readouterr().err == (
        "qdrl: error: task.reference_point: expected 2 numbers (one per objective of "
        "'halfcheetah_multi'), got [0.0, 0.0, 0.0]\n"
    )
    assert not (tmp_path / "o").exists()
