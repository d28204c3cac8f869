"""Seed sweeps: one spec run once per seed, one after the other, each into `OUT/seed_<n>/`."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from qdrl import checkpoint
from qdrl.config import ConfigError
from qdrl.experiment import check_spec, default_out_dir, flat_spec, load_spec, run

__all__ = ["finished_as_given", "parse_seeds", "run_seeds", "seed_dir"]


def parse_seeds(text: str) -> list[int]:
    """The seeds of `--seeds`: a range "0-4" (both ends included), a list "0,3,7", or both
    ("0-2,7"); ConfigError saying what was expected otherwise."""
    seeds: list[int] = []
    expected = 'expected seeds as "0-4" (a range) or "0,3,7" (a list)'
    for part in text.split(","):
        bounds = part.strip().split("-")
        try:
            if len(bounds) > 2:
                raise ValueError
            lo, hi = int(bounds[0]), int(bounds[-1])
        except ValueError:
            raise ConfigError(f"--seeds: {expected}, got {text!r}") from None
        if lo > hi or lo < 0 or hi > 2**32 - 1:
            raise ConfigError(f"--seeds: {expected}, increasing and in [0, 2**32), got {text!r}")
        seeds.extend(s for s in range(lo, hi + 1) if s not in seeds)
    return seeds


def seed_dir(out_dir: str | Path, seed: int) -> Path:
    """Where seed `seed` of a sweep into `out_dir` writes: `out_dir/seed_<seed>`."""
    return Path(out_dir) / f"seed_{seed}"


def _with_seed(spec: Mapping[str, Any], seed: int) -> dict[str, Any]:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in spec.items()}
    out.setdefault("experiment", {})["seed"] = seed
    return out


def finished_as_given(out_dir: Path, spec: Mapping[str, Any]) -> dict[str, Any] | None:
    """The summary of a finished run in `out_dir` whose resolved spec agrees with every key
    `spec` gives, or None (not finished, or another length or setting)."""
    summary, config = out_dir / "summary.json", out_dir / "config.toml"
    if not (summary.is_file() and config.is_file()):
        return None
    given = {f"{s}.{k}": v for s, table in spec.items() if isinstance(table, dict) for k, v in table.items()}
    resolved = flat_spec(config.read_text())
    if any(k not in resolved or resolved[k] != v for k, v in given.items()):
        return None
    loaded: dict[str, Any] = json.loads(summary.read_text())
    return loaded


def run_seeds(
    spec_path: str | Path,
    seeds: list[int],
    overrides: list[str] | None = None,
    out_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_start: Callable[[Path], None] | None = None,
) -> dict[str, Any]:
    """Run a spec once per seed, one after the other, each into `out_dir/seed_<n>/`.

    Each seed is a complete run (`run`), as `qdrl run SPEC --set experiment.seed=n`
    would make it, so a seed of a sweep is bit-identical to the same seed run alone
    (vmapping the seeds in one chunk was slower on CPUs and not bit-identical:
    `benchmarks/seeds_sequential_vs_vmap.py`). With `resume`, finished seeds are
    skipped, interrupted ones resume from their checkpoints and the others start.

    Returns {"out": the sweep directory, "runs": {seed: summary}}; `on_start` is called
    as each seed's run starts (`run`).
    Raises ConfigError (a bad spec, or a seed directory that already holds a run
    without `resume` or `overwrite`) before anything compiles, and RunInterrupted
    as `run` does.
    """
    if not seeds:
        raise ConfigError("--seeds: expected at least one seed, got none")
    base = load_spec(spec_path, overrides)
    out = Path(out_dir) if out_dir else default_out_dir(spec_path)
    check_spec(_with_seed(base, seeds[0]))
    if not resume and not overwrite:
        for seed in seeds:
            if checkpoint.checkpoints(seed_dir(out, seed) / "checkpoints"):
                raise ConfigError(
                    f"{seed_dir(out, seed)} already holds a run with checkpoints; pass --resume to "
                    "continue the sweep, --overwrite to discard its runs, or --out for a new directory"
                )
    summaries: dict[int, dict[str, Any]] = {}
    for i, seed in enumerate(seeds):
        spec, where = _with_seed(base, seed), seed_dir(out, seed)
        finished = finished_as_given(where, spec) if resume else None
        if finished is not None:
            print(f"qdrl: seed {seed} ({i + 1} of {len(seeds)}): finished in {where}, skipped", file=sys.stderr)
            summaries[seed] = finished
            continue
        started = bool(checkpoint.checkpoints(where / "checkpoints"))
        summaries[seed] = run(
            spec, where, resume=resume and started, overwrite=overwrite,
            label=f"seed {seed}, {i + 1} of {len(seeds)}", on_start=on_start,
        )
    return {"out": str(out), "runs": summaries}
