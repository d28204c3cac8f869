"""Startup time of `qdrl run` with an empty and with a warm persistent compilation cache.

For each spec, alternately: empty qdrl's cache directory, run the spec (cold),
run it again (warm). Startup is what the run records in compile_times.json:
the initial state plus the ahead-of-time compilation, the wait before the first
chunk. Each run is one log point long (`--set` below). Prints JSON lines.

    python benchmarks/compile_cache_startup.py [--reps 2] [--specs map_elites_arm sac_halfcheetah]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ONE_LOG_POINT = {
    "map_elites_arm": ["qd.num_iterations=50"],
    "map_elites_halfcheetah_uni_cpu": ["qd.num_iterations=10"],
    "sac_halfcheetah": ["train.total_env_steps=20000", "train.learning_starts=0"],
}


def run_once(spec: str, cache: Path, out: Path) -> dict[str, float]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env.update(QDRL_CACHE_DIR=str(cache), JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    sets = [a for s in [*ONE_LOG_POINT[spec], "log.plots=false", "log.progress=false"] for a in ("--set", s)]
    cmd = [sys.executable, "-m", "qdrl.cli", "run", str(ROOT / "agents" / f"{spec}.toml"), *sets,
           "--out", str(out), "--overwrite"]
    summary = json.loads(subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout)
    times = json.loads((cache / "compile_times.json").read_text())
    record = max((r for machine in times.values() for r in machine.values()), key=lambda r: r["when"])
    return {"startup_s": record["seconds"], "cold": record["cold"], "chunk_compile_s": summary["compile_s"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--specs", nargs="+", default=["map_elites_arm", "map_elites_halfcheetah_uni_cpu"])
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="compile-cache-bench-"))
    try:
        for rep in range(args.reps):
            for spec in args.specs:
                cache = root / "cache"
                shutil.rmtree(cache, ignore_errors=True)
                for phase in ("cold", "warm"):
                    result = run_once(spec, cache, root / "out")
                    print(json.dumps({"spec": spec, "rep": rep, "phase": phase, **result}), flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
