"""Compile time of one MAP-Elites program, qdrl against QDax 0.5.0, side by side.

    python benchmarks/compile_time_vs_qdax.py --qdax-python /path/to/qdax-venv/bin/python --repeats 4

Each side compiles the same program ahead of time in a fresh process, alternating
which goes first: the 100-DoF arm (CVT 1024, batch 1024) and halfcheetah_uni
(episodes of 100 steps, batch 128, CVT 1024), as `qdrl bench` and the QDax scripts
beside this one time them (`compare_qdax_map_elites.py`, `compare_qdax_brax.py`):
the scan of 200 iterations (arm) or 50 (halfcheetah_uni) those benchmarks time. (A
scan of 2 iterations is unrolled by XLA, which compiles the step twice.) Each
process then runs its program once. Records wall and process CPU time of the
compilation (mean and standard deviation over the repeats); the CPU time
is the steadier figure when other jobs share the cores. No persistent compilation
cache on either side. QDax's halfcheetah figure leaves out its eager reset of the
environment (`reset_s`); qdrl computes its start state in its own small program
while the initial population's evaluation is traced, also outside the timed one.
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
QDRL_ARM = "from qdrl.bench import time_map_elites as t; import json; print(json.dumps(t('cvt1024', iterations=200, hlo=False)))"
QDRL_CHEETAH = ("from qdrl.bench import time_policy_map_elites as t; import json; "
                "print(json.dumps(t('halfcheetah_uni', iterations=50)))")


def _run(cmd: list[str], env: dict[str, str]) -> dict[str, Any]:
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--qdax-python", required=True)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--out", default=str(HERE / "results" / "compile_time_vs_qdax.json"))
    args = p.parse_args()
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env.update(JAX_PLATFORMS="cpu", QDRL_COMPILE_CACHE="0")
    commands = {
        "arm": {
            "qdrl": [sys.executable, "-c", QDRL_ARM],
            "qdax": [args.qdax_python, str(HERE / "qdax_map_elites_arm.py"), "--iterations", "200"],
        },
        "halfcheetah_uni": {
            "qdrl": [sys.executable, "-c", QDRL_CHEETAH],
            "qdax": [args.qdax_python, str(HERE / "qdax_map_elites_brax.py"), "--iterations", "50"],
        },
    }
    runs: list[dict[str, Any]] = []
    for task, sides in commands.items():
        for r in range(args.repeats):
            for side in (["qdrl", "qdax"] if r % 2 == 0 else ["qdax", "qdrl"]):
                rec = _run(sides[side], env)
                row = {"task": task, "side": side, "repeat": r,
                       **{k: rec[k] for k in ("compile_s", "compile_cpu_s") if k in rec}}
                runs.append(row)
                print(json.dumps(row), file=sys.stderr)
    summary: dict[str, Any] = {}
    for task in commands:
        s: dict[str, Any] = {}
        for side in ("qdrl", "qdax"):
            rs = [x for x in runs if x["task"] == task and x["side"] == side]
            s[side] = {k: round(statistics.mean(x[k] for x in rs), 2) for k in ("compile_s", "compile_cpu_s")}
            if len(rs) > 1:
                s[side].update({f"{k}_std": round(statistics.stdev(x[k] for x in rs), 2)
                                for k in ("compile_s", "compile_cpu_s")})
        s["cpu_ratio_qdrl_over_qdax"] = round(s["qdrl"]["compile_cpu_s"] / s["qdax"]["compile_cpu_s"], 3)
        s["wall_ratio_qdrl_over_qdax"] = round(s["qdrl"]["compile_s"] / s["qdax"]["compile_s"], 3)
        summary[task] = s
    from qdrl.bench import machine

    record = {"machine": machine(), "repeats": args.repeats, "summary": summary, "runs": runs}
    Path(args.out).write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
