"""Compile time of one MAP-Elites program, qdrl against QDax 0.5.0, side by side.

    python benchmarks/compile_time_vs_qdax.py --qdax-python /path/to/qdax-venv/bin/python --repeats 4

Each side compiles the same program ahead of time in a fresh process, alternating
which goes first: the 100-DoF arm (CVT 1024, batch 1024) and halfcheetah_uni
(episodes of 100 steps, batch 128, CVT 1024), as `qdrl bench` and the QDax scripts
beside this one time them (`compare_qdax_map_elites.py`, `compare_qdax_brax.py`):
the scan of 200 iterations (arm) or 50 (halfcheetah_uni) those benchmarks time. (A
scan of 2 iterations is unrolled by XLA, which compiles the step twice.) Each
process then runs its program once. Records wall and process CPU time of the
compilation (mean and standard deviation over the repeats); the CPU time
is the steadier figure when other jobs share the cores. No persistent compilation
cache on either side. QDax's halfcheetah figure leaves out its eager reset of the
environment (`reset_s`); qdrl computes its start state in its own small program
while the initial population's evaluation is traced, also outside the timed one.

`--tasks` picks settings (default: arm and halfcheetah_uni): `arm` (CVT 1024, batch
1024), `arm_b16384` (batch 16384), `arm_grid100` (100x100 grid, batch 1024) and
`halfcheetah_uni`. `--gpu h200` compiles each program for an H200 that is not there,
through `gpu_compile_only.py` (XLA's compile-only GPU device; `--plugin-path` is a
directory holding jax's CUDA plugin, `pip install --target DIR --no-deps
jax-cuda13-plugin==V jax-cuda13-pjrt==V` for the jax version V of both sides): the
compile times are then those of the GPU programs on this machine's CPU, and each run
adds its GPU program's kernels and bytes per step (`qdrl.hlo_profile.hlo_profile`).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
QDRL_ARM = ("from qdrl.bench import time_map_elites as t; import json; "
            "print(json.dumps(t({container!r}, batch_size={batch}, iterations=200, hlo=False)))")
QDRL_CHEETAH = ("from qdrl.bench import time_policy_map_elites as t; import json; "
                "print(json.dumps(t('halfcheetah_uni', iterations=50)))")
# task -> (qdrl's code, QDax script and arguments, iterations of the timed scan)
TASKS: dict[str, tuple[str, list[str], int]] = {
    "arm": (QDRL_ARM.format(container="cvt1024", batch=1024),
            ["qdax_map_elites_arm.py", "--iterations", "200"], 200),
    "arm_b16384": (QDRL_ARM.format(container="cvt1024", batch=16384),
                   ["qdax_map_elites_arm.py", "--iterations", "200", "--batch", "16384"], 200),
    "arm_grid100": (QDRL_ARM.format(container="grid100", batch=1024),
                    ["qdax_map_elites_arm.py", "--iterations", "200", "--container", "grid",
                     "--grid-shape", "100", "100"], 200),
    "halfcheetah_uni": (QDRL_CHEETAH, ["qdax_map_elites_brax.py", "--iterations", "50"], 50),
}


def _run(cmd: list[str], env: dict[str, str]) -> dict[str, Any]:
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--qdax-python", required=True)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--tasks", nargs="+", choices=sorted(TASKS), default=["arm", "halfcheetah_uni"])
    p.add_argument("--gpu", choices=["h100", "h200"], default=None,
                   help="compile for this GPU without one (gpu_compile_only.py)")
    p.add_argument("--plugin-path", default=None, help="directory holding jax's CUDA plugin (with --gpu)")
    p.add_argument("--out", default=None)
    args = p.parse_args()
    out = args.out or str(HERE / "results" / (f"compile_time_vs_qdax_{args.gpu}_compile_only.json"
                                               if args.gpu else "compile_time_vs_qdax.json"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env.update(JAX_PLATFORMS="cpu", QDRL_COMPILE_CACHE="0")
    wrap: list[str] = []
    if args.gpu:
        wrap = [str(HERE / "gpu_compile_only.py"), "--gpu", args.gpu]
        if args.plugin_path:
            env["PYTHONPATH"] = os.pathsep.join(x for x in (args.plugin_path, env.get("PYTHONPATH")) if x)
    runs: list[dict[str, Any]] = []
    for task in args.tasks:
        code, qdax_args, iterations = TASKS[task]
        sides = {
            "qdrl": [sys.executable, *wrap, "-c", code],
            "qdax": [args.qdax_python, *wrap, str(HERE / qdax_args[0]), *qdax_args[1:]],
        }
        for r in range(args.repeats):
            for side in (["qdrl", "qdax"] if r % 2 == 0 else ["qdax", "qdrl"]):
                rec = _run(sides[side], env)
                row = {"task": task, "side": side, "repeat": r,
                       **{k: rec[k] for k in ("compile_s", "compile_cpu_s") if k in rec}}
                if "hlo" in rec:  # the GPU program (compile-only): per scanned step
                    row["kernels_per_step"] = round(rec["hlo"]["kernels"] / iterations, 2)
                    row["bytes_per_step"] = round(rec["hlo"]["bytes"] / iterations)
                    row["instructions"] = rec["hlo"]["instructions"]
                runs.append(row)
                print(json.dumps(row), file=sys.stderr)
    summary: dict[str, Any] = {}
    for task in args.tasks:
        s: dict[str, Any] = {}
        for side in ("qdrl", "qdax"):
            rs = [x for x in runs if x["task"] == task and x["side"] == side]
            s[side] = {k: round(statistics.mean(x[k] for x in rs), 2) for k in ("compile_s", "compile_cpu_s")}
            if len(rs) > 1:
                s[side].update({f"{k}_std": round(statistics.stdev(x[k] for x in rs), 2)
                                for k in ("compile_s", "compile_cpu_s")})
            for k in ("kernels_per_step", "bytes_per_step", "instructions"):
                if k in rs[0]:
                    s[side][k] = rs[0][k]
        s["cpu_ratio_qdrl_over_qdax"] = round(s["qdrl"]["compile_cpu_s"] / s["qdax"]["compile_cpu_s"], 3)
        s["wall_ratio_qdrl_over_qdax"] = round(s["qdrl"]["compile_s"] / s["qdax"]["compile_s"], 3)
        summary[task] = s
    from qdrl.bench import machine

    record: dict[str, Any] = {"machine": machine(), "repeats": args.repeats}
    if args.gpu:
        import jax

        record["target"] = (f"{args.gpu} compile-only (XLA's GPU compiler on this machine's CPU, "
                            f"jax {jax.__version__} CUDA plugin; no autotuning)")
    record.update(summary=summary, runs=runs)
    Path(out).write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
