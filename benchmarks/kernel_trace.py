"""Run a benchmark script under JAX's profiler and summarise the kernels the device ran.

    python benchmarks/kernel_trace.py --out kernels.json --steps 200 -- \\
        benchmarks/qdax_map_elites_arm.py --container cvt --batch 1024

The script after `--` runs as `__main__` (with its own arguments) inside
`jax.profiler.trace`. The trace's device events are grouped by the XLA module
that launched them (`hlo_module` and program id), and for each module the JSON gives the number
of kernels, their summed time, the device span from the first kernel's start to
the last one's end (span minus busy time is the time the device waited for
launches), and the kernels that took the most time (by HLO op). `--steps N`
also divides the figures of the module that launched the most kernels (the
timed scan) by N: per step of a scanned run.

On a GPU the events are those of the `/device:GPU:*` planes (one per kernel or
copy, as CUPTI saw them); on a CPU, XLA:CPU's thunks on the host plane. Both
sides of a comparison run through the same summary, so their figures compare.
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import runpy
import sys
import tempfile
from pathlib import Path
from typing import Any

import jax
from jax.profiler import ProfileData


def _events(path: str) -> tuple[str, list[tuple[str, str, float, float]]]:
    """(where the events come from, [(module, op, start_ns, duration_ns)]) of an xplane file."""
    data = ProfileData.from_file(path)
    planes = list(data.planes)
    device = [p for p in planes if p.name.startswith("/device:GPU")]
    source = "gpu" if device else "host"
    events: list[tuple[str, str, float, float]] = []
    for plane in device or planes:
        for line in plane.lines:
            for event in line.events:
                stats = dict(event.stats)
                if "hlo_op" not in stats and not device:
                    continue
                module = f"{stats.get('hlo_module', '?')}#{stats.get('program_id', '?')}"
                op = str(stats.get("hlo_op", event.name))
                events.append((module, op, float(event.start_ns), float(event.duration_ns)))
    return source, events


def summarise(path: str, steps: int = 1, top: int = 25) -> dict[str, Any]:
    """Per-module kernel counts, busy time and span (microseconds) of one trace file."""
    source, events = _events(path)
    by_module: dict[str, list[tuple[str, float, float]]] = collections.defaultdict(list)
    for module, op, start, dur in events:
        by_module[module].append((op, start, dur))
    modules: dict[str, Any] = {}
    for module, evs in sorted(by_module.items(), key=lambda kv: -sum(e[2] for e in kv[1])):
        ops: dict[str, list[float]] = collections.defaultdict(lambda: [0, 0.0])
        for op, _, dur in evs:
            ops[op][0] += 1
            ops[op][1] += dur / 1e3
        span = (max(s + d for _, s, d in evs) - min(s for _, s, _ in evs)) / 1e3
        modules[module] = {
            "kernels": len(evs),
            "busy_us": round(sum(d for *_, d in evs) / 1e3, 1),
            "span_us": round(span, 1),
            "top": [
                {"op": op, "count": int(c), "total_us": round(t, 1)}
                for op, (c, t) in sorted(ops.items(), key=lambda kv: -kv[1][1])[:top]
            ],
        }
    out: dict[str, Any] = {"source": source, "events": len(events), "modules": modules}
    if modules:
        name, main = max(modules.items(), key=lambda kv: kv[1]["kernels"])
        out["main_module"] = name
        out["per_step"] = {
            "kernels": round(main["kernels"] / steps, 2),
            "busy_us": round(main["busy_us"] / steps, 2),
            "span_us": round(main["span_us"] / steps, 2),
        }
    return out


def main() -> None:
    argv = sys.argv[1:]
    if "--" not in argv:
        raise SystemExit("usage: kernel_trace.py --out FILE [--steps N] -- SCRIPT [ARGS...]")
    cut = argv.index("--")
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", required=True, help="write the summary JSON here")
    p.add_argument("--steps", type=int, default=1, help="divide the main module's figures by this")
    p.add_argument("--top", type=int, default=25, help="kernels listed per module")
    args = p.parse_args(argv[:cut])
    script, *script_args = argv[cut + 1:]
    trace_dir = tempfile.mkdtemp(prefix="kernel_trace_")
    sys.argv = [script, *script_args]
    sys.path.insert(0, str(Path(script).resolve().parent))
    with jax.profiler.trace(trace_dir):
        runpy.run_path(script, run_name="__main__")
    (path,) = glob.glob(f"{trace_dir}/**/*.xplane.pb", recursive=True)
    summary = summarise(path, args.steps, args.top)
    summary["script"] = [script, *script_args]
    Path(args.out).write_text(json.dumps(summary, indent=1) + "\n")


if __name__ == "__main__":
    main()
