"""What evaluating policies in blocks of a fixed width costs MAP-Elites on a policy task.

    python benchmarks/policy_eval_blocks.py --task halfcheetah_uni --repeats 3

Policy tasks roll out a batch in blocks of `eval_batch` episodes (`lax.map` over
the blocks), so that a policy's fitness does not depend on the batch it is scored
in (`qdrl.tasks.policy`). A run sets `eval_batch` to its batch size: one block. This
script times `qdrl.bench.time_policy_map_elites` (episodes of 100 steps, batch 128,
CVT 1024, 50 iterations as one compiled scan) with one block (`eval_batch` = 128)
and without blocks (`eval_batch` None), each run in a fresh process, alternating
which goes first, and records compile time, env steps/s and the size of the
compiled program (HLO instructions) of both in JSON.

`--side blocks|none` runs one of them and prints its record.
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

HERE = Path(__file__).resolve().parent


def _one(args: argparse.Namespace) -> None:
    from qdrl.bench import time_policy_map_elites

    rec = time_policy_map_elites(args.task, blocks=args.side == "blocks", seed=args.seed, hlo=args.hlo)
    if "hlo" in rec:
        rec["hlo_instructions"] = rec.pop("hlo")["cpu_optimized"]["instructions"]
    print(json.dumps(rec))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="halfcheetah_uni")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--side", choices=["blocks", "none"], default=None)
    p.add_argument("--hlo", action="store_true")
    p.add_argument("--out", default=None)
    args = p.parse_args()
    if args.side is not None:
        _one(args)
        return
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"
    runs: list[dict[str, Any]] = []
    for r in range(args.repeats):
        for side in (["blocks", "none"] if r % 2 == 0 else ["none", "blocks"]):
            cmd = [sys.executable, __file__, "--task", args.task, "--side", side, "--seed", str(args.seed)]
            if r == 0:
                cmd.append("--hlo")
            out = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if out.returncode != 0:
                raise RuntimeError(out.stderr[-3000:])
            rec = json.loads(out.stdout.strip().splitlines()[-1])
            rec["side"] = side
            runs.append(rec)
            print(json.dumps(rec), file=sys.stderr)
    summary: dict[str, Any] = {}
    for side in ("blocks", "none"):
        rs = [x for x in runs if x["side"] == side]
        summary[side] = {k: round(statistics.mean(x[k] for x in rs), 2) for k in ("compile_s", "env_steps_per_s")}
        summary[side]["hlo_instructions"] = next(x["hlo_instructions"] for x in rs if "hlo_instructions" in x)
        # Same seed, same computation per episode: the QD score must not move.
        summary[side]["qd_score"] = sorted({x["qd_score"] for x in rs})
    summary["speed_ratio_blocks_over_none"] = round(
        summary["blocks"]["env_steps_per_s"] / summary["none"]["env_steps_per_s"], 3)
    summary["compile_ratio_blocks_over_none"] = round(
        summary["blocks"]["compile_s"] / summary["none"]["compile_s"], 3)
    from qdrl.bench import machine

    record = {"machine": machine(), "task": args.task, "repeats": args.repeats, "summary": summary, "runs": runs}
    path = Path(args.out or HERE / "results" / f"policy_eval_blocks_{args.task}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
