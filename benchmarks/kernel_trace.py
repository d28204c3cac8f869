"""Run a benchmark script under JAX's profiler and summarise the kernels the device ran.

    python benchmarks/kernel_trace.py --out kernels.json --steps 200 -- \\
        benchmarks/qdax_map_elites_arm.py --container cvt --batch 1024

The script after `--` runs as `__main__` (with its own arguments) inside
`jax.profiler.trace`; `qdrl.hlo_profile.kernel_summary` then groups the trace's device
events by the XLA program that launched them and writes, per program, the kernels,
their summed time, the device's span and the costliest ops; `--steps N` divides
the figures of the program that launched the most kernels (the timed scan) by N.
On a GPU the events are CUPTI's, on a CPU XLA's thunks: both sides of a
comparison go through the same summary, so their figures compare.
"""

from __future__ import annotations

import argparse
import glob
import json
import runpy
import sys
import tempfile
from pathlib import Path

import jax

from qdrl.hlo_profile import kernel_summary


def main() -> None:
    argv = sys.argv[1:]
    if "--" not in argv:
        raise SystemExit("usage: kernel_trace.py --out FILE [--steps N] -- SCRIPT [ARGS...]")
    cut = argv.index("--")
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", required=True, help="write the summary JSON here")
    p.add_argument("--steps", type=int, default=1, help="divide the main program's figures by this")
    p.add_argument("--top", type=int, default=25, help="ops listed per program")
    args = p.parse_args(argv[:cut])
    script, *script_args = argv[cut + 1 :]
    trace_dir = tempfile.mkdtemp(prefix="kernel_trace_")
    sys.argv = [script, *script_args]
    sys.path.insert(0, str(Path(script).resolve().parent))
    with jax.profiler.trace(trace_dir):
        runpy.run_path(script, run_name="__main__")
    (path,) = glob.glob(f"{trace_dir}/**/*.xplane.pb", recursive=True)
    summary = kernel_summary(path, args.steps, args.top)
    summary["script"] = [script, *script_args]
    Path(args.out).write_text(json.dumps(summary, indent=1) + "\n")


if __name__ == "__main__":
    main()
