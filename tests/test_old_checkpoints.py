"""Checkpoints written by qdrl 0.1.0 (before the algorithms became recipes) resume, bit for bit.

Each fixture is a tiny run of a packaged spec made by qdrl 0.1.0 (commit 71cd369): its
resolved spec, its first log point's metrics and checkpoint, and the final state and
summary that 0.1.0 reached after the second log point (`expected.json`). Resumed by this
qdrl, the run must end in the same state (every array of the checkpoint) and summary.

That record holds for the jax it was made with (`made_with`, the 3.12 and 3.13 locks):
another jax (3.11's lock) rounds float arithmetic differently, so there the resumed run is
checked for what does not depend on rounding: every array of the state by name, shape and
dtype, the counters and names of the summary.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import zlib
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest

from qdrl import __version__
from qdrl.config import ConfigError, load_toml
from qdrl.experiment import run

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "checkpoints_0.1.0"
TIMED = ("wall_s", "compile_s", "startup_s", "run_s", "env_steps_per_s", "evaluations_per_s")


COUNTERS = ("env_steps", "evaluations", "grad_steps", "iteration", "generation", "log_point")


def state_layout(checkpoint_dir: Path) -> dict[str, tuple[tuple[int, ...], str]]:
    """Name -> (shape, dtype) of every array of the newest checkpoint."""
    newest = sorted(checkpoint_dir.glob("step_*"))[-1]
    with np.load(newest / "state.npz") as npz:
        return {name: (npz[name].shape, str(npz[name].dtype)) for name in npz.files}


def state_digest(checkpoint_dir: Path) -> str:
    """SHA-256 of every array of the newest checkpoint, by name (as the fixtures record it)."""
    newest = sorted(checkpoint_dir.glob("step_*"))[-1]
    digest = hashlib.sha256()
    with np.load(newest / "state.npz") as npz:
        for name in sorted(npz.files):
            digest.update(name.encode())
            digest.update(np.ascontiguousarray(npz[name]).tobytes())
    return digest.hexdigest()[:16]


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not np.isfinite(value):
        return repr(value)
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_clean(v) for v in value]
    return value


def _resume(name: str, tmp_path: Path) -> tuple[Path, dict[str, Any]]:
    out = tmp_path / name
    shutil.copytree(FIXTURES / name, out)
    summary = run(load_toml(out / "config.toml"), out, resume=True)
    return out, summary


# The default run resumes three of the five (a QD run, CMA-ES and SAC); QD-PG's and PBT's
# states (critics, buffers, a population) compile programs of their own: `-m slow`.
SLOW = ("qdpg_point_maze_cpu", "sac_pbt_halfcheetah_cpu")


@pytest.mark.parametrize(
    "name",
    [n if n not in SLOW else pytest.param(n, marks=pytest.mark.slow) for n in sorted(p.name for p in FIXTURES.iterdir())],
)
def test_a_checkpoint_of_qdrl_0_1_0_resumes_bit_identically(name: str, tmp_path: Path) -> None:
    layout = state_layout(FIXTURES / name / "checkpoints")
    out, summary = _resume(name, tmp_path)
    expected = json.loads((FIXTURES / name / "expected.json").read_text())
    got = _clean({k: v for k, v in summary.items() if k not in TIMED})
    assert len((out / "metrics.csv").read_text().splitlines()) == 3  # header, 0.1.0's row, this one's
    assert state_layout(out / "checkpoints") == layout
    if jax.__version__ == expected["made_with"]["jax"]:
        assert state_digest(out / "checkpoints") == expected["state"]
        assert got == expected["summary"]
    else:
        assert set(got) == set(expected["summary"])
        for key, value in expected["summary"].items():
            if key in COUNTERS or isinstance(value, str | list):
                assert got[key] == value, key


def test_a_checkpoint_of_another_layout_fails_in_one_line_naming_its_version(tmp_path: Path) -> None:
    out = tmp_path / "arm"
    shutil.copytree(FIXTURES / "map_elites_arm", out)
    (meta_path,) = out.glob("checkpoints/step_*/meta.json")
    meta = json.loads(meta_path.read_text())
    meta["treedef"] = meta["treedef"].replace("QDState", "OldState")  # a state class since renamed
    meta_path.write_text(json.dumps(meta))
    manifest = meta_path.with_name("manifest.json")  # keep the manifest consistent with the edit
    record = json.loads(manifest.read_text())
    record["files"]["meta.json"] = {"size": meta_path.stat().st_size, "crc32": zlib.crc32(meta_path.read_bytes())}
    manifest.write_text(json.dumps(record))
    with pytest.raises(ConfigError) as info:
        run(load_toml(out / "config.toml"), out, resume=True)
    message = str(info.value)
    assert "\n" not in message and message.startswith("--resume: no usable checkpoint in ")
    assert message.endswith(f"the checkpoints were written by qdrl 0.1.0, this is qdrl {__version__}")
