"""Atomic save and bit-exact restore of any pytree (training state, repertoire, keys).

Layout of a checkpoint directory::

    directory/
      step_0000001000/
        state.npz    leaves of the flattened pytree, named leaf_00000, leaf_00001, ...
        meta.json    user metadata, step, leaf count, each leaf's shape and dtype,
                     the treedef as a string
      step_0000002000/
      .tmp-...       a save in progress (or killed mid-write); never read

A checkpoint is written into a temporary directory beside its final place and
renamed into place only once every file is fsynced, so a process killed at any
moment (SIGKILL included) leaves either the previous checkpoints or a complete
new one. `latest` only looks at `step_*` directories, which exist only complete.

Only one process should save into a given directory at a time.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.types import PyTree

__all__ = ["latest", "restore", "save", "step_of"]

STATE_FILE = "state.npz"
META_FILE = "meta.json"
FORMAT_VERSION = 1
_STEP_DIR = re.compile(r"^step_(\d{10,})$")
_TMP_PREFIX = ".tmp-"
_TRASH_PREFIX = ".trash-"


def _leaf_name(i: int) -> str:
    return f"leaf_{i:05d}"


def _is_key_array(x: Any) -> bool:
    dtype = getattr(x, "dtype", None)
    return dtype is not None and jnp.issubdtype(dtype, jax.dtypes.prng_key)


def _treedef_str(treedef: Any) -> str:
    # Custom nodes may show their aux data's repr, which can hold memory
    # addresses that differ from one process to the next.
    return re.sub(r" at 0x[0-9a-fA-F]+", "", str(treedef))


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _json_default(obj: Any) -> Any:
    # numpy / jax scalars and paths are common in experiment metadata.
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray | jax.Array) and np.ndim(obj) == 0:
        return np.asarray(obj).item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"metadata value {obj!r} of type {type(obj).__name__} is not JSON serialisable")


def _checkpoints(directory: Path) -> list[tuple[int, Path]]:
    """Complete checkpoints in `directory`, sorted by step."""
    if not directory.is_dir():
        return []
    found = []
    for child in directory.iterdir():
        m = _STEP_DIR.match(child.name)
        if m and (child / META_FILE).is_file() and (child / STATE_FILE).is_file():
            found.append((int(m.group(1)), child))
    return sorted(found)


def save(
    directory: str | os.PathLike[str],
    step: int,
    state: PyTree,
    metadata: Mapping[str, Any] | None = None,
    keep: int = 2,
) -> Path:
    """Atomically writes `state` as checkpoint `step` and prunes old checkpoints.

    Args:
      directory: parent directory of all checkpoints of a run (created if needed).
      step: non-negative step number; names the checkpoint `step_{step:010d}`.
        Saving a step that already exists replaces it.
      state: any pytree of arrays (jax, numpy, Python scalars). Typed PRNG key
        arrays are stored as their `jax.random.key_data` and rewrapped on restore.
      metadata: JSON-serialisable mapping (numpy scalars and paths are converted).
      keep: number of checkpoints (highest steps) to keep, >= 1. Older ones are
        deleted only after the new checkpoint is in place; the one just written
        is never deleted.

    Returns:
      The path of the new checkpoint directory.
    """
    if step < 0:
        raise ValueError(f"step must be >= 0, got {step}")
    if keep < 1:
        raise ValueError(f"keep must be >= 1, got {keep}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    final = directory / f"step_{step:010d}"

    leaves, treedef = jax.tree_util.tree_flatten(state)
    arrays: dict[str, Any] = {}  # Any: numpy stubs would match allow_pickle in **arrays
    leaf_meta = []
    for i, leaf in enumerate(leaves):
        key_impl = None
        if _is_key_array(leaf):
            key_impl = str(jax.random.key_impl(leaf))
            data = np.asarray(jax.random.key_data(leaf))
        elif isinstance(leaf, jax.Array | np.ndarray | np.generic):
            data = np.asarray(leaf)
        else:
            # Python scalars take JAX's default dtype, which is what restore returns.
            data = np.asarray(jnp.asarray(leaf))
        arrays[_leaf_name(i)] = data
        leaf_meta.append(
            {
                "shape": list(np.shape(leaf)),
                "dtype": str(leaf.dtype) if key_impl else str(data.dtype),
                "key_impl": key_impl,
            }
        )
    meta = {
        "format_version": FORMAT_VERSION,
        "step": step,
        "num_leaves": len(leaves),
        "leaves": leaf_meta,
        "treedef": _treedef_str(treedef),
        "metadata": dict(metadata or {}),
    }
    # Serialise before touching the disk so a bad metadata value fails cleanly.
    meta_text = json.dumps(meta, indent=1, default=_json_default, allow_nan=True)

    tmp = directory / f"{_TMP_PREFIX}{final.name}-{uuid.uuid4().hex}"
    tmp.mkdir()
    try:
        with open(tmp / STATE_FILE, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        with open(tmp / META_FILE, "w", encoding="utf-8") as f:
            f.write(meta_text)
            f.flush()
            os.fsync(f.fileno())
        _fsync_dir(tmp)
        if final.exists():
            # rename() cannot replace a non-empty directory: move the old one
            # aside first. A crash in between only loses this step to an older one.
            trash = directory / f"{_TRASH_PREFIX}{final.name}-{uuid.uuid4().hex}"
            os.replace(final, trash)
            os.replace(tmp, final)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(tmp, final)
        _fsync_dir(directory)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

    for old_step, old_path in _checkpoints(directory)[:-keep]:
        if old_step != step:
            shutil.rmtree(old_path, ignore_errors=True)
    # Leftovers of saves killed mid-write are never read; reclaim their space.
    for child in directory.iterdir():
        if child.name.startswith((_TMP_PREFIX, _TRASH_PREFIX)) and child.is_dir():
            shutil.rmtree(child, ignore_errors=True)
    return final


def latest(directory: str | os.PathLike[str]) -> Path | None:
    """Returns the complete checkpoint with the highest step, or None if there is none."""
    found = _checkpoints(Path(directory))
    return found[-1][1] if found else None


def step_of(path: str | os.PathLike[str]) -> int:
    """Returns the step a checkpoint was saved at (read from its meta.json)."""
    with open(Path(path) / META_FILE, encoding="utf-8") as f:
        return int(json.load(f)["step"])


def _template_shape_dtype(leaf: Any) -> tuple[tuple[int, ...], str]:
    if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
        return tuple(leaf.shape), str(leaf.dtype)
    arr = jnp.asarray(leaf)
    return tuple(arr.shape), str(arr.dtype)


def restore(
    path: str | os.PathLike[str], template: PyTree, check_treedef: bool = True
) -> tuple[PyTree, dict[str, Any]]:
    """Loads a checkpoint into the structure of `template`.

    Args:
      path: a checkpoint directory, e.g. `latest(directory)`.
      template: a pytree with the structure, shapes and dtypes of the saved
        state (e.g. a freshly initialised state, or `jax.eval_shape` of one).
      check_treedef: also compare the template's treedef string with the saved
        one. Turn off to load into a renamed but equally shaped class.

    Returns:
      `(state, metadata)`: the state as jax arrays in the template's structure,
      bit-exact, and the metadata dict given to `save`.

    Raises:
      ValueError: if the leaf count, a shape, a dtype or the structure differs.
    """
    path = Path(path)
    with open(path / META_FILE, encoding="utf-8") as f:
        meta = json.load(f)
    named, treedef = jax.tree_util.tree_flatten_with_path(template)
    if meta["num_leaves"] != len(named):
        raise ValueError(
            f"checkpoint {path} holds {meta['num_leaves']} leaves but the template has "
            f"{len(named)}.\n  saved structure:    {meta['treedef']}\n"
            f"  template structure: {_treedef_str(treedef)}"
        )
    if check_treedef and meta["treedef"] != _treedef_str(treedef):
        raise ValueError(
            f"checkpoint {path} was saved from a different pytree structure "
            f"(pass check_treedef=False if only class names changed).\n"
            f"  saved:    {meta['treedef']}\n  template: {_treedef_str(treedef)}"
        )
    errors = []
    for (key_path, leaf), saved in zip(named, meta["leaves"], strict=True):
        shape, dtype = _template_shape_dtype(leaf)
        if list(shape) != saved["shape"] or dtype != saved["dtype"]:
            errors.append(
                f"  leaf {jax.tree_util.keystr(key_path) or '<root>'}: template has "
                f"shape {shape} dtype {dtype}, checkpoint has shape "
                f"{tuple(saved['shape'])} dtype {saved['dtype']}"
            )
    if errors:
        raise ValueError(
            f"checkpoint {path} does not match the template ({len(errors)} leaves differ):\n"
            + "\n".join(errors)
        )

    leaves = []
    with np.load(path / STATE_FILE, allow_pickle=False) as npz:
        for i, saved in enumerate(meta["leaves"]):
            data = npz[_leaf_name(i)]
            if saved["key_impl"] is not None:
                leaves.append(jax.random.wrap_key_data(data, impl=saved["key_impl"]))
                continue
            dtype = jnp.dtype(saved["dtype"])
            if data.dtype != dtype:
                # Extension dtypes (bfloat16, float8) are stored as raw bytes.
                data = data.view(dtype)
            leaves.append(jnp.asarray(data))
    return jax.tree_util.tree_unflatten(treedef, leaves), meta["metadata"]
