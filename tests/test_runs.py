"""Runs you can load, replay and re-score: `qdrl.load_run`, `qdrl render`, `qdrl reevaluate`."""

from __future__ import annotations

import base64
import json
import re
import shutil
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import qdrl
from qdrl.cli import main
from qdrl.experiment import run_spec
from qdrl.render import write_html, write_path_png
from qdrl.runs import LoadedRun, RunError, Trajectory, load_run

POINT_MAZE = """
[experiment]
algorithm = "map_elites"
seed = 2

[task]
name = "point_maze"
episode_length = 20
policy_hidden = [8]

[repertoire]
grid_shape = [5, 5]

[emitter]
batch_size = 8

[qd]
num_iterations = 4
log_every = 2
init_batch_size = 8
reevaluate_samples = 4

[log]
progress = false
plots = false
"""

HALFCHEETAH = """
[experiment]
algorithm = "map_elites"
seed = 0

[task]
name = "halfcheetah_uni"
episode_length = 10
policy_hidden = [8]

[repertoire]
kind = "cvt"
num_centroids = 16
cvt_samples = 500

[emitter]
batch_size = 4
iso_sigma = 0.05
line_sigma = 0.1

[qd]
num_iterations = 2
log_every = 2
init_batch_size = 4

[log]
progress = false
plots = false
"""

SAC = """
[experiment]
algorithm = "sac"

[env]
name = "point"
episode_length = 20

[agent]
hidden = [8, 8]

[train]
total_env_steps = 200
num_envs = 4
batch_size = 16
buffer_size = 400
learning_starts = 40
eval_every = 200
num_eval_envs = 4

[log]
progress = false
plots = false
"""


def _run(tmp: Path, spec: str, name: str) -> Path:
    path = tmp / f"{name}.toml"
    path.write_text(spec)
    run_spec(path, [], tmp / name)
    return tmp / name


@pytest.fixture(scope="module")
def maze_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _run(tmp_path_factory.mktemp("maze"), POINT_MAZE, "run")


@pytest.fixture(scope="module")
def maze(maze_dir: Path) -> LoadedRun:
    return qdrl.load_run(maze_dir)


def test_a_finished_qd_run_loads(maze: LoadedRun, maze_dir: Path) -> None:
    assert maze.finished and maze.algorithm == "map_elites" and maze.task_name == "point_maze"
    assert maze.config["task"]["eval_batch"] == 8 and maze.config["qd"]["reevaluate_samples"] == 4
    assert list(maze.metrics["iteration"]) == [2, 4]
    assert maze.summary is not None and maze.summary["num_elites"] == len(maze.table)
    table = maze.table
    pd.testing.assert_frame_equal(table, pd.read_csv(maze_dir / "repertoire.csv"), check_dtype=False)
    best = maze.best()
    assert best.fitness == table["fitness"].max() == maze.summary["max_fitness"]
    assert set(best.genotype) == {"policy/~/linear_0", "policy/~/linear_1"}  # haiku params
    assert best.genotype["policy/~/linear_0"]["w"].shape == (2, 8)


def test_rollout_returns_the_stored_fitness_bit_for_bit(maze: LoadedRun) -> None:
    for cell in maze.table["cell"]:
        elite = maze.elite(int(cell))
        episode = maze.rollout(elite)
        assert episode.return_ == elite.fitness  # exact
        np.testing.assert_array_equal(episode.descriptor, elite.descriptor)
        assert episode.observations.shape == (20, 2) and episode.actions.shape == (20, 2)
        assert episode.state_descriptors.shape == (21, 2) and episode.states is None
        # The maze's descriptor is where the point ends; the return sums the rewards.
        np.testing.assert_array_equal(episode.state_descriptors[episode.length], elite.descriptor)
        assert np.sum(episode.rewards * episode.mask) == pytest.approx(elite.fitness, rel=1e-6)


def test_rollout_records_what_it_is_asked_to(maze: LoadedRun) -> None:
    elite = maze.best()
    episode = maze.rollout(elite, record=lambda state: state.obs)  # the batch's observations
    assert episode.return_ == elite.fitness
    np.testing.assert_array_equal(episode.states[: episode.length], episode.state_descriptors[1 : episode.length + 1])


def test_end_of_run_reevaluation_matches_the_command(
    maze: LoadedRun, maze_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    stored = json.loads((maze_dir / "reevaluation.json").read_text())
    assert maze.summary is not None
    assert maze.summary["corrected_qd_score"] == stored["corrected"]["qd_score"]
    assert maze.summary["reevaluate_samples"] == 4 == stored["samples"]
    assert stored["stored"]["qd_score"] == pytest.approx(maze.summary["qd_score"], rel=1e-6)
    # Random start states: the lucky first evaluations do not all hold up.
    assert stored["corrected"]["qd_score"] < stored["stored"]["qd_score"]
    assert main(["reevaluate", str(maze_dir), "--samples", "4"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["corrected"] == stored["corrected"] and again["seed"] == 2
    assert main(["reevaluate", str(maze_dir), "--samples", "4", "--seed", "7"]) == 0
    assert json.loads(capsys.readouterr().out)["corrected"] != stored["corrected"]


def test_render_writes_the_path_over_the_walls(
    maze: LoadedRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cell = int(maze.table["cell"].iloc[0])
    out = tmp_path / "path.png"
    assert main(["render", str(maze.path), "--cell", str(cell), "--out", str(out)]) == 0
    said = json.loads(capsys.readouterr().out)
    assert said["cell"] == cell and said["return"] == said["fitness"] == maze.elite(cell).fitness
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


def test_an_interrupted_run_loads_from_its_checkpoint(maze_dir: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut"
    shutil.copytree(maze_dir, cut)
    for name in ("repertoire.npz", "repertoire.csv", "summary.json"):
        (cut / name).unlink()
    run = load_run(cut)
    assert not run.finished and run.summary is None
    finished = load_run(maze_dir).repertoire
    np.testing.assert_array_equal(run.repertoire.fitnesses, finished.fitnesses)
    np.testing.assert_array_equal(
        run.repertoire.genotypes["policy/~/linear_1"]["w"], finished.genotypes["policy/~/linear_1"]["w"]
    )


def _error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("qdrl: error: ") and "\n" not in err, err
    return err


def test_bad_directories_and_cells_get_one_line_errors(
    maze_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "nowhere"
    assert "no such directory" in _error(["render", str(missing)], capsys)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("not a run")
    assert "holds no run: expected a directory written by `qdrl run`" in _error(["reevaluate", str(foreign), "--samples", "2"], capsys)
    partial = tmp_path / "partial"
    partial.mkdir()
    shutil.copy(maze_dir / "config.toml", partial)
    assert "holds no repertoire yet" in _error(["render", str(partial)], capsys)
    table = pd.read_csv(maze_dir / "repertoire.csv")
    empty = sorted(set(range(25)) - set(table["cell"]))[0]
    assert f"cell {empty} holds no elite" in _error(["render", str(maze_dir), "--cell", str(empty)], capsys)
    assert "expected a cell in [0, 25)" in _error(["render", str(maze_dir), "--cell", "25"], capsys)
    assert "expected a file ending with .png" in _error(
        ["render", str(maze_dir), "--out", str(tmp_path / "x.html")], capsys
    )
    assert "--samples: expected a positive integer" in _error(
        ["reevaluate", str(maze_dir), "--samples", "0"], capsys
    )


def test_an_rl_run_loads_without_genotypes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = _run(tmp_path, SAC, "sac")
    run = load_run(out)
    assert run.finished and run.algorithm == "sac" and run.task_name == "point"
    assert len(run.metrics) == 1 and run.metrics["env_steps"].iloc[0] == 200
    assert len(run.table) == run.summary["num_elites"] >= 1  # type: ignore[index]
    # archive.npz (the whole passive archive) gives the same table as the checkpoint.
    assert (out / "archive.csv").is_file() and (out / "archive.npz").is_file()
    from_checkpoint = load_run(out)
    from_checkpoint._repertoire = from_checkpoint._from_checkpoint()
    assert from_checkpoint.table.equals(run.table)
    best = run.best()
    assert best.fitness == run.table["fitness"].max()
    with pytest.raises(RunError, match="passive archive stores no genotypes"):
        _ = best.genotype
    with pytest.raises(RunError, match="expected a QD run"):
        run.rollout(best)
    # its agent replays (tests/test_skills_run.py), but not on this environment
    assert "render: expected a run of a brax task or point_maze, got task 'point'" in _error(["render", str(out)], capsys)


def _fake_episode(num_links: int, length: int) -> Trajectory:
    """An episode whose torso walks along x: link poses (brax `Transform`) and x-y path."""
    from brax.base import Transform

    steps = np.arange(length, dtype=np.float32)
    pos = np.zeros((length, num_links, 3), np.float32)
    pos[:, :, 0] = steps[:, None] * 0.5
    rot = np.tile(np.asarray([1.0, 0.0, 0.0, 0.0], np.float32), (length, num_links, 1))
    xy = np.stack([np.arange(length + 1) * 0.5, np.zeros(length + 1)], axis=1)
    return Trajectory(
        observations=np.zeros((length, 1)), actions=np.zeros((length, 1)), rewards=np.zeros(length),
        state_descriptors=xy, mask=np.ones(length), length=length, return_=0.0,
        descriptor=xy[-1], states=Transform(pos=pos, rot=rot),
    )


def test_html_replay_holds_every_frame(tmp_path: Path) -> None:
    from qdrl.envs.brax import BraxEnv

    env = BraxEnv("halfcheetah", "spring", episode_length=12)
    out = write_html(env.brax_env.sys, _fake_episode(len(env.brax_env.sys.link_names), 12), tmp_path / "r.html")
    page = out.read_text()
    # brax's viewer page embeds the system and the trajectory as zlib-compressed JSON.
    blob = max(re.findall(r"[A-Za-z0-9+/=]{200,}", page), key=len)
    scene = json.loads(zlib.decompress(base64.b64decode(blob)))
    assert len(scene["states"]["x"]) == 12
    assert scene["states"]["x"][11]["pos"][0] == [5.5, 0.0, 0.0]


def test_ant_maze_path_is_drawn_over_its_walls(tmp_path: Path) -> None:
    from qdrl.envs.brax_walls import MAZE_TARGET, MAZE_WALLS

    walls = [(w.start, w.end, w.radius) for w in MAZE_WALLS]
    out = write_path_png(
        _fake_episode(9, 40), tmp_path / "maze.png", walls, (-5.0, -5.0), (40.0, 40.0),
        goal=MAZE_TARGET, goal_half_width=0.5, title="ant maze",
    )
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


@pytest.fixture(scope="module")
def cheetah(tmp_path_factory: pytest.TempPathFactory) -> LoadedRun:
    return load_run(_run(tmp_path_factory.mktemp("cheetah"), HALFCHEETAH, "run"))


@pytest.mark.slow
def test_halfcheetah_rollout_is_bit_exact_and_renders_html(
    cheetah: LoadedRun, capsys: pytest.CaptureFixture[str]
) -> None:
    # Chaotic contacts: any other computation than the run's moves the return.
    for cell in cheetah.table["cell"]:
        elite = cheetah.elite(int(cell))
        episode = cheetah.rollout(elite)
        assert episode.return_ == elite.fitness
        np.testing.assert_array_equal(episode.descriptor, elite.descriptor)
        assert episode.states.pos.shape == (10, 7, 3)  # link poses: 7 links of halfcheetah
    assert main(["render", str(cheetah.path)]) == 0
    said = json.loads(capsys.readouterr().out)
    assert said["return"] == cheetah.best().fitness and said["out"].endswith(".html")
    page = Path(said["out"]).read_text()
    # brax's viewer page embeds the system and the trajectory as zlib-compressed JSON.
    blob = max(re.findall(r"[A-Za-z0-9+/=]{200,}", page), key=len)
    scene = json.loads(zlib.decompress(base64.b64decode(blob)))
    assert len(scene["states"]["x"]) == 10
