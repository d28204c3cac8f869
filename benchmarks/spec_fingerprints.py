"""A tiny run of every packaged spec, fingerprinted: a regression record of what each spec computes.

    python benchmarks/spec_fingerprints.py --out fingerprints.json [--only NAME ...]
    python benchmarks/spec_fingerprints.py --compare old.json new.json

Each spec of agents/ is shrunk (a few iterations or env steps, small batches and
networks, short episodes; `shrink`) and run by the driver into a temporary
directory, two log points with a checkpoint after each. The fingerprint is every
logged metric except the timings, the summary's non-timing fields, and a SHA-256
of the final checkpoint's state arrays. Two code versions that compute the same
thing give equal fingerprints for every spec; `--compare` lists the specs and
fields that differ. Run it with the test suite's XLA flags (as here) so that a
record is compared with one made the same way.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_flags = os.environ.get("XLA_FLAGS", "")
if "xla_backend_optimization_level" not in _flags:
    os.environ["XLA_FLAGS"] = (
        f"{_flags} --xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
    ).strip()

ROOT = Path(__file__).resolve().parents[1]
# Fields that measure time (they differ from run to run), or name the run's directory.
TIMED = ("wall_s", "compile_s", "run_s", "env_steps_per_s", "evaluations_per_s", "wall_time", "startup_s")

# (section, key) -> the value of a shrunk spec, set where the resolved spec has the key.
TINY: dict[tuple[str, str], Any] = {
    ("task", "episode_length"): 8,
    ("task", "policy_hidden"): [4],
    ("env", "episode_length"): 8,
    ("qd", "num_iterations"): 2,
    ("qd", "log_every"): 1,
    ("qd", "reevaluate_samples"): 0,
    ("repertoire", "num_centroids"): 16,
    ("repertoire", "cvt_samples"): 200,
    ("repertoire", "kmeans_iters"): 5,
    ("pg", "num_critic_training_steps"): 2,
    ("pg", "num_pg_training_steps"): 2,
    ("pg", "training_batch_size"): 8,
    ("pg", "critic_hidden"): [8],
    ("pg", "replay_buffer_size"): 4096,
    ("dcrl", "num_critic_training_steps"): 2,
    ("dcrl", "num_pg_training_steps"): 2,
    ("dcrl", "training_batch_size"): 8,
    ("dcrl", "critic_hidden"): [8],
    ("dcrl", "replay_buffer_size"): 4096,
    ("dcrl", "dcrl_batch_size"): 2,
    ("dcrl", "ai_batch_size"): 2,
    ("dpg", "archive_max_size"): 64,
    ("dpg", "candidates_per_update"): 8,
    ("es", "population_size"): 4,
    ("es", "num_optimizer_steps"): 2,
    ("es", "archive_size"): 64,
    ("me_pbt", "population_size"): 2,
    ("me_pbt", "ga_batch_size"): 2,
    ("me_pbt", "training_steps"): 8,
    ("me_pbt", "env_batch_size"): 2,
    ("me_pbt", "batch_size"): 8,
    ("me_pbt", "buffer_size"): 1024,
    ("me_pbt", "learning_starts"): 0,
    ("me_pbt", "grad_updates_per_step"): 1,
    ("agent", "hidden"): [8],
    ("skills", "hidden"): [8],
    ("train", "num_envs"): 4,
    ("train", "batch_size"): 8,
    ("train", "buffer_size"): 1024,
    ("train", "learning_starts"): 8,
    ("train", "grad_steps_per_iter"): 1,
    ("train", "eval_every"): 16,
    ("train", "total_env_steps"): 32,
    ("pbt", "population_size"): 2,
    ("pbt", "num_replace"): 1,
    ("pbt", "num_best"): 1,
    ("pbt", "exploit_every"): 1,
    ("cma_es", "num_generations"): 4,
    ("cma_es", "log_every"): 2,
    ("population", "size"): 8,
    ("mome", "pareto_front_max_length"): 4,
}


def shrink(resolved: dict[str, Any]) -> dict[str, Any]:
    """The resolved spec (every default filled in) shrunk to seconds of running."""
    spec: dict[str, Any] = {
        k: ([dict(t) for t in v] if isinstance(v, list) else dict(v)) for k, v in resolved.items()
    }
    for (section, key), value in TINY.items():
        table = spec.get(section)
        if isinstance(table, dict) and key in table:
            table[key] = value
    algorithm = spec["experiment"]["algorithm"]
    if "qd" in spec:
        spec["qd"]["init_batch_size"] = 8
    for table in [spec["emitter"]] if "emitter" in spec else spec.get("emitters", []):
        table["batch_size"] = 3 if table.get("kind") == "cma_mega" else 8
        if "num_instances" in table:
            table["num_instances"] = 2
    if "scheduler" in spec:
        spec["scheduler"]["num_active"] = 2
    if "cma_es" in spec:
        spec["cma_es"]["population_size"] = 6
    if "skills" in spec:
        spec["train"]["num_eval_envs"] = int(spec["skills"]["num_skills"])
    elif "train" in spec:
        spec["train"]["num_eval_envs"] = 2
    if algorithm in ("nsga2", "spea2"):
        spec["qd"]["init_batch_size"] = spec["population"]["size"]
    if "repertoire" in spec and spec["repertoire"].get("kind") == "grid":
        shape = spec["repertoire"]["grid_shape"]
        spec["repertoire"]["grid_shape"] = [min(int(n), 10) for n in shape]
    spec["log"] = {**spec.get("log", {}), "progress": False, "plots": False, "checkpoint_every": 1,
                   "keep_checkpoints": 2, "compile_cache": False}
    return spec


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_clean(v) for v in value]
    return value


def _state_digest(checkpoint_dir: Path) -> str:
    import numpy as np

    from qdrl.checkpoint import state_digest

    newest = sorted(checkpoint_dir.glob("step_*"))[-1]
    with np.load(newest / "state.npz") as npz:
        return state_digest({name: npz[name] for name in npz.files})


def fingerprint(name: str) -> dict[str, Any]:
    """Runs the shrunk packaged spec `name`; its metrics, summary and state digest."""
    import tomllib

    import pandas as pd

    from qdrl.experiment import check_spec_file, load_spec, run

    resolved = tomllib.loads(check_spec_file(name))
    spec = shrink(resolved)
    spec["experiment"]["name"] = name
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / name
        t0 = time.perf_counter()
        summary = run(spec, out)
        seconds = time.perf_counter() - t0
        metrics = pd.read_csv(out / "metrics.csv")
        rows = [
            {k: v for k, v in row.items() if k not in TIMED}
            for row in metrics.to_dict(orient="records")
        ]
        files = sorted(p.name for p in out.iterdir() if p.is_file())
        digest = _state_digest(out / "checkpoints")
    del load_spec
    return {
        "rows": _clean(rows),
        "summary": _clean({k: v for k, v in summary.items() if k not in TIMED}),
        "state": digest,
        "files": files,
        "seconds": round(seconds, 1),
    }


def compare(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """One line per spec and field that differs between two records."""
    lines = []
    for name in sorted(set(old) | set(new)):
        a, b = old.get(name), new.get(name)
        if a is None or b is None:
            lines.append(f"{name}: only in {'new' if a is None else 'old'}")
            continue
        if "error" in a or "error" in b:
            if a.get("error") != b.get("error"):
                lines.append(f"{name}: error {a.get('error')!r} -> {b.get('error')!r}")
            continue
        for field in ("rows", "summary", "state", "files"):
            if a[field] != b[field]:
                lines.append(f"{name}: {field} differs" + _first_difference(a[field], b[field]))
    return lines


def _first_difference(a: Any, b: Any) -> str:
    if isinstance(a, list) and isinstance(b, list) and a and isinstance(a[0], dict):
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            keys = [k for k in {**x, **y} if x.get(k) != y.get(k)]
            if keys:
                return f" (row {i}: " + ", ".join(f"{k} {x.get(k)!r} -> {y.get(k)!r}" for k in keys[:4]) + ")"
        return f" ({len(a)} rows -> {len(b)})"
    if isinstance(a, dict) and isinstance(b, dict):
        keys = [k for k in {**a, **b} if a.get(k) != b.get(k)]
        return " (" + ", ".join(f"{k} {a.get(k)!r} -> {b.get(k)!r}" for k in keys[:4]) + ")"
    return f" ({a!r} -> {b!r})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=None, help="the record to write (JSON; updated after each spec)")
    parser.add_argument("--only", nargs="*", default=None, help="only these packaged specs")
    parser.add_argument("--compare", nargs=2, default=None, metavar=("OLD", "NEW"))
    args = parser.parse_args()
    if args.compare:
        old, new = (json.loads(Path(p).read_text()) for p in args.compare)
        lines = compare(old, new)
        print("\n".join(lines) if lines else f"all {len(old)} specs agree")
        return 1 if lines else 0
    from qdrl import specs

    names = args.only or specs.spec_names()
    record: dict[str, Any] = {}
    out = Path(args.out) if args.out else None
    if out is not None and out.exists():
        record = json.loads(out.read_text())
    for i, name in enumerate(names):
        if name in record and "error" not in record[name]:
            continue
        try:
            record[name] = fingerprint(name)
            print(f"[{i + 1}/{len(names)}] {name}: {record[name]['seconds']} s", file=sys.stderr, flush=True)
        except Exception as e:  # recorded: the other version must fail the same way
            record[name] = {"error": f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"}
            print(f"[{i + 1}/{len(names)}] {name}: {record[name]['error']}", file=sys.stderr, flush=True)
        if out is not None:
            out.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    if out is None:
        print(json.dumps(record, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
