"""The Python code blocks of docs/getting-started.md, run as written (`pytest -m notebooks`,
beside the notebooks: the SAC block trains for a minute, too long for the default run).

The runs the last block loads are made first, tiny, under the names it uses."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "getting-started.md"
BLOCKS = re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S)
TINY_QD = ["qd.num_iterations=4", "qd.log_every=2", "log.plots=false", "log.progress=false"]


def test_the_page_has_its_three_blocks() -> None:
    assert len(BLOCKS) == 3
    assert "MapElites(score" in BLOCKS[0] and "make_sac" in BLOCKS[1] and "qdrl.load_run" in BLOCKS[2]


@pytest.mark.notebooks
@pytest.mark.parametrize("index", [0, 1], ids=["map_elites_function", "sac"])
def test_a_block_runs_as_written(index: int) -> None:
    namespace: dict[str, object] = {}
    exec(compile(BLOCKS[index], f"{PAGE.name}[{index}]", "exec"), namespace)
    assert "state" in namespace


@pytest.mark.notebooks
def test_the_loading_block_runs_on_the_runs_it_names(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from qdrl.experiment import run_spec
    from qdrl.sweeps import run_seeds

    monkeypatch.chdir(tmp_path)
    for name in ("map_elites_arm", "cvt_map_elites_arm"):
        extra = ["repertoire.num_centroids=32", "repertoire.cvt_samples=500"] if name.startswith("cvt") else []
        run_seeds(name, [0, 1], [*TINY_QD, "emitter.batch_size=32", *extra], Path("runs") / name)
    run_spec("map_elites_point_maze_cpu", [
        *TINY_QD, "task.episode_length=10", "task.policy_hidden=[8]", "emitter.batch_size=8",
        "qd.init_batch_size=8", "repertoire.num_centroids=16", "repertoire.cvt_samples=200",
    ], Path("runs") / "map_elites_point_maze_cpu")
    namespace: dict[str, object] = {}
    exec(compile(BLOCKS[2], f"{PAGE.name}[2]", "exec"), namespace)
    assert len(namespace["metrics"]) == 2 * 2 * 2  # type: ignore[arg-type]  # 2 specs x 2 seeds x 2 log points
