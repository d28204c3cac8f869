"""Test-wide settings: CPU only, quick XLA compiles, and a compilation cache shared by the run.

The tests check what the code computes, not how fast: XLA is asked for unoptimised
CPU code (`--xla_backend_optimization_level=0`, no expensive LLVM passes), which cut
the suite's CPU time by about a third (most of it is compiling brax and the agents'
updates), and every compiled function is kept in a persistent cache that later tests
and the subprocesses they start (which inherit these variables) reuse.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_cache = Path(__file__).resolve().parents[1] / ".jax_cache"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_cache))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
_flags = os.environ.get("XLA_FLAGS", "")
if "xla_backend_optimization_level" not in _flags:
    os.environ["XLA_FLAGS"] = (
        f"{_flags} --xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
    ).strip()
os.environ.setdefault("QDRL_CACHE_DIR", str(_cache / "qdrl"))  # compile-time records of test runs


@pytest.fixture
def resumes_bit_identically() -> Callable[[Path, Path, dict[str, Any], Sequence[str]], None]:
    """Checks a finished run (two checkpoints) resumed from its first checkpoint against its summary.

    The last checkpoint is dropped and the run resumed: everything the second half
    needs (emitter state, buffers, repertoire) comes back from the first, so the
    `keys` of the summary, and the summary file, are bit-identical.
    """
    from qdrl.experiment import run_spec

    def check(spec: Path, out: Path, summary: dict[str, Any], keys: Sequence[str]) -> None:
        checkpoints = sorted((out / "checkpoints").glob("step_*"))
        assert len(checkpoints) == 2
        shutil.rmtree(checkpoints[-1])
        resumed = run_spec(spec, [], out, resume=True)
        for key in keys:
            assert resumed[key] == summary[key], key
        assert json.loads((out / "summary.json").read_text())["qd_score"] == summary["qd_score"]

    return check
