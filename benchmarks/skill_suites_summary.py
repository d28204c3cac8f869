"""The final figures of a skill-method suite's runs (`qdrl suite run qdac_cpu` / `metra_cpu`), as JSON.

    python benchmarks/skill_suites_summary.py runs/qdac_cpu --out benchmarks/results/qdac_cpu.json
    python benchmarks/skill_suites_summary.py runs/metra_cpu --out benchmarks/results/metra_cpu.json
    python benchmarks/skill_suites_summary.py runs/qdac_cpu --at-env-steps 200000   # every run at one length

For every run directory `<task>/<algorithm>/seed_<n>/` with a metrics.csv: its last row's (or,
with `--at-env-steps N`, its row at N environment steps, so that runs of several lengths
compare at one)
distance to skill (direct and through the archive), share of targets reached, evaluation
return, for a QD run its `qdrl reevaluate` figures when it has them (the final repertoire's
elite nearest each target played again: `reevaluated`), METRA's cells visited, the passive archive's QD score and coverage, environment steps
and wall time, and the run's profiles.json when it wrote one; then per task and algorithm the
mean over seeds. Runs that have not finished are reported with `finished: false`. A run of a
feature task that did not log `archive_distance_to_skill` (an older version of qdrl) gets it
from its passive archive rebuilt from skills.csv (its evaluated episodes, in order, into the
same cells): the figures its run would have logged.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import tomllib
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from qdrl.algorithms.rl import ArchiveConfig
from qdrl.config import build
from qdrl.qd.repertoires.passive import feed
from qdrl.skill_metrics import archive_skill_metrics
from qdrl.tasks.brax_features import feature_space

KEYS = (
    "env_steps", "wall_s", "eval_return", "distance_to_skill", "reached", "archive_distance_to_skill",
    "archive_reached", "cells_visited", "qd_score", "coverage", "num_elites", "mean_fitness", "max_fitness",
    "lagrange",
)


def run_figures(run: Path, at_env_steps: int | None = None) -> dict[str, Any]:
    """The last logged value (or the value at `at_env_steps`) of each of `KEYS` a run has, and
    whether it finished."""
    with (run / "metrics.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    if at_env_steps is not None:
        rows = [r for r in rows if int(float(r["env_steps"])) <= at_env_steps]
    last = rows[-1] if rows else {}
    out: dict[str, Any] = {k: float(last[k]) for k in KEYS if last.get(k) not in (None, "")}
    if "archive_distance_to_skill" not in out and rows and (run / "skills.csv").is_file():
        out.update(rebuilt_archive_metrics(run, int(float(last["env_steps"]))))
    out["finished"] = (run / "summary.json").is_file()
    out["log_points"] = len(rows)
    reevaluation = run / "reevaluation.json"  # `qdrl reevaluate RUN --samples N` of a QD run's final repertoire
    if reevaluation.is_file() and "skills" in (report := json.loads(reevaluation.read_text())):
        out["reevaluated"] = {"samples": report["samples"], "elites": report["elites_reevaluated"],
                              **{k: v for k, v in report["skills"].items() if k.startswith("picked_")},
                              "corrected_archive_distance_to_skill": report["skills"]["corrected"]["archive_distance_to_skill"]}
    if (run / "profiles.json").is_file() and at_env_steps is None:
        out["profiles"] = json.loads((run / "profiles.json").read_text())
    return out


def rebuilt_archive_metrics(run: Path, env_steps: int) -> dict[str, float]:
    """`archive_skill_metrics` of a run's passive archive after `env_steps`, rebuilt from the
    episodes skills.csv holds ({} where the run's task has no feature space)."""
    config = tomllib.loads((run / "config.toml").read_text())
    space = feature_space(config["env"]["task"])
    if space is None:
        return {}
    archive_cfg = build(ArchiveConfig, config["archive"], "archive")
    archive = archive_cfg.empty(int(config["experiment"]["seed"]))
    with (run / "skills.csv").open(newline="") as f:
        episodes = [r for r in csv.DictReader(f) if int(r["env_steps"]) <= env_steps]
    columns = [c for c in episodes[0] if c.startswith("descriptor_")]
    for point in sorted({int(r["log_point"]) for r in episodes}):
        batch = [r for r in episodes if int(r["log_point"]) == point]
        desc = np.clip([[float(r[c]) for c in columns] for r in batch], archive_cfg.low, archive_cfg.high)
        archive, _ = feed(archive, jnp.asarray(desc, jnp.float32), jnp.asarray([float(r["return"]) for r in batch]),
                          archive_cfg.qd_offset)
    metrics = archive_skill_metrics(archive.descriptors, archive.fitnesses, space)
    return {k: float(v) for k, v in metrics.items()} | {"archive_rebuilt_from_skills_csv": 1.0}


def summarise(root: Path, at_env_steps: int | None = None) -> dict[str, Any]:
    """Every run under `root` (`<task>/<algorithm>/seed_<n>`) and the mean per task and algorithm."""
    runs: dict[str, dict[str, dict[str, Any]]] = {}
    for metrics in sorted(root.glob("*/*/seed_*/metrics.csv")):
        run = metrics.parent
        task, algorithm, seed = run.parent.parent.name, run.parent.name, run.name
        runs.setdefault(task, {}).setdefault(algorithm, {})[seed] = run_figures(run, at_env_steps)
    means: dict[str, dict[str, dict[str, float]]] = {}
    for task, by_algorithm in runs.items():
        for algorithm, by_seed in by_algorithm.items():
            keys = {k for fig in by_seed.values() for k in fig if k in KEYS}
            means.setdefault(task, {})[algorithm] = {
                k: statistics.fmean(fig[k] for fig in by_seed.values() if k in fig) for k in sorted(keys)
            } | {"seeds": len(by_seed)}
            replays = [fig["reevaluated"] for fig in by_seed.values() if "reevaluated" in fig]
            for k in sorted({k for r in replays for k in r if k.startswith(("picked_", "corrected_"))}):
                means[task][algorithm][f"reevaluated_{k}"] = statistics.fmean(r[k] for r in replays)
    return {"suite": root.name, "at_env_steps": at_env_steps, "runs": runs, "mean_over_seeds": means}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="the suite's output directory")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    parser.add_argument("--at-env-steps", type=int, help="read every run at this many env steps")
    args = parser.parse_args()
    record = summarise(args.root, args.at_env_steps)
    text = json.dumps(record, indent=2)
    print(json.dumps(record["mean_over_seeds"], indent=2))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
