"""Tests for qdrl.checkpoint: bit-exact roundtrip, latest, pruning, crash safety, verification, errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import checkpoint
from qdrl.types import Transition


class TrainState(NamedTuple):
    params: dict
    opt_count: jax.Array
    key: jax.Array
    steps: jax.Array


def make_state(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    f32 = lambda *s: jnp.asarray(rng.standard_normal(s).astype(np.float32))  # noqa: E731
    params = {  # haiku-like: module name -> parameter name -> array
        "mlp/~/linear_0": {"w": f32(3, 8), "b": f32(8)},
        "mlp/~/linear_1": {"w": f32(8, 2), "b": f32(2)},
    }
    special = jnp.array([np.nan, np.inf, -np.inf, -0.0, 1e-45], jnp.float32)
    return {
        "train": TrainState(
            params=params,
            opt_count=jnp.array(7, jnp.int32),
            key=jax.random.PRNGKey(seed),  # uint32[2]
            steps=jnp.array(2**32 - 1, jnp.uint32),
        ),
        "typed_key": jax.random.key(seed + 1),
        "bf16": jnp.array([1.5, -2.25], jnp.bfloat16),
        "special": special,
        "transition": Transition(*[f32(2, 3) for _ in Transition._fields]),
        "scalar_f": jnp.float32(0.1),
        "py_int": 3,
        "bools": jnp.array([True, False]),
    }


def assert_bit_exact(a, b) -> None:
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        x = jnp.asarray(x)  # Python scalars are saved with JAX's default dtype
        if jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            assert y.dtype == x.dtype
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        x, y = np.asarray(x), np.asarray(y)
        assert x.shape == y.shape and x.dtype == y.dtype
        assert x.tobytes() == y.tobytes()  # NaN payloads and -0.0 included


def test_roundtrip_is_bit_exact(tmp_path: Path) -> None:
    state = make_state()
    meta = {"algo": "sac", "env_steps": np.int64(1000), "lr": 3e-4, "dir": tmp_path}
    path = checkpoint.save(tmp_path, 1000, state, meta)
    assert path == tmp_path / "step_0000001000"
    assert (path / "state.npz").is_file() and (path / "meta.json").is_file()
    assert (path / "manifest.json").is_file()
    checkpoint.verify(path)

    restored, got_meta = checkpoint.restore(path, make_state(seed=1))
    assert_bit_exact(state, restored)
    assert all(isinstance(x, jax.Array) for x in jax.tree_util.tree_leaves(restored))
    assert isinstance(restored["train"], TrainState)
    assert isinstance(restored["transition"], Transition)
    assert got_meta == {"algo": "sac", "env_steps": 1000, "lr": 3e-4, "dir": str(tmp_path)}
    assert checkpoint.step_of(path) == 1000

    saved = json.loads((path / "meta.json").read_text())
    assert saved["num_leaves"] == len(jax.tree_util.tree_leaves(state))
    assert {"shape": [], "dtype": "key<fry>", "key_impl": "threefry2x32"} in saved["leaves"]

    # The restored typed key draws the same numbers as the original.
    np.testing.assert_array_equal(
        jax.random.uniform(state["typed_key"], (4,)),
        jax.random.uniform(restored["typed_key"], (4,)),
    )


def test_restore_accepts_shape_dtype_struct_template(tmp_path: Path) -> None:
    state = make_state()
    path = checkpoint.save(tmp_path, 0, state, {})
    template = jax.eval_shape(lambda: make_state())
    restored, _ = checkpoint.restore(path, template)
    assert_bit_exact(state, restored)


def test_latest_picks_newest_and_keep_prunes(tmp_path: Path) -> None:
    assert checkpoint.latest(tmp_path / "missing") is None
    assert checkpoint.latest(tmp_path) is None
    state = {"x": jnp.zeros(3)}
    for step in [5, 10, 200, 30]:
        checkpoint.save(tmp_path, step, {"x": jnp.full(3, float(step))}, {}, keep=3)
    # Pruning is by step: 5 went; 30 was just written, so it stays.
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["step_0000000010", "step_0000000030", "step_0000000200"]
    assert checkpoint.latest(tmp_path) == tmp_path / "step_0000000200"
    restored, _ = checkpoint.restore(checkpoint.latest(tmp_path), state)
    np.testing.assert_array_equal(restored["x"], [200.0] * 3)

    checkpoint.save(tmp_path, 300, state, {})  # default keep=2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["step_0000000200", "step_0000000300"]
    # Steps beyond 10 digits still sort numerically.
    checkpoint.save(tmp_path, 10**11, state, {})
    assert checkpoint.latest(tmp_path) == tmp_path / f"step_{10**11}"


def test_saving_an_existing_step_replaces_it(tmp_path: Path) -> None:
    checkpoint.save(tmp_path, 1, {"x": jnp.zeros(2)}, {"v": 1})
    path = checkpoint.save(tmp_path, 1, {"x": jnp.ones(2)}, {"v": 2})
    restored, meta = checkpoint.restore(path, {"x": jnp.zeros(2)})
    np.testing.assert_array_equal(restored["x"], [1.0, 1.0])
    assert meta == {"v": 2}
    assert [p.name for p in tmp_path.iterdir()] == ["step_0000000001"]


def test_leftover_temp_dir_is_ignored_then_cleaned(tmp_path: Path) -> None:
    checkpoint.save(tmp_path, 100, {"x": jnp.zeros(2)}, {})
    # A save killed mid-write leaves a temp dir with a truncated file behind.
    crashed = tmp_path / ".tmp-step_0000000200-deadbeef"
    crashed.mkdir()
    (crashed / "state.npz").write_bytes(b"PK\x03\x04 truncated")
    # A hand-made step dir without its files is not a checkpoint either.
    (tmp_path / "step_0000000300").mkdir()
    assert checkpoint.latest(tmp_path) == tmp_path / "step_0000000100"
    checkpoint.save(tmp_path, 101, {"x": jnp.zeros(2)}, {})
    assert not crashed.exists()
    assert checkpoint.latest(tmp_path) == tmp_path / "step_0000000101"


def test_failed_save_leaves_nothing_behind(tmp_path: Path) -> None:
    checkpoint.save(tmp_path, 1, {"x": jnp.zeros(2)}, {})
    with pytest.raises(TypeError, match="not JSON serialisable"):
        checkpoint.save(tmp_path, 2, {"x": jnp.zeros(2)}, {"bad": object()})
    assert [p.name for p in tmp_path.iterdir()] == ["step_0000000001"]


def test_mismatched_template_raises_clear_errors(tmp_path: Path) -> None:
    state = {"a": jnp.zeros((2, 3)), "b": jnp.zeros(4, jnp.int32), "c": jax.random.PRNGKey(0)}
    path = checkpoint.save(tmp_path, 0, state, {})

    with pytest.raises(ValueError, match=r"holds 3 leaves but the template has 2"):
        checkpoint.restore(path, {"a": jnp.zeros((2, 3)), "b": jnp.zeros(4, jnp.int32)})
    with pytest.raises(
        ValueError,
        match=r"2 leaves differ\):\n  leaf \['a'\]: template has shape \(3, 2\) dtype float32, "
        r"checkpoint has shape \(2, 3\) dtype float32\n  leaf \['b'\]: .*dtype float32, .*dtype int32",
    ):
        checkpoint.restore(path, {"a": jnp.zeros((3, 2)), "b": jnp.zeros(4), "c": state["c"]})
    # Same leaves under different keys: caught by the structure check.
    renamed = {"a": state["a"], "b": state["b"], "d": state["c"]}
    with pytest.raises(ValueError, match=r"different pytree structure"):
        checkpoint.restore(path, renamed)
    restored, _ = checkpoint.restore(path, renamed, check_treedef=False)
    np.testing.assert_array_equal(restored["d"], state["c"])
    # A typed key template against a saved uint32 key is a dtype mismatch.
    with pytest.raises(ValueError, match=r"leaf \['c'\].*key<fry>.*uint32"):
        checkpoint.restore(path, {**state, "c": jax.random.key(0)})


def test_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="step"):
        checkpoint.save(tmp_path, -1, {"x": jnp.zeros(1)}, {})
    with pytest.raises(ValueError, match="keep"):
        checkpoint.save(tmp_path, 0, {"x": jnp.zeros(1)}, {}, keep=0)


_WRITER = textwrap.dedent(
    """
    import sys
    import numpy as np
    from qdrl import checkpoint
    step = 0
    while True:
        # ~8 MB per checkpoint so that kills often land mid-write.
        state = {"x": np.full((2_000_000,), step, np.float32), "step": np.int32(step)}
        checkpoint.save(sys.argv[1], step, state, {"step": step}, keep=2)
        step += 1
    """
)


@pytest.mark.parametrize("delay_s", [0.05, 0.23])
def test_survives_sigkill_at_any_moment(tmp_path: Path, delay_s: float) -> None:
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(tmp_path)], env=env)
    try:
        deadline = time.monotonic() + 60
        while checkpoint.latest(tmp_path) is None:
            assert proc.poll() is None, "writer died"
            assert time.monotonic() < deadline, "writer never saved"
            time.sleep(0.01)
        time.sleep(delay_s)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    path = checkpoint.latest(tmp_path)
    assert path is not None
    template = {"x": np.zeros((2_000_000,), np.float32), "step": np.int32(0)}
    state, meta = checkpoint.restore(path, template)
    step = checkpoint.step_of(path)
    assert meta == {"step": step} and int(state["step"]) == step
    assert bool((state["x"] == step).all())


def _corrupt(path: Path, mode: str) -> None:
    if mode == "delete":
        path.unlink()
    elif mode == "truncate":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    else:  # garbage: same size, bytes flipped in the middle
        data = bytearray(path.read_bytes())
        mid = len(data) // 2
        data[mid : mid + 8] = bytes(b ^ 0xFF for b in data[mid : mid + 8])
        path.write_bytes(bytes(data))


@pytest.mark.parametrize("mode", ["truncate", "garbage", "delete"])
@pytest.mark.parametrize("name", ["state.npz", "meta.json", "manifest.json"])
def test_a_corrupt_checkpoint_is_detected_and_skipped(tmp_path: Path, name: str, mode: str) -> None:
    template = {"x": jnp.zeros(1000), "k": jax.random.key(0)}
    for step in (1, 2):
        checkpoint.save(tmp_path, step, {"x": jnp.full(1000, float(step)), "k": jax.random.key(step)}, {"s": step})
    newest = tmp_path / "step_0000000002"
    _corrupt(newest / name, mode)
    with pytest.raises(checkpoint.CheckpointError, match=name.replace(".", r"\.")) as info:
        checkpoint.restore(newest, template)
    assert "\n" not in str(info.value)
    state, meta, path, skipped = checkpoint.restore_newest(tmp_path, template)
    assert path == tmp_path / "step_0000000001" and meta == {"s": 1}
    np.testing.assert_array_equal(state["x"], np.ones(1000))
    assert [(p.name, name in why) for p, why in skipped] == [("step_0000000002", True)]


def test_restore_newest_fails_in_one_line_when_nothing_loads(tmp_path: Path) -> None:
    with pytest.raises(checkpoint.CheckpointError, match="no checkpoint in"):
        checkpoint.restore_newest(tmp_path, {"x": jnp.zeros(2)})
    checkpoint.save(tmp_path, 1, {"x": jnp.zeros(2)}, {})
    checkpoint.save(tmp_path, 2, {"x": jnp.zeros(2)}, {})
    (tmp_path / "step_0000000002" / "state.npz").unlink()
    # A template of another shape: the older checkpoint loads no better.
    with pytest.raises(checkpoint.CheckpointError) as info:
        checkpoint.restore_newest(tmp_path, {"x": jnp.zeros(3)})
    msg = str(info.value)
    assert "\n" not in msg
    assert "step_0000000002: state.npz is missing" in msg
    assert "step_0000000001: checkpoint" in msg and "does not match the template" in msg


_KILLER = textwrap.dedent(
    """
    import os, sys
    import numpy as np
    from qdrl import checkpoint
    directory, phase, step = sys.argv[1], sys.argv[2], int(sys.argv[3])
    for s in (1, 2):
        checkpoint.save(directory, s, {"x": np.full(1000, s, np.float32)}, {"s": s}, keep=2)
    def crash(p):
        if p == phase:
            os._exit(17)  # no cleanup, no flush: what SIGKILL leaves
    checkpoint._crash_point = crash
    checkpoint.save(directory, step, {"x": np.full(1000, step, np.float32)}, {"s": step}, keep=2)
    """
)


def test_a_save_killed_between_any_two_steps_leaves_a_complete_checkpoint(tmp_path: Path) -> None:
    # (phase killed in, step saved, the newest checkpoint that must load after the kill)
    cases = [
        ("files_written", 3, 2), ("manifest_written", 3, 2), ("renamed", 3, 3), ("pruned", 3, 3),
        ("moved_aside", 2, 1),  # replacing an existing step: the older one survives
    ]
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    procs = [
        subprocess.Popen([sys.executable, "-c", _KILLER, str(tmp_path / phase), phase, str(step)], env=env)
        for phase, step, _ in cases
    ]
    for (phase, _, expected), proc in zip(cases, procs, strict=True):
        assert proc.wait(timeout=120) == 17, phase
        state, meta, path, _ = checkpoint.restore_newest(tmp_path / phase, {"x": np.zeros(1000, np.float32)})
        assert meta == {"s": expected} and checkpoint.step_of(path) == expected, phase
        assert bool((state["x"] == expected).all()), phase
        # A later save cleans the leftovers up and prunes to `keep` again.
        checkpoint.save(tmp_path / phase, 4, {"x": np.zeros(1000, np.float32)}, {}, keep=2)
        names = sorted(p.name for p in (tmp_path / phase).iterdir())
        assert names[-1] == "step_0000000004" and len(names) == 2, (phase, names)


def test_a_checkpoint_of_the_first_format_is_named_as_such(tmp_path: Path) -> None:
    path = checkpoint.save(tmp_path, 1, {"x": jnp.zeros(2)}, {})
    (path / "manifest.json").unlink()
    meta = json.loads((path / "meta.json").read_text())
    (path / "meta.json").write_text(json.dumps({**meta, "format_version": 1}))
    with pytest.raises(checkpoint.CheckpointError, match="format 1 by an older qdrl"):
        checkpoint.restore(path, {"x": jnp.zeros(2)})
