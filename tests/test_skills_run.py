"""`qdrl run` for skill discovery: tiny runs per algorithm, the passive archive, specs, bad configs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest

from qdrl import checkpoint
from qdrl.algorithms.skills import skill_task
from qdrl.config import ConfigError, load_toml
from qdrl.experiment import build_run, run

ROOT = Path(__file__).resolve().parents[1]
SPECS = sorted(
    p for pattern in ("diayn_*.toml", "dads_*.toml", "smerl_*.toml")
    for p in (ROOT / "agents").glob(pattern)
)


def tiny_spec(algorithm: str) -> dict:  # type: ignore[type-arg]
    spec = {
        "experiment": {"algorithm": algorithm, "seed": 0},
        "env": {"task": "point_maze", "episode_length": 20},
        "agent": {"hidden": [16, 16]},
        "train": {"total_env_steps": 640, "num_envs": 4, "batch_size": 32, "buffer_size": 1000,
                  "learning_starts": 80, "grad_steps_per_iter": 2, "eval_every": 320,
                  "num_eval_envs": 8},
        "skills": {"num_skills": 4, "hidden": [16, 16]},
        "archive": {"grid_shape": [8, 8]},
        "log": {"progress": False},
    }
    if algorithm.startswith("smerl"):
        spec["smerl"] = {"target": -30.0, "margin": 5.0}
    return spec


@pytest.mark.parametrize(
    "algorithm",
    [
        "diayn",
        # SMERL's gate and DADS's model are checked on their own in tests/agents/test_skills.py,
        # and a SMERL-DIAYN run resumes below.
        pytest.param("smerl_dads", marks=pytest.mark.slow),
        pytest.param("dads", marks=pytest.mark.slow),
        pytest.param("smerl_diayn", marks=pytest.mark.slow),
    ],
)
def test_tiny_run_fills_the_passive_archive(tmp_path: Path, algorithm: str) -> None:
    summary = run(tiny_spec(algorithm), tmp_path)
    assert summary["env_steps"] == 640
    # 2 evaluations x 8 episodes offered to an 8x8 archive over [-1, 1]^2
    assert 1 <= summary["num_elites"] <= 16
    assert summary["coverage"] == pytest.approx(summary["num_elites"] / 64)
    assert summary["qd_score"] > 0  # every return is above the task's QD offset
    model = "discriminator_accuracy" if algorithm.endswith("diayn") else "dynamics_log_likelihood"
    for key in (f"eval_{model}", f"eval_final_{model}", model, "intrinsic_reward", "critic_loss"):
        assert summary[key] is not None, key
    if algorithm.startswith("smerl"):
        assert 0.0 <= summary["gate_open"] <= 1.0
    assert (tmp_path / "plots" / "skills.png").stat().st_size > 0
    assert len((tmp_path / "skills.csv").read_text().splitlines()) == 1 + 2 * 8  # 2 log points x 8 episodes
    assert (tmp_path / "plots" / "archive.png").exists()
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["algorithm"] == algorithm
    # The passive archive is exported as QD runs export their repertoire.
    assert written["descriptor_names"] == ["final x", "final y"]
    archive = (tmp_path / "archive.csv").read_text().splitlines()
    assert archive[0].startswith("cell,fitness,descriptor_0,descriptor_1") and len(archive) == 1 + summary["num_elites"]


def test_every_skill_spec_is_a_known_algorithm_and_task() -> None:
    assert len(SPECS) == 40
    for path in SPECS:
        spec = load_toml(path)
        algorithm = spec["experiment"]["algorithm"]
        assert path.stem.startswith(algorithm), path
        assert path.stem[len(algorithm) + 1 :].removesuffix("_cpu") == spec["env"]["task"], path
        assert spec["train"]["num_eval_envs"] % spec["skills"]["num_skills"] == 0, path


@pytest.mark.parametrize("path", [p for p in SPECS if "point_maze" in p.stem], ids=lambda p: p.stem)
def test_point_maze_specs_build(path: Path) -> None:
    run_, _, _ = build_run(load_toml(path))
    assert run_.task == "point_maze"


@pytest.mark.slow
@pytest.mark.parametrize("path", [p for p in SPECS if "point_maze" not in p.stem], ids=lambda p: p.stem)
def test_brax_specs_build(path: Path) -> None:
    spec = load_toml(path)
    run_, _, _ = build_run(spec)
    assert run_.task == spec["env"]["task"]
    # The agent acts on the task's observation followed by a one-hot skill.
    state = jax.eval_shape(run_.init, jax.random.PRNGKey(0))
    k = run_.sections["skills"].num_skills
    base = skill_task(spec["env"]["task"], 5, spec["env"].get("backend", "spring")).env.observation_size
    assert state.train.env.obs.shape[-1] == base + k


@pytest.mark.parametrize(
    ("section", "key", "value", "message"),
    [
        ("skills", "num_skills", 0, "skills.num_skills"),
        ("skills", "model_input", "pixels", "skills.model_input"),
        ("skills", "learning_rate", -1.0, "skills.learning_rate"),
        ("train", "num_eval_envs", 6, "train.num_eval_envs"),
        ("smerl", "margin", -1.0, "smerl.margin"),
        ("env", "task", "ant_uni", "env.task"),
    ],
)
def test_bad_config_names_the_key(section: str, key: str, value: object, message: str) -> None:
    spec = tiny_spec("smerl_dads")
    spec[section][key] = value
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        build_run(spec)


def test_archive_must_match_the_descriptor_size() -> None:
    spec = tiny_spec("diayn")
    spec["archive"] = {"grid_shape": [4, 4, 4], "low": [-1.0] * 3, "high": [1.0] * 3}
    with pytest.raises(ConfigError, match=r"archive\.grid_shape: expected 2 entries"):
        build_run(spec)


def test_dads_bad_omitted_dim_names_the_key() -> None:
    spec = tiny_spec("dads")
    spec["skills"]["omit_input_dims"] = [2]  # the descriptor of point_maze has 2 dims
    with pytest.raises(ConfigError, match=r"skills\.omit_input_dims"):
        build_run(spec)


def test_smerl_run_resumed_after_its_first_checkpoint_matches_an_uninterrupted_run(
    tmp_path: Path,
) -> None:
    # SMERL on DIAYN carries the most state: SAC, the discriminator, the trajectory buffer
    # (ring, episode ids, return table), the environments mid-episode and the archive.
    spec = tiny_spec("smerl_diayn")  # 2 log points of 320 steps, a checkpoint after each
    spec["log"]["plots"] = False
    full = run(spec, tmp_path / "full")

    # What a run stopped after its first checkpoint leaves: that checkpoint, its config
    # and one row of metrics (checkpoints are complete once their directory exists).
    out = tmp_path / "stopped"
    shutil.copytree(tmp_path / "full", out)
    shutil.rmtree(checkpoint.latest(out / "checkpoints"))  # type: ignore[arg-type]
    (out / "summary.json").unlink()
    rows = (out / "metrics.csv").read_text().splitlines()
    (out / "metrics.csv").write_text("\n".join(rows[:2]) + "\n")
    episodes = (out / "skills.csv").read_text().splitlines()  # written at each log point
    (out / "skills.csv").write_text("\n".join(episodes[: 1 + 8]) + "\n")
    assert checkpoint.step_of(checkpoint.latest(out / "checkpoints")) == 1  # type: ignore[arg-type]

    resumed = run(spec, out, resume=True)
    timing = {"wall_s", "compile_s", "startup_s", "run_s", "env_steps_per_s"}
    keys = sorted(k for k, v in full.items() if isinstance(v, int | float) and k not in timing)
    assert {"eval_return", "coverage", "gate_open", "discriminator_loss", "train_return"} <= set(keys)
    for key in keys:
        assert resumed[key] == full[key], key
    # The final states, parameters and buffers included, are bit-identical.
    final = checkpoint.latest(tmp_path / "full" / "checkpoints")
    assert final is not None and checkpoint.step_of(final) == 2
    with np.load(final / "state.npz") as a, \
            np.load(out / "checkpoints" / final.name / "state.npz") as b:
        assert a.files == b.files and len(a.files) > 20
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 2
    # skills.csv, as the stopped run left it (its first log point's 8 episodes): the resumed
    # session appends its own, as metrics.csv's, bit for bit the uninterrupted run's.
    skills = (out / "skills.csv").read_text()
    assert skills == (tmp_path / "full" / "skills.csv").read_text()
    assert len(skills.splitlines()) == 1 + 2 * 8
