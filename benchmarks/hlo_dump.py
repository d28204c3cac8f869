"""Write a jitted program's HLO texts for `qdrl.bench.hlo_summary`, from a peer's virtual environment.

The peer scripts (`qdax_map_elites_arm.py`, `qdax_map_elites_brax.py`) run where
qdrl is not installed, so they cannot call `qdrl.bench.module_texts`; this writes
the same texts under the same names: `<backend>_optimized.txt`,
`<backend>_lowered.txt` and, off a GPU, `cuda_lowered.txt`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax


def write_module_texts(out_dir: str | Path, traced: Any, compiled: Any) -> None:
    """`traced` is `jax.jit(f).trace(...)`, `compiled` its compiled form on this backend."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    here = jax.default_backend()
    (out / f"{here}_optimized.txt").write_text(compiled.as_text())
    (out / f"{here}_lowered.txt").write_text(traced.lower().as_text(dialect="hlo"))
    if here != "gpu":
        (out / "cuda_lowered.txt").write_text(traced.lower(lowering_platforms=("cuda",)).as_text(dialect="hlo"))
