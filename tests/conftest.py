"""Test-wide settings: CPU only, quick XLA compiles, and a compilation cache shared by the run.

The tests check what the code computes, not how fast: XLA is asked for unoptimised
CPU code (`--xla_backend_optimization_level=0`, no expensive LLVM passes; most of the
suite's time is compiling brax and the agents' updates), and every compiled function
is kept in a persistent cache that later tests and the subprocesses they start (which
inherit these variables) reuse. The cache is the suite's own: `$QDRL_TEST_CACHE_DIR`
(`.ci/run` gives a fresh, empty one) or the checkout's `.jax_cache/`, never a
`JAX_COMPILATION_CACHE_DIR` the environment set, so every run starts from what this
suite compiled, as a new user's does. On Python 3.11, whose coverage tracer slows every
Python frame, jax's lowering and XLA's compile (no qdrl code in either) run untraced.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_cache = Path(os.environ.get("QDRL_TEST_CACHE_DIR") or Path(__file__).resolve().parents[1] / ".jax_cache")
os.environ["JAX_COMPILATION_CACHE_DIR"] = str(_cache)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
_flags = os.environ.get("XLA_FLAGS", "")
if "xla_backend_optimization_level" not in _flags:
    os.environ["XLA_FLAGS"] = (
        f"{_flags} --xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
    ).strip()
os.environ["QDRL_CACHE_DIR"] = str(_cache / "qdrl")  # compile-time records of test runs


def _untraced(fn: Callable[..., Any]) -> Callable[..., Any]:
    """`fn` run with the thread's trace function (coverage's tracer) off, then back on."""

    @functools.wraps(fn)
    def call(*args: Any, **kwargs: Any) -> Any:
        tracer = sys.gettrace()
        if tracer is None:
            return fn(*args, **kwargs)
        sys.settrace(None)
        try:
            return fn(*args, **kwargs)
        finally:
            sys.settrace(tracer)

    return call


def _lower_and_compile_untraced() -> None:
    """On Python 3.11 coverage measures with `sys.settrace` (no `sys.monitoring`), which slows
    every Python frame while it is on, qdrl's or not. jax's lowering of a traced program to
    MLIR and XLA's backend compile run none of qdrl's code (qdrl's runs while jax traces, and
    its jax.monitoring listeners are called around these two, all of which stays measured):
    they run with the tracer off, as 3.12's `sys.monitoring` leaves them untouched."""
    if sys.version_info >= (3, 12):
        return
    from jax._src import compiler
    from jax._src.interpreters import mlir

    # jax's internals: where another jax has them no longer, the suite just runs traced
    for module, name in ((mlir, "lower_jaxpr_to_module"), (compiler, "backend_compile_and_load")):
        if callable(getattr(module, name, None)):
            setattr(module, name, _untraced(getattr(module, name)))


_lower_and_compile_untraced()


@pytest.fixture
def resumes_bit_identically() -> Callable[[Path, Path, dict[str, Any], Sequence[str]], None]:
    """Checks a finished run (two checkpoints) resumed from its first checkpoint against its summary.

    The last checkpoint is dropped and the run resumed: everything the second half
    needs (emitter state, buffers, repertoire) comes back from the first, so the
    `keys` of the summary, and the summary file, are bit-identical. The resumed half draws
    no plots (`[log]` may change on resume; the first run's test checks its plots).
    """
    from qdrl.experiment import run_spec

    def check(spec: Path, out: Path, summary: dict[str, Any], keys: Sequence[str]) -> None:
        checkpoints = sorted((out / "checkpoints").glob("step_*"))
        assert len(checkpoints) == 2
        shutil.rmtree(checkpoints[-1])
        resumed = run_spec(spec, ["log.plots=false"], out, resume=True)
        for key in keys:
            assert resumed[key] == summary[key], key
        assert json.loads((out / "summary.json").read_text())["qd_score"] == summary["qd_score"]

    return check


class Compilations:
    """Counts the XLA programs compiled (or loaded from the persistent cache) inside a `with` block."""

    def __init__(self) -> None:
        self.count = 0

    def __enter__(self) -> Compilations:
        import jax.monitoring

        def compiled(event: str, duration: float, **kwargs: Any) -> None:
            if event == "/jax/core/compile/backend_compile_duration":
                self.count += 1

        def loaded(event: str, **kwargs: Any) -> None:
            if event == "/jax/compilation_cache/cache_hits":
                self.count += 1

        self._listeners = (compiled, loaded)
        jax.monitoring.register_event_duration_secs_listener(compiled)
        jax.monitoring.register_event_listener(loaded)
        return self

    def __exit__(self, *exc: object) -> None:
        import jax.monitoring

        compiled, loaded = self._listeners
        jax.monitoring.unregister_event_listener(loaded)
        unregister = getattr(jax.monitoring, "unregister_event_duration_listener", None)
        if unregister is None:  # older jax: the private function
            from jax._src import monitoring

            unregister = monitoring._unregister_event_duration_listener_by_callback
        unregister(compiled)


@pytest.fixture
def compilations() -> Callable[[], Compilations]:
    """`with compilations() as c: ...; assert c.count == 0`: a check that fails when a spec error
    is reported only after something compiled (whatever the machine's speed)."""
    return Compilations
