"""qdrl.checkpoint against orbax-checkpoint's CheckpointManager on real run states.

Measures, alternating the two libraries run by run: import time (fresh
processes, after jax), what a restore does with 64 flipped bytes in a
checkpoint, save and restore time, and whether the restored state is
bit-identical (typed PRNG keys, NamedTuples, chex dataclasses, restoring into a
template). States: the initial state of `agents/sac_halfcheetah.toml` (its
1M-transition replay buffer) and of `agents/map_elites_arm.toml` (32x32 grid of
100-joint arms), float leaves filled with noise. Prints one JSON line per measurement and a summary.

    python benchmarks/checkpoint_vs_orbax.py [--reps 3]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from qdrl import checkpoint
from qdrl.config import load_toml
from qdrl.experiment import build_run, initial_state

ROOT = Path(__file__).resolve().parents[1]


def import_seconds(module: str) -> float:
    code = f"import time, jax; t = time.perf_counter(); import {module}; print(time.perf_counter() - t)"
    return float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)


def state_of(spec_name: str) -> Any:
    """The spec's initial state with every float leaf filled with noise, as after training
    (an empty replay buffer is zeros, which orbax's compression would make look cheap)."""
    run, exp, _ = build_run(load_toml(ROOT / "agents" / spec_name))
    state = initial_state(run, exp.seed)
    rng = np.random.default_rng(0)

    def fill(x: Any) -> Any:
        if jax.numpy.issubdtype(x.dtype, jax.numpy.floating):
            return jax.numpy.asarray(rng.standard_normal(x.shape).astype(x.dtype))
        return x

    return jax.block_until_ready(jax.tree.map(fill, state))


def nbytes(state: Any) -> int:
    return sum(
        np.asarray(jax.random.key_data(x) if jax.numpy.issubdtype(x.dtype, jax.dtypes.prng_key) else x).nbytes
        for x in jax.tree.leaves(state)
    )


def bit_identical(a: Any, b: Any) -> bool:
    if jax.tree.structure(a) != jax.tree.structure(b):
        return False
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        key = jax.numpy.issubdtype(x.dtype, jax.dtypes.prng_key)
        if key != jax.numpy.issubdtype(y.dtype, jax.dtypes.prng_key):
            return False
        if key:
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
            return False
    return True


def qdrl_roundtrip(state: Any, directory: Path, step: int) -> tuple[float, float, bool]:
    t0 = time.perf_counter()
    checkpoint.save(directory, step, jax.device_get(state), {"chunk": step}, keep=2)
    save_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    restored, _ = checkpoint.restore(checkpoint.latest(directory), state)  # type: ignore[arg-type]
    jax.block_until_ready(restored)
    return save_s, time.perf_counter() - t0, bit_identical(state, restored)


def orbax_roundtrip(state: Any, directory: Path, step: int) -> tuple[float, float, bool]:
    import orbax.checkpoint as ocp

    options = ocp.CheckpointManagerOptions(max_to_keep=2, enable_async_checkpointing=False)
    with ocp.CheckpointManager(directory, options=options) as manager:
        t0 = time.perf_counter()
        manager.save(step, args=ocp.args.StandardSave(state))
        manager.wait_until_finished()
        save_s = time.perf_counter() - t0
        template = jax.tree.map(ocp.utils.to_shape_dtype_struct, state)
        t0 = time.perf_counter()
        restored = manager.restore(manager.latest_step(), args=ocp.args.StandardRestore(template))
        jax.block_until_ready(restored)
        return save_s, time.perf_counter() - t0, bit_identical(state, restored)


def corrupted_restore(lib: str, directory: Path) -> str:
    """Flips 64 bytes in the middle of the largest file of a saved checkpoint and restores it."""
    state = {"x": jax.numpy.arange(1_000_000, dtype=jax.numpy.float32), "key": jax.random.key(0)}
    (orbax_roundtrip if lib == "orbax" else qdrl_roundtrip)(state, directory, 0)
    _, biggest = max((p.stat().st_size, p) for p in directory.rglob("*") if p.is_file())
    data = bytearray(biggest.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 64] = bytes(b ^ 0xFF for b in data[mid : mid + 64])
    biggest.write_bytes(bytes(data))
    try:
        if lib == "orbax":
            import orbax.checkpoint as ocp

            with ocp.CheckpointManager(directory) as manager:
                template = jax.tree.map(ocp.utils.to_shape_dtype_struct, state)
                out = manager.restore(0, args=ocp.args.StandardRestore(template))
        else:
            out, _ = checkpoint.restore(checkpoint.latest(directory), state)  # type: ignore[arg-type]
    except Exception as e:
        return f"error: {type(e).__name__}: {str(e).splitlines()[0][:120]}"
    wrong = int((np.asarray(out["x"]) != np.asarray(state["x"])).sum())
    return f"restored without an error, {wrong} values wrong"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--reps", type=int, default=3)
    args = parser.parse_args()
    results: dict[str, list[float]] = {}

    def note(name: str, value: float, **extra: Any) -> None:
        results.setdefault(name, []).append(value)
        print(json.dumps({"measure": name, "value": round(value, 4), **extra}), flush=True)

    for _ in range(args.reps):
        note("import_s/orbax.checkpoint", import_seconds("orbax.checkpoint"))
        note("import_s/qdrl.checkpoint", import_seconds("qdrl.checkpoint"))
    root = Path(tempfile.mkdtemp(prefix="ckpt-corrupt-"))
    try:
        for lib in ("qdrl", "orbax"):
            print(json.dumps({"corrupted_restore": lib, "outcome": corrupted_restore(lib, root / lib)}), flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    for spec in ("map_elites_arm.toml", "sac_halfcheetah.toml"):
        state = state_of(spec)
        print(json.dumps({"state": spec, "bytes": nbytes(state), "leaves": len(jax.tree.leaves(state))}))
        root = Path(tempfile.mkdtemp(prefix="ckpt-bench-"))
        try:
            for rep in range(args.reps):
                for lib, fn in (("qdrl", qdrl_roundtrip), ("orbax", orbax_roundtrip)):
                    save_s, restore_s, exact = fn(state, root / lib, rep)
                    note(f"save_s/{lib}/{spec}", save_s, bit_identical=exact)
                    note(f"restore_s/{lib}/{spec}", restore_s, bit_identical=exact)
        finally:
            shutil.rmtree(root, ignore_errors=True)
    print(json.dumps({"median": {k: round(statistics.median(v), 4) for k, v in results.items()}}, indent=1))


if __name__ == "__main__":
    main()
