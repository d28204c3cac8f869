"""`qdrl run` for skill discovery: tiny runs per algorithm, the passive archive, specs, bad configs;
and a run looked at skill by skill: its agent, policies and rollouts (`qdrl.load_run`),
`qdrl render --skill`, skills.csv, and rollouts compiled once into the persistent cache.

One tiny DIAYN run on point_maze (2 log points, 4 skills, 8 evaluation episodes each) is
shared by the tests that look at a finished run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from stopped_runs import assert_resumed_as_uninterrupted, stopped_copy

from qdrl.algorithms.skills import skill_columns, skill_task
from qdrl.cli import main
from qdrl.config import ConfigError, dump_toml, load_toml
from qdrl.experiment import build_run, run
from qdrl.render import render
from qdrl.runs import LoadedRun, RunError, load_run

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
def test_tiny_run_fills_the_passive_archive(
    tmp_path: Path, algorithm: str, request: pytest.FixtureRequest
) -> None:
    if algorithm == "diayn":  # the run the tests below share
        shared: LoadedRun = request.getfixturevalue("diayn")
        tmp_path, summary = shared.path, shared.summary
        assert summary is not None
    else:
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
    assert len(SPECS) == 48
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


def test_continuous_smerl_and_reverse_smerl_runs(tmp_path: Path) -> None:
    """The QDAC paper's SMERL baselines: continuous DIAYN skills z in [-1, 1]^2, one per evaluation
    episode; Reverse SMERL's gate reads the same episode returns."""
    for algorithm in ("smerl_diayn", "smerl_reverse"):
        spec = tiny_spec(algorithm)
        spec["skills"].update(num_skills=2, continuous=True)
        spec["log"]["plots"] = False
        summary = run(spec, tmp_path / algorithm)
        assert np.isfinite(summary["eval_final_discriminator_log_likelihood"]) and 0 <= summary["gate_open"] <= 1
        episodes = pd.read_csv(tmp_path / algorithm / "skills.csv")
        assert sorted(set(episodes.skill)) == list(range(8))
    spec = tiny_spec("smerl_reverse")
    spec["smerl"]["reverse"] = False
    with pytest.raises(ConfigError, match=r"smerl\.reverse: expected true"):
        build_run(spec)


def test_domino_run_holds_its_multipliers_and_skills(tmp_path: Path) -> None:
    spec = tiny_spec("domino")
    spec["skills"] = {"num_skills": 4}
    spec["domino"] = {"optimality_ratio": 0.8}
    spec["log"]["plots"] = False
    summary = run(spec, tmp_path)
    assert 0.0 < summary["lagrange"] < 1.0 and 0.0 <= summary["constraint_satisfied"] <= 1.0
    assert np.isfinite(summary["diversity_reward"]) and summary["num_elites"] >= 1
    assert sorted(set(pd.read_csv(tmp_path / "skills.csv").skill)) == [0, 1, 2, 3]
    spec["skills"]["hidden"] = [8]  # DOMiNO has no skill model to size
    with pytest.raises(ConfigError, match=r"skills\.hidden: unknown key"):
        build_run(spec)
    del spec["skills"]["hidden"]
    spec["domino"]["optimality_ratio"] = 1.5
    with pytest.raises(ConfigError, match=r"domino\.optimality_ratio"):
        build_run(spec)


@pytest.mark.parametrize(
    ("section", "key", "value", "message"),
    [
        ("skills", "num_skills", 0, "skills.num_skills"),
        ("skills", "model_input", "pixels", "skills.model_input"),
        ("skills", "learning_rate", -1.0, "skills.learning_rate"),
        ("train", "num_eval_envs", 6, "train.num_eval_envs"),
        ("smerl", "margin", -1.0, "smerl.margin"),
        ("env", "task", "hopper_uni", "env.task"),
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
    out = tmp_path / "stopped"
    stopped_copy(tmp_path / "full", out, episodes_per_log_point=8)
    resumed = run(spec, out, resume=True)
    # The final states, parameters and buffers included, are bit-identical; skills.csv, as the
    # stopped run left it (its first log point's 8 episodes), gets the resumed session's rows.
    assert_resumed_as_uninterrupted(
        full, resumed, tmp_path / "full", out, {"eval_return", "coverage", "gate_open", "discriminator_loss"}
    )
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 2
    assert len((out / "skills.csv").read_text().splitlines()) == 1 + 2 * 8


K, EPISODES, LOG_POINTS = 4, 8, 2
SPEC: dict[str, Any] = tiny_spec("diayn")  # the run shared by the tests below


@pytest.fixture(scope="module")
def diayn(tmp_path_factory: pytest.TempPathFactory) -> LoadedRun:
    out = tmp_path_factory.mktemp("diayn")
    run(SPEC, out)
    return load_run(out)


@pytest.fixture(scope="module")
def skills_csv(diayn: LoadedRun) -> pd.DataFrame:
    return pd.read_csv(diayn.path / "skills.csv")


def _unrun(tmp_path: Path, spec: dict[str, Any]) -> LoadedRun:
    """A run directory holding only its config (a run that has not reached its first log point)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "config.toml").write_text(dump_toml(spec))
    return load_run(tmp_path)


def test_skills_csv_has_every_episode_of_every_log_point(diayn: LoadedRun, skills_csv: pd.DataFrame) -> None:
    names = skill_task("point_maze", 20, "spring").descriptor_names
    assert names == ("final x", "final y")
    assert list(skills_csv.columns) == [
        "log_point", "env_steps", "episode", "skill", "return", "length", "descriptor_final_x",
        "descriptor_final_y", "cell",
    ] == ["log_point", "env_steps", "episode", "skill", "return", "length", *skill_columns(names), "cell"]
    assert len(skills_csv) == LOG_POINTS * EPISODES
    assert skills_csv["log_point"].tolist() == np.repeat(np.arange(LOG_POINTS), EPISODES).tolist()
    assert skills_csv["env_steps"].tolist() == np.repeat([320, 640], EPISODES).tolist()
    assert skills_csv["skill"].tolist() == (np.arange(LOG_POINTS * EPISODES) % K).tolist()
    assert (skills_csv["length"] == 20).all()  # no goal reached: every episode runs its 20 steps
    # Each log point's rows average to the metrics row's evaluation return (float32 mean there).
    for point, rows in skills_csv.groupby("log_point"):
        assert rows["return"].mean() == pytest.approx(diayn.metrics["eval_return"].iloc[point], rel=1e-6)
    # The cell is the passive archive's cell of the descriptor, and every filled cell holds the
    # best return offered to it: the archive is exactly what the rows fed it.
    archive = diayn.repertoire
    desc = skills_csv[["descriptor_final_x", "descriptor_final_y"]].to_numpy(np.float32)
    np.testing.assert_array_equal(skills_csv["cell"], np.asarray(archive.cell_index(desc)))
    best = skills_csv.groupby("cell")["return"].max()
    fitnesses = np.asarray(archive.fitnesses)
    assert sorted(best.index) == np.flatnonzero(fitnesses > -np.inf).tolist()
    np.testing.assert_array_equal(fitnesses[best.index], best.to_numpy(np.float32))


def test_a_skill_rollout_is_the_runs_own_evaluation_bit_for_bit(
    diayn: LoadedRun, skills_csv: pd.DataFrame
) -> None:
    # Bit for bit, not to a tolerance: the rollout runs the run's own episode function
    # (`skill_episodes`) on the checkpointed agent, with the same keys and batch width, and
    # XLA computes it to the same bits alone as inside the training chunk. skills.csv keeps
    # each float32 return as an exact double.
    last = skills_csv[skills_csv["log_point"] == LOG_POINTS - 1].set_index("episode")
    assert diayn.num_skills == K
    for z in range(K):
        episode = diayn.rollout(skill=z)
        assert episode.return_ == last.loc[z, "return"], z  # episode z plays skill z
        assert episode.length == last.loc[z, "length"] == int(episode.mask.sum())
        np.testing.assert_array_equal(
            episode.descriptor, last.loc[z, ["descriptor_final_x", "descriptor_final_y"]].to_numpy(np.float32)
        )
        np.testing.assert_array_equal(episode.state_descriptors[episode.length], episode.descriptor)
        assert episode.observations.shape == (20, 2) == episode.actions.shape  # x-y, no skill code
        assert float(np.sum(episode.rewards * episode.mask)) == pytest.approx(episode.return_, rel=1e-6)
    # Skills play different episodes (their own starts and policies).
    assert len({diayn.rollout(skill=z).return_ for z in range(K)}) == K


def test_the_policy_of_a_skill_is_the_one_the_evaluation_played(diayn: LoadedRun, compilations: Any) -> None:
    fresh = load_run(diayn.path)
    with compilations() as c:
        agent = fresh.agent()  # restored from the checkpoint: nothing compiled, nothing run
    assert c.count == 0
    # SAC's state inside the skill model's wrapper, at the run's last log point.
    assert int(agent.steps) == int(agent.agent.steps) == diayn.summary["grad_steps"] > 0  # type: ignore[index]
    assert agent.aux is not None  # the discriminator's parameters and optimiser state
    for z in (0, K - 1):
        episode = diayn.rollout(skill=z)
        act = jax.jit(diayn.policy(skill=z))
        # The same network on the same inputs, alone rather than inside the episode's scan.
        np.testing.assert_allclose(act(episode.observations), episode.actions, rtol=1e-6, atol=1e-6)
        one = diayn.policy(skill=np.int64(z))(jnp.asarray(episode.observations[0]))  # unbatched, not jitted
        np.testing.assert_allclose(one, episode.actions[0], rtol=1e-6, atol=1e-6)
    with pytest.raises(RunError, match=r"expected observations \(\.\.\., 2\)"):
        diayn.policy(skill=0)(np.zeros((3, 2 + K)))  # the skill code is the policy's to append


@pytest.mark.parametrize("skill", [K, -1, "1", 1.0, True, None])
def test_a_bad_skill_names_the_skills_there_are(diayn: LoadedRun, skill: Any) -> None:
    with pytest.raises(RunError, match=r"skill: expected an int in \[0, 4\) \(skills\.num_skills of this diayn run\)"):
        diayn.rollout(skill=skill)
    with pytest.raises(RunError, match=r"expected an int in \[0, 4\)"):
        diayn.policy(skill=skill)


def test_runs_without_an_agent_or_skills_say_what_was_expected(tmp_path: Path) -> None:
    qd = _unrun(tmp_path / "qd", {
        "experiment": {"algorithm": "map_elites"}, "task": {"name": "point_maze", "episode_length": 5},
    })
    with pytest.raises(RunError, match=r"agent: expected a run that trains one agent .*this map_elites run has none"):
        qd.agent()
    with pytest.raises(RunError, match=r"rollout: expected an elite of this QD run \(run\.best\(\)"):
        qd.rollout(skill=0)
    sac = _unrun(tmp_path / "sac", {"experiment": {"algorithm": "sac"}, "env": {"name": "point"}})
    assert sac.num_skills == 0
    with pytest.raises(RunError, match="skill: expected none, this sac run's agent has no skills"):
        sac.rollout(skill=0)
    with pytest.raises(RunError, match="holds no checkpoint: expected one in checkpoints/"):
        sac.agent()


def _error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("qdrl: error: ") and "\n" not in err, err
    return err


def test_render_draws_one_skill_or_every_skill(
    diayn: LoadedRun, skills_csv: pd.DataFrame, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    last = skills_csv[skills_csv["log_point"] == LOG_POINTS - 1].set_index("episode")
    out = tmp_path / "skill2.png"
    assert main(["render", str(diayn.path), "--skill", "2", "--out", str(out)]) == 0
    said = json.loads(capsys.readouterr().out)
    assert said == {"out": str(out), "skill": 2, "return": last.loc[2, "return"], "length": 20}
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
    assert main(["render", str(diayn.path)]) == 0
    every = json.loads(capsys.readouterr().out)
    assert every["out"] == str(diayn.path / "plots" / "replay_skills.png") and Path(every["out"]).stat().st_size > 10_000
    assert every["skills"] == list(range(K)) and every["returns"] == last["return"].iloc[:K].tolist()
    assert "--cell: expected a QD run's elite; this diayn run replays its agent: pass --skill Z (0 to 3)" in _error(
        ["render", str(diayn.path), "--cell", "0"], capsys
    )
    assert "expected an int in [0, 4)" in _error(["render", str(diayn.path), "--skill", "4"], capsys)
    assert "expected a file ending with .png" in _error(
        ["render", str(diayn.path), "--skill", "0", "--out", str(tmp_path / "x.html")], capsys
    )
    qd = _unrun(tmp_path / "qd", {
        "experiment": {"algorithm": "map_elites"}, "task": {"name": "point_maze", "episode_length": 5},
    })
    assert "--skill: expected a skill-discovery run; this map_elites run is a QD run" in _error(
        ["render", str(qd.path), "--skill", "0"], capsys
    )


_REPLAY = """
import json, sys
from qdrl import compile_cache, load_run
with compile_cache.cache_hits() as counts:
    if sys.argv[2] == "rollout":
        episode_return = load_run(sys.argv[1]).rollout(skill=1).return_
    else:
        from qdrl.render import render
        episode_return = render(load_run(sys.argv[1]), skill=1, out=sys.argv[2])["return"]
print(json.dumps({**counts, "return": episode_return}))
"""


def test_a_render_in_a_new_process_loads_its_programs_from_the_cache(diayn: LoadedRun, tmp_path: Path) -> None:
    env = {
        **os.environ, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax"), "QDRL_CACHE_DIR": str(tmp_path / "qdrl"),
        # The tiny run's programs compile in well under jax's 1 s threshold for caching.
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
    }
    said = []
    # A rollout of skill 1 fills the empty cache; a render of skill 1, in a second process, finds there
    # what it compiles (the same program: the render plays the rollout).
    for what in ("rollout", str(tmp_path / "skill1.png")):
        done = subprocess.run(
            [sys.executable, "-c", _REPLAY, str(diayn.path), what],
            env=env, capture_output=True, text=True, timeout=300, check=False,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        said.append(json.loads(done.stdout.strip().splitlines()[-1]))
    first, second = said
    assert first["lookups"] > 0 and first["hits"] == 0  # compiled, and stored
    assert second["hits"] > 0 and second["hits"] == second["lookups"]  # every program loaded
    assert first["return"] == second["return"] == diayn.rollout(skill=1).return_
    assert (tmp_path / "skill1.png").stat().st_size > 10_000


@pytest.mark.slow
def test_a_sac_run_gives_its_agent_without_a_skill(tmp_path: Path) -> None:
    spec = {
        "experiment": {"algorithm": "sac", "seed": 1},
        "env": {"name": "point", "episode_length": 20},
        "agent": {"hidden": [8, 8]},
        "train": {"total_env_steps": 200, "num_envs": 4, "batch_size": 16, "buffer_size": 400,
                  "learning_starts": 40, "eval_every": 200, "num_eval_envs": 1},
        "log": {"progress": False, "plots": False},
    }
    run(spec, tmp_path)
    sac = load_run(tmp_path)
    episode = sac.rollout()
    # One evaluation episode: the metrics row's mean return is its return (float32, exact in the csv).
    assert episode.return_ == sac.metrics["eval_return"].iloc[-1]
    np.testing.assert_allclose(jax.jit(sac.policy())(episode.observations), episode.actions, rtol=1e-6, atol=1e-6)
    assert int(sac.agent().steps) == sac.summary["grad_steps"]  # type: ignore[index]
    # SAC on the point maze renders like a skill: a PNG of its evaluation's first episode
    maze_dir = tmp_path / "maze"
    run({**spec, "env": {"name": "point_maze", "episode_length": 20}}, maze_dir)
    result = render(load_run(maze_dir))
    assert Path(result["out"]).name == "replay_agent.png" and Path(result["out"]).stat().st_size > 1000
    assert result["return"] == load_run(maze_dir).metrics["eval_return"].iloc[-1]
