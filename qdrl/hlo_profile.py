"""What a compiled XLA program does: HLO op, kernel and byte counts, and a trace's kernels.

`hlo_profile` counts what one compiled (or only lowered) XLA module does, to
compare programs op by op; `module_texts` gives a jitted function's HLO as compiled
here, as lowered here and as lowered for CUDA; `kernel_summary` reads what the device
ran from a `jax.profiler.trace`. `qdrl bench` records these for its timed programs.

Only jax and the standard library are imported: benchmark scripts load this module
from the source tree inside another library's environment (benchmarks/*qdax*.py,
gpu_compile_only.py, kernel_trace.py), where qdrl's other dependencies may be absent.
"""

from __future__ import annotations

import collections
import dataclasses
import re
import warnings
from pathlib import Path
from typing import Any

import jax
from jax.profiler import ProfileData

__all__ = [
    "HEAVY_OPS", "hlo_profile", "hlo_summary", "kernel_summary", "module_texts", "per_iteration",
    "write_module_texts",
]

_DTYPE_BYTES = {"pred": 1, "s8": 1, "u8": 1, "s16": 2, "u16": 2, "f16": 2, "bf16": 2,
                "s32": 4, "u32": 4, "f32": 4, "s64": 8, "u64": 8, "f64": 8}
_SHAPE = re.compile(r"\b(pred|[suf]\d+|bf16)\[([\d,]*)\]")
_INSTRUCTION = re.compile(r"^\s+(?:ROOT\s+)?%?[\w.\-]+ = (.*?) ([a-z][\w\-]*)\((.*)$")
_TRIP_COUNT = re.compile(r'"known_trip_count":\{"n":"(\d+)"')
# Instructions that move no data and launch nothing.
_FREE_OPS = frozenset(
    {"parameter", "constant", "get-tuple-element", "tuple", "bitcast", "after-all", "opt-barrier"}
)
# Ops that name a fusion's kind (the first one present wins) and that an accelerator
# runs as kernels of their own or that bound fusion.
HEAVY_OPS = ("scatter", "sort", "dot", "custom-call", "gather", "dynamic-update-slice",
             "reduce-window", "reduce")


def _bytes_of(text: str) -> int:
    total = 0
    for dtype, dims in _SHAPE.findall(text):
        size = 1
        for d in dims.split(","):
            if d:
                size *= int(d)
        total += size * _DTYPE_BYTES[dtype]
    return total


def _called(attrs: str, key: str) -> list[str]:
    m = re.search(r"\b" + key + r"=(\{[^}]*\}|%?[\w.\-]+)", attrs)
    return re.findall(r"%?([\w.\-]+)", m.group(1)) if m else []


@dataclasses.dataclass
class _Tally:
    ops: collections.Counter[str]
    kernels: collections.Counter[str]
    bytes: int

    def add(self, other: _Tally) -> None:
        self.ops.update(other.ops)
        self.kernels.update(other.kernels)
        self.bytes += other.bytes


def hlo_profile(hlo_text: str) -> dict[str, Any]:
    """What one call of an XLA HLO module executes: ops by kind, kernels, bytes moved.

    `hlo_text` is HLO text, optimised (`jax.jit(f).lower(...).compile().as_text()`)
    or not (`lower(...).as_text(dialect="hlo")`). The module is walked from its
    entry: called computations once per call, while bodies once per iteration
    when XLA annotated a known trip count (un-optimised modules have none: once),
    and of a conditional's branches the costliest (most bytes), so that the
    figures bound one execution from above. Returns:

    - `instructions`: instructions in the module text (its size);
    - `ops`: executed ops by opcode, fusions opened (parameters, constants,
      tuples, bitcasts left out); `while_iterations` counts loop iterations;
    - `kernels`: executed top-level ops (each fusion counts once) and
      `kernels_by_kind` (a fusion is named `fusion:` + the first of HEAVY_OPS it
      holds, else `fusion:loop`): in an optimised module, the kernels launched;
      in an un-optimised one, an upper bound;
    - `bytes`: bytes read and written by those top-level ops (their operands and
      results), the traffic to memory when nothing stays in caches.
    """
    comps: dict[str, list[tuple[str, str, str]]] = {}
    entry, current, instructions = None, None, 0
    for line in hlo_text.splitlines():
        if line and not line[0].isspace() and line.rstrip().endswith("{") and not line.startswith("HloModule"):
            m = re.match(r"^(ENTRY\s+)?%?([\w.\-]+)", line)
            if m:
                current = m.group(2)
                comps[current] = []
                entry = current if m.group(1) else entry
            continue
        if line.strip() == "}":
            current = None
            continue
        m = _INSTRUCTION.match(line)
        if m and current is not None:
            instructions += 1
            comps[current].append((m.group(1), m.group(2), m.group(3)))
    if entry is None:
        raise ValueError("hlo_profile: expected HLO text with an ENTRY computation")
    def tally(name: str, times: int, top: bool) -> _Tally:
        out = _Tally(collections.Counter(), collections.Counter(), 0)
        for shape, op, rest in comps[name]:
            if op == "while":
                trip = _TRIP_COUNT.search(rest)
                iterations = times * (int(trip.group(1)) if trip else 1)
                out.ops["while"] += times
                out.ops["while_iterations"] += iterations
                for c in _called(rest, "body") + _called(rest, "condition"):
                    out.add(tally(c, iterations, top))
                continue
            if op == "conditional":
                out.ops["conditional"] += times
                branches = [
                    tally(c, times, top)
                    for key in ("branch_computations", "true_computation", "false_computation")
                    for c in _called(rest, key)
                ]
                if branches:  # the costliest branch: an upper bound of one execution
                    out.add(max(branches, key=lambda t: (t.bytes, sum(t.kernels.values()))))
                continue
            if op == "call":
                for c in _called(rest, "to_apply"):
                    out.add(tally(c, times, top))
                continue
            if op in _FREE_OPS:
                continue
            kind = op
            if op == "fusion":
                inner = [o for c in _called(rest, "calls") for _, o, _ in comps.get(c, [])]
                for c in _called(rest, "calls"):
                    out.ops.update(tally(c, times, False).ops)
                kind = "fusion:" + next((h for h in HEAVY_OPS if h in inner), "loop")
            else:
                out.ops[op] += times
            if top:
                out.kernels[kind] += times
                out.bytes += times * (_bytes_of(shape) + _bytes_of(rest.split("), ")[0]))
        return out

    total = tally(entry, 1, True)
    ops, kernels, moved = total.ops, total.kernels, total.bytes
    return {
        "instructions": instructions,
        "ops": dict(sorted(ops.items())),
        "kernels": sum(kernels.values()),
        "kernels_by_kind": dict(sorted(kernels.items())),
        "bytes": moved,
    }


def module_texts(traced: Any, compiled: Any) -> dict[str, str]:
    """HLO texts of a jitted function: as compiled here, as lowered here, and lowered for CUDA.

    `traced` is `jax.jit(f).trace(...)`, `compiled` its compiled form on this
    backend. Lowering for CUDA needs no GPU (only XLA:GPU's optimisation does): it
    shows the program a GPU starts from (unrolled threefry, no CPU-only branch of
    `lax.platform_dependent`).
    """
    here = jax.default_backend()
    texts = {
        f"{here}_optimized": compiled.as_text(),
        f"{here}_lowered": traced.lower().as_text(dialect="hlo"),
    }
    if here != "gpu":
        texts["cuda_lowered"] = traced.lower(lowering_platforms=("cuda",)).as_text(dialect="hlo")
    return texts


def write_module_texts(directory: str | Path, traced: Any, compiled: Any) -> None:
    """Writes each text of `module_texts` to DIRECTORY/NAME.txt (the directory is created)."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    for name, text in module_texts(traced, compiled).items():
        (out / f"{name}.txt").write_text(text)


def per_iteration(profile: dict[str, Any], iterations: int) -> dict[str, Any]:
    """`hlo_profile` of a scanned run divided by its iterations (rounded to 0.01)."""

    def div(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: div(v) for k, v in x.items()}
        return round(x / iterations, 2)

    return {k: (v if k == "instructions" else div(v)) for k, v in profile.items()}


def hlo_summary(texts: dict[str, str], iterations: int) -> dict[str, Any]:
    """`hlo_profile` of each text of `module_texts` for a run of `iterations` scanned steps, per step.

    Optimised modules carry the scan's trip count (their totals are divided by
    `iterations`); lowered ones count the scan's body once, i.e. one step.
    """
    return {
        name: per_iteration(hlo_profile(text), iterations if name.endswith("_optimized") else 1)
        for name, text in texts.items()
    }


def _trace_events(path: str | Path) -> tuple[str, list[tuple[str, str, float, float]]]:
    """(where the events come from, [(module, op, start_ns, duration_ns)]) of an xplane file."""

    planes = list(ProfileData.from_file(str(path)).planes)
    device = [p for p in planes if p.name.startswith("/device:GPU")]
    events: list[tuple[str, str, float, float]] = []
    for plane in device or planes:
        for line in plane.lines:
            for event in line.events:
                with warnings.catch_warnings():  # jaxlib's event_stats type lacks __module__ (Python 3.12 warns)
                    warnings.simplefilter("ignore", DeprecationWarning)
                    stats = dict(event.stats)
                if "hlo_op" not in stats and not device:
                    continue  # host planes: only XLA's thunks, not Python's frames
                module = f"{stats.get('hlo_module', '?')}#{stats.get('program_id', '?')}"
                events.append((module, str(stats.get("hlo_op", event.name)), float(event.start_ns), float(event.duration_ns)))
    return ("gpu" if device else "host"), events


def kernel_summary(trace_file: str | Path, steps: int = 1, top: int = 25) -> dict[str, Any]:
    """What the device ran in a `jax.profiler.trace`: kernels per XLA program, busy time and span.

    `trace_file` is the trace's `*.xplane.pb`. On a GPU the events are the
    `/device:GPU:*` planes' (one per kernel or copy, as CUPTI saw them); on a CPU,
    XLA's thunks on the host plane. Events are grouped by the program that launched
    them (`hlo_module#program_id`); per program: kernels, summed time (`busy_us`),
    the span from the first kernel's start to the last one's end (`span_us`; span
    minus busy is time the device waited for launches) and the `top` costliest HLO
    ops. `per_step` divides the figures of the program that launched the most
    kernels (a scanned run) by `steps`.
    """
    source, events = _trace_events(trace_file)
    by_module: dict[str, list[tuple[str, float, float]]] = collections.defaultdict(list)
    for module, op, start, dur in events:
        by_module[module].append((op, start, dur))
    modules: dict[str, Any] = {}
    for module, evs in sorted(by_module.items(), key=lambda kv: -sum(e[2] for e in kv[1])):
        ops: dict[str, list[float]] = collections.defaultdict(lambda: [0, 0.0])
        for op, _, dur in evs:
            ops[op][0] += 1
            ops[op][1] += dur / 1e3
        modules[module] = {
            "kernels": len(evs),
            "busy_us": round(sum(d for *_, d in evs) / 1e3, 1),
            "span_us": round((max(s + d for _, s, d in evs) - min(s for _, s, _ in evs)) / 1e3, 1),
            "top": [
                {"op": op, "count": int(c), "total_us": round(t, 1)}
                for op, (c, t) in sorted(ops.items(), key=lambda kv: -kv[1][1])[:top]
            ],
        }
    out: dict[str, Any] = {"source": source, "events": len(events), "modules": modules}
    if modules:
        name, main = max(modules.items(), key=lambda kv: kv[1]["kernels"])
        out["main_module"] = name
        out["per_step"] = {k: round(main[k] / steps, 2) for k in ("kernels", "busy_us", "span_us")}
    return out
