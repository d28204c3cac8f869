"""MAP-Elites on the arm, qdrl against QDax 0.5.0, alternating runs in one session.

    python benchmarks/compare_qdax_map_elites.py --qdax-python /path/to/qdax-venv/bin/python

For each seed and each container (CVT 1024, grid 32x32, grid 100x100) it runs
`qdrl bench map_elites --config C --seed S` and `qdax_map_elites_arm.py` with the
same settings, each in a fresh process (so both compile cold, and neither uses a
persistent compilation cache), alternating which goes first. It prints and
writes JSON with every run, the means per side, and the ratios qdrl / QDax.
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
CONTAINERS = {"cvt1024": ["--container", "cvt", "--num-centroids", "1024"],
              "grid32": ["--container", "grid", "--grid-shape", "32", "32"],
              "grid100": ["--container", "grid", "--grid-shape", "100", "100"]}


def _json_from(text: str) -> dict[str, Any]:
    """The JSON document that ends the output (libraries may print lines before it)."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith(("{", "[")):
            try:
                return dict(json.loads("\n".join(lines[i:])))
            except json.JSONDecodeError:
                continue
    raise ValueError(f"no JSON in output: {text[-500:]!r}")


def run_qdrl(container: str, seed: int, env: dict[str, str]) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "qdrl.cli", "bench", "map_elites", "--config", container, "--seed", str(seed)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
    return dict(_json_from(out.stdout)["results"][0])


def run_qdax(python: str, container: str, seed: int, env: dict[str, str]) -> dict[str, Any]:
    cmd = [python, str(HERE / "qdax_map_elites_arm.py"), *CONTAINERS[container], "--seed", str(seed)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
    return _json_from(out.stdout)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--qdax-python", required=True, help="python of a venv with qdax==0.5.0")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--containers", nargs="+", default=list(CONTAINERS))
    p.add_argument("--out", default=str(HERE / "results" / "map_elites_arm_vs_qdax.json"))
    args = p.parse_args()
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"
    runs: list[dict[str, Any]] = []
    for seed in range(args.seeds):
        for container in args.containers:
            order = ["qdrl", "qdax"] if seed % 2 == 0 else ["qdax", "qdrl"]
            for side in order:
                rec = run_qdrl(container, seed, env) if side == "qdrl" else run_qdax(args.qdax_python, container, seed, env)
                rec.update({"side": side, "config": container})
                runs.append(rec)
                print(json.dumps(rec), file=sys.stderr)
    summary: dict[str, Any] = {}
    for container in args.containers:
        row: dict[str, Any] = {}
        for side in ("qdrl", "qdax"):
            rs = [r for r in runs if r["side"] == side and r["config"] == container]
            row[side] = {k: round(statistics.mean(r[k] for r in rs), 4)
                         for k in ("evals_per_s", "compile_s", "qd_score", "coverage")}
        row["speed_ratio"] = round(row["qdrl"]["evals_per_s"] / row["qdax"]["evals_per_s"], 2)
        row["compile_ratio"] = round(row["qdrl"]["compile_s"] / row["qdax"]["compile_s"], 2)
        row["qd_score_ratio"] = round(row["qdrl"]["qd_score"] / row["qdax"]["qd_score"], 4)
        summary[container] = row
    from qdrl.bench import machine

    record = {"machine": machine(), "seeds": args.seeds, "summary": summary, "runs": runs}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
