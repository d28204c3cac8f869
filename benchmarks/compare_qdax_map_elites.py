"""MAP-Elites on the arm, qdrl against QDax 0.5.0: speed, compile time and HLO, side by side.

    python benchmarks/compare_qdax_map_elites.py --qdax-python /path/to/qdax-venv/bin/python

For each seed and each container (CVT 1024, grid 32x32, grid 100x100) it runs
qdrl's `time_map_elites` (what `qdrl bench map_elites --config C` runs) and
`qdax_map_elites_arm.py` with the same settings (100-DoF arm, iso-line 0.05 / 0.1,
`--batch` offspring, `--iterations` iterations as one compiled scan), each in a
fresh process with the same environment (so both compile cold, and neither uses
a persistent compilation cache), alternating which side goes first. Then, once
per container, each side profiles the HLO of the program it times
(`qdrl.hlo_profile.hlo_summary`, per step): the module XLA:CPU compiled, and the
un-optimised modules lowered for the CPU and for CUDA (a GPU program before
XLA:GPU's fusion; lowering needs no GPU). It writes JSON with every run, the means
per side, the ratios qdrl / QDax and both sides' op counts.

`--side qdrl` is the qdrl half of one run (it prints one JSON record).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
CONTAINERS = {"cvt1024": ["--container", "cvt", "--num-centroids", "1024"],
              "grid32": ["--container", "grid", "--grid-shape", "32", "32"],
              "grid100": ["--container", "grid", "--grid-shape", "100", "100"]}
# The counts that tell GPU kernels apart (see qdrl.hlo_profile.hlo_profile).
OPS = ("scatter", "gather", "sort", "while", "while_iterations", "conditional", "reduce",
       "reduce-window", "dot", "dynamic-update-slice", "custom-call", "copy")


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


def _run(cmd: list[str], env: dict[str, str]) -> dict[str, Any]:
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{out.stderr[-3000:]}")
    return _json_from(out.stdout)


def run_qdrl(container: str, seed: int, batch: int, iterations: int, env: dict[str, str],
             hlo: bool = False) -> dict[str, Any]:
    cmd = [sys.executable, __file__, "--side", "qdrl", "--containers", container, "--seed", str(seed),
           "--batch", str(batch), "--iterations", str(iterations)] + (["--hlo"] if hlo else [])
    return _run(cmd, env)


def run_qdax(python: str, container: str, seed: int, batch: int, iterations: int,
             env: dict[str, str], hlo: bool = False) -> dict[str, Any]:
    cmd = [python, str(HERE / "qdax_map_elites_arm.py"), *CONTAINERS[container], "--seed", str(seed),
           "--batch", str(batch), "--iterations", str(iterations)]
    if not hlo:
        return _run(cmd, env)
    from qdrl.hlo_profile import hlo_summary

    with tempfile.TemporaryDirectory() as tmp:
        record = _run([*cmd, "--hlo-dir", tmp], env)
        texts = {p.stem: p.read_text() for p in Path(tmp).glob("*.txt")}
    record["hlo"] = hlo_summary(texts, iterations)
    return record


def _side_qdrl(args: argparse.Namespace) -> None:
    from qdrl.bench import time_map_elites

    (container,) = args.containers
    record = time_map_elites(container, seed=args.seed, batch_size=args.batch,
                             iterations=args.iterations, hlo=args.hlo)
    print(json.dumps(record))


def _hlo_table(qdrl: dict[str, Any], qdax: dict[str, Any]) -> dict[str, Any]:
    """Per module both sides have: instructions, kernels, bytes and the OPS counts, per step."""
    table: dict[str, Any] = {}
    for module in sorted(set(qdrl["hlo"]) & set(qdax["hlo"])):
        rows: dict[str, Any] = {}
        for side, rec in (("qdrl", qdrl), ("qdax", qdax)):
            prof = rec["hlo"][module]
            rows[side] = {"instructions": prof["instructions"], "kernels": prof["kernels"],
                          "bytes": prof["bytes"],
                          **{op: prof["ops"].get(op, 0) for op in OPS}}
        table[module] = rows
    return table


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--qdax-python", help="python of a venv with qdax==0.5.0")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--seed", type=int, default=0, help="(--side qdrl) the run's seed")
    p.add_argument("--containers", nargs="+", default=list(CONTAINERS), choices=list(CONTAINERS))
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--iterations", type=int, default=200)
    p.add_argument("--platform", choices=["cpu", "cuda"], default="cpu",
                   help="JAX_PLATFORMS of every run (cuda: an NVIDIA GPU)")
    p.add_argument("--hlo-containers", nargs="*", default=None,
                   help="containers whose HLO both sides profile (default: all of --containers)")
    p.add_argument("--side", choices=["qdrl"], default=None, help="run one qdrl run and print it")
    p.add_argument("--hlo", action="store_true", help="(--side qdrl) profile the program's HLO")
    p.add_argument("--out", default=str(HERE / "results" / "map_elites_arm_vs_qdax.json"))
    args = p.parse_args()
    if args.side == "qdrl":
        _side_qdrl(args)
        return
    if args.qdax_python is None:
        p.error("--qdax-python is required")
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = args.platform
    hlo_containers = args.containers if args.hlo_containers is None else args.hlo_containers
    b, n = args.batch, args.iterations
    runs: list[dict[str, Any]] = []
    for seed in range(args.seeds):
        for container in args.containers:
            order = ["qdrl", "qdax"] if seed % 2 == 0 else ["qdax", "qdrl"]
            for side in order:
                if side == "qdrl":
                    rec = run_qdrl(container, seed, b, n, env)
                else:
                    rec = run_qdax(args.qdax_python, container, seed, b, n, env)
                rec.pop("hlo", None)
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
        if container in hlo_containers:
            row["hlo_per_step"] = _hlo_table(run_qdrl(container, 0, b, n, env, hlo=True),
                                             run_qdax(args.qdax_python, container, 0, b, n, env, hlo=True))
        summary[container] = row
        print(json.dumps({container: row}, indent=1), file=sys.stderr)
    from qdrl.bench import machine

    record = {"machine": machine(), "seeds": args.seeds, "batch": b, "iterations": n,
              "summary": summary, "runs": runs}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
