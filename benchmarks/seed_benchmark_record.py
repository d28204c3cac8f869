"""Records a run of the skill-discovery benchmark's suite: every run's final figures as one JSON.

    qdrl suite run benchmarks/suites/seed_benchmark_slice.toml --out runs/seed_benchmark_slice
    python benchmarks/seed_benchmark_record.py runs/seed_benchmark_slice \\
        --out benchmarks/results/seed_benchmark_slice_cpu.json

Per run (task, algorithm, seed): environment steps, wall and run time, log points, the passive
archive's (or repertoire's) QD score, range QD score, coverage and max fitness, and, where
`qdrl adapt` ran, the best return at every perturbation value; plus the machine. `plot`
draws records' final figures side by side (docs/seed_benchmark_cpu.png).
`--merge` keeps the runs already in `--out` that the folder does not hold (a suite recorded over
several sessions or machines): a run in both is taken from the folder.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
from pathlib import Path
from typing import Any

KEYS = ("env_steps", "wall_s", "run_s", "compile_s", "log_points", "num_log_points", "stopped_by",
        "qd_score", "range_qd_score", "coverage", "max_fitness", "evaluations")


def record(folder: Path) -> dict[str, Any]:
    runs = []
    for summary_path in sorted(folder.glob("*/*/seed_*/summary.json")):
        run = summary_path.parent
        summary = json.loads(summary_path.read_text())
        entry: dict[str, Any] = {"task": run.parent.parent.name, "algorithm": run.parent.name, "seed": int(run.name[5:])}
        entry.update({k: summary[k] for k in KEYS if k in summary})
        adaptation = run / "adaptation" / "adaptation.csv"
        if adaptation.is_file():
            with adaptation.open(newline="") as f:
                rows = list(csv.DictReader(f))
            entry["adaptation"] = {
                name: {row["value"]: float(row["best_return"]) for row in rows if row["perturbation"] == name}
                for name in dict.fromkeys(r["perturbation"] for r in rows)
            }
        runs.append(entry)
    return {
        "suite": str(folder), "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                                          "python": platform.python_version()},
        "runs": runs,
    }


def merge(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """`new`'s runs with those of `old` that it lacks, sorted by task, algorithm and seed, under
    `old`'s description (suite, machine)."""
    def key(run: dict[str, Any]) -> tuple[str, str, int]:
        return run["task"], run["algorithm"], run["seed"]

    have = {key(r) for r in new["runs"]}
    runs = sorted(new["runs"] + [r for r in old["runs"] if key(r) not in have], key=key)
    return {**new, **{k: v for k, v in old.items() if k != "runs"}, "runs": runs}


PLOT_METRICS = (("coverage", "coverage of the 1,024 cells"), ("range_qd_score", "QD score / (cells x fitness range)"),
                ("max_fitness", "max fitness, 0-1: the task's fitness range"))


def _fitness_range(task: str) -> tuple[float, float]:
    """The study's fitness range of `task` (its QD score's normalisation), from the packaged spec."""
    import tomllib

    spec = Path(__file__).resolve().parents[1] / "agents" / "seed_benchmark" / f"map_elites_{task}_cpu.toml"
    low, high = tomllib.loads(spec.read_text())["repertoire"]["fitness_range"]
    return float(low), float(high)


def plot(*records: dict[str, Any], path: str | Path) -> Path:
    """One panel per metric (coverage and range QD score on a log scale, max fitness on the study's
    0-1 scale of each task's fitness range), tasks along x, one marker per run and a bar at the
    mean over its seeds per algorithm: the records' final figures side by side (several records,
    for example one per seed, are pooled)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    runs = [r for record in records for r in record["runs"]]

    def order(names: set[str], first: tuple[str, ...]) -> list[str]:
        return [n for n in first if n in names] + sorted(names - set(first))

    tasks = order({r["task"] for r in runs}, ("ant_omni", "ant_trap", "ant_maze", "point_maze", "halfcheetah_uni",
                                              "walker2d_uni", "ant_uni"))
    algorithms = order({r["algorithm"] for r in runs}, ("map_elites", "pga_me", "smerl_diayn", "diayn", "dads",
                                                        "smerl_dads"))
    width = 0.8 / len(algorithms)
    fig = Figure(figsize=(max(8.0, 1.6 * len(tasks)), 3.2 * len(PLOT_METRICS)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(PLOT_METRICS), 1)
    for ax, (key, label) in zip(axes, PLOT_METRICS, strict=True):
        for a, algorithm in enumerate(algorithms):
            colour = f"C{a}"
            for t, task in enumerate(tasks):
                values = [r[key] for r in runs if r["task"] == task and r["algorithm"] == algorithm and key in r]
                if not values:
                    continue
                x = t - 0.4 + width * (a + 0.5)
                if key == "max_fitness":  # on the study's scale: 0 and 1 are its task's fitness range
                    low, high = _fitness_range(task)
                    values = [(v - low) / (high - low) for v in values]
                ax.bar(x, sum(values) / len(values), width, color=colour, alpha=0.35, label=algorithm)
                ax.plot([x] * len(values), values, "o", color=colour, markersize=3)
        if key != "max_fitness":
            ax.set_yscale("log")
        ax.set_ylabel(label, fontsize=8)
        ax.set_xticks(range(len(tasks)), tasks, fontsize=8)
    handles, labels = axes[0].get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))  # one entry per algorithm, not per bar
    axes[0].legend(unique.values(), unique.keys(), fontsize=7, ncols=len(unique), loc="lower center",
                   bbox_to_anchor=(0.5, 1.0))
    seeds = sorted({r["seed"] for r in runs})
    fig.suptitle(f"seed_benchmark_cpu, 600 s a run: final figures (seed{'s' * (len(seeds) > 1)} "
                 f"{', '.join(map(str, seeds))}; markers: runs, bars: their mean)")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--merge", action="store_true", help="keep the runs of --out that the folder does not hold")
    args = parser.parse_args(argv)
    result = record(args.folder)
    if not result["runs"]:
        print(f"{args.folder}: no finished run of a suite", file=sys.stderr)
        return 1
    if args.merge and args.out.is_file():
        result = merge(json.loads(args.out.read_text()), result)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{len(result['runs'])} runs into {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
