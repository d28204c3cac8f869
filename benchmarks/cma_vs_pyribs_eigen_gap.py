"""qdrl's CMA-MAE with `emitter.eigen_gap = 106` against pyribs 0.12 on the LP sphere 100-D, alternating.

As `benchmarks/cma_vs_pyribs.py` (whose `run_pyribs` it reuses: same settings, 10,000
iterations, fresh processes, the order flipping each seed), with qdrl decomposing
each covariance every 106 generations (QDax's gap) instead of pyribs' (every 3):

    python benchmarks/cma_vs_pyribs_eigen_gap.py --seeds 3 \
        --out benchmarks/results/cma_vs_pyribs_eigen_gap.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cma_vs_pyribs import run_pyribs

ROOT = Path(__file__).resolve().parents[1]
SETS = ("emitter.eigen_gap=106",)


def run_qdrl(seed: int) -> dict[str, Any]:
    """One `qdrl run agents/cma_mae_lp_sphere.toml` with `SETS`, in a fresh process."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "qdrl.cli", "run", str(ROOT / "agents" / "cma_mae_lp_sphere.toml"),
               "--set", f"experiment.seed={seed}", *(a for s in SETS for a in ("--set", s)),
               "--set", "log.progress=false", "--set", "log.plots=false", "--out", str(Path(tmp) / "run")]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        process_s = time.perf_counter() - t0
        summary = json.loads((Path(tmp) / "run" / "summary.json").read_text())
    return {"normalised_qd_score": summary["normalised_qd_score"], "iterations": summary["iteration"],
            "loop_s": summary["run_s"], "compile_s": summary["compile_s"], "process_s": process_s,
            "set": list(SETS)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ribs-python", required=True, help="python of a virtual environment with ribs 0.12")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "cma_vs_pyribs_eigen_gap.jsonl")
    args = p.parse_args()
    for seed in range(args.seeds):
        for side in (("qdrl", "pyribs") if seed % 2 == 0 else ("pyribs", "qdrl")):
            load = os.getloadavg()[0]
            rec = run_qdrl(seed) if side == "qdrl" else run_pyribs(args.ribs_python, "cma_mae", seed)
            rec.update(algo="cma_mae", seed=seed, side=side, load_before=load, load_after=os.getloadavg()[0])
            with args.out.open("a") as f:
                f.write(json.dumps(rec) + "\n")
            print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
