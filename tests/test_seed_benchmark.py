"""The skill-discovery benchmark's specs (agents/seed_benchmark/) and what they rely on: the
study's settings, CVT passive archives shared with MAP-Elites, the fitness-range QD score."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import spec_schema, specs
from qdrl.algorithms.qd import cvt_cells
from qdrl.algorithms.rl import ArchiveConfig
from qdrl.config import ConfigError, load_toml
from qdrl.experiment import check_spec
from qdrl.qd.metrics import range_qd_score
from qdrl.qd.repertoires import passive_archive
from qdrl.qd.repertoires.passive import feed

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):  # benchmarks/ is no package: load the script as a module
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(name, module)
    spec.loader.exec_module(module)
    return module


GEN = _script("seed_benchmark_specs")
NAMES = specs.spec_names("seed_benchmark")


def test_the_packaged_specs_are_the_generators_table() -> None:
    assert GEN.main(["--check"]) == 0
    assert len(NAMES) == len(GEN.ALGORITHMS) * len(GEN.TASKS) * 2 == 140


def test_every_benchmark_spec_passes_both_checks() -> None:
    for name in NAMES:
        spec = load_toml(specs.resolve(name))
        spec_schema.precheck(spec)  # before jax: the CLI's check
        check_spec(spec)  # the full check, nothing built


def _spec(name: str) -> dict:
    return load_toml(specs.resolve(f"seed_benchmark/{name}"))


def test_the_study_settings() -> None:
    me = _spec("map_elites_ant_maze")
    assert me["emitter"]["batch_size"] == 1000 and me["task"]["episode_length"] == 500
    assert me["task"]["policy_hidden"] == [256, 256] and me["task"]["policy_activation"] == "relu"
    assert (me["emitter"]["iso_sigma"], me["emitter"]["line_sigma"]) == (0.005, 0.05)
    assert (me["repertoire"]["num_centroids"], me["repertoire"]["cvt_samples"]) == (1024, 50_000)
    assert me["experiment"]["time_limit_s"] == 8400
    pga = _spec("pga_me_walker2d_uni")
    assert pga["emitter"]["batch_size"] == 100 and pga["task"]["episode_length"] == 250
    assert (pga["pg"]["num_critic_training_steps"], pga["pg"]["num_pg_training_steps"]) == (300, 100)
    assert (pga["pg"]["policy_learning_rate"], pga["pg"]["critic_learning_rate"]) == (1e-3, 3e-4)
    smerl = _spec("smerl_dads_ant_omni")
    assert smerl["train"]["num_envs"] == smerl["train"]["grad_steps_per_iter"] == 200
    assert smerl["agent"]["learn_alpha"] is False and smerl["agent"]["init_alpha"] == 0.1
    assert (smerl["smerl"]["target"], smerl["smerl"]["margin"]) == (249.0, 24.9)
    assert smerl["skills"]["diversity_scale"] == 4.0 and smerl["skills"]["model_input"] == "descriptor"
    assert smerl["experiment"]["time_limit_s"] == 5400  # DADS off halfcheetah_uni
    assert smerl["archive"]["fitness_range"] == [-500.0, 250.0]
    cheetah = _spec("diayn_reward_halfcheetah_uni")
    assert cheetah["agent"]["reward_scale"] == 5.0 and cheetah["skills"]["model_input"] == "full"
    assert cheetah["skills"]["extrinsic_scale"] == 1.0 and "smerl" not in cheetah
    assert _spec("diayn_halfcheetah_uni")["skills"]["extrinsic_scale"] == 0.0
    assert "time_limit_s" not in _spec("map_elites_point_maze")["experiment"]
    cpu = _spec("smerl_diayn_walker2d_uni_cpu")  # the study's scale: episodes, rewards, targets
    assert cpu["env"]["episode_length"] == 250 and cpu["smerl"]["target"] == 1180.0
    assert cpu["experiment"]["time_limit_s"] == 600


def test_a_spec_of_the_folder_with_a_typo_is_refused_with_close_names() -> None:
    with pytest.raises(ConfigError, match="close names: seed_benchmark/map_elites_ant_omni_cpu"):
        specs.resolve("seed_benchmark/map_elite_ant_omni_cpu")


def test_range_qd_score_clips_and_scales_each_cell() -> None:
    rep = passive_archive("grid", grid_shape=(4,), low=0.0, high=1.0)
    rep, metrics = feed(
        rep, jnp.array([[0.1], [0.3], [0.6], [0.6]]), jnp.array([-300.0, 50.0, 900.0, 100.0]), -500.0, (-100.0, 100.0)
    )
    # cells: -300 -> 0 (clipped), 50 -> 0.75, 900 -> 1 (clipped); the 4th cell empty; / 4 cells
    np.testing.assert_allclose(float(metrics["range_qd_score"]), (0.0 + 0.75 + 1.0) / 4)
    np.testing.assert_allclose(float(range_qd_score(rep, (-100.0, 100.0))), 0.4375)
    with pytest.raises(ValueError, match="min < max"):
        range_qd_score(rep, (1.0, 1.0))


def test_a_cvt_passive_archive_has_the_cells_of_a_map_elites_run_of_its_seed() -> None:
    cfg = ArchiveConfig(kind="cvt", num_centroids=16, cvt_samples=400, low=(0.0, -1.0), high=(1.0, 1.0), kmeans_iters=5)
    cfg.check()
    archive = cfg.empty(7)
    np.testing.assert_array_equal(np.asarray(archive.centroids), cvt_cells(7, 16, 400, (0.0, -1.0), (1.0, 1.0), 5))
    assert not np.array_equal(np.asarray(cfg.empty(8).centroids), np.asarray(archive.centroids))
    with pytest.raises(ValueError, match=r"archive\.cvt_samples: expected at least"):
        ArchiveConfig(kind="cvt", num_centroids=16, cvt_samples=8).check()


def test_policy_activation_is_the_tasks_hidden_activation() -> None:
    from qdrl.tasks import TASKS

    relu = TASKS["point_maze"].build(episode_length=5, policy_hidden=(8,), policy_activation="relu")
    tanh = TASKS["point_maze"].build(episode_length=5, policy_hidden=(8,))
    params = relu.init_fn(jax.random.PRNGKey(0), 1)
    one = jax.tree.map(lambda x: x[0], params)
    obs = jnp.full((relu.env.observation_size,), 3.0)
    a_relu = relu.policy.network.apply(one, obs)
    a_tanh = tanh.policy.network.apply(one, obs)
    assert not np.allclose(np.asarray(a_relu), np.asarray(a_tanh))
    with pytest.raises(ConfigError, match="policy_activation"):
        check_spec({**_spec("map_elites_point_maze_cpu"), "task": {"name": "point_maze", "policy_activation": "nope"}})


def test_the_record_merges_runs_of_earlier_sessions(tmp_path: Path) -> None:
    record = _script("seed_benchmark_record")
    for task, algorithm, qd in (("ant_omni", "pga_me", 7.0), ("walker2d_uni", "map_elites", 3.0)):
        run = tmp_path / "suite" / task / algorithm / "seed_0"
        run.mkdir(parents=True)
        (run / "summary.json").write_text(f'{{"env_steps": 100, "qd_score": {qd}, "stopped_by": "time_limit"}}')
    out = tmp_path / "record.json"
    old = {"suite": "seed 0, 600 s", "machine": {"cpus": 2, "jax": "x"},
           "runs": [{"task": "ant_omni", "algorithm": "pga_me", "seed": 0, "qd_score": 5.0},
                    {"task": "ant_maze", "algorithm": "map_elites", "seed": 0, "qd_score": 1.0}]}
    out.write_text(json.dumps(old))
    assert record.main([str(tmp_path / "suite"), "--out", str(out), "--merge"]) == 0
    merged = json.loads(out.read_text())
    assert merged["suite"] == "seed 0, 600 s" and merged["machine"] == old["machine"]
    assert [(r["task"], r["algorithm"], r["qd_score"]) for r in merged["runs"]] == [
        ("ant_maze", "map_elites", 1.0), ("ant_omni", "pga_me", 7.0), ("walker2d_uni", "map_elites", 3.0)]
    assert record.main([str(tmp_path / "suite"), "--out", str(out)]) == 0  # without --merge: the folder only
    assert len(json.loads(out.read_text())["runs"]) == 2
