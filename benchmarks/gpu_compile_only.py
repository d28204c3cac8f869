"""Compile a benchmark's timed program for a GPU that is not there, and time that compilation.

    python benchmarks/gpu_compile_only.py [--gpu h200] SCRIPT [ARGS...]
    python benchmarks/gpu_compile_only.py [--gpu h200] -c CODE

XLA can compile for an NVIDIA GPU on a machine without one (a compile-only device
made from a description of the GPU: `jax.experimental.topologies`). This wrapper
runs a benchmark script (or `-c` code) in this process, with `jax.jit(f).trace(*args)`
redirected: the arguments become abstract values placed on the compile-only GPU, so
that the script's own `traced.lower().compile()` compiles its timed program for that
GPU. When that compilation returns, the wrapper prints one JSON line (the wall and
process CPU time from the start of tracing to the end of compilation, as the
benchmarks time it on a real GPU, and the GPU program's `qdrl.hlo_profile.hlo_profile`)
and exits before the script would run the program. Every other jitted call (the
initial population, CVT centroids) runs on the CPU as usual.

Needs jax's CUDA plugin for this jax version (no NVIDIA driver, no NVIDIA
libraries): `pip install --no-deps jax-cuda13-plugin==$JAXV jax-cuda13-pjrt==$JAXV`,
and a CUDA toolkit for ptxas (`XLA_FLAGS=--xla_gpu_cuda_data_dir=...` if not under
/usr/local/cuda). Autotuning needs the device, so it is skipped: for programs with
matrix products the real compile time is longer by the autotuning. Compile times
measured this way are figures of this machine's CPU, to compare two programs side by
side here, not a GPU machine's figures.
"""

from __future__ import annotations

import functools
import json
import os
import runpy
import sys
import time
from pathlib import Path
from typing import Any

# The GPUs this wrapper can describe: XLA's device description of each (published
# hardware figures; the compiler reads the compute capability, the number of SMs and
# the per-SM and per-block limits when it chooses launch dimensions and fusions).
GPUS: dict[str, dict[str, Any]] = {
    "h200": {"name": "NVIDIA H200", "cc": (9, 0), "sms": 132, "memory": 151_397_597_184,
             "bandwidth": 4_800_000_000_000, "l2": 52_428_800, "clock_ghz": 1.98},
    "h100": {"name": "NVIDIA H100 80GB HBM3", "cc": (9, 0), "sms": 132, "memory": 85_029_158_912,
             "bandwidth": 3_352_320_000_000, "l2": 52_428_800, "clock_ghz": 1.98},
}


def target_config(gpu: str) -> str:
    """XLA's `GpuTargetConfigProto` of `gpu` in text format."""
    g = GPUS[gpu]
    info = {
        "threads_per_block_limit": 1024, "threads_per_warp": 32, "shared_memory_per_block": 49152,
        "shared_memory_per_core": 233472, "threads_per_core_limit": 2048, "core_count": g["sms"],
        "fpus_per_core": 128, "block_dim_limit_x": 2147483647, "block_dim_limit_y": 65535,
        "block_dim_limit_z": 65535, "memory_bandwidth": g["bandwidth"], "l2_cache_size": g["l2"],
        "clock_rate_ghz": g["clock_ghz"], "device_memory_size": g["memory"],
        "shared_memory_per_block_optin": 232448, "registers_per_core_limit": 65536,
        "registers_per_block_limit": 65536,
    }
    lines = ["gpu_device_info {"]
    lines += [f"  {k}: {v}" for k, v in info.items()]
    lines += [f"  cuda_compute_capability {{ major: {g['cc'][0]} minor: {g['cc'][1]} }}", "}"]
    lines += ['platform_name: "CUDA"', f'device_description_str: "{g["name"]}"']
    return "\n".join(lines) + "\n"


def compile_only_device(gpu: str) -> Any:
    """A compile-only device of the CUDA plugin that describes `gpu`."""
    import jax
    from jax.experimental import topologies

    try:
        topology = topologies.get_topology_desc("qdrl", "cuda", target_config=target_config(gpu), topology="1x1x1")
    except (NotImplementedError, RuntimeError) as e:
        raise SystemExit(
            f"gpu_compile_only: no compile-only CUDA device ({e}); expected jax's CUDA plugin for jax "
            f"{jax.__version__} on the path: pip install --target DIR --no-deps "
            f"jax-cuda13-plugin=={jax.__version__} jax-cuda13-pjrt=={jax.__version__}, then PYTHONPATH=DIR"
        ) from None
    return topology.devices[0]


def _report(t0: float, c0: float, compiled: Any, gpu: str) -> None:
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    import jax

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # qdrl.hlo_profile imports only jax
    from qdrl.hlo_profile import hlo_profile

    record = {
        "platform": f"cuda compile-only ({GPUS[gpu]['name']})",
        "jax": jax.__version__,
        "cpu_count": os.cpu_count(),
        "compile_s": round(wall, 3),
        "compile_cpu_s": round(cpu, 3),
        "hlo": hlo_profile(compiled.as_text()),
    }
    print(json.dumps(record), flush=True)
    os._exit(0)


def install(gpu: str) -> None:
    """Redirect the next `jax.jit(f).trace(*args)` to the compile-only GPU (see the module doc)."""
    import jax
    from jax.sharding import SingleDeviceSharding

    device = compile_only_device(gpu)
    sharding = SingleDeviceSharding(device)
    real_jit = jax.jit

    def abstract(x: Any) -> Any:
        if isinstance(x, jax.Array):
            return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding)
        return x

    class Compiled:
        def __init__(self, lowered: Any, t0: float, c0: float) -> None:
            self._lowered, self._t0, self._c0 = lowered, t0, c0

        def compile(self, *a: Any, **kw: Any) -> Any:
            _report(self._t0, self._c0, self._lowered.compile(*a, **kw), gpu)

    class Traced:
        def __init__(self, traced: Any, t0: float, c0: float) -> None:
            self._traced, self._t0, self._c0 = traced, t0, c0

        def lower(self, *a: Any, **kw: Any) -> Compiled:
            return Compiled(self._traced.lower(*a, **kw), self._t0, self._c0)

    class Jitted:
        def __init__(self, jitted: Any) -> None:
            self._jitted = jitted
            functools.update_wrapper(self, jitted)

        def __call__(self, *a: Any, **kw: Any) -> Any:
            return self._jitted(*a, **kw)

        def __get__(self, obj: Any, objtype: Any = None) -> Any:
            return self if obj is None else functools.partial(self, obj)

        def __getattr__(self, name: str) -> Any:
            return getattr(self._jitted, name)

        def trace(self, *args: Any, **kwargs: Any) -> Traced:
            t0, c0 = time.perf_counter(), time.process_time()
            args, kwargs = jax.tree.map(abstract, (args, kwargs))
            return Traced(self._jitted.trace(*args, **kwargs), t0, c0)

    @functools.wraps(real_jit)
    def jit(fun: Any = None, *a: Any, **kw: Any) -> Any:
        if fun is None:
            return lambda f: Jitted(real_jit(f, *a, **kw))
        return Jitted(real_jit(fun, *a, **kw))

    jax.jit = jit


def main() -> None:
    argv = sys.argv[1:]
    gpu = "h200"
    if argv[:1] == ["--gpu"]:
        gpu, argv = argv[1], argv[2:]
    if not argv or gpu not in GPUS:
        sys.exit(f"usage: gpu_compile_only.py [--gpu {{{','.join(GPUS)}}}] SCRIPT [ARGS...] | -c CODE")
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    install(gpu)
    if argv[0] == "-c":
        sys.argv = ["-c", *argv[2:]]
        exec(compile(argv[1], "<string>", "exec"), {"__name__": "__main__"})
    else:
        sys.argv = argv
        runpy.run_path(argv[0], run_name="__main__")
    sys.exit("the program never compiled for the GPU: no jax.jit(f).trace(...).lower().compile() was reached")


if __name__ == "__main__":
    main()
