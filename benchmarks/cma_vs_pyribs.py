"""qdrl against pyribs 0.12, side by side on the LP sphere: CMA-MAE (100-D), CMA-MEGA (1000-D), and the
novelty, density and discount-model family (100-D: ns_cma, nslc, nslc_cma_imp, dds, dms, dns).

Alternating runs on one machine (the order flips each seed), each in a fresh process,
one at a time; each finished run is one JSON line of `--out` and runs already there
are skipped (the script resumes where it stopped):

    python benchmarks/cma_vs_pyribs.py --ribs-python /path/to/ribs-venv/bin/python --seeds 3 \
        --out benchmarks/results/cma_vs_pyribs.jsonl
    python benchmarks/cma_vs_pyribs.py --table --out benchmarks/results/cma_vs_pyribs.jsonl
    python benchmarks/cma_vs_pyribs.py --sides qdrl --seeds 5 --algos ns_cma nslc nslc_cma_imp dds dms dns \
        --out benchmarks/results/novelty_lp_sphere.jsonl

qdrl runs `qdrl run agents/cma_mae_lp_sphere.toml` (or cma_mega_lp_sphere.toml)
with the seed; pyribs runs `benchmarks/pyribs_lp_sphere.py` with the same settings
(10,000 iterations). Recorded: the final normalised QD score, the seconds spent in
iterations (qdrl: `run_s`, compilation excluded; pyribs: ask/evaluate/tell, its
numba compilation included in the first iterations), the whole process's wall
time, and the machine's load average before and after (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
CASES = {
    "cma_mae": "cma_mae_lp_sphere", "cma_mega": "cma_mega_lp_sphere",
    # the novelty, density and discount-model family (pyribs' examples/sphere.py settings)
    "ns_cma": "ns_cma_lp_sphere", "nslc": "nslc_lp_sphere", "nslc_cma_imp": "nslc_cma_imp_lp_sphere",
    "dds": "dds_lp_sphere", "dms": "dms_lp_sphere", "dns": "dns_lp_sphere",
}


def _last_json(text: str) -> dict[str, Any]:
    for line in reversed(text.splitlines()):
        if line.startswith("{"):
            return dict(json.loads(line))
    raise ValueError(f"no JSON line in {text[-300:]!r}")


def run_qdrl(algo: str, seed: int, sets: tuple[str, ...] = (), iterations: int | None = None) -> dict[str, Any]:
    if iterations is not None:
        sets = (*sets, f"qd.num_iterations={iterations}", f"qd.log_every={min(iterations, 500)}")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "qdrl.cli", "run", str(ROOT / "agents" / f"{CASES[algo]}.toml"),
               "--set", f"experiment.seed={seed}", *(a for x in sets for a in ("--set", x)),
               "--set", "log.progress=false", "--set", "log.plots=false", "--out", str(Path(tmp) / "run")]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        process_s = time.perf_counter() - t0
        summary = json.loads((Path(tmp) / "run" / "summary.json").read_text())
    return {"normalised_qd_score": summary["normalised_qd_score"], "iterations": summary["iteration"],
            "coverage": summary["coverage"], "loop_s": summary["run_s"], "compile_s": summary["compile_s"],
            "process_s": process_s, **{k: summary[k] for k in ("cqd_score", "search_size") if k in summary},
            **({"set": list(sets)} if sets else {})}


def run_pyribs(python: str, algo: str, seed: int, iterations: int | None = None) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "r.jsonl"
        cmd = [python, str(ROOT / "benchmarks" / "pyribs_lp_sphere.py"), "--algo", algo, "--seed", str(seed),
               "--budget", "1e9", "--out", str(out)]
        if iterations is not None:
            cmd += ["--max-iterations", str(iterations), "--log-every", str(min(iterations, 250))]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        process_s = time.perf_counter() - t0
        result = _last_json(out.read_text())
    final = result["final"]
    return {"normalised_qd_score": final["normalised_qd_score"], "iterations": result["iterations"],
            "loop_s": result["s_per_iteration"] * result["iterations"], "process_s": process_s,
            **{k: final[k] for k in ("coverage", "search_size") if k in final}}


def table(records: list[dict[str, Any]]) -> str:
    lines = ["| run | library | normalised QD score | coverage | loop time (s) | process time (s) | speed-up (loop / process) |",
             "|---|---|---|---|---|---|---|"]
    for algo in CASES:
        means = {}
        for side in ("qdrl", "pyribs"):
            rs = [r for r in records if r["algo"] == algo and r["side"] == side]
            if not rs:
                continue
            q = [r["normalised_qd_score"] for r in rs]
            means[side] = {k: statistics.mean(r[k] for r in rs) for k in ("loop_s", "process_s")}
            sd = statistics.stdev(q) if len(q) > 1 else 0.0
            ratio = ""
            if side == "pyribs" and "qdrl" in means:
                ratio = (f"{means['pyribs']['loop_s'] / means['qdrl']['loop_s']:.1f}x / "
                         f"{means['pyribs']['process_s'] / means['qdrl']['process_s']:.1f}x")
            cov = [r["coverage"] for r in rs if "coverage" in r]
            coverage = f"{100 * statistics.mean(cov):.2f}%" if cov else ""
            lines.append(f"| {algo} | {side} | {statistics.mean(q):.2f} ± {sd:.2f} ({len(q)}) | {coverage} | "
                         f"{means[side]['loop_s']:.1f} | {means[side]['process_s']:.1f} | {ratio} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ribs-python", default=None, help="python of a virtual environment with ribs 0.12")
    p.add_argument("--sides", nargs="+", default=["qdrl", "pyribs"], choices=["qdrl", "pyribs"],
                   help="run only these libraries (e.g. qdrl alone for more seeds)")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--algos", nargs="+", default=list(CASES), choices=list(CASES))
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "cma_vs_pyribs.jsonl")
    p.add_argument("--set", action="append", default=[],
                   help="a --set override for qdrl's runs (e.g. emitter.eigen_gap=evaluations)")
    p.add_argument("--iterations", type=int, default=None, help="both libraries' run length (default: the spec's)")
    p.add_argument("--table", action="store_true")
    args = p.parse_args()
    done = [json.loads(line) for line in args.out.read_text().splitlines()] if args.out.exists() else []
    if args.table:
        print(table(done))
        return
    env_note = {"OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS")}
    for seed in range(args.seeds):
        for algo in args.algos:
            order = ("qdrl", "pyribs") if seed % 2 == 0 else ("pyribs", "qdrl")
            for side in order:
                if side not in args.sides:
                    continue
                if side == "pyribs" and args.ribs_python is None:
                    p.error("--ribs-python is needed to run pyribs")
                if any(r["algo"] == algo and r["seed"] == seed and r["side"] == side for r in done):
                    continue
                load = os.getloadavg()[0]
                rec = (run_qdrl(algo, seed, tuple(args.set), args.iterations) if side == "qdrl"
                       else run_pyribs(args.ribs_python, algo, seed, args.iterations))
                rec.update(algo=algo, seed=seed, side=side, load_before=load, load_after=os.getloadavg()[0],
                           env=env_note)
                done.append(rec)
                with args.out.open("a") as f:
                    f.write(json.dumps(rec) + "\n")
                print(json.dumps(rec), flush=True)
    print(table(done))


if __name__ == "__main__":
    main()
