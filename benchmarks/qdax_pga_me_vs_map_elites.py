"""QDax 0.5.0's own PGA-ME against its own MAP-Elites on halfcheetah_uni, at the CPU budget.

    python benchmarks/qdax_pga_me_vs_map_elites.py --qdax-python /path/to/qdax-venv/bin/python --seeds 3
    python benchmarks/qdax_pga_me_vs_map_elites.py --qdax-python /path/to/qdax-venv/bin/python \
        --first-seed 3 --seeds 2

(the recorded file: seeds 0-2, then seeds 3 and 4 added; `--seeds 0` only re-summarises and re-plots).

The reference check for `benchmarks/pga_me_vs_map_elites.py`: does the reference
implementation's PGA-ME beat MAP-Elites at the budget qdrl's CPU comparison runs at?
Both run `benchmarks/qdax_pga_me.py` (QDax's old-pins venv) with the settings of
`agents/{pga_me,map_elites}_halfcheetah_uni_cpu.toml`: spring, 100-step episodes,
64 offspring per iteration (PGA-ME: 32 iso-line + 31 PG + the greedy actor; MAP-Elites:
64 iso-line), CVT 256, `--iterations` iterations (500: 32,064 evaluations), TD3 of the
light schedule (50 critic steps, 20 PG steps, batches of 64, a buffer of 100k).

Every finished run is written to `--out` at once (`benchmarks/results/
qdax_pga_me_vs_map_elites.json`), so a stopped invocation keeps its runs and a later one
with `--first-seed` adds seeds. The summary compares the algorithms at the evaluations
all runs reached; the plot `docs/qdax_pga_me_vs_map_elites_halfcheetah_uni_evaluations.png`
sets QDax's mean curves beside the mean curves of qdrl's runs of the same specs from `--qdrl-runs`.
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

from compare_qdax_map_elites import _json_from

HERE = Path(__file__).resolve().parent
ALGORITHMS = ("pga_me", "map_elites")


def at_evaluations(run: dict[str, Any], evaluations: int) -> dict[str, Any]:
    """A run's QD figures at its last logged row within `evaluations`."""
    return [r for r in run["rows"] if r["evaluations"] <= evaluations][-1]


def mean_curve(runs_rows: list[list[dict[str, Any]]]) -> list[dict[str, float]]:
    """The mean QD figures over runs at the evaluations every run logged."""
    common = set.intersection(*({r["evaluations"] for r in rows} for rows in runs_rows))
    return [
        {"evaluations": e} | {
            k: statistics.mean(next(r[k] for r in rows if r["evaluations"] == e) for rows in runs_rows)
            for k in ("qd_score", "coverage", "max_fitness")
        }
        for e in sorted(common)
    ]


def mean_curves(library: str, runs: list[dict[str, Any]]) -> dict[str, list[dict[str, float]]]:
    """One mean curve per algorithm that has runs, labelled with the library and the seed count."""
    by_algorithm = {a: [r["rows"] for r in runs if r["algorithm"] == a] for a in ALGORITHMS}
    return {f"{library} {a} ({len(rows)} seeds)": mean_curve(rows) for a, rows in by_algorithm.items() if rows}


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per algorithm, the mean figures at the evaluations all runs reached, and PGA-ME's ratio."""
    budget = min(r["rows"][-1]["evaluations"] for r in runs)
    summary: dict[str, Any] = {"evaluations": budget}
    for algorithm in ALGORITHMS:
        rs = [r for r in runs if r["algorithm"] == algorithm]
        if not rs:
            continue
        rows = [at_evaluations(r, budget) for r in rs]
        summary[algorithm] = {
            k: round(statistics.mean(row[k] for row in rows), 3) for k in ("qd_score", "coverage", "max_fitness")
        } | {
            "env_steps_per_s": round(statistics.mean(r["env_steps_per_s"] for r in rs), 1),
            "seeds": sorted(r["seed"] for r in rs),
        }
    if all(a in summary for a in ALGORITHMS):
        summary["qd_score_ratio"] = round(summary["pga_me"]["qd_score"] / summary["map_elites"]["qd_score"], 3)
    return summary


def plot(results: dict[str, Any], qdrl_results: dict[str, Any] | None, path: str | Path) -> Path:
    """Draws QDax's mean curves (`results`, a results file of this script) beside the mean curves of
    qdrl's halfcheetah_uni runs in `qdrl_results` (a results file of `pga_me_vs_map_elites.py`; None:
    QDax's alone) and writes it to `path`."""
    from qdrl import plotting

    curves = mean_curves("QDax", results["runs"])
    if qdrl_results is not None:
        curves |= mean_curves("qdrl", [r for r in qdrl_results["runs"] if r["task"] == "halfcheetah_uni"])
    return plotting.plot_comparison(
        curves, "qd_score", "evaluations", path,
        title="PGA-ME and MAP-Elites, QDax 0.5.0 and qdrl\n(halfcheetah_uni, CPU specs, means over seeds)",
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--qdax-python", required=True)
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--iterations", type=int, default=500)
    p.add_argument("--log-every", type=int, default=50)
    p.add_argument("--out", default=str(HERE / "results" / "qdax_pga_me_vs_map_elites.json"))
    p.add_argument("--qdrl-runs", default=str(HERE / "results" / "pga_me_vs_map_elites_1000.json"),
                   help="a results file of benchmarks/pga_me_vs_map_elites.py whose halfcheetah_uni runs are plotted beside")
    p.add_argument("--plots", default=str(HERE.parent / "docs"))
    args = p.parse_args()
    if args.seeds < 0 or args.iterations < 1 or args.log_every < 1:
        p.error(f"expected --seeds >= 0, --iterations >= 1, --log-every >= 1; got "
                f"{args.seeds}, {args.iterations}, {args.log_every}")

    from qdrl.bench import machine

    out = Path(args.out)
    previous = json.loads(out.read_text()) if out.exists() else {}
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    runs: list[dict[str, Any]] = [r for r in previous.get("runs", []) if r["seed"] not in seeds]
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"

    def write() -> dict[str, Any]:
        summary = summarise(runs) if runs else {}
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"machine": machine(), "task": "halfcheetah_uni", "summary": summary,
                                   "runs": runs}, indent=2) + "\n")
        return summary

    for seed in seeds:
        for algorithm in ALGORITHMS if seed % 2 == 0 else ALGORITHMS[::-1]:
            cmd = [args.qdax_python, str(HERE / "qdax_pga_me.py"), "--algorithm", algorithm, "--seed", str(seed),
                   "--iterations", str(args.iterations), "--log-every", str(args.log_every)]
            rec = _json_from(subprocess.run(cmd, capture_output=True, text=True, check=True, env=env).stdout)
            runs.append(rec)
            write()
            print(json.dumps({k: v for k, v in rec.items() if k != "rows"}), file=sys.stderr)
    summary = write()
    qdrl_file = Path(args.qdrl_runs)
    qdrl_results = json.loads(qdrl_file.read_text()) if qdrl_file.exists() else None
    plot({"runs": runs}, qdrl_results, Path(args.plots) / f"{out.stem}_halfcheetah_uni_evaluations.png")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
