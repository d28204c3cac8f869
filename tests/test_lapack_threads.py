"""`single_threaded_lapack`: one OpenBLAS thread inside the block, the previous count after it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.lapack_threads import _libraries, single_threaded_lapack


def test_openblas_runs_on_one_thread_inside_and_is_restored_after() -> None:
    libs = _libraries()
    if not libs:
        pytest.skip("no OpenBLAS loaded in this process (another BLAS or OS)")
    before = [get() for _, get in libs]
    c = jnp.asarray(np.diag([3.0, 1.0, 2.0]) + 0.1, jnp.float32)
    with single_threaded_lapack():
        assert [get() for _, get in libs] == [1] * len(libs)
        values = jax.block_until_ready(jnp.linalg.eigh(c)[0])
    np.testing.assert_allclose(np.asarray(values), np.linalg.eigvalsh(np.asarray(c)), rtol=1e-5)
    assert [get() for _, get in libs] == before
    with pytest.raises(RuntimeError), single_threaded_lapack():
        raise RuntimeError("the count comes back on errors too")
    assert [get() for _, get in libs] == before
