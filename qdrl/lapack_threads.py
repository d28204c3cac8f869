"""One OpenBLAS thread for jax's CPU LAPACK calls (eigh, cholesky, ...), as pyribs does.

On CPU, jax hands `jnp.linalg.eigh` and the other LAPACK routines to the
OpenBLAS that SciPy ships. OpenBLAS starts as many threads as there are cores;
for the small matrices of CMA-ES (n <= a few hundred) they only wait on each
other, which on a loaded machine makes eigendecompositions far slower than with
one thread (figures in docs/benchmarks.md). pyribs wraps its CMA-ES in
`threadpoolctl.threadpool_limits(1)` for the same reason. `single_threaded_lapack` sets the loaded OpenBLAS libraries to
one thread and restores them afterwards; where none is found (another BLAS,
another OS) it does nothing. XLA's own kernels (matmuls, convolutions) do not
use OpenBLAS and are not affected.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import jax
import jax.numpy as jnp

__all__ = ["single_threaded_lapack"]

_RTLD_NOLOAD = getattr(os, "RTLD_NOLOAD", 4)  # glibc's value where os lacks it

# (setter, getter) symbol names of the OpenBLAS builds in SciPy / NumPy wheels and plain OpenBLAS.
_SYMBOLS = (
    ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("openblas_set_num_threads", "openblas_get_num_threads"),
)


def _loaded_openblas() -> list[tuple[Callable[[int], None], Callable[[], int]]]:
    """(set, get) of every OpenBLAS library loaded in this process (Linux: /proc/self/maps)."""
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return []
    paths = sorted({line.split()[-1] for line in maps.read_text().splitlines()
                    if "openblas" in line.lower() and line.split()[-1].startswith("/")})
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=_RTLD_NOLOAD)  # a handle to the copy already loaded
        except OSError:
            continue
        for setter, getter in _SYMBOLS:
            if hasattr(lib, setter) and hasattr(lib, getter):
                set_fn, get_fn = getattr(lib, setter), getattr(lib, getter)
                set_fn.argtypes, set_fn.restype = [ctypes.c_int], None
                get_fn.argtypes, get_fn.restype = [], ctypes.c_int
                found.append((set_fn, get_fn))
                break
    return found


@functools.cache
def _libraries() -> tuple[tuple[Callable[[int], None], Callable[[], int]], ...]:

    # jax loads its LAPACK (SciPy's OpenBLAS) on the first LAPACK call.
    jax.block_until_ready(jnp.linalg.eigh(jnp.eye(2)))
    return tuple(_loaded_openblas())


@contextlib.contextmanager
def single_threaded_lapack() -> Iterator[None]:
    """Within the block, OpenBLAS (jax's CPU LAPACK) runs on one thread; restored on exit."""
    libs = _libraries()
    before = [get() for _, get in libs]
    for set_fn, _ in libs:
        set_fn(1)
    try:
        yield
    finally:
        for (set_fn, _), n in zip(libs, before, strict=True):
            set_fn(n)
