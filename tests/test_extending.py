"""Adding an algorithm from outside the package: docs/extending.md's emitter and its row, run
through `qdrl run` with a checkpoint and `--resume`, and refused values named before compiling."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from qdrl import algorithms
from qdrl.cli import main
from qdrl.config import ConfigError
from qdrl.experiment import check_spec

ROOT = Path(__file__).resolve().parents[1]
PAGE = (ROOT / "docs" / "extending.md").read_text()
(CODE,) = [c for c in re.findall(r"```python\n(.*?)```", PAGE, flags=re.S) if "GaussEmitter" in c]
(SPEC,) = [c for c in re.findall(r"```toml\n(.*?)```", PAGE, flags=re.S) if "gauss_me" in c]


@pytest.fixture(scope="module")
def gauss_me() -> Iterator[dict[str, Any]]:
    """The page's code executed: `gauss_me` is in the table while the tests run."""
    namespace: dict[str, Any] = {"__name__": "gauss_me_example"}
    # As a user's module reads it: no `from __future__ import annotations` of this file.
    exec(compile(CODE, "docs/extending.md", "exec", dont_inherit=True), namespace)
    try:
        yield namespace
    finally:
        algorithms.ALGORITHMS.pop("gauss_me", None)


def test_the_row_is_in_the_table_and_its_section_is_checked(gauss_me: dict[str, Any]) -> None:
    assert "gauss_me" in algorithms.algorithm_names()
    with pytest.raises(ValueError, match="already in the table"):
        algorithms.register("gauss_me", algorithms.ALGORITHMS["gauss_me"])
    spec = {"experiment": {"algorithm": "gauss_me"}, "task": {"name": "arm"}, "gauss": {"sigma": -1.0}}
    with pytest.raises(ConfigError, match=r"^gauss\.sigma: expected a number > 0, got -1\.0$"):
        check_spec(spec)
    with pytest.raises(ConfigError, match=r"^gauss\.sigmaa: unknown key; did you mean 'sigma'\?; expected one of \['batch_size', 'sigma'\]$"):
        check_spec({**spec, "gauss": {"sigmaa": 1.0}})
    with pytest.raises(ConfigError, match=r"^gausss: unknown section for algorithm 'gauss_me'"):
        check_spec({**spec, "gauss": {}, "gausss": {}})


def test_the_new_algorithm_runs_checkpoints_and_resumes_through_qdrl_run(
    gauss_me: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = tmp_path / "gauss.toml"
    spec.write_text(SPEC.replace("num_iterations = 100", "num_iterations = 8").replace("log_every = 50", "log_every = 4"))
    out = tmp_path / "out"
    assert main(["run", str(spec), "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["algorithm"] == "gauss_me" and summary["iteration"] == 8
    assert summary["evaluations"] == 32 + 8 * 32 and summary["coverage"] > 0.05
    checkpoints = sorted((out / "checkpoints").glob("step_*"))
    assert len(checkpoints) == 2
    shutil.rmtree(checkpoints[-1])  # as if killed after the first log point
    assert main(["run", str(spec), "--out", str(out), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out)
    for key in ("qd_score", "coverage", "max_fitness", "evaluations", "num_elites"):
        assert resumed[key] == summary[key], key
    assert (out / "repertoire.npz").is_file() and (out / "plots" / "repertoire.png").is_file()
