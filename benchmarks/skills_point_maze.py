"""Skill discovery against SAC on the point maze, measured with the same passive archive.

Runs, with the same number of environment steps, the same SAC settings and the
same evaluation budget (16 deterministic episodes per log point offered to a
32x32 grid archive of the final x-y position over [-1, 1]^2):

1. SAC alone on the task reward (`qdrl.runners.rl`);
2. DIAYN, 8 skills, discriminator on x-y (`agents/diayn_point_maze_cpu.toml`);
3. SMERL on DIAYN, 5 skills, with R* = SAC's final evaluation return (the paper's
   protocol: R* is the return of a policy trained on the task alone) and
   epsilon = 10% of |R*| (`agents/smerl_diayn_point_maze_cpu.toml`).

Writes `benchmarks/results/skills_point_maze.json` (every log point of each run,
their summaries and the machine load) and copies DIAYN's and SMERL's skill
pictures to `docs/skills_point_maze_diayn.png` / `docs/skills_point_maze_smerl.png`.

    nice -n 19 python benchmarks/skills_point_maze.py [--steps 1000000] [--seed 0]
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
    from qdrl.config import load_toml

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=1_000_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(ROOT / "runs" / "skills_point_maze"))
    args = p.parse_args()
    out = Path(args.out)

    diayn = load_toml(ROOT / "agents" / "diayn_point_maze_cpu.toml")
    smerl = load_toml(ROOT / "agents" / "smerl_diayn_point_maze_cpu.toml")
    for spec in (diayn, smerl):
        spec["experiment"]["seed"] = args.seed
        spec["train"]["total_env_steps"] = args.steps
        spec["train"]["eval_every"] = args.steps // 10
        spec["train"]["buffer_size"] = args.steps
        spec.setdefault("log", {})["progress"] = False
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

    table = {}
    for name, r in results["runs"].items():
        s = r["summary"]
        table[name] = {
            k: s.get(k)
            for k in ("env_steps", "coverage", "qd_score", "max_fitness", "eval_return",
                      "eval_return_min", "eval_final_discriminator_accuracy",
                      "eval_discriminator_accuracy", "env_steps_per_s", "run_s", "compile_s")
        }
    results["table"] = table
    dest = ROOT / "benchmarks" / "results" / "skills_point_maze.json"
    dest.write_text(json.dumps(results, indent=1, default=float) + "\n")
    for name, png in (("diayn", "skills_point_maze_diayn.png"),
                      ("smerl_diayn", "skills_point_maze_smerl.png")):
        shutil.copy(out / name / "plots" / "skills.png", ROOT / "docs" / png)
    print(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
