"""Archive-, Adaptive- and Parallel-Adaptive-Sampling against MAP-Elites on the noisy arm, at equal
evaluations: corrected QD scores (`[qd] reevaluate_samples`), JSON lines.

Each method runs its `agents/*_noisy_arm_cpu.toml`; MAP-Elites runs
`agents/map_elites_noisy_arm_cpu.toml` when it exists, else the same settings without
`[resampling]` (a batch of 512 evaluated once each). Every evaluation counts, the elites'
re-evaluations included (the loop's `evaluations`); the final re-scoring that gives the
corrected metrics is the measurement, not the run's. One line per run:

    python benchmarks/uncertain_sampling_noisy_arm.py --seeds 0 1 2 \
        --out benchmarks/results/uncertain_sampling_noisy_arm.jsonl

`--only ALGORITHM --set KEY=VALUE` runs one of them with spec overrides instead (a variant,
recorded with its overrides), e.g. `--only parallel_adaptive_sampling --set resampling.max_samples=4`.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import tomllib
from pathlib import Path
from typing import Any

import jax

from qdrl.experiment import run_spec

METHODS = ("archive_sampling", "adaptive_sampling", "parallel_adaptive_sampling")
ROOT = Path(__file__).resolve().parent.parent
KEYS = (
    "evaluations", "qd_score", "coverage", "num_elites", "corrected_qd_score", "corrected_coverage",
    "corrected_max_fitness", "corrected_num_elites", "reevaluate_samples", "wall_s",
)


def _toml(value: Any) -> str:
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def baseline_spec(tmp: Path) -> Path:
    """MAP-Elites' spec: the shared one, or Archive-Sampling's settings without `[resampling]`."""
    shared = ROOT / "agents" / "map_elites_noisy_arm_cpu.toml"
    if shared.is_file():
        return shared
    spec = tomllib.loads((ROOT / "agents" / "archive_sampling_noisy_arm_cpu.toml").read_text())
    spec.pop("resampling")
    spec["experiment"]["algorithm"] = "map_elites"
    text = "\n".join(
        f"[{name}]\n" + "".join(f"{k} = {_toml(v)}\n" for k, v in table.items()) for name, table in spec.items()
    )
    path = tmp / "map_elites_noisy_arm_cpu.toml"
    path.write_text(text)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/uncertain_sampling_noisy_arm.jsonl")
    parser.add_argument("--only", choices=("map_elites", *METHODS), help="run this algorithm only")
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="a spec override KEY=VALUE")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        specs = {"map_elites": baseline_spec(tmp)}
        specs.update({m: ROOT / "agents" / f"{m}_noisy_arm_cpu.toml" for m in METHODS})
        if args.only is not None:
            specs = {args.only: specs[args.only]}
        with args.out.open("a") as out:
            for seed in args.seeds:
                for name, spec in specs.items():
                    summary = run_spec(
                        spec, [f"experiment.seed={seed}", "log.progress=false", "log.plots=false", *args.overrides],
                        tmp / f"{name}_{seed}",
                    )
                    line = {
                        "algorithm": name, "seed": seed, "spec": str(spec.relative_to(ROOT) if spec.is_relative_to(ROOT)
                                                               else "derived: archive_sampling's without [resampling]"),
                        "overrides": args.overrides, **{k: summary[k] for k in KEYS}, "device": str(jax.devices()[0]),
                        "note": "benchmarks/uncertain_sampling_noisy_arm.py",
                    }
                    out.write(json.dumps(line) + "\n")
                    out.flush()
                    print(json.dumps(line))


if __name__ == "__main__":
    main()
