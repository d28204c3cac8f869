"""PBT against the same population with its random hyperparameters fixed.

    python benchmarks/pbt_vs_fixed.py [--spec agents/sac_pbt_halfcheetah_cpu.toml] [--out runs/pbt_evidence]

Runs the spec twice with the same seed, so both populations start from the same
agents and the same sampled hyperparameters: once as written (PBT), once with
`pbt.num_replace = 0` (nothing is ever exploited or explored). A run whose
`summary.json` already exists in the output directory is read, not re-run.
Writes `benchmarks/results/pbt_vs_fixed_<spec>.json` (final and per-log-point
best / median evaluation returns of both) and `docs/pbt_vs_fixed_<spec>.png`.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent


def _rows(path: Path) -> list[dict[str, float]]:
    with path.open() as f:
        return [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(f)]


def plot(record: dict[str, Any], path: str | Path) -> Path:
    """Draws the best and median members' evaluation returns of both runs in `record` (a results
    file of this script) against each member's env steps and writes it to `path`."""
    from qdrl.plotting import plot_comparison

    def curve(key: str) -> list[dict[str, float]]:
        return [{"member_env_steps": s, "eval_return": v}
                for s, v in zip(record["member_env_steps"], record[key], strict=True)]

    curves = {
        "PBT: best member": curve("pbt_best"),
        "PBT: median member": curve("pbt_median"),
        "fixed hyperparameters: best": curve("fixed_best"),
        "fixed hyperparameters: median": curve("fixed_median"),
    }
    return plot_comparison(curves, "eval_return", "member_env_steps", path,
                           title="SAC on halfcheetah: PBT vs fixed random hyperparameters")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--spec", default="agents/sac_pbt_halfcheetah_cpu.toml")
    p.add_argument("--out", default="runs/pbt_evidence")
    args = p.parse_args()

    from qdrl.experiment import run_spec

    stem = Path(args.spec).stem
    out = Path(args.out)
    prefix = "sac" if "sac" in stem else "td3"
    runs = {"pbt": (out / f"{prefix}_pbt", []), "fixed": (out / f"{prefix}_fixed", ["pbt.num_replace=0"])}
    rows: dict[str, list[dict[str, float]]] = {}
    summaries = {}
    for name, (run_dir, overrides) in runs.items():
        if not (run_dir / "summary.json").exists():
            run_spec(Path(args.spec), overrides, run_dir, overwrite=True)
        summaries[name] = json.loads((run_dir / "summary.json").read_text())
        rows[name] = _rows(run_dir / "metrics.csv")

    def series(name: str, key: str) -> list[float]:
        return [r[key] for r in rows[name]]

    record = {
        "spec": args.spec,
        "member_env_steps": series("pbt", "member_env_steps"),
        "pbt_best": series("pbt", "eval_return"),
        "pbt_median": series("pbt", "eval_return_median"),
        "fixed_best": series("fixed", "eval_return"),
        "fixed_median": series("fixed", "eval_return_median"),
        "final": {
            "pbt_best": summaries["pbt"]["eval_return"],
            "pbt_median": summaries["pbt"]["eval_return_median"],
            "fixed_best": summaries["fixed"]["eval_return"],
            "fixed_median": summaries["fixed"]["eval_return_median"],
            "pbt_wall_s": summaries["pbt"]["wall_s"],
            "fixed_wall_s": summaries["fixed"]["wall_s"],
            "pbt_final_hparams": summaries["pbt"]["final_hparams"],
            "fixed_hparams": summaries["fixed"]["final_hparams"],
        },
    }
    from qdrl.bench import machine

    record["machine"] = machine()
    (HERE / "results" / f"pbt_vs_fixed_{stem}.json").write_text(json.dumps(record, indent=2) + "\n")
    plot(record, HERE.parent / "docs" / f"pbt_vs_fixed_{stem}.png")
    print(json.dumps(record["final"], indent=2))


if __name__ == "__main__":
    main()
