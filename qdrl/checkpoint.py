"""Atomic save and verified, bit-exact restore of any pytree (training state, repertoire, keys).

Layout of a checkpoint directory::

    directory/
      step_0000000001/
        state.npz      leaves of the flattened pytree, named leaf_00000, leaf_00001, ...
        meta.json      user metadata, step, leaf count, each leaf's shape and dtype,
                       the treedef as a string
        manifest.json  size and CRC-32 of the two files above; written last
      step_0000000002/
      .tmp-...         a save in progress (or killed mid-write); never read

`step` is any counter that grows with each save (the experiment driver uses the
number of log points done). A save writes its files into a temporary directory,
fsyncs them, writes the manifest, fsyncs it, renames the directory into place,
fsyncs the parent, and only then prunes checkpoints beyond `keep`. So at every
instant (SIGKILL included) the checkpoints that were complete before the save
stay complete until a newer one is durable. `restore` checks a checkpoint
against its manifest before loading it; `restore_newest` falls back past
checkpoints that fail (truncated, overwritten or deleted files) to the newest
one that loads.

Only one process should save into a given directory at a time.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import uuid
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.types import PyTree

__all__ = [
    "CheckpointError",
    "checkpoints",
    "latest",
    "read_metadata",
    "remove",
    "restore",
    "restore_newest",
    "save",
    "state_digest",
    "step_of",
    "verify",
]

STATE_FILE = "state.npz"
META_FILE = "meta.json"
MANIFEST_FILE = "manifest.json"
FORMAT_VERSION = 2
_STEP_DIR = re.compile(r"^step_(\d{10,})$")
_TMP_PREFIX = ".tmp-"
_TRASH_PREFIX = ".trash-"
_CHUNK = 1 << 23


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: a file missing, truncated or corrupt."""


def _crash_point(phase: str) -> None:
    """Called between the steps of `save` (a seam for tests that kill a save there)."""


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


def _crc32(path: Path) -> int:
    crc = 0
    with open(path, "rb") as f:
        while block := f.read(_CHUNK):
            crc = zlib.crc32(block, crc)
    return crc


def _json_default(obj: Any) -> Any:
    # numpy / jax scalars and paths are common in experiment metadata.
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray | jax.Array) and np.ndim(obj) == 0:
        return np.asarray(obj).item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"metadata value {obj!r} of type {type(obj).__name__} is not JSON serialisable")


def checkpoints(directory: str | os.PathLike[str]) -> list[Path]:
    """Every `step_*` directory in `directory`, complete or not, newest (highest step) first."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = []
    for child in directory.iterdir():
        m = _STEP_DIR.match(child.name)
        if m and child.is_dir():
            found.append((int(m.group(1)), child))
    return [path for _, path in sorted(found, reverse=True)]


def _complete(path: Path) -> bool:
    return all((path / name).is_file() for name in (STATE_FILE, META_FILE, MANIFEST_FILE))


def remove(path: str | os.PathLike[str]) -> None:
    """Deletes a checkpoint: renamed out of the `step_*` namespace first, so never seen half-deleted."""
    path = Path(path)
    trash = path.parent / f"{_TRASH_PREFIX}{path.name}-{uuid.uuid4().hex}"
    os.replace(path, trash)
    shutil.rmtree(trash, ignore_errors=True)


def _write_synced(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def step_name(step: int) -> str:
    """The directory name of checkpoint `step`."""
    return f"step_{step:010d}"


def save(
    directory: str | os.PathLike[str],
    step: int,
    state: PyTree,
    metadata: Mapping[str, Any] | None = None,
    keep: int = 2,
) -> Path:
    """Atomically writes `state` as checkpoint `step`, then prunes old checkpoints.

    Args:
      directory: parent directory of all checkpoints of a run (created if needed).
      step: non-negative counter that grows with each save; names the checkpoint
        `step_{step:010d}`. Saving a step that already exists replaces it.
      state: any pytree of arrays (jax, numpy, Python scalars). Typed PRNG key
        arrays are stored as their `jax.random.key_data` and rewrapped on restore.
      metadata: JSON-serialisable mapping (numpy scalars and paths are converted).
      keep: number of checkpoints (highest steps) to keep, >= 1. Older ones are
        deleted only once the new checkpoint is durable in place; the one just
        written is never deleted.

    Returns:
      The path of the new checkpoint directory.
    """
    if step < 0:
        raise ValueError(f"step must be >= 0, got {step}")
    if keep < 1:
        raise ValueError(f"keep must be >= 1, got {keep}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    final = directory / step_name(step)

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
    meta_bytes = json.dumps(meta, indent=1, default=_json_default, allow_nan=True).encode()

    tmp = directory / f"{_TMP_PREFIX}{final.name}-{uuid.uuid4().hex}"
    tmp.mkdir()
    try:
        with open(tmp / STATE_FILE, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        _write_synced(tmp / META_FILE, meta_bytes)
        _crash_point("files_written")
        manifest = {
            "format_version": FORMAT_VERSION,
            "files": {
                STATE_FILE: {"size": (tmp / STATE_FILE).stat().st_size, "crc32": _crc32(tmp / STATE_FILE)},
                META_FILE: {"size": len(meta_bytes), "crc32": zlib.crc32(meta_bytes)},
            },
        }
        _write_synced(tmp / MANIFEST_FILE, json.dumps(manifest, indent=1).encode())
        _fsync_dir(tmp)
        _crash_point("manifest_written")
        if final.exists():
            # rename() cannot replace a non-empty directory: move the old one aside
            # first. Older checkpoints stay complete meanwhile.
            trash = directory / f"{_TRASH_PREFIX}{final.name}-{uuid.uuid4().hex}"
            os.replace(final, trash)
            _crash_point("moved_aside")
        os.replace(tmp, final)
        _fsync_dir(directory)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _crash_point("renamed")

    # Keep the `keep` newest complete checkpoints; a step directory with a file
    # missing is no checkpoint and does not count.
    for old in [p for p in checkpoints(directory) if _complete(p)][keep:]:
        if old != final:
            remove(old)
    _crash_point("pruned")
    # Leftovers of saves killed mid-write are never read; reclaim their space.
    for child in directory.iterdir():
        if child.name.startswith((_TMP_PREFIX, _TRASH_PREFIX)) and child.is_dir():
            shutil.rmtree(child, ignore_errors=True)
    return final


def state_digest(arrays: Mapping[str, Any]) -> str:
    """16 hex digits of the SHA-256 of a checkpoint's arrays (`state.npz`'s, by name): equal
    digests, bit-identical states (regression records, old-checkpoint fixtures)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(arrays[name]).tobytes())
    return digest.hexdigest()[:16]


def latest(directory: str | os.PathLike[str]) -> Path | None:
    """The checkpoint with the highest step whose three files exist (not verified), or None."""
    for path in checkpoints(directory):
        if _complete(path):
            return path
    return None


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_bytes())
    except FileNotFoundError:
        raise CheckpointError(f"{path.name} is missing") from None
    except (OSError, ValueError) as e:
        raise CheckpointError(f"{path.name} is unreadable ({type(e).__name__}: {e})") from e


def verify(path: str | os.PathLike[str]) -> None:
    """Raises CheckpointError (naming the file and what is wrong) unless the files match the manifest."""
    path = Path(path)
    if not (path / MANIFEST_FILE).exists():
        version = None
        with contextlib.suppress(CheckpointError, AttributeError):
            version = _read_json(path / META_FILE).get("format_version")
        if version is not None and version != FORMAT_VERSION:
            raise CheckpointError(
                f"written in checkpoint format {version} by an older qdrl (no {MANIFEST_FILE}); "
                "resume it with that version"
            )
    manifest = _read_json(path / MANIFEST_FILE)
    files = manifest.get("files") if isinstance(manifest, dict) else None
    if not isinstance(files, dict) or set(files) != {STATE_FILE, META_FILE}:
        raise CheckpointError(f"{MANIFEST_FILE} is not a qdrl manifest")
    for name, expected in files.items():
        file = path / name
        if not file.is_file():
            raise CheckpointError(f"{name} is missing")
        size = file.stat().st_size
        if size != expected["size"]:
            raise CheckpointError(f"{name} has {size} bytes, the manifest says {expected['size']}")
        if _crc32(file) != expected["crc32"]:
            raise CheckpointError(f"{name} does not match its CRC-32 in the manifest")


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The metadata dict given to `save` (read from meta.json, not verified)."""
    return dict(_read_json(Path(path) / META_FILE)["metadata"])


def step_of(path: str | os.PathLike[str]) -> int:
    """Returns the step a checkpoint was saved at (read from its meta.json)."""
    return int(_read_json(Path(path) / META_FILE)["step"])


def _template_shape_dtype(leaf: Any) -> tuple[tuple[int, ...], str]:
    if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
        return tuple(leaf.shape), str(leaf.dtype)
    arr = jnp.asarray(leaf)
    return tuple(arr.shape), str(arr.dtype)


def restore(
    path: str | os.PathLike[str], template: PyTree, check_treedef: bool = True
) -> tuple[PyTree, dict[str, Any]]:
    """Verifies a checkpoint against its manifest and loads it into the structure of `template`.

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
      CheckpointError: if a file is missing or does not match the manifest.
      ValueError: if the leaf count, a shape, a dtype or the structure differs.
    """
    path = Path(path)
    verify(path)
    meta = _read_json(path / META_FILE)
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{META_FILE} has format version {meta.get('format_version')}, expected {FORMAT_VERSION}"
        )
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
    try:
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
                leaves.append(jax.device_put(data))  # jnp.asarray compiles a program per shape
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise CheckpointError(f"{STATE_FILE} is unreadable ({type(e).__name__}: {e})") from e
    return jax.tree_util.tree_unflatten(treedef, leaves), meta["metadata"]


def restore_newest(
    directory: str | os.PathLike[str], template: PyTree
) -> tuple[PyTree, dict[str, Any], Path, list[tuple[Path, str]]]:
    """The newest checkpoint in `directory` that verifies and loads into `template`.

    Returns:
      `(state, metadata, path, skipped)`: `skipped` lists each newer checkpoint
      that failed, with the reason.

    Raises:
      CheckpointError: naming each checkpoint and why it failed, when none loads
        (or there is none).
    """
    skipped: list[tuple[Path, str]] = []
    for path in checkpoints(directory):
        try:
            state, metadata = restore(path, template)
        except ValueError as e:  # CheckpointError included
            skipped.append((path, str(e).splitlines()[0]))
            continue
        return state, metadata, path, skipped
    if not skipped:
        raise CheckpointError(f"no checkpoint in {directory}")
    reasons = "; ".join(f"{p.name}: {why}" for p, why in skipped)
    raise CheckpointError(f"no usable checkpoint in {directory} ({reasons})")
