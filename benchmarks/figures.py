"""Every figure of the docs, redrawn from the results recorded in `benchmarks/results/`.

    python benchmarks/figures.py                    # redraw every figure where the docs expect it
    python benchmarks/figures.py --only NAME ...    # only these (NAME: the file name without .png)
    python benchmarks/figures.py --out DIR          # write DIR/<file name> instead
    python benchmarks/figures.py --list             # print the table

No benchmark runs: each figure is drawn from the results files its benchmark recorded,
by the plotting function that benchmark's script itself calls after a run (seconds for
all of them). `FIGURES` is the one table of them: the file, the recorded results and
the drawing function. A figure whose results were never recorded in the repository (the
runs' own files were not kept) stays in the table with the reason (`unrecorded`); it is
not redrawn, and `--list` and every redraw say so.
"""

from __future__ import annotations

import argparse
import csv
import importlib
import json
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = "benchmarks/results"


@dataclass(frozen=True)
class Figure:
    """One figure of the docs.

    path: where the docs expect it, relative to the repository.
    draw: "module:function" that draws it; a bare module is a script of `benchmarks/`.
      It is called as `function(*results, **args, path=out)`, each results file loaded
      (`.json`: its object, `.jsonl`: a list of its lines' objects, `.csv`: a list of
      rows of floats).
    results: the recorded results it is drawn from, relative to the repository.
    args: keyword arguments of `draw` besides `path`.
    recorded_by: the command that recorded the results (and first drew the figure).
    unrecorded: why it cannot be redrawn: its results were never recorded (empty when they were).
    """

    path: str
    draw: str
    results: tuple[str, ...] = ()
    args: Mapping[str, Any] = field(default_factory=dict)
    recorded_by: str = ""
    unrecorded: str = ""

    @property
    def name(self) -> str:
        return Path(self.path).stem

    @property
    def redrawable(self) -> bool:
        return not self.unrecorded


def _import(module: str) -> Any:
    """A module by name; a bare name is a script of `benchmarks/` (they import one another by
    their bare names, so `benchmarks/` is on the path while one is imported)."""
    if "." in module or str(HERE) in sys.path:
        return importlib.import_module(module)
    sys.path.insert(0, str(HERE))
    try:
        return importlib.import_module(module)
    finally:
        sys.path.remove(str(HERE))


def run_curve(rows: list[dict[str, float]], metric: str, title: str, path: str | Path) -> Path:
    """One metric of one run, drawn as `qdrl run` draws its `plots/<metric>.png`
    (`qdrl/experiment.py`: `plotting.plot_curves` against the default x keys)."""
    from qdrl import plotting

    with tempfile.TemporaryDirectory() as tmp:
        (drawn,) = plotting.plot_curves(
            rows, tmp, x_keys=plotting.default_x_keys(rows), y_keys=[metric], title=title
        )
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(drawn.read_bytes())
    return out


_PGA = "python benchmarks/pga_me_vs_map_elites.py"
_PAPER_TD3 = "--algorithms pga_me --variant pga_me:cpu_paper_td3"
# The results files of benchmarks/pga_me_vs_map_elites.py and the invocations that recorded them.
_QD_RUNS = {
    "pga_me_vs_map_elites": f"{_PGA} --seeds 1; {_PGA} --first-seed 1",
    "pga_me_vs_map_elites_1000": f"{_PGA} --tasks halfcheetah_uni --iterations 1000 --log-every 50 "
                                 f"(seeds 1, 2: --first-seed 1 --seeds 2 --iterations 500) --out {RESULTS}/pga_me_vs_map_elites_1000.json",
    "pga_me_paper_td3_vs_map_elites": f"{_PGA} --tasks walker2d_uni {_PAPER_TD3} --seeds 2 "
                                      f"--compare-with {RESULTS}/pga_me_vs_map_elites.json --out {RESULTS}/pga_me_paper_td3_vs_map_elites.json",
    "pga_me_paper_td3_vs_map_elites_1000": f"{_PGA} --tasks halfcheetah_uni {_PAPER_TD3} --iterations 1000 --log-every 50 "
                                           f"--compare-with {RESULTS}/pga_me_vs_map_elites_1000.json "
                                           f"--out {RESULTS}/pga_me_paper_td3_vs_map_elites_1000.json (seeds 1, 2: --first-seed)",
    "dcrl_me_vs_map_elites": f"{_PGA} --algorithms dcrl_me --compare-with {RESULTS}/pga_me_vs_map_elites.json "
                             f"--out {RESULTS}/dcrl_me_vs_map_elites.json",
    "qd_rl_vs_map_elites_300": f"{_PGA} --tasks halfcheetah_uni --algorithms pga_me map_elites dcrl_me --seeds 2 "
                               f"--iterations 300 --log-every 20 --out {RESULTS}/qd_rl_vs_map_elites_300.json",
    "qd_rl_point_maze": f"{_PGA} --tasks point_maze --algorithms qdpg me_es map_elites --seeds 2 --iterations 200 "
                        f"--log-every 20 --override ... (the runs' overrides are in the file) --out {RESULTS}/qd_rl_point_maze.json",
}


def _qd_runs(stem: str, task: str, x_key: str) -> Figure:
    """A figure of `benchmarks/pga_me_vs_map_elites.py`: the QD score of every run of `task` in
    `benchmarks/results/<stem>.json` against `x_key`."""
    suffix = _import("pga_me_vs_map_elites").PLOT_X_KEYS[x_key]
    return Figure(
        f"docs/{stem}_{task}_{suffix}.png", "pga_me_vs_map_elites:plot_task",
        (f"{RESULTS}/{stem}.json",), {"task": task, "x_key": x_key}, _QD_RUNS[stem],
    )


def _mome(path: str, seed: int) -> Figure:
    """A figure of `benchmarks/mome_halfcheetah_vs_map_elites.py`: `seed`'s two global fronts."""
    return Figure(
        path, "mome_halfcheetah_vs_map_elites:plot_fronts", (f"{RESULTS}/mome_halfcheetah_vs_map_elites.jsonl",),
        {"seed": seed},
        "python benchmarks/mome_halfcheetah_vs_map_elites.py --seeds 3 "
        f"--out {RESULTS}/mome_halfcheetah_vs_map_elites.jsonl",
    )


_REPORT = (
    "qdrl run map_elites_arm --seeds 0-4; qdrl run cvt_map_elites_arm --seeds 0-4; "
    "qdrl report runs/map_elites_arm runs/cvt_map_elites_arm"
)
_RL = "a 150k-step `qdrl run` of agents/{0}_halfcheetah.toml's agent (its metrics.csv kept as {0}_halfcheetah_150k.csv; the run's plots/eval_return.png)"

FIGURES: tuple[Figure, ...] = (
    # Multi-task MAP-Elites (docs/algorithms/multi-task.md)
    Figure("docs/mt_me_arm.png", "mt_me_arm:plot", (f"{RESULTS}/mt_me_arm.jsonl",),
           recorded_by="python benchmarks/mt_me_arm.py --seeds 3; python benchmarks/mt_me_arm.py "
                       "--methods cma_es_per_task_x10 --seeds 1 --append"),
    # MAP-Elites and CVT-MAP-Elites (docs/algorithms/qd.md, README, index, getting started)
    Figure("docs/report_arm_qd_score.png", "qdrl.plotting:plot_comparison", recorded_by=f"{_REPORT} (arm/qd_score.png)",
           unrecorded="drawn by `qdrl report` from the 10 runs' metrics.csv (runs/, not kept); "
                      "benchmarks/results/report_arm_seeds_final.csv holds only the report's final values"),
    Figure("docs/report_arm_repertoires.png", "qdrl.plotting:plot_repertoires",
           recorded_by=f"{_REPORT} (arm/repertoires.png)",
           unrecorded="drawn by `qdrl report` from the runs' final repertoires (runs/, not kept)"),
    # SAC and TD3 (docs/algorithms/rl.md)
    Figure("docs/sac_halfcheetah_eval_return.png", "figures:run_curve", (f"{RESULTS}/sac_halfcheetah_150k.csv",),
           {"metric": "eval_return", "title": "sac on halfcheetah"}, _RL.format("sac")),
    Figure("docs/td3_halfcheetah_eval_return.png", "figures:run_curve", (f"{RESULTS}/td3_halfcheetah_150k.csv",),
           {"metric": "eval_return", "title": "td3 on halfcheetah"}, _RL.format("td3")),
    # Skill discovery (docs/algorithms/skills.md)
    Figure("docs/skills_point_maze_diayn.png", "qdrl.plotting:plot_skills",
           recorded_by="python benchmarks/skills_point_maze.py --steps 1000000 "
                       "(copies runs/skills_point_maze/diayn/plots/skills.png)",
           unrecorded="the DIAYN run's plots/skills.png, drawn from its evaluation trajectories, "
                      "which skills_point_maze.json does not keep (metric rows and summaries only)"),
    Figure("docs/skills_point_maze_smerl.png", "qdrl.plotting:plot_skills",
           recorded_by="python benchmarks/skills_point_maze.py --steps 1000000 "
                       "(copies runs/skills_point_maze/smerl_diayn/plots/skills.png)",
           unrecorded="the SMERL-DIAYN run's plots/skills.png, drawn from its evaluation trajectories, "
                      "which skills_point_maze.json does not keep (metric rows and summaries only)"),
    # PBT and ME-PBT (docs/algorithms/pbt.md)
    Figure("docs/pbt_vs_fixed_sac_pbt_halfcheetah_cpu.png", "pbt_vs_fixed:plot",
           (f"{RESULTS}/pbt_vs_fixed_sac_pbt_halfcheetah_cpu.json",), recorded_by="python benchmarks/pbt_vs_fixed.py"),
    Figure("docs/me_pbt_vs_map_elites_halfcheetah_uni.png", "me_pbt_vs_map_elites:plot",
           recorded_by="python benchmarks/me_pbt_vs_map_elites.py",
           unrecorded="drawn from both runs' metrics.csv (runs/me_pbt_evidence/, not kept); "
                      "me_pbt_vs_map_elites_halfcheetah_uni.json holds only final values"),
    # Multi-objective (docs/algorithms/mo.md: seed 0), and the script's own plot of each seed
    _mome("docs/mome_halfcheetah_vs_map_elites.png", 0),
    *(_mome(f"{RESULTS}/mome_halfcheetah_vs_map_elites_seed{seed}.png", seed) for seed in range(3)),
    # QD-RL (docs/algorithms/qd-rl.md)
    *(_qd_runs(stem, task, x_key)
      for stem, tasks in (
          ("pga_me_vs_map_elites", ("halfcheetah_uni", "walker2d_uni")),
          ("pga_me_vs_map_elites_1000", ("halfcheetah_uni",)),
          ("pga_me_paper_td3_vs_map_elites", ("walker2d_uni",)),
          ("pga_me_paper_td3_vs_map_elites_1000", ("halfcheetah_uni",)),
          ("dcrl_me_vs_map_elites", ("halfcheetah_uni", "walker2d_uni")),
          ("qd_rl_vs_map_elites_300", ("halfcheetah_uni",)),
          ("qd_rl_point_maze", ("point_maze",)),
      )
      for task in tasks for x_key in ("evaluations", "wall_s")),
    # The skill-discovery benchmark (docs/skill-discovery-benchmark.md)
    Figure("docs/seed_benchmark_cpu.png", "seed_benchmark_record:plot",
           (f"{RESULTS}/seed_benchmark_cpu_seed0.json", f"{RESULTS}/seed_benchmark_cpu_seed1.json"),
           recorded_by="qdrl suite run benchmarks/suites/seed_benchmark_cpu_seed{0,1}.toml --out DIR; "
                       "python benchmarks/seed_benchmark_record.py DIR --out "
                       "benchmarks/results/seed_benchmark_cpu_seed{0,1}.json --merge (one seed's runs each)"),
    *(Figure(f"docs/pga_me_study_vs_qdax_2000_cpu_{task}.png", "pga_me_study_vs_qdax:plot_record",
             (f"{RESULTS}/pga_me_study_vs_qdax_2000_cpu.json",), {"task": task},
             recorded_by="python benchmarks/pga_me_study_vs_qdax.py --qdax-python QDAX_VENV/bin/python "
                         f"--tasks {task} --seeds 3 --evaluations 2000 (halfcheetah_uni: then --first-seed 3 --seeds 2) "
                         f"--out {RESULTS}/pga_me_study_vs_qdax_2000_cpu.json")
      for task in ("halfcheetah_uni", "walker2d_uni")),
    Figure("docs/qdax_pga_me_vs_map_elites_halfcheetah_uni_evaluations.png", "qdax_pga_me_vs_map_elites:plot",
           (f"{RESULTS}/qdax_pga_me_vs_map_elites.json", f"{RESULTS}/pga_me_vs_map_elites_1000.json"),
           recorded_by="python benchmarks/qdax_pga_me_vs_map_elites.py --qdax-python QDAX_VENV/bin/python "
                       "--seeds 3, then --first-seed 3 --seeds 2"),
)
BY_NAME: dict[str, Figure] = {f.name: f for f in FIGURES}
assert len(BY_NAME) == len(FIGURES), "two figures of the table share a file name"


def drawing_function(figure: Figure) -> Callable[..., Any]:
    """The function `figure.draw` names (a bare module: a script of `benchmarks/`)."""
    module, _, name = figure.draw.partition(":")
    if module == "figures":  # this file, run as a script or imported
        return globals()[name]
    func: Callable[..., Any] = getattr(_import(module), name)
    return func


def load(path: Path) -> Any:
    """A recorded results file: `.json` its object, `.jsonl` its lines' objects, `.csv` its rows as floats."""
    if path.suffix == ".json":
        return json.loads(path.read_text())
    if path.suffix == ".jsonl":
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if path.suffix == ".csv":
        with path.open(newline="") as f:
            return [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(f)]
    raise ValueError(f"no loader for {path}")


def redraw(figure: Figure, out: Path) -> Path:
    """Draws `figure` from its recorded results to `out`."""
    if not figure.redrawable:
        raise ValueError(f"{figure.name}: not redrawable: {figure.unrecorded}")
    import matplotlib

    matplotlib.use("Agg")
    out.parent.mkdir(parents=True, exist_ok=True)
    loaded = [load(ROOT / r) for r in figure.results]
    drawing_function(figure)(*loaded, **figure.args, path=out)
    return out


def table() -> str:
    """The table as text: per figure its file, drawing function and results (or why it has none)."""
    lines = []
    for f in FIGURES:
        lines.append(f"{f.name}\n  file:        {f.path}\n  drawn by:    {f.draw}" + (
            "".join(f" {k}={v!r}" for k, v in f.args.items())))
        if f.redrawable:
            lines.append("  results:     " + ", ".join(f.results))
        else:
            lines.append(f"  NOT RECORDED, not redrawn: {f.unrecorded}")
        lines.append(f"  recorded by: {f.recorded_by}")
    missing = [f.name for f in FIGURES if not f.redrawable]
    lines.append(f"\n{len(FIGURES)} figures; {len(FIGURES) - len(missing)} redrawn from benchmarks/results/, "
                 f"{len(missing)} not (their results were never recorded): {', '.join(missing)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="+", metavar="NAME", choices=sorted(BY_NAME),
                   help="redraw only these figures (their file names without .png)")
    p.add_argument("--out", type=Path, default=None,
                   help="write every figure as DIR/<file name> (default: the path the docs expect)")
    p.add_argument("--list", action="store_true", help="print the table of figures and exit")
    args = p.parse_args(argv)
    if args.list:
        print(table())
        return 0
    chosen = [BY_NAME[n] for n in args.only] if args.only else list(FIGURES)
    skipped = [f for f in chosen if not f.redrawable]
    t0 = time.perf_counter()
    for f in chosen:
        if not f.redrawable:
            continue
        out = args.out / Path(f.path).name if args.out else ROOT / f.path
        t = time.perf_counter()
        redraw(f, out)
        print(f"{out.relative_to(ROOT) if out.is_relative_to(ROOT) else out}  ({time.perf_counter() - t:.2f} s)")
    print(f"redrew {len(chosen) - len(skipped)} figures in {time.perf_counter() - t0:.1f} s")
    for f in skipped:
        print(f"NOT REDRAWN {f.path}: results never recorded: {f.unrecorded}", file=sys.stderr)
    if args.only and skipped:
        return 1  # asked for by name, and not drawn
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
