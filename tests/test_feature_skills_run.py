"""`qdrl run` for feature-space skills (QDAC, UVFA): tiny runs, their metrics and files, options,
specs, bad configs, exact resume, a loaded run's skills; and QDAC learning to reach its targets."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pandas as pd
import pytest
from stopped_runs import assert_resumed_as_uninterrupted, stopped_copy

from qdrl.config import ConfigError, load_toml
from qdrl.envs.skills import SkillSpace
from qdrl.experiment import build_run, run
from qdrl.runs import RunError, load_run
from qdrl.skill_metrics import evaluation_targets

ROOT = Path(__file__).resolve().parents[1]
SPECS = sorted(p for pattern in ("qdac_*.toml", "uvfa_*.toml") for p in (ROOT / "agents").glob(pattern))


def tiny_spec(algorithm: str, **qdac: Any) -> dict[str, Any]:
    spec: dict[str, Any] = {
        "experiment": {"algorithm": algorithm, "seed": 0},
        "env": {"task": "point_position", "episode_length": 20},
        "agent": {"hidden": [16, 16]},
        "train": {"total_env_steps": 640, "num_envs": 4, "batch_size": 32, "buffer_size": 1000,
                  "learning_starts": 80, "grad_steps_per_iter": 2, "eval_every": 320, "num_eval_envs": 8},
        "archive": {"num_centroids": 16, "cvt_samples": 1000},
        "log": {"progress": False},
    }
    if qdac:
        spec["qdac"] = qdac
    return spec


@pytest.mark.parametrize(
    ("algorithm", "options"),
    [("qdac", {}), ("qdac", {"constraint": "naive", "lagrange": "fixed", "fixed_lagrange": 0.25}), ("uvfa", {})],
    ids=["qdac", "qdac_no_sf_fixed_lambda", "uvfa"],
)
def test_tiny_run_logs_distance_to_skill_and_fills_the_archive(
    tmp_path: Path, algorithm: str, options: dict[str, Any]
) -> None:
    summary = run(tiny_spec(algorithm, **options), tmp_path)
    assert summary["env_steps"] == 640
    assert 0.0 < summary["distance_to_skill"] < 2 * np.sqrt(2)
    assert 0.0 <= summary["reached"] <= 1.0
    assert 1 <= summary["num_elites"] <= 16
    if algorithm == "qdac":
        if options:  # the fixed-lambda ablation holds lambda; the learnt one is a sigmoid
            assert summary["lagrange"] == pytest.approx(0.25)
        else:
            assert 0.0 < summary["lagrange"] <= 1.0 and np.isfinite(summary["lagrange_loss"])
        assert np.isfinite(summary["feature_loss"]) and np.isfinite(summary["constraint_distance"])
    else:
        assert np.isfinite(summary["feature_distance"])
    # every evaluated episode: its target, average feature and distance, as the metric reads them
    episodes = pd.read_csv(tmp_path / "skills.csv")
    assert len(episodes) == 2 * 8
    last = episodes[episodes.log_point == 1]
    dist = np.hypot(last.descriptor_x - last.target_x, last.descriptor_y - last.target_y)
    np.testing.assert_allclose(last.distance, dist, rtol=1e-5)
    assert float(np.mean(last.distance)) == pytest.approx(summary["distance_to_skill"], rel=1e-5)
    # the targets are the fixed evaluation skills, the same for every run
    want = evaluation_targets(SkillSpace((-1.0, -1.0), (1.0, 1.0)), 8, "sample")
    np.testing.assert_allclose(last[["target_x", "target_y"]], want, rtol=1e-6)
    profiles = json.loads((tmp_path / "profiles.json").read_text())
    assert len(profiles["distance_profile"]["share"]) == 21 and len(profiles["performance_profile"]["share"]) == 21
    assert profiles["distance_profile"]["share"][-1] == 1.0  # every distance is below the diagonal
    assert profiles["distance_to_skill"] == pytest.approx(summary["distance_to_skill"], rel=1e-6)
    for plot in ("skills.png", "profiles.png", "archive.png", "summary.png"):
        assert (tmp_path / "plots" / plot).stat().st_size > 1000, plot


def test_a_run_resumed_after_its_first_checkpoint_matches_an_uninterrupted_one(tmp_path: Path) -> None:
    spec = tiny_spec("qdac")
    spec["log"]["plots"] = False
    full = run(spec, tmp_path / "full")
    stopped_copy(tmp_path / "full", tmp_path / "stopped", episodes_per_log_point=8)
    resumed = run(spec, tmp_path / "stopped", resume=True)
    assert_resumed_as_uninterrupted(
        full, resumed, tmp_path / "full", tmp_path / "stopped", {"distance_to_skill", "lagrange", "feature_loss"}
    )


def test_a_loaded_run_plays_each_evaluation_skill(tmp_path: Path) -> None:
    spec = tiny_spec("uvfa")
    spec["log"]["plots"] = False
    run(spec, tmp_path)
    loaded = load_run(tmp_path)
    last = pd.read_csv(tmp_path / "skills.csv").query("log_point == 1").set_index("episode")
    assert loaded.num_skills == 8  # the evaluation skills
    for z in (0, 5):
        episode = loaded.rollout(skill=z)  # the run's own evaluation episode z, bit for bit
        assert episode.return_ == last.loc[z, "return"]
        mean_feature = episode.state_descriptors[1:].mean(axis=0)
        np.testing.assert_allclose(mean_feature, last.loc[z, ["descriptor_x", "descriptor_y"]], rtol=1e-5)
        act = jax.jit(loaded.policy(skill=z))
        np.testing.assert_allclose(act(episode.observations), episode.actions, rtol=1e-6, atol=1e-6)
    with pytest.raises(RunError, match=r"expected an int in \[0, 8\) \(train\.num_eval_envs evaluation skills"):
        loaded.policy(skill=8)


@pytest.mark.parametrize(
    ("section", "key", "value", "message"),
    [
        ("qdac", "delta", -0.1, "qdac.delta"),
        ("qdac", "lagrange", "learnt", "qdac.lagrange"),
        ("qdac", "constraint", "none", "qdac.constraint"),
        ("qdac", "fixed_lagrange", 1.5, "qdac.fixed_lagrange"),
        ("env", "task", "walker2d_uni", "env.task"),
        ("evaluation", "skills", "random", "evaluation.skills"),
        ("evaluation", "threshold", 0.0, "evaluation.threshold"),
        ("archive", "descriptor", "final", "archive.descriptor"),
    ],
)
def test_bad_config_names_the_key(section: str, key: str, value: object, message: str) -> None:
    spec = tiny_spec("qdac", delta=0.01)
    spec.setdefault(section, {})[key] = value
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        build_run(spec)


def test_a_grid_of_evaluation_skills_needs_a_power_of_the_dimension() -> None:
    spec = tiny_spec("uvfa")
    spec["evaluation"] = {"skills": "grid"}
    spec["train"]["num_eval_envs"] = 9  # 3 x 3 over the 2 features
    run_, _, _ = build_run(spec)
    grid = evaluation_targets(SkillSpace((-1.0, -1.0), (1.0, 1.0)), 9, "grid")
    assert sorted(set(grid[:, 0].tolist())) == [-1.0, 0.0, 1.0]
    spec["train"]["num_eval_envs"] = 8
    with pytest.raises(ConfigError, match=r"train\.num_eval_envs: expected k\^2 skills"):
        build_run(spec)
    del run_


def test_every_spec_names_its_algorithm_and_task_and_builds() -> None:
    assert {p.stem for p in SPECS} >= {"qdac_walker2d_feet_contact", "qdac_walker2d_feet_contact_cpu",
                                      "uvfa_walker2d_feet_contact_cpu", "qdac_ant_velocity_cpu"}
    # the baselines of the QDAC paper on its tasks: SMERL, Reverse SMERL, DOMiNO
    baselines = sorted(
        p for pattern in ("smerl_diayn_*_feet_contact*.toml", "smerl_diayn_ant_velocity*.toml", "smerl_reverse_*.toml",
                          "domino_*.toml")
        for p in (ROOT / "agents").glob(pattern)
    )
    assert len(baselines) == 12
    built: set[tuple[str, str]] = set()
    for path in [*SPECS, *baselines]:
        spec = load_toml(path)
        algorithm = spec["experiment"]["algorithm"]
        assert path.stem.startswith(algorithm), path
        assert spec["env"]["episode_length"] == 1000, path
        assert path.stem[len(algorithm) + 1 :].removesuffix("_cpu") == spec["env"]["task"], path
        # One spec of each method and task is built (a `_cpu` variant differs in sizes only, which
        # test_spec_schema checks for every packaged spec), with a small passive archive (its 1024
        # cells would take a k-means); every other section as packaged.
        if (algorithm, spec["env"]["task"]) in built:
            continue
        built.add((algorithm, spec["env"]["task"]))
        spec.setdefault("archive", {}).update(num_centroids=8, cvt_samples=100)
        run_, _, _ = build_run(spec)
        assert run_.task == spec["env"]["task"]


@pytest.mark.slow
def test_qdac_learns_to_reach_its_targets_on_the_point_mass(tmp_path: Path) -> None:
    """16 targets over [-1, 1]^2: the mean distance of the average position to its target falls
    from that of a policy that has not learnt (~0.75) to under 0.35 in 30,000 steps.

    A learning curve (about 2 minutes on 2 cores), so `-m slow`; the 2-core record of QDAC on
    walker2d feet contact and ant velocity is benchmarks/results/qdac_cpu_*.json."""
    spec = tiny_spec("qdac")
    spec["env"]["episode_length"] = 50
    spec["agent"]["hidden"] = [64, 64]
    spec["train"].update(total_env_steps=30_000, num_envs=8, batch_size=128, buffer_size=30_000,
                         learning_starts=1000, grad_steps_per_iter=4, eval_every=5000, num_eval_envs=16)
    spec["log"]["plots"] = False
    run(spec, tmp_path)
    rows = pd.read_csv(tmp_path / "metrics.csv")
    assert rows.distance_to_skill.iloc[0] > 0.6
    assert rows.distance_to_skill.iloc[-1] < 0.35, rows.distance_to_skill.tolist()


def test_the_throughput_bench_refuses_an_unknown_method() -> None:
    from qdrl.bench_skill_methods import method_parts
    from qdrl.tasks import make_task

    with pytest.raises(ValueError, match="unknown skill method 'dqn'"):
        method_parts("dqn", "ant_omni", make_task("ant_omni", episode_length=5).env)


@pytest.mark.slow
def test_the_throughput_bench_builds_every_method_beside_sac() -> None:
    """`qdrl bench skill_methods` (a benchmark, `-m slow` like this check of it): each method's
    trainer builds on its paper's environment, with the same loop settings as SAC's."""
    from qdrl.bench_skill_methods import FEATURE_METHODS, POSITION_METHODS, method_parts
    from qdrl.off_policy import TrainConfig, make_trainer
    from qdrl.tasks import make_task

    config = TrainConfig(total_env_steps=64, num_envs=4, batch_size=8, buffer_size=64, eval_every=32)
    for task, methods in (("walker2d_feet_contact", FEATURE_METHODS), ("ant_omni", POSITION_METHODS)):
        env = make_task(task, episode_length=5).env
        for method in methods:
            train_env, agent, storage = method_parts(method, task, env)
            trainer = make_trainer(train_env, agent, config, storage)
            state = jax.eval_shape(trainer.init, jax.random.PRNGKey(0))
            assert state.env.obs.shape[0] == 4, method


@pytest.mark.slow  # the throughput benchmark's analysis (docs/algorithms): compiles three updates
def test_update_flops_count_each_methods_arithmetic() -> None:
    """The benchmark's `update_flops`: QDAC's update (two twin critics, the policy and lambda's
    network on its batch and as many relabelled transitions) is about 3.9x SAC's arithmetic, and
    twice the batch doubles SAC's."""
    from qdrl.bench import update_flops
    from qdrl.bench_skill_methods import method_parts
    from qdrl.tasks import make_task

    env = make_task("walker2d_feet_contact", episode_length=5).env
    sac = update_flops(*method_parts("sac", "walker2d_feet_contact", env), 256)
    qdac = update_flops(*method_parts("qdac", "walker2d_feet_contact", env), 256)
    assert 3.5 < qdac / sac < 4.3, qdac / sac
    double = update_flops(*method_parts("sac", "walker2d_feet_contact", env), 512)
    assert 1.9 < double / sac < 2.1, double / sac


def test_qd_runs_on_a_feature_task_read_their_repertoire_as_skills() -> None:
    """DCRL-ME, QD-PG (and any QD run) on a feature task log the archive figures every skill
    method there logs: the repertoire's nearest elite to each of the 256 fixed targets."""
    import jax.numpy as jnp

    from qdrl import skill_metrics
    from qdrl.algorithms.qd import with_range_score
    from qdrl.qd.repertoires import grid_repertoire
    from qdrl.tasks.brax_features import feature_space

    space = feature_space("walker2d_feet_contact")
    assert space is not None and space.low == (0.0, 0.0) and space.high == (1.0, 1.0)
    rep = grid_repertoire(jnp.zeros((3,)), (4, 4), (0.0, 0.0), (1.0, 1.0))
    rep = rep.add(jnp.zeros((2, 3)), jnp.array([[0.1, 0.1], [0.9, 0.6]]), jnp.array([5.0, 7.0]))[0]
    metrics = with_range_score(rep, 0.0, space=space)
    want = skill_metrics.archive_skill_metrics(rep.descriptors, rep.fitnesses, space)
    assert float(metrics["archive_distance_to_skill"]) == float(want["archive_distance_to_skill"]) > 0.0
    assert "range_qd_score" not in metrics and float(metrics["qd_score"]) == 12.0
    for task, algorithm in itertools.product(("walker2d_feet_contact", "ant_velocity"), ("dcrl_me", "qdpg")):
        name = f"{algorithm}_{task}"
        for variant in (name, f"{name}_cpu"):
            spec = load_toml(ROOT / "agents" / f"{variant}.toml")
            run_, _, _ = build_run(spec)
            assert run_.task == task
        # the 2-core variant stops past the environment steps the QDAC suite reads every method at
        assert spec["experiment"]["env_steps_limit"] == 200_000, variant
        qd, episode = spec["qd"], spec["task"]["episode_length"]
        episodes = qd["init_batch_size"] + qd["num_iterations"] * spec["emitter"]["batch_size"]
        assert episodes * episode >= 20 * 200_000, (variant, episodes)  # the limit binds, not the iterations


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [p.stem for p in SPECS if p.stem.endswith("_cpu")]
    + ["smerl_diayn_walker2d_feet_contact_cpu", "smerl_reverse_ant_velocity_cpu", "domino_walker2d_feet_contact_cpu"],
)
def test_every_cpu_spec_runs_a_tiny_version(tmp_path: Path, name: str) -> None:
    """Each 2-core spec of the QDAC comparison, shrunk (20-step episodes, 2 log points), runs on
    its brax task and logs the figures the comparison reads."""
    spec = load_toml(ROOT / "agents" / f"{name}.toml")
    spec["env"]["episode_length"] = 20
    spec["train"].update(total_env_steps=320, num_envs=4, batch_size=16, buffer_size=1000, learning_starts=80,
                         grad_steps_per_iter=1, eval_every=160, num_eval_envs=10 if "domino" in name else 8)
    spec["archive"].update(num_centroids=32, cvt_samples=2000)
    spec["log"] = {"progress": False, "plots": False}
    summary = run(spec, tmp_path)
    assert summary["env_steps"] == 320
    assert np.isfinite(summary["archive_distance_to_skill"]) and 0.0 <= summary["archive_reached"] <= 1.0


@pytest.mark.slow
@pytest.mark.parametrize(
    "name", [f"{a}_{t}_cpu" for a in ("dcrl_me", "qdpg") for t in ("walker2d_feet_contact", "ant_velocity")]
)
def test_every_qd_baseline_cpu_spec_runs_a_tiny_version_to_its_steps_limit(tmp_path: Path, name: str) -> None:
    """The QD baselines' 2-core specs of the QDAC comparison, shrunk (20-step episodes, 8
    offspring, a few training steps, a 400-step limit), run on their brax task, stop at the first
    iteration past the limit and log the archive figures the comparison reads."""
    spec = load_toml(ROOT / "agents" / f"{name}.toml")
    spec["experiment"]["env_steps_limit"] = 400
    spec["task"].update(episode_length=20, policy_hidden=[8])
    spec["repertoire"].update(num_centroids=32, cvt_samples=2000)
    spec["emitter"]["batch_size"] = 8
    spec["qd"].update(init_batch_size=8)
    section = "dcrl" if "dcrl" in name else "pg"
    spec[section].update(num_critic_training_steps=2, num_pg_training_steps=2, training_batch_size=8,
                         replay_buffer_size=1000, critic_hidden=[8])
    if section == "dcrl":
        spec["dcrl"].update(dcrl_batch_size=2, ai_batch_size=2)
    else:
        spec["dpg"]["archive_max_size"] = 100
    spec["log"] = {"progress": False, "plots": False}
    summary = run(spec, tmp_path)
    rows = pd.read_csv(tmp_path / "metrics.csv")
    assert summary["stopped_by"] == "env_steps_limit" and rows.env_steps.iloc[-1] >= 400 > rows.env_steps.iloc[-2]
    assert np.isfinite(summary["archive_distance_to_skill"]) and 0.0 <= summary["archive_reached"] <= 1.0


def test_a_qd_run_on_a_feature_task_logs_and_replays_its_elites_as_skills(tmp_path: Path) -> None:
    """End to end: MAP-Elites on walker2d feet contact logs the archive figures every skill method
    there logs, in metrics.csv and summary.json, and its end-of-run re-evaluation plays the elite
    nearest each target again (`skills` in reevaluation.json)."""
    spec = {
        "experiment": {"algorithm": "map_elites", "seed": 0},
        "task": {"name": "walker2d_feet_contact", "episode_length": 10, "policy_hidden": [8]},
        "repertoire": {"kind": "grid", "grid_shape": [4, 4]},
        "emitter": {"kind": "isoline", "batch_size": 8},
        "qd": {"num_iterations": 2, "log_every": 1, "init_batch_size": 8, "reevaluate_samples": 2},
        "log": {"progress": False, "plots": False},
    }
    summary = run(spec, tmp_path)
    rows = pd.read_csv(tmp_path / "metrics.csv")
    assert len(rows) == 2 and rows.archive_distance_to_skill.notna().all()
    assert 0.0 < rows.archive_distance_to_skill.iloc[-1] <= rows.archive_distance_to_skill.iloc[0]
    assert summary["archive_distance_to_skill"] == pytest.approx(rows.archive_distance_to_skill.iloc[-1])
    skills = json.loads((tmp_path / "reevaluation.json").read_text())["skills"]
    assert skills["stored"]["archive_distance_to_skill"] == pytest.approx(rows.archive_distance_to_skill.iloc[-1])
    assert 0.0 < skills["picked_distance_to_skill"] < math.sqrt(2.0) and 0.0 <= skills["picked_reached"] <= 1.0
