"""MAP-Elites on a brax QD task (default halfcheetah_uni), qdrl against QDax 0.5.0.

    python benchmarks/compare_qdax_brax.py --qdax-python /path/to/qdax-venv/bin/python

Spring backend, episodes of 100 steps, batch 128, CVT 1024, policies 64x64 tanh,
iso-line 0.005 / 0.05, the same number of iterations (so the same number of
evaluations) on both sides; each run a fresh process, alternating which side
goes first per seed. Writes every run, the means and the ratios as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from compare_qdax_map_elites import _json_from

HERE = Path(__file__).resolve().parent


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--qdax-python", required=True)
    p.add_argument("--task", default="halfcheetah_uni")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--platform", choices=["cpu", "cuda"], default="cpu",
                   help="JAX_PLATFORMS of every run (cuda: an NVIDIA GPU)")
    p.add_argument("--append", action="store_true", help="keep the runs already in --out")
    p.add_argument("--out", default=str(HERE / "results" / "map_elites_halfcheetah_uni_vs_qdax.json"))
    args = p.parse_args()
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = args.platform
    runs: list[dict[str, Any]] = []
    if args.append and Path(args.out).exists():
        runs = json.loads(Path(args.out).read_text())["runs"]
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for side in (["qdrl", "qdax"] if seed % 2 == 0 else ["qdax", "qdrl"]):
            if side == "qdrl":
                cmd = [sys.executable, "-m", "qdrl.cli", "bench", "policy_map_elites",
                       "--config", args.task, "--seed", str(seed)]
                rec = dict(_json_from(subprocess.run(cmd, capture_output=True, text=True, check=True, env=env).stdout)["results"][0])
            else:
                cmd = [args.qdax_python, str(HERE / "qdax_map_elites_brax.py"), "--task", args.task, "--seed", str(seed)]
                rec = _json_from(subprocess.run(cmd, capture_output=True, text=True, check=True, env=env).stdout)
            rec["side"] = side
            runs.append(rec)
            print(json.dumps(rec), file=sys.stderr)
    summary: dict[str, Any] = {}
    for side in ("qdrl", "qdax"):
        rs = [r for r in runs if r["side"] == side]
        summary[side] = {k: round(statistics.mean(r[k] for r in rs), 3)
                         for k in ("env_steps_per_s", "compile_s", "qd_score", "coverage", "evaluations")}
        summary[side]["qd_score_std"] = round(statistics.pstdev(r["qd_score"] for r in rs), 1)
        summary[side]["seeds"] = len(rs)
    summary["speed_ratio"] = round(summary["qdrl"]["env_steps_per_s"] / summary["qdax"]["env_steps_per_s"], 2)
    summary["qd_score_ratio"] = round(summary["qdrl"]["qd_score"] / summary["qdax"]["qd_score"], 4)
    from qdrl.bench import machine

    Path(args.out).write_text(json.dumps({"machine": machine(), "task": args.task, "summary": summary, "runs": runs}, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
