"""ME-PBT against MAP-Elites at equal environment steps.

    python benchmarks/me_pbt_vs_map_elites.py [--task halfcheetah_uni] [--out runs/me_pbt_evidence]

Runs `agents/me_pbt_sac_<task>_cpu.toml` and `agents/map_elites_<task>_cpu.toml`
(same task, episode length and CVT), MAP-Elites for as many iterations as it
takes to spend at least ME-PBT's environment steps (ME-PBT's count its agents'
training steps as well as its evaluations). Reports both QD scores at ME-PBT's
final env-step count (MAP-Elites' interpolated between its log points) and
writes `benchmarks/results/me_pbt_vs_map_elites_<task>.json` and
`docs/me_pbt_vs_map_elites_<task>.png`. Finished runs are read, not re-run.
"""

from __future__ import annotations

import argparse
import json
import math
import tomllib
from pathlib import Path

import numpy as np
from pbt_vs_fixed import _rows

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def plot(pbt_rows: list[dict[str, float]], me_rows: list[dict[str, float]], task: str, path: str | Path) -> Path:
    """Draws ME-PBT's and MAP-Elites' QD score (their runs' metric rows) against env steps and writes
    it to `path`."""
    from qdrl.plotting import plot_comparison

    return plot_comparison({"ME-PBT (SAC)": pbt_rows, "MAP-Elites": me_rows}, "qd_score", "env_steps", path,
                           title=f"{task}: QD score vs env steps")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--task", default="halfcheetah_uni")
    p.add_argument("--out", default="runs/me_pbt_evidence")
    args = p.parse_args()

    from qdrl.experiment import run_spec

    out = Path(args.out)
    me_pbt_spec = ROOT / "agents" / f"me_pbt_sac_{args.task}_cpu.toml"
    me_spec = ROOT / "agents" / f"map_elites_{args.task}_cpu.toml"
    pbt_dir, me_dir = out / f"me_pbt_{args.task}", out / f"map_elites_{args.task}"
    if not (pbt_dir / "summary.json").exists():
        run_spec(me_pbt_spec, [], pbt_dir, overwrite=True)
    pbt_rows = _rows(pbt_dir / "metrics.csv")
    target = pbt_rows[-1]["env_steps"]
    me = tomllib.loads(me_spec.read_text())
    per_iter = me["emitter"]["batch_size"] * me["task"]["episode_length"]
    log_every = me["qd"]["log_every"]
    iterations = log_every * math.ceil(target / per_iter / log_every)
    if not (me_dir / "summary.json").exists():
        run_spec(me_spec, [f"qd.num_iterations={iterations}"], me_dir, overwrite=True)
    me_rows = _rows(me_dir / "metrics.csv")

    me_steps = np.array([r["env_steps"] for r in me_rows])
    at = {k: float(np.interp(target, me_steps, [r[k] for r in me_rows])) for k in ("qd_score", "coverage", "max_fitness")}
    final = pbt_rows[-1]
    record = {
        "task": args.task,
        "env_steps": target,
        "me_pbt": {k: final[k] for k in ("qd_score", "coverage", "max_fitness", "evaluations", "train_env_steps", "wall_s")},
        "map_elites_at_equal_env_steps": at,
        "map_elites_final": {k: me_rows[-1][k] for k in ("qd_score", "coverage", "max_fitness", "env_steps", "evaluations", "wall_s")},
        "qd_score_ratio": round(final["qd_score"] / at["qd_score"], 3),
        "max_fitness_ratio": round(final["max_fitness"] / at["max_fitness"], 3) if at["max_fitness"] else None,
    }
    from qdrl.bench import machine

    record["machine"] = machine()
    (HERE / "results" / f"me_pbt_vs_map_elites_{args.task}.json").write_text(json.dumps(record, indent=2) + "\n")
    plot(pbt_rows, me_rows, args.task, ROOT / "docs" / f"me_pbt_vs_map_elites_{args.task}.png")
    print(json.dumps(record, indent=2))


if __name__ == "__main__":
    main()
