"""PGA-ME against MAP-Elites at equal evaluations, on halfcheetah_uni and walker2d_uni (CPU budget).

    python benchmarks/pga_me_vs_map_elites.py --tasks halfcheetah_uni walker2d_uni --seeds 1
    python benchmarks/pga_me_vs_map_elites.py --tasks halfcheetah_uni walker2d_uni --first-seed 1

(the second call adds seed 1 to the results of the first).

    python benchmarks/pga_me_vs_map_elites.py --algorithms dcrl_me --tasks halfcheetah_uni \
        --compare-with benchmarks/results/pga_me_vs_map_elites.json \
        --out benchmarks/results/dcrl_me_vs_map_elites.json

runs another algorithm's CPU spec (`agents/<algorithm>_<task>_cpu.toml`, here DCRL-ME,
same sizing) and sets it beside the runs of `--compare-with` (copied, not re-run).

Runs `agents/pga_me_<task>_cpu.toml` and `agents/map_elites_<task>_cpu.toml` through
the experiment driver (`qdrl run`): the same task (spring, 100-step episodes,
policies 64x64 tanh), the same CVT archive (256 cells) and the same number of
offspring per iteration (64) and iterations, so both spend the same evaluations
and environment steps. PGA-ME spends extra compute on TD3 (50 critic steps per
iteration, 20 actor steps per PG offspring, batches of 64): the wall-time curve
shows what that costs. `--iterations` overrides both specs' `qd.num_iterations`.

`--variant pga_me:cpu_paper_td3` runs `agents/pga_me_<task>_cpu_paper_td3.toml`
instead (the same task and archive, the paper's TD3 schedule).
`--full` runs the full-size specs `agents/<algorithm>_<task>.toml` (the papers'
settings: 1000-step episodes, 1024 cells, 4000 iterations of 100; a GPU budget).

Writes `benchmarks/results/pga_me_vs_map_elites.json` (every run's metric rows,
final figures and the per-task means; where a task's runs have different lengths,
the means are taken at the evaluations all of them reached, from the logged rows)
and, per task, `docs/pga_me_vs_map_elites_<task>_{evaluations,wall_time}.png`
(QD score against evaluations and against wall time, one line per run).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ALGORITHMS = ("pga_me", "map_elites")


def run_one(
    algorithm: str, task: str, seed: int, iterations: int | None, log_every: int | None,
    extra: list[str] | None = None, variant: str = "cpu",
) -> dict[str, Any]:
    """One `qdrl run` of `agents/<algorithm>_<task>_<variant>.toml`, or of `agents/<algorithm>_<task>.toml`
    for the empty variant (the full-size spec); the `extra` overrides go last."""
    from qdrl.experiment import run_spec

    spec = ROOT / "agents" / (f"{algorithm}_{task}_{variant}.toml" if variant else f"{algorithm}_{task}.toml")
    if not spec.exists():
        raise SystemExit(f"no spec {spec.relative_to(ROOT)} (algorithm {algorithm!r}, variant {variant!r})")
    overrides = [f"experiment.seed={seed}", "log.progress=false", "log.plots=false"]
    if iterations is not None:
        overrides.append(f"qd.num_iterations={iterations}")
    if log_every is not None:
        overrides.append(f"qd.log_every={log_every}")
    overrides += extra or []
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_spec(spec, overrides, Path(tmp) / "out")
        lines = (Path(tmp) / "out" / "metrics.csv").read_text().splitlines()
    header = lines[0].split(",")
    rows = [dict(zip(header, (float(v) for v in line.split(",")), strict=True)) for line in lines[1:]]
    return {
        "algorithm": algorithm,
        "task": task,
        "seed": seed,
        "spec": str(spec.relative_to(ROOT)),
        "overrides": overrides,
        "summary": {k: summary[k] for k in (
            "evaluations", "env_steps", "qd_score", "coverage", "max_fitness", "compile_s", "run_s",
            "wall_s", "env_steps_per_s",
        )},
        "rows": [{k: r[k] for k in ("evaluations", "env_steps", "wall_s", "qd_score", "coverage", "max_fitness")} for r in rows],
    }


NAMES = {"pga_me": "PGA-ME", "map_elites": "MAP-Elites", "dcrl_me": "DCRL-ME"}


def per_task_names(runs: list[dict[str, Any]], task: str) -> list[str]:
    """Display names of the algorithms run on `task`, in the order they first appear."""
    seen = dict.fromkeys(r["algorithm"] for r in runs if r["task"] == task)
    return [NAMES.get(a, a) for a in seen]


def comparison_title(names: list[str], task: str) -> str:
    """"A vs B on task (CPU specs)"; with more algorithms, on two lines so that it fits the plot."""
    if len(names) <= 2:
        return f"{' vs '.join(names)} on {task} (CPU specs)"
    return f"{', '.join(names)}\non {task} (CPU specs)"


# The x keys of the plots, and the file-name suffix of each: `<results stem>_<task>_<suffix>.png`.
PLOT_X_KEYS = {"evaluations": "evaluations", "wall_s": "wall_time"}


def plot_task(results: dict[str, Any], task: str, x_key: str, path: str | Path) -> Path:
    """Draws the QD score of every run of `task` in `results` (a results file of this script)
    against `x_key` (evaluations or wall_s), one line per run, and writes it to `path`."""
    from qdrl import plotting

    runs = results["runs"]
    curves = {f"{r['algorithm']} seed {r['seed']}": r["rows"] for r in runs if r["task"] == task}
    return plotting.plot_comparison(
        curves, "qd_score", x_key, path, title=comparison_title(per_task_names(runs, task), task),
    )


def at_budget(run: dict[str, Any], evaluations: float) -> dict[str, Any]:
    """A run's figures after `evaluations` (its last logged row within it; its summary if it ended there).

    The rates (env steps/s) and compile time are the whole run's; `run_s` is the time to that row.
    """
    summary = run["summary"]
    if summary["evaluations"] <= evaluations:
        return summary
    row = [r for r in run["rows"] if r["evaluations"] <= evaluations][-1]
    before_loop_s = summary["wall_s"] - summary["run_s"]  # setup and compilation: row wall_s counts them
    figures = ("evaluations", "env_steps", "qd_score", "coverage", "max_fitness")
    return summary | {k: row[k] for k in figures} | {"run_s": row["wall_s"] - before_loop_s}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--tasks", nargs="+", default=["halfcheetah_uni", "walker2d_uni"])
    p.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS),
                   help="algorithms whose agents/<algorithm>_<task>_cpu.toml are run")
    p.add_argument("--compare-with", default=None,
                   help="a results file of this script whose runs of other algorithms are set beside")
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--iterations", type=int, default=None)
    p.add_argument("--log-every", type=int, default=None)
    p.add_argument("--override", nargs="*", default=[], metavar="ALGORITHM:KEY=VALUE",
                   help="a spec override for one algorithm's runs, e.g. map_elites:emitter.batch_size=48")
    p.add_argument("--variant", nargs="*", default=[], metavar="ALGORITHM:NAME",
                   help="run agents/<algorithm>_<task>_<NAME>.toml for that algorithm instead of _cpu, "
                        "e.g. pga_me:cpu_paper_td3")
    p.add_argument("--full", action="store_true",
                   help="run every algorithm's full-size spec agents/<algorithm>_<task>.toml (the papers' "
                        "settings: 1000-step episodes, 1024 cells; a GPU budget) instead of _cpu")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "pga_me_vs_map_elites.json"))
    p.add_argument("--plots", default=str(ROOT / "docs"))
    args = p.parse_args()

    from qdrl.bench import machine

    out = Path(args.out)
    previous = json.loads(out.read_text()) if out.exists() else {}
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    algorithms = tuple(args.algorithms)
    extra: dict[str, list[str]] = {a: [] for a in algorithms}
    for item in args.override:
        name, _, override = item.partition(":")
        if name not in extra or "=" not in override:
            p.error(f"--override: expected ALGORITHM:KEY=VALUE with ALGORITHM in {list(algorithms)}, got {item!r}")
        extra[name].append(override)
    variants: dict[str, str] = dict.fromkeys(algorithms, "" if args.full else "cpu")
    for item in args.variant:
        name, _, variant = item.partition(":")
        if name not in variants or not variant:
            p.error(f"--variant: expected ALGORITHM:NAME with ALGORITHM in {list(algorithms)}, got {item!r}")
        variants[name] = variant
    # runs of other tasks, seeds or algorithms stay, so seeds can be added one invocation at a time
    runs: list[dict[str, Any]] = [
        r for r in previous.get("runs", [])
        if r["task"] not in args.tasks or r["seed"] not in seeds or r["algorithm"] not in algorithms
    ]
    if args.compare_with:
        # runs copied from the reference file (marked "from") for these tasks are replaced by its current ones
        reference = json.loads(Path(args.compare_with).read_text())
        runs = [r for r in runs if "from" not in r or r["task"] not in args.tasks] + [
            r | {"from": args.compare_with} for r in reference.get("runs", [])
            if r["algorithm"] not in algorithms and r["task"] in args.tasks
        ]
    for task in args.tasks:
        for seed in seeds:
            # alternate which algorithm goes first, so machine load drifts hit both alike
            order = algorithms if seed % 2 == 0 else algorithms[::-1]
            for algorithm in order:
                rec = run_one(
                    algorithm, task, seed, args.iterations, args.log_every, extra[algorithm], variants[algorithm]
                )
                runs.append(rec)
                print(json.dumps({"algorithm": algorithm, "task": task, "seed": seed, **rec["summary"]}),
                      file=sys.stderr)
    summary: dict[str, Any] = {}
    for task in sorted({r["task"] for r in runs}):
        per_task: dict[str, Any] = {}
        present = sorted({r["algorithm"] for r in runs if r["task"] == task})
        # runs of different lengths compare at the budget all of them reached
        budget = min(r["summary"]["evaluations"] for r in runs if r["task"] == task)
        for algorithm in [*[a for a in ALGORITHMS if a in present], *[a for a in present if a not in ALGORITHMS]]:
            rs = [at_budget(r, budget) for r in runs if r["task"] == task and r["algorithm"] == algorithm]
            per_task[algorithm] = {
                k: round(statistics.mean(r[k] for r in rs), 3)
                for k in ("evaluations", "qd_score", "coverage", "max_fitness", "run_s", "compile_s",
                          "env_steps_per_s")
            } | {"seeds": len(rs)}
        if "map_elites" in per_task:
            for algorithm in [a for a in per_task if a != "map_elites"]:
                # "qd_score_ratio" is PGA-ME's (the key this file has always had)
                key = "qd_score_ratio" if algorithm == "pga_me" else f"{algorithm}_qd_score_ratio"
                per_task[key] = round(
                    per_task[algorithm]["qd_score"] / per_task["map_elites"]["qd_score"], 3
                )
        summary[task] = per_task
        for x_key, suffix in PLOT_X_KEYS.items():
            plot_task({"runs": runs}, task, x_key, Path(args.plots) / f"{Path(args.out).stem}_{task}_{suffix}.png")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": machine(), "summary": summary, "runs": runs}, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
