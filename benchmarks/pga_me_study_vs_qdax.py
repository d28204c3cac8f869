"""PGA-ME against MAP-Elites at the skill-discovery study's settings, in qdrl and in QDax 0.5.0,
at equal evaluations: does PGA-ME lead, and by how much, in each library?

    python benchmarks/pga_me_study_vs_qdax.py --qdax-python /path/to/qdax-venv/bin/python \
        --tasks halfcheetah_uni walker2d_uni --seeds 3 --evaluations 5000
    python benchmarks/pga_me_study_vs_qdax.py --summarise      # only the summary and plots of --out

The settings are the study's (Chalumeau, Boige et al. 2023), `agents/seed_benchmark/
{map_elites,pga_me}_<task>.toml`: spring backend, episodes of 250 steps, policies 256x256 (relu,
tanh output), iso-line 0.005 / 0.05, 1024 CVT cells from 50,000 samples; MAP-Elites batches of
1000; PGA-ME batches of 100 (half GA, half PG), 300 critic and 100 policy-gradient steps per
iteration, TD3 batches of 256, a buffer of 1e6. QDax runs the same settings through
`benchmarks/qdax_pga_me.py` in its own virtual environment (old pins; see that script).

Both algorithms spend `--evaluations` episodes (a multiple of 1000): the initial batch, then
MAP-Elites `E/1000 - 1` iterations and PGA-ME `E/100 - 1`, logged every iteration and recorded
every 1000 episodes. Every run
is its own process (both libraries compile cold, no persistent compilation cache), the order of
the libraries and of the algorithms alternates with the seed, and every finished run is written to
`--out` at once: a killed invocation keeps its runs, and the next one runs only what is missing
(runs are keyed by library, algorithm, task, seed and evaluations).

The summary gives, per task and library, each algorithm's mean QD score, coverage and max fitness
at `--evaluations` with their standard errors over seeds, PGA-ME's QD score over MAP-Elites',
and per algorithm qdrl's QD score and environment steps per second over QDax's (QDax counts
batch x 250 steps per iteration; qdrl counts the steps played, the same on halfcheetah_uni,
fewer on walker2d_uni when a walker falls). Plots: `docs/<out stem>_<task>.png` (QD score
against evaluations, mean and band over seeds, four lines).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from compare_qdax_map_elites import _json_from
from table2_vs_qdax import BATCH, qdax_study_command

HERE = Path(__file__).resolve().parent
TASKS = ("halfcheetah_uni", "walker2d_uni")
ALGORITHMS = ("map_elites", "pga_me")
LIBRARIES = ("qdrl", "qdax")
NAMES = {"map_elites": "MAP-Elites", "pga_me": "PGA-ME", "qdrl": "qdrl", "qdax": "QDax 0.5.0"}
FIGURES = ("qd_score", "coverage", "max_fitness")
LOG_EVALUATIONS = 1000


def iterations(algorithm: str, evaluations: int) -> int:
    """The iterations after the initial batch that make `evaluations` episodes."""
    return evaluations // BATCH[algorithm] - 1


def _process(cmd: list[str], env: dict[str, str]) -> tuple[subprocess.CompletedProcess[str], float]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    return proc, wall


def qdrl_run(algorithm: str, task: str, seed: int, evaluations: int, env: dict[str, str]) -> dict[str, Any]:
    """`qdrl run seed_benchmark/<algorithm>_<task>` for `evaluations` episodes, in its own process."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        sets = [f"experiment.seed={seed}", f"qd.num_iterations={iterations(algorithm, evaluations)}",
                "qd.log_every=1", "log.checkpoint_every=100000",
                "log.plots=false", "log.progress=false"]
        cmd = [sys.executable, "-m", "qdrl.cli", "run", f"seed_benchmark/{algorithm}_{task}", "--out", str(out)]
        for s in sets:
            cmd += ["--set", s]
        _, wall = _process(cmd, env)
        with (out / "metrics.csv").open(newline="") as f:
            rows = [{k: float(r[k]) for k in ("evaluations", "env_steps", "wall_s", *FIGURES)} for r in csv.DictReader(f)
                    if int(float(r["evaluations"])) % LOG_EVALUATIONS == 0]
        summary = json.loads((out / "summary.json").read_text())
    return {
        "library": "qdrl", "algorithm": algorithm, "task": task, "seed": seed, "evaluations": evaluations,
        **{k: float(rows[-1][k]) for k in FIGURES},
        "env_steps": rows[-1]["env_steps"],
        "env_steps_per_s": round(float(summary["env_steps_per_s"]), 1),
        "compile_s": round(float(summary["compile_s"]), 2), "run_s": round(float(summary["run_s"]), 2),
        "process_s": round(wall, 1), "rows": rows,
    }


def qdax_run(python: str, algorithm: str, task: str, seed: int, evaluations: int,
             env: dict[str, str]) -> dict[str, Any]:
    """QDax 0.5.0's run of the same settings (`benchmarks/qdax_pga_me.py`), in its own process."""
    cmd = [*qdax_study_command(python, algorithm, task, seed, iterations(algorithm, evaluations)), "--log-every", "1"]
    proc, wall = _process(cmd, env)
    rec = _json_from(proc.stdout)
    if rec["evaluations"] != evaluations:
        raise RuntimeError(f"QDax's {algorithm} ran {rec['evaluations']} evaluations, expected {evaluations}")
    rec["rows"] = [r for r in rec["rows"] if r["evaluations"] % LOG_EVALUATIONS == 0]
    keep = ("evaluations", *FIGURES, "env_steps_per_s", "compile_s", "init_s", "run_s", "rows")
    return {"library": "qdax", "algorithm": algorithm, "task": task, "seed": seed,
            **{k: rec[k] for k in keep}, "process_s": round(wall, 1)}


def _mean_se(values: list[float]) -> dict[str, float | None]:
    """The mean and its standard error (None for one seed: the JSON stays strict)."""
    se = round(statistics.stdev(values) / math.sqrt(len(values)), 3) if len(values) > 1 else None
    return {"mean": round(statistics.mean(values), 3), "se": se}


def summarise(runs: list[dict[str, Any]], evaluations: int) -> dict[str, Any]:
    """Per task and library: each algorithm's figures at `evaluations` (mean and standard error over
    seeds), PGA-ME over MAP-Elites; per task and algorithm, qdrl over QDax."""
    summary: dict[str, Any] = {"evaluations": evaluations}
    for task in sorted({r["task"] for r in runs}):
        per_task: dict[str, Any] = {}
        for library in LIBRARIES:
            per_library: dict[str, Any] = {}
            for algorithm in ALGORITHMS:
                rs = [r for r in runs if (r["task"], r["library"], r["algorithm"], r["evaluations"])
                      == (task, library, algorithm, evaluations)]
                if rs:
                    per_library[algorithm] = {k: _mean_se([r[k] for r in rs]) for k in FIGURES} | {
                        "env_steps_per_s": round(statistics.mean(r["env_steps_per_s"] for r in rs), 1),
                        "seeds": sorted(r["seed"] for r in rs),
                    }
            if len(per_library) == len(ALGORITHMS):
                per_library["pga_me_over_map_elites_qd_score"] = round(
                    per_library["pga_me"]["qd_score"]["mean"] / per_library["map_elites"]["qd_score"]["mean"], 3)
            if per_library:
                per_task[library] = per_library
        for algorithm in ALGORITHMS:
            sides = [per_task.get(library, {}).get(algorithm) for library in LIBRARIES]
            if all(sides):
                qdrl, qdax = sides
                per_task[f"{algorithm}_qdrl_over_qdax"] = {
                    "qd_score": round(qdrl["qd_score"]["mean"] / qdax["qd_score"]["mean"], 3),
                    "env_steps_per_s": round(qdrl["env_steps_per_s"] / qdax["env_steps_per_s"], 3),
                }
        summary[task] = per_task
    return summary


def plot(runs: list[dict[str, Any]], task: str, evaluations: int, path: Path) -> Path:
    """QD score against evaluations, one line (mean and band over seeds) per library and algorithm."""
    from qdrl import plotting

    curves = {}
    for library in LIBRARIES:
        for algorithm in ALGORITHMS:
            rows = [r["rows"] for r in runs if (r["task"], r["library"], r["algorithm"], r["evaluations"])
                    == (task, library, algorithm, evaluations)]
            if rows:
                curves[f"{NAMES[library]} {NAMES[algorithm]}"] = rows
    return plotting.plot_comparison(
        curves, "qd_score", "evaluations", path,
        title=f"PGA-ME and MAP-Elites at the study's settings\n({task}, mean and band over seeds)",
    )


def plot_record(record: dict[str, Any], task: str, path: Path) -> Path:
    """`plot` of a recorded `--out` file at its summary's evaluations (`benchmarks/figures.py`)."""
    return plot(record["runs"], task, int(record["summary"]["evaluations"]), path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--qdax-python", default=None, help="python of the venv with qdax==0.5.0 and its old pins "
                                                       "(without it, only qdrl's runs are made)")
    p.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    p.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS), choices=ALGORITHMS)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--evaluations", type=int, default=5000,
                   help="episodes each run spends: a multiple of 1000, at least 2000")
    p.add_argument("--summarise", action="store_true", help="only recompute the summary and plots of --out")
    p.add_argument("--out", default=str(HERE / "results" / "pga_me_study_vs_qdax.json"))
    p.add_argument("--plots", default=str(HERE.parent / "docs"))
    args = p.parse_args(argv)
    if args.evaluations < 2000 or args.evaluations % LOG_EVALUATIONS:
        p.error(f"--evaluations: expected a multiple of 1000 of at least 2000, got {args.evaluations}")
    if args.seeds < 1 or args.first_seed < 0:
        p.error(f"expected --seeds >= 1 and --first-seed >= 0, got {args.seeds} and {args.first_seed}")
    if args.qdax_python is not None and not Path(args.qdax_python).is_file():
        p.error(f"--qdax-python: expected the python of QDax's virtual environment, got {args.qdax_python!r}")

    from qdrl.bench import machine

    out = Path(args.out)
    runs: list[dict[str, Any]] = json.loads(out.read_text())["runs"] if out.exists() else []
    libraries = LIBRARIES if args.qdax_python else ("qdrl",)
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = os.environ.get("JAX_PLATFORMS", "cpu")  # the CPU unless told (gpu_seed_benchmark.sh)

    def write() -> dict[str, Any]:
        summary = summarise(runs, args.evaluations)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"machine": machine(), "settings": "agents/seed_benchmark/<algorithm>_<task>.toml",
                                   "summary": summary, "runs": runs}, indent=2) + "\n")
        return summary

    if not args.summarise:
        for task in args.tasks:
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                # alternate the order, so that drifts of the machine's load hit both sides alike
                for library in libraries if seed % 2 == 0 else libraries[::-1]:
                    for algorithm in args.algorithms if seed % 2 == 0 else args.algorithms[::-1]:
                        key = (library, algorithm, task, seed, args.evaluations)
                        if any((r["library"], r["algorithm"], r["task"], r["seed"], r["evaluations"]) == key
                               for r in runs):
                            continue
                        if library == "qdrl":
                            rec = qdrl_run(algorithm, task, seed, args.evaluations, env)
                        else:
                            rec = qdax_run(args.qdax_python, algorithm, task, seed, args.evaluations, env)
                        runs.append(rec)
                        write()
                        print(json.dumps({k: v for k, v in rec.items() if k != "rows"}), file=sys.stderr)
    summary = write()
    for task in sorted({r["task"] for r in runs if r["evaluations"] == args.evaluations}):
        plot(runs, task, args.evaluations, Path(args.plots) / f"{out.stem}_{task}.png")
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
