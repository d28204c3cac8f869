"""The QDax paper's Table 2 (environment steps per hour) for qdrl and QDax 0.5.0, side by side.

    python benchmarks/table2_vs_qdax.py --qdax-python /path/to/qdax-venv/bin/python

MAP-Elites, PGA-ME, DIAYN-SMERL, DADS and DIAYN on ant_omni and halfcheetah_uni, at the
skill-discovery benchmark's settings (agents/seed_benchmark/<algorithm>_<task>.toml: MAP-Elites
batch 1000, PGA-ME env batch 100 with 300 critic / 100 PG steps, the skill methods 200
environments with one gradient step per environment step; policies 256x256, episodes of 250,
1024 CVT cells), each run in a fresh process, alternating which library goes first.

- qdrl: `qdrl run seed_benchmark/<algorithm>_<task>` bounded by `experiment.env_steps_limit`,
  with a log point every iteration (MAP-Elites, PGA-ME) or every `--skill-log-steps` environment
  steps (skill methods), no checkpoint before the end; steps/s is the environment steps between the
  first and the last log point over the wall time between them. It therefore counts what a run
  does between log points besides training: the skill methods' deterministic evaluation of every
  skill (the spec's 200 episodes of 250 steps, which the study plays every 100,000 steps) and its
  insertion into the passive archive, metrics and progress lines.
- qdrl's training scan (skill methods, side `qdrl_scan`): `benchmarks/skill_train_scan.py`, the
  same spec's off-policy loop alone as one scan of the same number of steps, compiled ahead of
  time: measured as QDax's side is (`ratio_scan`).
- QDax: its own training loop (`benchmarks/qdax_pga_me.py` for MAP-Elites and PGA-ME on its brax
  v2 tasks, `benchmarks/qdax_skills.py` for the skill baselines, which run on brax v1 as in the
  study), as ONE `lax.scan` compiled ahead of time, timed without compilation and without
  evaluation.

Writes every run, and per algorithm and task the ratio qdrl / QDax, as JSON (--out).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from compare_qdax_map_elites import _json_from

HERE = Path(__file__).resolve().parent
ALGORITHMS = ("map_elites", "pga_me", "smerl_diayn", "dads", "diayn")
TASKS = ("ant_omni", "halfcheetah_uni")
# iterations timed per side: MAP-Elites (1000 episodes each), PGA-ME (100 episodes each)
QD_ITERATIONS = {"map_elites": 3, "pga_me": 4}


def qdrl_run(algorithm: str, task: str, seed: int, skill_log_steps: int, skill_log_points: int,
             env: dict[str, str]) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        sets = ["log.checkpoint_every=100000", f"experiment.seed={seed}"]
        if algorithm in QD_ITERATIONS:
            batch = 1000 if algorithm == "map_elites" else 100
            steps = batch * 250 * (QD_ITERATIONS[algorithm] + 1)  # the initial batch, then the iterations
            sets += ["qd.log_every=1", f"experiment.env_steps_limit={steps}"]
        else:
            sets += [f"train.eval_every={skill_log_steps}",
                     f"experiment.env_steps_limit={skill_log_steps * skill_log_points}"]
        cmd = [sys.executable, "-m", "qdrl.cli", "run", f"seed_benchmark/{algorithm}_{task}", "--out", str(out)]
        for s in sets:
            cmd += ["--set", s]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
        with (out / "metrics.csv").open(newline="") as f:
            rows = list(csv.DictReader(f))
        summary = json.loads((out / "summary.json").read_text())
    if len(rows) < 2:
        raise RuntimeError(f"{algorithm} on {task}: {len(rows)} log point(s); two are needed for a rate")
    first, last = rows[0], rows[-1]
    steps_done = float(last["env_steps"]) - float(first["env_steps"])
    seconds = float(last["wall_s"]) - float(first["wall_s"])
    return {
        "library": "qdrl", "algorithm": algorithm, "task": task, "seed": seed,
        "log_points": len(rows), "env_steps_timed": steps_done, "run_s": round(seconds, 3),
        "env_steps_per_s": round(steps_done / seconds, 2), "env_steps_per_hour": round(steps_done / seconds * 3600.0, 1),
        "compile_s": round(float(summary.get("compile_s", float("nan"))), 2), "process_s": round(wall, 1),
        "qd_score": float(last["qd_score"]) if "qd_score" in last else None,
        "coverage": float(last["coverage"]) if "coverage" in last else None,
        "max_fitness": float(last["max_fitness"]) if "max_fitness" in last else None,
        "env_steps": float(last["env_steps"]),
    }


def qdax_study_command(python: str, algorithm: str, task: str, seed: int, iterations: int) -> list[str]:
    """`benchmarks/qdax_pga_me.py` at the study's settings: MAP-Elites or PGA-ME on `task`, QDax 0.5.0."""
    return [python, str(HERE / "qdax_pga_me.py"), "--algorithm", algorithm, "--task", task,
            "--seed", str(seed), "--episode-length", "250", "--hidden", "256,256", "--activation", "relu",
            "--batch", str(BATCH[algorithm]), "--iterations", str(iterations), "--cells", "1024",
            "--cvt-samples", "50000", "--critic-steps", "300", "--pg-steps", "100", "--train-batch", "256",
            "--buffer", "1000000"]


def qdax_run(python: str, algorithm: str, task: str, seed: int, skill_iterations: int,
             env: dict[str, str]) -> dict[str, Any]:
    if algorithm in QD_ITERATIONS:
        cmd = qdax_study_command(python, algorithm, task, seed, QD_ITERATIONS[algorithm])
    else:
        cmd = [python, str(HERE / "qdax_skills.py"), "--algorithm", algorithm, "--task", task,
               "--seed", str(seed), "--iterations", str(skill_iterations)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    rec = _json_from(proc.stdout)
    rec["env_steps_per_hour"] = round(float(rec["env_steps_per_s"]) * 3600.0, 1)
    rec["process_s"] = round(wall, 1)
    return rec


BATCH = {"map_elites": 1000, "pga_me": 100}


def nominal_rate(run: dict[str, Any]) -> float:
    """Environment steps per hour counted as QDax counts them: batch x episode length per iteration of
    MAP-Elites and PGA-ME (episodes that end early, as the ant's do when it falls, still count 250);
    the skill methods count every step of the 200 environments on both sides."""
    if run["algorithm"] not in BATCH:
        return float(run["env_steps_per_hour"])
    if run["side"] == "qdax":
        return float(run["env_steps_per_hour"])
    iterations = run["log_points"] - 1  # the log points are one iteration apart
    return BATCH[run["algorithm"]] * 250 * iterations / run["run_s"] * 3600.0


def summarise(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per task and algorithm, the mean steps per hour of each side (qdrl's as it counts them, and as
    QDax counts them) and the ratio qdrl / QDax on QDax's count."""
    table: list[dict[str, Any]] = []
    for task in TASKS:
        for algorithm in ALGORITHMS:
            mine = [r for r in runs if r["side"] == "qdrl" and r["algorithm"] == algorithm and r["task"] == task]
            theirs = [r for r in runs if r["side"] == "qdax" and r["algorithm"] == algorithm and r["task"] == task]
            if mine and theirs:
                q = statistics.mean(nominal_rate(r) for r in mine)
                x = statistics.mean(nominal_rate(r) for r in theirs)
                row = {"task": task, "algorithm": algorithm,
                       "qdrl_env_steps_per_hour": round(statistics.mean(r["env_steps_per_hour"] for r in mine), 1),
                       "qdrl_env_steps_per_hour_qdax_count": round(q, 1),
                       "qdax_env_steps_per_hour": round(x, 1), "ratio": round(q / x, 3)}
                scans = [r for r in runs if r["side"] == "qdrl_scan" and r["algorithm"] == algorithm and r["task"] == task]
                if scans:  # the training scan alone, measured as QDax's side is
                    sq = statistics.mean(float(r["env_steps_per_hour"]) for r in scans)
                    row.update({"qdrl_scan_env_steps_per_hour": round(sq, 1), "ratio_scan": round(sq / x, 3)})
                table.append(row)
    return table


def qdrl_scan(algorithm: str, task: str, seed: int, iterations: int, env: dict[str, str]) -> dict[str, Any]:
    """qdrl's skill training alone (`benchmarks/skill_train_scan.py`): the measure of QDax's side."""
    cmd = [sys.executable, str(HERE / "skill_train_scan.py"), "--algorithm", algorithm, "--task", task,
           "--seed", str(seed), "--iterations", str(iterations)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    rec = _json_from(proc.stdout)
    rec["process_s"] = round(time.perf_counter() - t0, 1)
    return rec


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--qdax-python", required=True, help="python of the venv with qdax==0.5.0 and its old pins")
    p.add_argument("--algorithms", default=",".join(ALGORITHMS))
    p.add_argument("--tasks", default=",".join(TASKS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--skill-log-steps", type=int, default=6000,
                   help="qdrl's skill runs: environment steps between log points (10 steps of the 200 envs each)")
    p.add_argument("--skill-log-points", type=int, default=3)
    p.add_argument("--append", action="store_true", help="keep the runs already in --out")
    p.add_argument("--summarise", action="store_true", help="only recompute the table of the runs in --out")
    p.add_argument("--out", default=str(HERE / "results" / "table2_vs_qdax_cpu.json"))
    args = p.parse_args()
    algorithms = [a for a in args.algorithms.split(",") if a]
    tasks = [t for t in args.tasks.split(",") if t]
    unknown = sorted(set(algorithms) - set(ALGORITHMS)) + sorted(set(tasks) - set(TASKS))
    if unknown:
        p.error(f"unknown {unknown}; expected algorithms among {ALGORITHMS} and tasks among {TASKS}")
    if args.skill_log_steps % 200 or args.skill_log_steps < 200 or args.skill_log_points < 2:
        p.error("expected --skill-log-steps a positive multiple of 200 and --skill-log-points >= 2")
    if args.summarise:
        result = json.loads(Path(args.out).read_text())
        result["table"] = summarise(result["runs"])
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
        for row in result["table"]:
            print(json.dumps(row))
        return
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"
    runs: list[dict[str, Any]] = []
    if args.append and Path(args.out).exists():
        runs = json.loads(Path(args.out).read_text())["runs"]
    # the same environment steps timed on both sides for the skill methods
    skill_iterations = args.skill_log_steps * (args.skill_log_points - 1) // 200
    n = 0
    for task in tasks:
        for algorithm in algorithms:
            sides = ["qdrl", "qdax"] if n % 2 == 0 else ["qdax", "qdrl"]
            n += 1
            if algorithm not in QD_ITERATIONS:  # the skill methods: also qdrl's training scan alone
                sides.insert(sides.index("qdrl"), "qdrl_scan")
            for side in sides:
                if side == "qdrl":
                    rec = qdrl_run(algorithm, task, args.seed, args.skill_log_steps, args.skill_log_points, env)
                elif side == "qdrl_scan":
                    rec = qdrl_scan(algorithm, task, args.seed, skill_iterations, env)
                else:
                    rec = qdax_run(args.qdax_python, algorithm, task, args.seed, skill_iterations, env)
                rec["side"] = side
                runs.append(rec)
                print(json.dumps(rec), file=sys.stderr, flush=True)
                Path(args.out).write_text(json.dumps({"runs": runs}, indent=1) + "\n")
    table = summarise(runs)
    result = {
        "machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]},
        "settings": "agents/seed_benchmark/<algorithm>_<task>.toml (the study's); see this script's docstring",
        "table": table, "runs": runs,
    }
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    for row in table:
        print(json.dumps(row))


if __name__ == "__main__":
    main()
