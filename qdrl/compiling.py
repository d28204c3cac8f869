"""Compile a function ahead of time and time it: the one place where qdrl's loops are compiled.

The experiment driver compiles each run's chunk with it, and the throughput
benchmarks (`qdrl bench`) their timed programs, so a compile time means the same
thing everywhere: wall and process-CPU seconds from tracing to an executable.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax

__all__ = ["Compiled", "compile_timed"]


class Compiled(NamedTuple):
    """An executable compiled ahead of time, and what its compilation cost."""

    fn: Callable[..., Any]  # the compiled executable: call it with arguments like the examples
    seconds: float  # wall time from tracing to the executable
    cpu_seconds: float  # process CPU time of the same (steadier than wall time on a shared machine)
    traced: Any  # the `jax.jit(...).trace(...)` result, for reading its HLO (`qdrl.hlo_profile`)


def compile_timed(
    fn: Callable[..., Any], *example_args: Any, donate_argnums: int | Sequence[int] = ()
) -> Compiled:
    """`jax.jit(fn, donate_argnums)` traced, lowered and compiled for `example_args`, timed.

    The arguments are only read for their shapes, dtypes and shardings; a donated
    argument is donated when the executable is called, not here.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    traced = jax.jit(fn, donate_argnums=donate_argnums).trace(*example_args)
    executable = traced.lower().compile()
    return Compiled(executable, time.perf_counter() - t0, time.process_time() - c0, traced)
