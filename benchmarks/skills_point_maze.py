"""Skill discovery against SAC on the point maze, measured with the same passive archive.

Runs, with the same number of environment steps, the same SAC settings and the
same evaluation budget (16 deterministic episodes per log point offered to a
32x32 grid archive of the final x-y position over [-1, 1]^2):

1. SAC alone on the task reward (`qdrl.algorithms.rl`);
2. DIAYN, 8 skills, discriminator on x-y (`agents/diayn_point_maze_cpu.toml`);
3. SMERL on DIAYN, 5 skills, with R* = SAC's final evaluation return (the paper's
   protocol: R* is the return of a policy trained on the task alone) and
   epsilon = 10% of |R*| (`agents/smerl_diayn_point_maze_cpu.toml`).

Writes `benchmarks/results/skills_point_maze.json` (every log point of each run,
their summaries and the machine load) and copies DIAYN's and SMERL's skill
pictures to `docs/skills_point_maze_diayn.png` / `docs/skills_point_maze_smerl.png`.

`--smerl-dads` runs only SMERL on DADS (`agents/smerl_dads_point_maze_cpu.toml`,
5 skills, lambda = 2) with the R* and epsilon that SAC's run gave the other SMERL
(read from `skills_point_maze.json`), and writes
`benchmarks/results/skills_point_maze_smerl_dads.json` with the same table (its skills
picture stays in the run's `plots/`), plus SAC's and DADS's rows (from `skills_point_maze.json` and `skills_point_maze_dads.json`)
to compare with.

    nice -n 19 python benchmarks/skills_point_maze.py [--steps 1000000] [--seed 0] [--smerl-dads]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _rows(out: Path) -> list[dict[str, float]]:
    with (out / "metrics.csv").open() as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


TABLE_KEYS = (
    "env_steps", "coverage", "qd_score", "max_fitness", "eval_return", "eval_return_min",
    "eval_final_discriminator_accuracy", "eval_discriminator_accuracy",
    "eval_final_dynamics_log_likelihood", "eval_dynamics_log_likelihood", "env_steps_per_s",
    "run_s", "compile_s",
)


def _table_row(summary: dict[str, Any]) -> dict[str, Any]:
    return {k: summary[k] for k in TABLE_KEYS if k in summary}


def _point_maze_spec(name: str, steps: int, seed: int) -> dict[str, Any]:
    """A CPU spec of `agents/` with `steps` env steps, 10 log points, no progress bar."""
    from qdrl.config import load_toml

    spec = load_toml(ROOT / "agents" / f"{name}_point_maze_cpu.toml")
    spec["experiment"]["seed"] = seed
    spec["train"]["total_env_steps"] = steps
    spec["train"]["eval_every"] = steps // 10
    spec["train"]["buffer_size"] = steps
    spec.setdefault("log", {})["progress"] = False
    return spec


def smerl_dads(steps: int, seed: int, out: Path) -> None:
    """SMERL on DADS with the R* and epsilon of `skills_point_maze.json`; writes its own file."""
    from qdrl import bench

    results_dir = ROOT / "benchmarks" / "results"
    before = json.loads((results_dir / "skills_point_maze.json").read_text())
    spec = _point_maze_spec("smerl_dads", steps, seed)
    spec["smerl"] = dict(before["smerl_target"])
    run = _run(spec, out / "smerl_dads")
    dads = json.loads((results_dir / "skills_point_maze_dads.json").read_text())["summary"]
    table = {
        "sac": before["table"]["sac"],
        "dads": _table_row(dads),
        "smerl_diayn": before["table"]["smerl_diayn"],
        "smerl_dads": _table_row(run["summary"]),
    }
    results = {
        "machine": bench.machine(),
        "steps": steps,
        "smerl_target": spec["smerl"],
        "spec": spec,
        "note": "sac, dads and smerl_diayn rows copied from skills_point_maze.json and "
                "skills_point_maze_dads.json (same steps, SAC settings, evaluation and archive)",
        "runs": {"smerl_dads": run},
        "table": table,
    }
    dest = results_dir / "skills_point_maze_smerl_dads.json"
    dest.write_text(json.dumps(results, indent=1, default=float) + "\n")
    print(json.dumps(table, indent=1))


def _run(spec: dict[str, Any], out: Path) -> dict[str, Any]:
    from qdrl.experiment import run

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    summary = run(spec, out, overwrite=True)
    return {
        "summary": summary,
        "rows": _rows(out),
        "total_s": round(time.perf_counter() - t0, 1),
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
    }


def main() -> None:
    from qdrl import bench

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=1_000_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(ROOT / "runs" / "skills_point_maze"))
    p.add_argument("--smerl-dads", action="store_true",
                   help="run only SMERL on DADS, with R* from skills_point_maze.json")
    args = p.parse_args()
    out = Path(args.out)
    if args.smerl_dads:
        smerl_dads(args.steps, args.seed, out)
        return

    diayn = _point_maze_spec("diayn", args.steps, args.seed)
    smerl = _point_maze_spec("smerl_diayn", args.steps, args.seed)
    archive = {"descriptor": "final", "grid_shape": [32, 32], "low": [-1.0, -1.0],
               "high": [1.0, 1.0], "qd_offset": -2.0 * 2.0**0.5 * 100}
    sac = {
        "experiment": {"algorithm": "sac", "seed": args.seed},
        "env": {"name": "point_maze", "episode_length": 100},
        # SAC exactly as in the skill runs (their [agent] section), on the task reward.
        "agent": dict(diayn["agent"]),
        "train": dict(diayn["train"]),
        "archive": archive,
        "log": {"progress": False},
    }
    results: dict[str, Any] = {"machine": bench.machine(), "steps": args.steps, "runs": {}}
    results["runs"]["sac"] = _run(sac, out / "sac")
    target = float(results["runs"]["sac"]["summary"]["eval_return"])
    smerl["smerl"] = {"target": round(target, 2), "margin": round(0.1 * abs(target), 2)}
    results["smerl_target"] = smerl["smerl"]
    results["runs"]["diayn"] = _run(diayn, out / "diayn")
    results["runs"]["smerl_diayn"] = _run(smerl, out / "smerl_diayn")

    table = {name: _table_row(r["summary"]) for name, r in results["runs"].items()}
    results["table"] = table
    dest = ROOT / "benchmarks" / "results" / "skills_point_maze.json"
    dest.write_text(json.dumps(results, indent=1, default=float) + "\n")
    for name, png in (("diayn", "skills_point_maze_diayn.png"),
                      ("smerl_diayn", "skills_point_maze_smerl.png")):
        shutil.copy(out / name / "plots" / "skills.png", ROOT / "docs" / png)
    print(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
