"""`qdrl report` on run directories written here by hand: grouping by task, the x axis of each
metric, final values (mean, std, IQM), and one-line errors. No run is compiled."""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from qdrl.cli import main
from qdrl.report import report
from qdrl.runs import RunError, load_run
from qdrl.stats import bootstrap_ci, iqm


def fake_run(
    path: Path, algorithm: str, task: str, seed: int, rows: Sequence[dict[str, float]], rl: bool = False,
    name: str | None = None,
) -> Path:
    """A run directory as `qdrl run` leaves it: config.toml, metrics.csv, summary.json. The
    spec's name (`experiment.name`) is the sweep's folder (seed_<n>/) or the run's own."""
    path.mkdir(parents=True)
    section = f'[env]\nname = "{task}"\n' if rl else f'[task]\nname = "{task}"\n'
    if name is None:
        name = path.parent.name if path.name.startswith("seed_") else path.name
    (path / "config.toml").write_text(
        f'[experiment]\nalgorithm = "{algorithm}"\nseed = {seed}\nname = "{name}"\n\n{section}'
    )
    with (path / "metrics.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (path / "summary.json").write_text(json.dumps({"algorithm": algorithm, **rows[-1]}))
    return path


def qd_rows(scale: float, env_steps_per_eval: int = 0) -> list[dict[str, float]]:
    return [
        {"log_point": i, "iteration": 10 * (i + 1), "evaluations": 100 * (i + 1),
         "env_steps": env_steps_per_eval * 100 * (i + 1), "qd_score": scale * (i + 1),
         "coverage": 0.1 * (i + 1), "wall_s": 1.0 + i}
        for i in range(4)
    ]


def rl_rows(final: float) -> list[dict[str, float]]:
    return [
        {"log_point": i, "env_steps": 1000 * (i + 1), "eval_return": final * (i + 1) / 4,
         "qd_score": 5.0 * (i + 1), "wall_s": 2.0 + i}
        for i in range(4)
    ]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    for seed, scale in enumerate((1.0, 2.0, 3.0)):
        fake_run(root / "me_arm" / f"seed_{seed}", "map_elites", "arm", seed, qd_rows(scale))
    fake_run(root / "cvt_arm", "cvt_map_elites", "arm", 0, qd_rows(10.0))
    for seed, final in enumerate((1.0, 2.0, 3.0, 4.0, 100.0)):
        fake_run(root / "sac_maze" / f"seed_{seed}", "sac", "point_maze", seed, rl_rows(final), rl=True)
    fake_run(root / "me_maze" / "seed_0", "map_elites", "point_maze", 0, qd_rows(1.0, env_steps_per_eval=50))
    return root


@pytest.fixture(scope="module")
def reported(runs: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    out = tmp_path_factory.mktemp("report")
    return report([runs], out), out


def test_runs_of_different_tasks_are_grouped_apart(reported: tuple[dict[str, Any], Path]) -> None:
    result, tmp_path = reported
    assert sorted(result["groups"]) == ["arm", "point_maze"]
    arm, maze = result["groups"]["arm"], result["groups"]["point_maze"]
    assert arm["labels"] == {"cvt_arm": [0], "me_arm": [0, 1, 2]}
    assert maze["labels"] == {"me_maze": [0], "sac_maze": [0, 1, 2, 3, 4]}
    assert {Path(f["path"]).parent.name for f in arm["figures"]} == {"arm"}
    assert (tmp_path / "arm" / "qd_score.png").stat().st_size > 10_000
    # eval_return exists only on the maze; the arm's figures never draw it.
    assert "eval_return" not in {f["metric"] for f in arm["figures"]}


def test_each_metric_takes_the_cost_every_run_counts(reported: tuple[dict[str, Any], Path]) -> None:
    result, _ = reported
    x = {(task, f["metric"]): f["x"] for task, g in result["groups"].items() for f in g["figures"]}
    assert x["arm", "qd_score"] == ["evaluations", "wall_s"]  # the arm's env steps are all 0
    assert x["point_maze", "eval_return"] == ["env_steps", "wall_s"]  # SAC counts no evaluations
    assert x["point_maze", "qd_score"] == ["env_steps", "wall_s"]  # SAC beside MAP-Elites: env steps
    assert x["point_maze", "coverage"] == ["evaluations", "wall_s"]  # MAP-Elites alone


def test_final_values_give_mean_std_and_the_interquartile_mean(reported: tuple[dict[str, Any], Path]) -> None:
    _, tmp_path = reported
    final = pd.read_csv(tmp_path / "final.csv").set_index(["spec", "metric"])
    sac = final.loc["sac_maze", "eval_return"]
    values = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    assert sac.seeds == 5 and sac["mean"] == pytest.approx(22.0)
    assert sac["std"] == pytest.approx(values.std(ddof=1))
    assert sac["iqm"] == pytest.approx(3.0)  # the outlier seed is cut: mean of 2, 3, 4
    assert sac.iqm_low <= sac["iqm"] <= sac.iqm_high
    me = final.loc["me_arm", "qd_score"]
    assert (me["mean"], me["min"], me["max"]) == pytest.approx((8.0, 4.0, 12.0))
    table = (tmp_path / "report.md").read_text()
    assert "| sac_maze | 0, 1, 2, 3, 4 | 22 ± 44 (IQM 3) |" in table
    assert "![qd_score](arm/qd_score.png)" in table


def test_a_directory_without_runs_is_named_in_one_line(
    runs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(RunError, match="empty holds no run: expected a directory written by `qdrl run`"):
        report([runs / "me_arm", tmp_path / "empty"], tmp_path / "out")
    assert main(["report", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "missing: no such directory" in err
    assert main(["report", str(runs / "cvt_arm"), "--confidence", "2"]) == 2
    assert "--confidence: expected a number in (0, 1), got 2.0" in capsys.readouterr().err


def test_the_command_writes_the_report(runs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(runs / "me_arm"), str(runs / "cvt_arm"), "--out", str(tmp_path / "r")]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert list(printed["groups"]) == ["arm"] and Path(printed["csv"]).is_file()


def test_the_spec_column_is_the_spec_name_and_one_seed_is_said(tmp_path: Path) -> None:
    # one spec run into two folders (other --set values), another spec into a folder of any name
    fake_run(tmp_path / "runs" / "lr_small", "map_elites", "arm", 0, qd_rows(1.0), name="map_elites_arm")
    fake_run(tmp_path / "runs" / "lr_big", "map_elites", "arm", 0, qd_rows(2.0), name="map_elites_arm")
    for seed in (0, 1):
        fake_run(tmp_path / "runs" / "mine" / f"seed_{seed}", "cvt_map_elites", "arm", seed, qd_rows(3.0),
                 name="cvt_map_elites_arm")
    result = report([tmp_path / "runs"], tmp_path / "r")
    assert set(result["groups"]["arm"]["labels"]) == {
        "map_elites_arm (lr_big)", "map_elites_arm (lr_small)", "cvt_map_elites_arm",
    }
    with (tmp_path / "r" / "final.csv").open() as f:
        assert {row["spec"] for row in csv.DictReader(f)} == set(result["groups"]["arm"]["labels"])
    md = (tmp_path / "r" / "report.md").read_text()
    assert "One seed only: map_elites_arm (lr_big), map_elites_arm (lr_small). Bands and ± need two seeds" in md
    assert "| map_elites_arm (lr_big) | 0 | " in md and "(one seed)" in md
    assert "| cvt_map_elites_arm | 0, 1 | 12 ± 0 (IQM 12)" in md  # two seeds: mean ± std


def test_a_sweep_is_not_one_run(runs: Path) -> None:
    with pytest.raises(RunError, match=r"me_arm holds 3 runs \(a sweep or a folder of runs\), not one"):
        load_run(runs / "me_arm")


def test_interquartile_mean_and_bootstrap_interval() -> None:
    assert float(iqm(np.arange(1.0, 9.0))) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    trim_mean = pytest.importorskip("scipy.stats").trim_mean  # rliable's definition
    for n in (1, 3, 4, 7, 10):
        x = np.random.default_rng(n).normal(size=(n, 3))
        np.testing.assert_allclose(iqm(x), trim_mean(x, 0.25, axis=0), rtol=1e-12)
        np.testing.assert_allclose(iqm(x.T, axis=1), trim_mean(x.T, 0.25, axis=1), rtol=1e-12)
    values = np.array([[1.0, 10.0], [2.0, 10.0], [3.0, 10.0], [4.0, 10.0]])
    low, high = bootstrap_ci(values)
    assert low.shape == (2,) and low[0] < 2.5 < high[0] and low[1] == high[1] == 10.0
    again = bootstrap_ci(values)
    np.testing.assert_array_equal(again[0], low)  # seeded: the same band every time
    one = bootstrap_ci(values[:1])
    np.testing.assert_array_equal(one[0], values[0])
    wide = bootstrap_ci(values, confidence=0.99)
    assert wide[0][0] <= low[0] and wide[1][0] >= high[0]


def test_adapted_runs_are_compared_per_perturbation(tmp_path: Path) -> None:
    """Runs with adaptation/adaptation.csv (`qdrl adapt`): each spec's best return per multiplier,
    the mean over its adapted seeds, in adaptation.csv and one figure per task."""
    for label, seeds in (("map_elites", (0, 1)), ("smerl_diayn", (0,))):
        for seed in seeds:
            run = fake_run(tmp_path / "runs" / label / f"seed_{seed}", label, "walker2d_uni", seed, rl_rows(1.0), rl=True)
            (run / "adaptation").mkdir()
            lines = ["perturbation,value,best_return,median_return,mean_return,num_policies"]
            lines += [f"gravity,{v},{100.0 * v + seed},0,0,3" for v in (0.5, 1.0)]
            lines += [f"actuator:foot_left_joint,{v},{-v},0,0,3" for v in (0.0, 1.0)]
            (run / "adaptation" / "adaptation.csv").write_text("\n".join(lines) + "\n")
    result = report([tmp_path / "runs"], tmp_path / "report")
    rows = list(csv.DictReader((tmp_path / "report" / "adaptation.csv").read_text().splitlines()))
    gravity = {(r["spec"], float(r["value"])): (float(r["best_return"]), int(r["seeds"])) for r in rows if r["perturbation"] == "gravity"}
    assert gravity == {("map_elites", 0.5): (50.5, 2), ("map_elites", 1.0): (100.5, 2),
                       ("smerl_diayn", 0.5): (50.0, 1), ("smerl_diayn", 1.0): (100.0, 1)}
    assert {r["perturbation"] for r in rows} == {"gravity", "actuator:foot_left_joint"}
    figures = result["groups"]["walker2d_uni"]["figures"]
    assert any(f["metric"] == "adaptation" and Path(f["path"]).is_file() for f in figures)
    assert "adaptation.png" in Path(result["table"]).read_text()
