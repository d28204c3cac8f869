"""`qdrl report DIR...`: several runs and sweeps compared in figures and tables.

    qdrl run map_elites_arm --seeds 0-4
    qdrl run cvt_map_elites_arm --seeds 0-4
    qdrl report runs/map_elites_arm runs/cvt_map_elites_arm --out report/arm

Runs are grouped by task (runs of different tasks are never drawn together) and,
within a task, by spec: the runs of one sweep (`seed_<n>/`) or of one run
directory are the seeds of one curve. For each metric the report draws the mean
over seeds and its 95% percentile bootstrap confidence band (`qdrl.stats`)
against the run's cost, evaluations for QD runs (environment steps when the
runs compared do not all count evaluations, or when an evaluation costs
environment steps for some and not others) and wall time; a column that is zero
everywhere (the env steps of a function task) is never an axis. It writes:

- `<task>/<metric>.png`: one figure per metric, one panel per x axis;
- `<task>/repertoires.png`: each spec's final repertoire (its lowest seed) side by
  side, on one colour scale, axes named after the task's descriptors;
- `<task>/fitness_histogram.png` and `<task>/fitness_ecdf.png`, for QD runs that wrote
  their repertoire (repertoire.npz / repertoire.csv, one objective): a histogram of each
  spec's final elites' fitnesses (its lowest seed), and their empirical CDF, per spec
  the median over seeds with a min-max band;
- `final.csv`: the final value of every metric, per task and spec: seeds, mean,
  std, min, max, and the interquartile mean (IQM) with its bootstrap interval, as
  rliable recommends for RL returns (Agarwal et al. 2021);
- `throughput.csv`: per task and spec, the environment steps done and the steps per hour,
  of wall time (compilation included) and of run time (compilation excluded), means over
  seeds (the QDax paper's Table 2);
- `<task>/adaptation.png` and `adaptation.csv`, where runs were adapted (`qdrl adapt`, their
  `adaptation/adaptation.csv`): per perturbation set, each spec's best return among its
  elites or skills against the multiplier, mean over the adapted seeds;
- `report.md`: the headline metrics' table (mean ± std, IQM), the throughput table and the figures.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import re
import types
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from qdrl import plotting, stats
from qdrl.runs import LoadedRun, RunError, find_runs

__all__ = ["HEADLINE_METRICS", "Group", "collect", "report"]

# Shown in report.md when the runs have them, in this order; final.csv has every metric.
HEADLINE_METRICS = (
    "eval_return",
    "qd_score",
    "normalized_qd_score",
    "coverage",
    "max_fitness",
    "mean_fitness",
    "num_elites",
)
# The columns that measure cost, not progress; never a metric of their own.
COST_KEYS = frozenset({*plotting.COUNTER_KEYS, *plotting.X_KEYS})


@dataclasses.dataclass
class Group:
    """The runs of one task, by label (a spec's sweep or run directory), seeds in order."""

    task: str
    runs: dict[str, list[LoadedRun]]


def _folder(run: LoadedRun) -> str:
    """A run's folder name: its sweep's for a seed of a sweep (`seed_<n>/`), else its own."""
    path = run.path.resolve()
    return path.parent.name if re.fullmatch(r"seed_\d+", path.name) else path.name


def _labels(runs: Sequence[LoadedRun]) -> dict[Path, str]:
    """Each run's label: its spec's name (`experiment.name`), with the folder's name added
    where runs of one spec name lie in several folders (a spec run twice with other --set
    values), except in the folder named after the spec (`qdrl run`'s default)."""
    names = {run.path: str(run.config["experiment"].get("name") or _folder(run)) for run in runs}
    folders: dict[str, set[str]] = {}
    for run in runs:
        folders.setdefault(names[run.path], set()).add(_folder(run))
    labels = {}
    for run in runs:
        name, folder = names[run.path], _folder(run)
        labels[run.path] = name if len(folders[name]) == 1 or folder == name else f"{name} ({folder})"
    return labels


def collect(paths: Sequence[str | Path]) -> list[Group]:
    """The runs at or under `paths`, grouped by task then label; RunError names a path
    that holds no run, or a set of paths whose runs logged no metrics."""
    groups: dict[str, dict[str, list[LoadedRun]]] = {}
    runs = [run for run in map(LoadedRun, find_runs(paths)) if not run.metrics.empty]
    labels = _labels(runs)
    for run in runs:
        groups.setdefault(run.task_name, {}).setdefault(labels[run.path], []).append(run)
    if not groups:
        raise RunError(
            f"{', '.join(str(p) for p in paths)}: the runs there logged no metrics yet; expected "
            "runs with at least one row in metrics.csv"
        )
    return [
        Group(task, {label: sorted(runs, key=lambda r: r.seed) for label, runs in sorted(by_label.items())})
        for task, by_label in sorted(groups.items())
    ]


def _rows(run: LoadedRun) -> list[dict[str, Any]]:
    return list(run.metrics.to_dict("records"))


def _numeric(run: LoadedRun, key: str) -> bool:
    column = run.metrics.get(key)
    return column is not None and column.dtype.kind in "biuf" and bool(np.isfinite(column).any())


def _nonzero(run: LoadedRun, key: str) -> bool:
    column = run.metrics.get(key)
    return column is not None and bool((np.nan_to_num(column.to_numpy(dtype=float)) != 0).any())


def metrics_of(group: Group) -> list[str]:
    """The metric columns of a group's runs, in first-seen order (costs and counters left out)."""
    keys: dict[str, None] = {}
    for runs in group.runs.values():
        for run in runs:
            for key in run.metrics.columns:
                if key not in COST_KEYS and key not in keys and _numeric(run, key):
                    keys[key] = None
    return list(keys)


def x_keys_for(runs: Sequence[LoadedRun]) -> list[str]:
    """The x axes of a figure of `runs`: the first cost that every run counts with a non-zero
    value (evaluations, then env steps), then wall time."""
    keys = [x for x in ("evaluations", "env_steps") if all(_nonzero(r, x) for r in runs)][:1]
    return [*keys, "wall_s"]


def _final(runs: Sequence[LoadedRun], key: str) -> np.ndarray:
    """Each run's last finite value of `key` (NaN where it has none)."""
    values = []
    for run in runs:
        column = run.metrics.get(key)
        finite = column.to_numpy(dtype=float) if column is not None else np.zeros(0)
        finite = finite[np.isfinite(finite)]
        values.append(float(finite[-1]) if finite.size else math.nan)
    return np.asarray(values, dtype=np.float64)


def final_values(group: Group, key: str, resamples: int = 2000) -> dict[str, dict[str, float]]:
    """Per label: the final value of `key` over seeds (seeds, mean, std, min, max, iqm and its
    95% bootstrap interval); labels whose runs lack the metric are left out."""
    out = {}
    for label, runs in group.runs.items():
        values = _final(runs, key)
        values = values[np.isfinite(values)]
        if not values.size:
            continue
        low, high = stats.bootstrap_ci(values, "iqm", resamples=resamples)
        out[label] = {
            "seeds": int(values.size),
            "mean": float(values.mean()),
            "std": float(values.std(ddof=1)) if values.size > 1 else 0.0,
            "min": float(values.min()),
            "max": float(values.max()),
            "iqm": float(stats.iqm(values)),
            "iqm_low": float(low),
            "iqm_high": float(high),
        }
    return out


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "task"


def _repertoire_of(run: LoadedRun) -> tuple[Any, list[float], list[float], list[str] | None] | None:
    """A run's final repertoire (duck-typed for plotting) with its descriptor bounds and names,
    read from repertoire.npz / archive.npz and summary.json; None when the run has neither."""
    npz = next((run.path / n for n in ("repertoire.npz", "archive.npz") if (run.path / n).is_file()), None)
    summary = run.summary or {}
    if npz is None:
        return None
    with np.load(npz) as f:
        arrays = {k: f[k] for k in f.files if not k.startswith("genotypes")}
    rep = types.SimpleNamespace(
        fitnesses=arrays["fitnesses"],
        descriptors=arrays["descriptors"],
        centroids=arrays.get("centroids"),
        grid_shape=tuple(int(n) for n in arrays["grid_shape"]) if "grid_shape" in arrays else None,
        low=tuple(float(v) for v in arrays["low"]) if "low" in arrays else None,
        high=tuple(float(v) for v in arrays["high"]) if "high" in arrays else None,
    )
    low = summary.get("descriptor_low") or (list(rep.low) if rep.low is not None else None)
    high = summary.get("descriptor_high") or (list(rep.high) if rep.high is not None else None)
    if low is None or high is None:
        if not run.is_qd:
            return None
        task = run.qd_task  # an older run: its bounds from the task, rebuilt
        low, high = list(task.descriptor_low), list(task.descriptor_high)
        summary = {**summary, "descriptor_names": list(task.descriptor_names)}
    names = summary.get("descriptor_names")
    return rep, low, high, names if names and len(names) == len(low) else None


def _final_fitnesses(run: LoadedRun) -> np.ndarray | None:
    """The fitnesses of a QD run's final elites, from repertoire.npz (its filled cells) or
    repertoire.csv; None for a run without them, or whose elites have several objectives."""
    npz, table = run.path / "repertoire.npz", run.path / "repertoire.csv"
    if npz.is_file():
        with np.load(npz) as f:
            fitnesses = f["fitnesses"] if "fitnesses" in f.files else None
        if fitnesses is None or fitnesses.ndim != 1:
            return None
        return fitnesses[fitnesses > -np.inf]
    if table.is_file():
        with table.open(newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows or "fitness" not in rows[0]:
            return None
        return np.asarray([float(r["fitness"]) for r in rows], dtype=np.float64)
    return None


def _plot_distributions(group: Group, task_dir: Path) -> dict[str, str] | None:
    """`fitness_histogram.png` (each spec's lowest seed) and `fitness_ecdf.png` (every seed) of
    the group's QD runs that wrote their repertoire; None when none did."""
    seeds: dict[str, list[tuple[int, np.ndarray]]] = {}
    for label, runs in group.runs.items():
        for run in runs:
            fitnesses = _final_fitnesses(run)
            if fitnesses is not None:
                seeds.setdefault(label, []).append((run.seed, fitnesses))
    if not seeds:
        return None
    histogram = plotting.plot_fitness_histogram(
        {f"{label}, seed {found[0][0]}": found[0][1] for label, found in seeds.items()},
        task_dir / "fitness_histogram.png", title=f"{group.task}: final elites' fitnesses",
    )
    ecdf = plotting.plot_fitness_ecdf(
        {label: [f for _, f in found] for label, found in seeds.items()},
        task_dir / "fitness_ecdf.png", title=f"{group.task}: empirical CDF of the final elites' fitnesses",
    )
    return {"histogram": str(histogram), "ecdf": str(ecdf)}


def throughput(group: Group) -> list[dict[str, Any]]:
    """Per spec of a task: seeds, mean environment steps, mean wall and run time, and the mean
    environment steps per hour of wall time and of run time (runs that wrote their summary)."""
    out = []
    for label, runs in group.runs.items():
        done = [
            r.summary for r in runs
            if r.summary and all(float(r.summary.get(k) or 0) > 0 for k in ("env_steps", "wall_s", "run_s"))
        ]
        if not done:
            continue
        steps = np.array([float(s["env_steps"]) for s in done])
        wall = np.array([float(s["wall_s"]) for s in done])
        run_s = np.array([float(s["run_s"]) for s in done])
        out.append({
            "task": group.task, "spec": label, "seeds": len(done), "env_steps": float(steps.mean()),
            "wall_s": float(wall.mean()), "run_s": float(run_s.mean()),
            "env_steps_per_hour": float(np.mean(steps / wall * 3600.0)),
            "env_steps_per_hour_run": float(np.mean(steps / run_s * 3600.0)),
        })
    return out


def adaptation_curves(group: Group) -> dict[str, dict[str, list[tuple[float, float, int]]]]:
    """Per perturbation set, per spec: (multiplier, mean best return over the adapted seeds,
    seeds) from each run's adaptation/adaptation.csv (`qdrl adapt`); empty when none was adapted."""
    found: dict[str, dict[str, dict[float, list[float]]]] = {}
    for label, runs in group.runs.items():
        for run in runs:
            path = run.path / "adaptation" / "adaptation.csv"
            if not path.is_file():
                continue
            with path.open(newline="") as f:
                for row in csv.DictReader(f):
                    values = found.setdefault(row["perturbation"], {}).setdefault(label, {})
                    values.setdefault(float(row["value"]), []).append(float(row["best_return"]))
    return {
        name: {
            label: [(v, float(np.mean(b)), len(b)) for v, b in sorted(by_value.items())]
            for label, by_value in by_label.items()
        }
        for name, by_label in found.items()
    }


def _plot_adaptation(curves: Mapping[str, Mapping[str, Sequence[tuple[float, float, int]]]], path: Path, task: str) -> Path:
    """One panel per perturbation set, a line per spec: best return against the multiplier."""
    names = list(curves)
    fig = plotting._new_figure(len(names))
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    for ax, name in zip(axes, names, strict=True):
        for label, points in curves[name].items():
            ax.plot([p[0] for p in points], [p[1] for p in points], marker="o", ms=3, label=label)
        ax.set_xlabel(f"{name} multiplier")
        ax.set_ylabel("best return (mean over seeds)")
        ax.set_title(name)
        ax.legend(fontsize="small")
    fig.suptitle(f"{task}: adaptation to perturbed dynamics (best elite or skill)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def _decimals(std: float, value: float) -> int:
    """Decimals that show two significant digits of `std` (of `value` when std is 0)."""
    scale = std if std > 0 and math.isfinite(std) else abs(value)
    if scale == 0 or not math.isfinite(scale):
        return 0
    return int(min(6, max(0, 1 - math.floor(math.log10(scale)))))


def _fmt(x: float, decimals: int) -> str:
    return f"{x:,.{decimals}f}" if math.isfinite(x) else "nan"


def _cell(value: Mapping[str, float]) -> str:
    """`mean ± std (IQM iqm)`, rounded to the std's second significant digit; one seed's
    value alone (no spread to show)."""
    if value["seeds"] == 1:
        return f"{_fmt(value['mean'], _decimals(0.0, value['mean']) + 1)} (one seed)"
    d = _decimals(value["std"], value["mean"])
    return f"{_fmt(value['mean'], d)} ± {_fmt(value['std'], d)} (IQM {_fmt(value['iqm'], d)})"


def report(
    paths: Sequence[str | Path],
    out_dir: str | Path = "report",
    confidence: float = 0.95,
    resamples: int = 2000,
) -> dict[str, Any]:
    """Writes the report of the runs at or under `paths` into `out_dir` (see the module
    docstring); returns {"out", "groups": {task: {"labels", "figures", "repertoires",
    "distributions"}}, "table", "csv"}. RunError names a path that holds no run."""
    groups = collect(paths)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"out": str(out), "groups": {}}
    csv_rows: list[dict[str, Any]] = []
    speed_rows: list[dict[str, Any]] = []
    adapt_rows: list[dict[str, Any]] = []
    md = ["# Report", "", "Runs: " + ", ".join(f"`{p}`" for p in paths), ""]
    md += [
        f"Curves: mean over seeds, band: {confidence:.0%} percentile bootstrap interval over seeds "
        f"({resamples} resamples). Final values: mean ± std over seeds; IQM: interquartile mean "
        "(Agarwal et al. 2021).",
        "",
    ]
    single = sorted({label for g in groups for label, runs in g.runs.items() if len(runs) == 1})
    if single:
        md += [
            f"One seed only: {', '.join(single)}. Bands and ± need two seeds or more (`qdrl run SPEC "
            "--seeds 0-4`); these curves are drawn without a band.",
            "",
        ]
    for group in groups:
        task_dir = out / _slug(group.task)
        figures: list[dict[str, Any]] = []
        for key in metrics_of(group):
            members = {
                label: [_rows(r) for r in runs if _numeric(r, key)]
                for label, runs in group.runs.items()
            }
            members = {label: rows for label, rows in members.items() if rows}
            with_key = [r for runs in group.runs.values() for r in runs if _numeric(r, key)]
            x_keys = x_keys_for(with_key)
            path = plotting.plot_comparison(
                members, key, x_keys, task_dir / f"{_slug(key)}.png",
                title=f"{group.task}: {key}", confidence=confidence,
            )
            figures.append({"metric": key, "path": str(path), "x": x_keys})
            for label, values in final_values(group, key, resamples).items():
                csv_rows.append({"task": group.task, "spec": label, "metric": key, **values})
        repertoires, low, high, names = {}, None, None, None
        for label, runs in group.runs.items():
            found = _repertoire_of(runs[0])
            if found is not None:
                rep, low, high, run_names = found
                names = names or run_names
                repertoires[f"{label} (seed {runs[0].seed})"] = rep
        rep_path = None
        if repertoires and low is not None and high is not None:
            rep_path = plotting.plot_repertoires(
                repertoires, task_dir / "repertoires.png", low, high,
                title=f"{group.task}: final repertoires", labels=names,
            )
        distributions = _plot_distributions(group, task_dir)
        result["groups"][group.task] = {
            "labels": {label: [r.seed for r in runs] for label, runs in group.runs.items()},
            "figures": figures,
            "repertoires": str(rep_path) if rep_path else None,
            "distributions": distributions,
        }
        speed = throughput(group)
        speed_rows.extend(speed)
        curves = adaptation_curves(group)
        adapt_path = None
        if curves:
            adapt_path = _plot_adaptation(curves, task_dir / "adaptation.png", group.task)
            figures.append({"metric": "adaptation", "path": str(adapt_path), "x": ["multiplier"]})
            adapt_rows.extend(
                {"task": group.task, "perturbation": name, "spec": label, "value": v, "best_return": b, "seeds": n}
                for name, by_label in curves.items() for label, points in by_label.items() for v, b, n in points
            )
        md += _task_section(
            group, [r for r in csv_rows if r["task"] == group.task], figures, rep_path, out, speed, distributions
        )

    csv_path = out / "final.csv"
    fields = ["task", "spec", "metric", "seeds", "mean", "std", "min", "max", "iqm", "iqm_low", "iqm_high"]
    with csv_path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(csv_rows)
    speed_path = out / "throughput.csv"
    with speed_path.open("w", newline="") as f:
        speed_fields = ["task", "spec", "seeds", "env_steps", "wall_s", "run_s", "env_steps_per_hour", "env_steps_per_hour_run"]
        writer = csv.DictWriter(f, fieldnames=speed_fields)
        writer.writeheader()
        writer.writerows(speed_rows)
    if adapt_rows:
        with (out / "adaptation.csv").open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["task", "perturbation", "spec", "value", "best_return", "seeds"])
            writer.writeheader()
            writer.writerows(adapt_rows)
        result["adaptation"] = str(out / "adaptation.csv")
    md_path = out / "report.md"
    md_path.write_text("\n".join(md) + "\n")
    result.update({"table": str(md_path), "csv": str(csv_path), "throughput": str(speed_path)})
    (out / "report.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


def _task_section(
    group: Group, rows: list[dict[str, Any]], figures: list[dict[str, Any]], rep_path: Path | None, out: Path,
    speed: Sequence[Mapping[str, Any]] = (),
    distributions: Mapping[str, str] | None = None,
) -> list[str]:
    """report.md's section of one task: the headline table, the throughput table, then the figures."""
    lines = [f"## {group.task}", ""]
    seeds = {label: ", ".join(str(r.seed) for r in runs) for label, runs in group.runs.items()}
    metrics = [m for m in HEADLINE_METRICS if any(r["metric"] == m for r in rows)]
    if not metrics:  # no standard metric: the group's first few
        metrics = list(dict.fromkeys(r["metric"] for r in rows))[:4]
    lines.append("| spec | seeds | " + " | ".join(metrics) + " |")
    lines.append("|---|---|" + "---|" * len(metrics))
    for label in group.runs:
        cells = []
        for metric in metrics:
            value = next((r for r in rows if r["spec"] == label and r["metric"] == metric), None)
            cells.append("" if value is None else _cell(value))
        lines.append(f"| {label} | {seeds[label]} | " + " | ".join(cells) + " |")
    lines.append("")
    if speed:
        lines.append("| spec | seeds | env steps | wall time (s) | env steps per hour | per hour, compilation excluded |")
        lines.append("|---|---|---|---|---|---|")
        for r in speed:
            lines.append(
                f"| {r['spec']} | {r['seeds']} | {r['env_steps']:,.0f} | {r['wall_s']:,.0f} | "
                f"{r['env_steps_per_hour']:.3g} | {r['env_steps_per_hour_run']:.3g} |"
            )
        lines.append("")
    for figure in figures:
        lines.append(f"![{figure['metric']}]({Path(figure['path']).relative_to(out).as_posix()})")
    if rep_path is not None:
        lines.append(f"![repertoires]({rep_path.relative_to(out).as_posix()})")
    for name, path in (distributions or {}).items():
        lines.append(f"![fitness {name}]({Path(path).relative_to(out).as_posix()})")
    lines.append("")
    return lines

