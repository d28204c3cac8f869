"""`qdrl suite`: specs x tasks x seeds under one budget, resumed where they stopped; bad suites
refused before anything compiles."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from qdrl import report, suites
from qdrl.cli import main
from qdrl.config import ConfigError, dump_toml

ME = {
    "experiment": {"algorithm": "map_elites", "name": "map_elites"},
    "task": {"name": "point_maze", "episode_length": 20, "policy_hidden": [8], "policy_activation": "relu"},
    "repertoire": {"kind": "grid", "grid_shape": [8, 8], "fitness_range": [-50.0, 0.0]},
    "emitter": {"kind": "isoline", "batch_size": 8},
    "qd": {"num_iterations": 8, "log_every": 2, "init_batch_size": 8},
    "log": {"progress": False},
}
DIAYN = {
    "experiment": {"algorithm": "diayn", "name": "diayn"},
    "env": {"task": "point_maze", "episode_length": 20},
    "agent": {"hidden": [16, 16]},
    "train": {"total_env_steps": 1280, "num_envs": 4, "batch_size": 32, "buffer_size": 2000,
              "learning_starts": 80, "grad_steps_per_iter": 2, "eval_every": 320, "num_eval_envs": 8},
    "skills": {"num_skills": 4, "hidden": [16, 16]},
    # the CVT passive archive of the benchmark's skill runs, on the study's fitness scale
    "archive": {"kind": "cvt", "num_centroids": 32, "cvt_samples": 1000, "fitness_range": [-50.0, 0.0]},
    "log": {"progress": False},
}


def write_suite(tmp: Path, budget: str, algorithms: str = '["map_elites", "diayn"]', extra: str = "") -> Path:
    for spec in (ME, DIAYN):
        (tmp / f"{spec['experiment']['name']}_point_maze.toml").write_text(dump_toml(spec))
    path = tmp / "tiny.toml"
    path.write_text(
        f'[suite]\nname = "tiny"\nseeds = [0]\n{budget}\n\n[[runs]]\nspecs = "{tmp}/{{algorithm}}_{{task}}.toml"\n'
        f'algorithms = {algorithms}\ntasks = ["point_maze"]\n{extra}'
    )
    return path


@pytest.mark.parametrize(
    "algorithms",
    [("map_elites",), pytest.param(("map_elites", "diayn"), marks=pytest.mark.slow)],  # a skill run: +25 s
    ids=["map_elites", "map_elites+diayn"],
)
def test_a_suite_runs_to_its_budget_says_so_and_a_larger_budget_resumes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], algorithms: tuple[str, ...]
) -> None:
    out, n, listed = tmp_path / "out", len(algorithms), json.dumps(list(algorithms))
    path = write_suite(tmp_path, "env_steps = 600", listed)
    assert main(["suite", "status", str(path), "--out", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"0 done, 0 partial, {n} not started; in {out}"
    assert main(["suite", "run", str(path), "--out", str(out)]) == 0
    status = json.loads(capsys.readouterr().out)
    assert status["counts"] == {"done": n, "partial": 0, "not started": 0}
    for algorithm in algorithms:
        run = out / "point_maze" / algorithm / "seed_0"
        summary = json.loads((run / "summary.json").read_text())
        # stopped at the first log point at or past 600 environment steps, before its length
        assert summary["stopped_by"] == "env_steps_limit" and summary["env_steps_limit"] == 600
        assert 600 <= summary["env_steps"] < 1280 and summary["log_points"] < summary["num_log_points"]
        assert "range_qd_score" in summary and 0.0 <= summary["range_qd_score"] <= 1.0
    assert json.loads((out / "suite.json").read_text())["budget"] == {"time_limit_s": None, "env_steps": 600}
    # Run again: nothing to do.
    assert main(["suite", "run", str(path), "--out", str(out)]) == 0
    assert f"{n} of {n} runs done, 0 to run" in capsys.readouterr().err
    # A larger budget: both are behind it and resume from their checkpoints to the new one.
    path = write_suite(tmp_path, "env_steps = 2000", listed)
    assert main(["suite", "status", str(path), "--out", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"0 done, {n} partial, 0 not started; in {out}"
    assert main(["suite", "run", str(path), "--out", str(out)]) == 0
    status = json.loads(capsys.readouterr().out)
    assert status["counts"]["done"] == n
    for algorithm in algorithms:  # their whole length: under the budget, the first session's rows kept
        run = out / "point_maze" / algorithm / "seed_0"
        assert "stopped_by" not in json.loads((run / "summary.json").read_text())
        assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 4
    # The report over the suite's folder: the algorithms on the task, steps per hour.
    result = report.report([out], tmp_path / "report")
    assert result["groups"]["point_maze"]["labels"] == {a: [0] for a in algorithms}
    speed = {r["spec"]: r for r in csv.DictReader(Path(result["throughput"]).read_text().splitlines())}
    assert set(speed) == set(algorithms)
    for r in speed.values():
        assert float(r["env_steps_per_hour_run"]) >= float(r["env_steps_per_hour"]) > 0  # compile excluded
    assert "env steps per hour" in Path(result["table"]).read_text()


@pytest.mark.parametrize(
    ("budget", "algorithms", "extra", "message"),
    [
        ("env_steps = 0", None, "", r"suite\.env_steps: expected a positive integer"),
        ("time_limit_s = -5", None, "", r"suite\.time_limit_s: expected a number > 0"),
        ("seeds_typo = 1", None, "", r"suite\.seeds_typo: unknown key"),
        ("", '["map_elites", "nope"]', "", r"runs\[0\]\.specs: nope on point_maze: spec file .*nope_point_maze\.toml. not found"),
        ("", '["map_elites", "map_elites"]', "", r"runs\[0\]: map_elites on point_maze is listed twice"),
        ("", None, "[other]\nx = 1\n", r"other: expected the sections \[suite\] and \[\[runs\]\]"),
    ],
)
def test_a_bad_suite_is_refused_with_the_key_before_anything_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], budget: str, algorithms: str | None, extra: str, message: str
) -> None:
    path = write_suite(tmp_path, budget, algorithms or '["map_elites", "diayn"]', extra)
    assert main(["suite", "run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("qdrl: error: ") and len(err.strip().splitlines()) == 1
    assert __import__("re").search(message, err), err
    assert not (tmp_path / "out").exists()


def test_a_spec_of_another_task_or_a_bad_value_is_named(tmp_path: Path) -> None:
    path = write_suite(tmp_path, "")
    text = path.read_text().replace('tasks = ["point_maze"]', 'tasks = ["point_maze"]\n')
    (tmp_path / "diayn_point_maze.toml").write_text(dump_toml({**DIAYN, "env": {**DIAYN["env"], "task": "ant_omni"}}))
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"diayn on point_maze runs on 'ant_omni'; expected a spec of the task 'point_maze'"):
        suites.load_suite(path, tmp_path / "out")
    (tmp_path / "diayn_point_maze.toml").write_text(dump_toml({**DIAYN, "train": {**DIAYN["train"], "num_envs": 0}}))
    with pytest.raises(ConfigError, match=r"diayn_point_maze\.toml \(diayn on point_maze\): train\.num_envs: expected a positive integer"):
        suites.load_suite(path, tmp_path / "out")


def test_the_recorded_benchmark_suites_are_slices_of_the_packaged_one(tmp_path: Path) -> None:
    """benchmarks/suites/*.toml: each loads, and one that names a packaged suite runs only that
    suite's runs (same spec, same budget, same folder), so their results share one folder."""
    root = Path(__file__).resolve().parents[1] / "benchmarks" / "suites"
    paths = sorted(root.glob("*.toml"))
    assert {"seed_benchmark_cpu_seed0.toml", "seed_benchmark_cpu_seed1.toml"} <= {p.name for p in paths}
    for path in paths:
        part = suites.load_suite(path, tmp_path)  # every one loads: its specs exist, its values are valid
        if part.config.name not in suites.suite_names():
            continue
        whole = suites.load_suite(part.config.name, tmp_path)
        assert part.config.time_limit_s == whole.config.time_limit_s
        packaged = {(e.task, e.algorithm, e.seed): e.spec.name for e in whole.entries}
        for e in part.entries:
            assert packaged.get((e.task, e.algorithm, e.seed)) == e.spec.name, (path.name, e.task, e.algorithm, e.seed)
            assert e.out == tmp_path / e.task / e.algorithm / f"seed_{e.seed}"


def test_the_packaged_suites_name_only_specs_that_exist() -> None:
    assert suites.suite_names() == ["dns_walker2d", "metra_cpu", "qdac_cpu", "seed_benchmark", "seed_benchmark_cpu"]
    full, cpu = suites.load_suite("seed_benchmark"), suites.load_suite("seed_benchmark_cpu")
    assert len(full.entries) == 10 * 7 * 5 and len(cpu.entries) == (3 * 7 + 3 * 2) * 2
    assert cpu.config.time_limit_s == 600 and full.config.time_limit_s is None  # the specs' own budgets
    assert {e.spec.parent.name for e in cpu.entries} == {"seed_benchmark"}
    with pytest.raises(ConfigError, match="close names: seed_benchmark_cpu"):
        suites.resolve_suite("seed_benchmark_cp")
    # the comparisons with METRA and QDAC: every method at one budget, on its paper's tasks
    metra, qdac = suites.load_suite("metra_cpu"), suites.load_suite("qdac_cpu")
    assert sorted({e.algorithm for e in metra.entries}) == ["dads", "diayn", "lsd", "metra"] and len(metra.entries) == 12
    assert sorted({e.task for e in metra.entries}) == ["ant_omni", "halfcheetah_omni"]
    assert sorted({e.task for e in qdac.entries}) == ["ant_velocity", "walker2d_feet_contact"]
    for task in ("walker2d_feet_contact", "ant_velocity"):
        assert sorted({e.algorithm for e in qdac.entries if e.task == task}) == [
            "dcrl_me", "domino", "qdac", "qdpg", "smerl_diayn", "smerl_reverse", "uvfa"]
    assert len(qdac.entries) == 7 * 2 * 2
