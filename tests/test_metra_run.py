"""`qdrl run` for METRA and LSD: tiny runs with continuous and discrete skills, the coverage metric,
specs, bad configs, exact resume, a loaded run's skills; and METRA spreading its skills."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from stopped_runs import assert_resumed_as_uninterrupted, stopped_copy

from qdrl import specs
from qdrl.config import ConfigError, load_toml
from qdrl.experiment import build_run, run
from qdrl.runs import load_run

ROOT = Path(__file__).resolve().parents[1]
SPECS = [*sorted((ROOT / "agents").glob("metra_*.toml")), *sorted((ROOT / "agents").glob("lsd_*.toml")),
         *sorted((ROOT / "agents" / "metra_baselines").glob("*.toml"))]


def tiny_spec(algorithm: str, **skills: Any) -> dict[str, Any]:
    return {
        "experiment": {"algorithm": algorithm, "seed": 0},
        "env": {"task": "point_maze", "episode_length": 20},
        "agent": {"hidden": [16, 16]},
        "train": {"total_env_steps": 640, "num_envs": 4, "batch_size": 32, "buffer_size": 1000,
                  "learning_starts": 80, "grad_steps_per_iter": 2, "eval_every": 320, "num_eval_envs": 8},
        "skills": {"num_skills": 2, "hidden": [16, 16], "model_input": "descriptor", **skills},
        "archive": {"grid_shape": [8, 8]},
        "log": {"progress": False},
    }


@pytest.mark.parametrize(
    ("algorithm", "skills"),
    [("metra", {}), ("lsd", {}), ("metra", {"discrete": True, "num_skills": 4})],
    ids=["metra", "lsd", "metra_discrete"],
)
def test_tiny_run_logs_coverage_and_its_representation(tmp_path: Path, algorithm: str, skills: dict[str, Any]) -> None:
    summary = run(tiny_spec(algorithm, **skills), tmp_path)
    assert summary["env_steps"] == 640
    assert 1 <= summary["cells_visited"] <= 4  # the point maze's [-1, 1]^2 spans 4 unit cells
    assert np.isfinite(summary["representation_loss"]) and np.isfinite(summary["phi_delta_dot_z"])
    assert ("dual_lambda" in summary) == (algorithm == "metra")
    episodes = pd.read_csv(tmp_path / "skills.csv")
    k = 4 if skills else 8  # continuous skills: one direction per evaluation episode
    assert sorted(set(episodes.skill)) == list(range(k))
    assert (tmp_path / "plots" / "skills.png").stat().st_size > 1000


def test_a_loaded_continuous_run_plays_its_evaluation_directions(tmp_path: Path) -> None:
    spec = tiny_spec("metra")
    spec["log"]["plots"] = False
    run(spec, tmp_path)
    loaded = load_run(tmp_path)
    assert loaded.num_skills == 8  # 8 directions evenly spread on the circle
    last = pd.read_csv(tmp_path / "skills.csv").query("log_point == 1").set_index("episode")
    for z in (0, 3):
        episode = loaded.rollout(skill=z)
        assert episode.return_ == last.loc[z, "return"]
        action = loaded.policy(skill=z)(episode.observations[:1])
        np.testing.assert_allclose(action, episode.actions[:1], rtol=1e-6, atol=1e-6)


def test_a_metra_run_resumed_after_its_first_checkpoint_matches_an_uninterrupted_one(tmp_path: Path) -> None:
    spec = tiny_spec("metra")
    spec["log"]["plots"] = False
    full = run(spec, tmp_path / "full")
    stopped_copy(tmp_path / "full", tmp_path / "stopped", episodes_per_log_point=8)
    resumed = run(spec, tmp_path / "stopped", resume=True)
    assert_resumed_as_uninterrupted(
        full, resumed, tmp_path / "full", tmp_path / "stopped", {"cells_visited", "dual_lambda", "representation_loss"}
    )


@pytest.mark.parametrize(
    ("algorithm", "key", "value", "message"),
    [
        ("metra", "dual_slack", -1.0, "skills.dual_slack"),
        ("metra", "lsd", True, "skills.lsd: expected false for metra"),
        ("metra", "num_skills", 0, "skills.num_skills"),
        ("lsd", "learning_rate", 0.0, "skills.learning_rate"),
    ],
)
def test_bad_config_names_the_key(algorithm: str, key: str, value: object, message: str) -> None:
    spec = tiny_spec(algorithm)
    spec["skills"][key] = value
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        build_run(spec)


def test_every_spec_builds_and_the_suite_names_them() -> None:
    assert {p.stem for p in SPECS} == {
        f"{a}_{t}{s}" for a in ("metra", "lsd") for t in ("ant_omni", "halfcheetah_omni") for s in ("", "_cpu")
    } | {"diayn_ant_omni", "dads_ant_omni"}
    for path in SPECS:
        spec = load_toml(path)
        spec.setdefault("archive", {}).update(num_centroids=8, cvt_samples=100)  # not the packaged archive's k-means
        run_, _, _ = build_run(spec)
        assert run_.task in ("ant_omni", "halfcheetah_omni") and spec["env"]["episode_length"] == 200
        # METRA's settings: 2-D unit vectors on the ant, 16 discrete skills on the cheetah
        if spec["experiment"]["algorithm"] in ("metra", "lsd"):
            cheetah = run_.task == "halfcheetah_omni"
            assert (spec["skills"]["num_skills"], spec["skills"]["discrete"]) == ((16, True) if cheetah else (2, False))
    assert specs.resolve("metra_baselines/dads_ant_omni").is_file()
    # each comparison's runs share SAC's settings and their length
    for task in ("ant_omni", "halfcheetah_omni"):
        cpu = [load_toml(p) for p in SPECS if (p.stem.endswith("_cpu") or p.parent.name == "metra_baselines")
               and task in p.stem]
        assert len(cpu) >= 2 and len({str((s["agent"], s["train"])) for s in cpu}) == 1


@pytest.mark.slow
@pytest.mark.parametrize("name", [p.stem for p in SPECS if p.stem.endswith("_cpu")])
def test_every_cpu_spec_runs_a_tiny_version(tmp_path: Path, name: str) -> None:
    """Each 2-core spec, shrunk (20-step episodes, 2 log points), runs on its brax task and counts
    the cells its skills visit: 1x1 x-y cells on the ant, 1-wide x bins on the cheetah."""
    spec = load_toml(ROOT / "agents" / f"{name}.toml")
    spec["env"]["episode_length"] = 20
    spec["train"].update(total_env_steps=320, num_envs=4, batch_size=16, buffer_size=1000, learning_starts=80,
                         grad_steps_per_iter=1, eval_every=160)
    spec["agent"]["hidden"] = spec["skills"]["hidden"] = [16, 16]
    spec["archive"].update(num_centroids=32, cvt_samples=2000)
    spec["log"] = {"progress": False, "plots": "halfcheetah" in name}  # one descriptor dimension: x over steps
    summary = run(spec, tmp_path)
    assert summary["env_steps"] == 320 and summary["cells_visited"] >= 1
    assert ("halfcheetah" not in name) or (tmp_path / "plots" / "skills.png").stat().st_size > 1000
    episodes = pd.read_csv(tmp_path / "skills.csv")
    assert len(episodes.query("log_point == 1")) == spec["train"]["num_eval_envs"]


@pytest.mark.slow
def test_metra_spreads_its_skills_in_the_point_maze(tmp_path: Path) -> None:
    """16 directions after 10,000 steps: the skills' final positions spread over the maze (mean
    distance to their centroid above 0.7; the untrained policy's is 0.33), each step within
    METRA's constraint.

    A learning run, so `-m slow`; the 2-core record of METRA against DIAYN, DADS and LSD on
    ant_omni and halfcheetah_omni is benchmarks/results/metra_cpu_*.json."""
    spec = tiny_spec("metra")
    spec["env"]["episode_length"] = 50
    spec["agent"].update(hidden=[64, 64], init_alpha=0.01)
    spec["skills"].update(hidden=[64, 64], learning_rate=3e-4)
    spec["train"].update(total_env_steps=10_000, num_envs=8, batch_size=128, buffer_size=10_000,
                         learning_starts=1000, grad_steps_per_iter=4, eval_every=5000, num_eval_envs=16)
    spec["log"]["plots"] = False
    summary = run(spec, tmp_path)
    final = pd.read_csv(tmp_path / "skills.csv").query("log_point == 1")
    xy = final[["descriptor_final_x", "descriptor_final_y"]].to_numpy()
    assert float(np.mean(np.linalg.norm(xy - xy.mean(axis=0), axis=1))) > 0.7
    assert summary["phi_delta_dot_z"] > 0.0 and summary["phi_step_sq_max"] < 1.5
