"""The checkpoints of qdrl 0.1.0 in tests/fixtures/checkpoints_0.1.0, and how their record is made.

Each fixture holds a tiny run's first checkpoint as 0.1.0 wrote it; `final_state.npz` and
`expected.json` hold the state and summary that 0.1.0 reached by resuming it, and what
that was computed on (`made_with`: jax, numpy, Python, and the CPU's vector features,
which decide how XLA rounds float arithmetic). Rerecorded with qdrl 0.1.0 on the path:

    git worktree add /tmp/qdrl-0.1.0 71cd369
    PYTHONPATH=/tmp/qdrl-0.1.0 python tests/checkpoint_fixtures.py

(from the checkout's root, in an environment of a constraints file; the XLA flags are the
test suite's, tests/conftest.py).
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "checkpoints_0.1.0"
TIMED = ("wall_s", "compile_s", "startup_s", "run_s", "env_steps_per_s", "evaluations_per_s")
_VECTOR_FLAGS = re.compile(r"^(avx|fma|f16c|amx|sse4|asimd|sve|neon)")


def cpu_signature() -> str:
    """The machine's architecture and the vector features XLA compiles for (e.g. 'x86_64:avx,avx2,fma')."""
    machine = platform.machine()
    flags: set[str] = set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.split(":")[0].strip() in ("flags", "Features"):
                flags |= {f for f in line.split(":", 1)[1].split() if _VECTOR_FLAGS.match(f)}
    except OSError:
        return f"{machine}:{platform.processor()}"
    return f"{machine}:{','.join(sorted(flags))}"


def state_arrays(checkpoint_dir: Path) -> dict[str, np.ndarray]:
    """Every array of the newest checkpoint, by name."""
    newest = sorted(checkpoint_dir.glob("step_*"))[-1]
    with np.load(newest / "state.npz") as npz:
        return {name: npz[name] for name in npz.files}


def clean(value: Any) -> Any:
    """A summary as JSON writes it (non-finite numbers as their repr)."""
    if isinstance(value, float) and not np.isfinite(value):
        return repr(value)
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    if isinstance(value, list):
        return [clean(v) for v in value]
    return value


def resume(name: str, into: Path) -> tuple[Path, dict[str, Any]]:
    """Resumes fixture `name` (copied under `into`) to its end; (its directory, the summary)."""
    from qdrl.config import load_toml
    from qdrl.experiment import run

    out = into / name
    shutil.copytree(FIXTURES / name, out, ignore=shutil.ignore_patterns("final_state.npz", "expected.json"))
    return out, run(load_toml(out / "config.toml"), out, resume=True)


def record() -> None:
    """Rewrites each fixture's `final_state.npz` and `expected.json` from the qdrl on the path."""
    import jax

    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    for fixture in sorted(p for p in FIXTURES.iterdir() if p.is_dir()):
        with tempfile.TemporaryDirectory() as tmp:
            out, summary = resume(fixture.name, Path(tmp))
            arrays = state_arrays(out / "checkpoints")
        np.savez_compressed(fixture / "final_state.npz", **arrays)  # type: ignore[arg-type]
        expected = {
            "made_with": {
                "jax": jax.__version__,
                "numpy": np.__version__,
                "python": f"{sys.version_info[0]}.{sys.version_info[1]}",
                "cpu": cpu_signature(),
            },
            "summary": clean({k: v for k, v in summary.items() if k not in TIMED}),
        }
        (fixture / "expected.json").write_text(json.dumps(expected, indent=1, sort_keys=True) + "\n")
        print(fixture.name, len(arrays), "arrays")


if __name__ == "__main__":
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_optimization_level" not in flags:  # the test suite's (tests/conftest.py)
        os.environ["XLA_FLAGS"] = (
            f"{flags} --xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
        ).strip()
    record()
