"""Checkpoints written by qdrl 0.1.0 (before the algorithms became recipes) resume, bit for bit.

Each fixture is a tiny run of a packaged spec made by qdrl 0.1.0 (commit 71cd369): its
resolved spec, its first log point's metrics and checkpoint, and the final state
(`final_state.npz`) and summary (`expected.json`) that 0.1.0 reached from it
(tests/checkpoint_fixtures.py records them). Resumed by this qdrl, the run must end in the
same state (every array of the checkpoint) and summary.

Bit for bit holds where the record was computed (`made_with`: the jax of the 3.12 and 3.13
locks and the CPU's vector features, which decide how XLA rounds float arithmetic). On
another CPU with that jax the floats agree to rounding and everything else exactly; with
another jax (3.11's lock) the resumed run is checked for what does not depend on rounding:
every array of the state by name, shape and dtype, the counters and names of the summary.
"""

from __future__ import annotations

import json
import shutil
import zlib
from pathlib import Path

import jax
import numpy as np
import pytest
from checkpoint_fixtures import (
    FIXTURES,
    TIMED,
    clean,
    cpu_signature,
    resume,
    state_arrays,
)

from qdrl import __version__
from qdrl.config import ConfigError, load_toml
from qdrl.experiment import run

COUNTERS = ("env_steps", "evaluations", "grad_steps", "iteration", "generation", "log_point")


def layout(arrays: dict[str, np.ndarray]) -> dict[str, tuple[tuple[int, ...], str]]:
    return {name: (a.shape, str(a.dtype)) for name, a in arrays.items()}


# The default run resumes three of the five (a QD run, CMA-ES and SAC); QD-PG's and PBT's
# states (critics, buffers, a population) compile programs of their own: `-m slow`.
SLOW = ("qdpg_point_maze_cpu", "sac_pbt_halfcheetah_cpu")


@pytest.mark.parametrize(
    "name",
    [
        n if n not in SLOW else pytest.param(n, marks=pytest.mark.slow)
        for n in sorted(p.name for p in FIXTURES.iterdir() if p.is_dir())
    ],
)
def test_a_checkpoint_of_qdrl_0_1_0_resumes_bit_identically(name: str, tmp_path: Path) -> None:
    out, summary = resume(name, tmp_path)
    expected = json.loads((FIXTURES / name / "expected.json").read_text())
    with np.load(FIXTURES / name / "final_state.npz") as npz:
        reference = {k: npz[k] for k in npz.files}
    state = state_arrays(out / "checkpoints")
    got = clean({k: v for k, v in summary.items() if k not in TIMED})
    assert len((out / "metrics.csv").read_text().splitlines()) == 3  # header, 0.1.0's row, this one's
    assert layout(state) == layout(state_arrays(FIXTURES / name / "checkpoints")) == layout(reference)
    assert set(got) == set(expected["summary"])
    made_with = expected["made_with"]
    if jax.__version__ != made_with["jax"]:  # another jax rounds differently: what does not round
        for key, value in expected["summary"].items():
            if key in COUNTERS or isinstance(value, str | list):
                assert got[key] == value, key
    elif cpu_signature() == made_with["cpu"]:
        for key, value in reference.items():  # every array, bit for bit
            assert state[key].tobytes() == value.tobytes(), key
        assert got == expected["summary"]
    else:  # the same jax on other vector units: floats to rounding, the rest exactly
        for key, value in reference.items():
            if np.issubdtype(value.dtype, np.floating):
                np.testing.assert_allclose(state[key], value, rtol=1e-3, atol=1e-5, err_msg=key)
            else:
                np.testing.assert_array_equal(state[key], value, err_msg=key)
        for key, value in expected["summary"].items():
            if isinstance(value, float):
                assert got[key] == pytest.approx(value, rel=1e-3, abs=1e-5), key
            else:
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
