"""D-PG (QD-PG): descriptor archive, novelty reward by hand, composition, a tiny run."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import nets
from qdrl.experiment import run_spec
from qdrl.qd.base import Evaluation
from qdrl.qd.emitters.novelty import (
    NoveltyConfig,
    NoveltyReward,
    add_to_archive,
    init_archive,
    novelty,
    qdpg_emitter,
)
from qdrl.qd.emitters.pg import PG_TD3, PGConfig, PGEmitter
from qdrl.types import Transition


def test_archive_accepts_only_candidates_farther_than_the_threshold() -> None:
    candidates = jnp.array([[0.0, 0.0], [0.1, 0.0], [1.0, 0.0], [1.0, 0.2], [3.0, 3.0]])
    archive = add_to_archive(init_archive(10, 2), candidates, acceptance_threshold=0.5)
    assert int(archive.size) == 3
    np.testing.assert_array_equal(np.asarray(archive.data[:3]), [[0, 0], [1, 0], [3, 3]])
    # candidates of one call screen each other, and a full archive takes nothing more
    small = add_to_archive(init_archive(2, 2), candidates, acceptance_threshold=0.5)
    assert int(small.size) == 2
    np.testing.assert_array_equal(np.asarray(small.data), [[0, 0], [1, 0]])


def test_novelty_is_the_mean_distance_to_the_k_nearest() -> None:
    archive = add_to_archive(init_archive(8, 2), jnp.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]]), 0.1)
    got = novelty(archive, jnp.array([[0.0, 0.0], [2.0, 0.0], [0.0, 4.0]]), num_neighbours=2)
    np.testing.assert_allclose(np.asarray(got), [0.5, 1.0, (4.0 + np.sqrt(17.0)) / 2], rtol=1e-6)
    # fewer entries than k: the mean over those there are; empty archive: 0
    got = novelty(archive, jnp.array([[0.0, 0.0]]), num_neighbours=5)
    np.testing.assert_allclose(np.asarray(got), [(0.0 + 1.0 + 3.0) / 3], rtol=1e-6)
    assert float(novelty(init_archive(8, 2), jnp.ones((1, 2)), 3)[0]) == 0.0


def test_novelty_reward_relabels_with_the_next_descriptor_novelty() -> None:
    hook = NoveltyReward(2, NoveltyConfig(acceptance_threshold=0.1, archive_max_size=8, num_neighbours=1, novelty_scale=2.0))
    archive = add_to_archive(init_archive(8, 2), jnp.array([[0.0, 0.0]]), 0.1)
    batch = Transition(
        obs=jnp.zeros((2, 1)), action=jnp.zeros((2, 1)), reward=jnp.array([5.0, 5.0]),
        next_obs=jnp.zeros((2, 1)), terminated=jnp.zeros(2), truncated=jnp.zeros(2),
        desc=jnp.zeros((2, 2)), next_desc=jnp.array([[3.0, 4.0], [0.0, 1.0]]),
    )
    np.testing.assert_allclose(np.asarray(hook.relabel(archive, batch).reward), [10.0, 2.0])


def test_novelty_reward_update_offers_visited_descriptors_of_valid_steps() -> None:
    import jax

    t, n = 3, 2
    desc = jnp.arange(t * n * 2, dtype=jnp.float32).reshape(t, n, 2)
    tr = Transition(
        obs=jnp.zeros((t, n, 1)), action=jnp.zeros((t, n, 1)), reward=jnp.zeros((t, n)),
        next_obs=jnp.zeros((t, n, 1)), terminated=jnp.zeros((t, n)), truncated=jnp.zeros((t, n)),
        desc=desc, next_desc=desc,
    )
    mask = jnp.ones((t, n)).at[1:, 1].set(0.0)  # 4 valid steps
    ev = Evaluation(jnp.zeros(n), jnp.zeros((n, 2)), {"transitions": tr, "mask": mask}, jnp.zeros((), jnp.int32))
    hook = NoveltyReward(2, NoveltyConfig(acceptance_threshold=0.5, archive_max_size=16, candidates_per_update=64))
    archive = hook.init(ev, jax.random.PRNGKey(0))
    stored = {tuple(map(float, row)) for row in np.asarray(archive.data[: int(archive.size)])}
    valid = {tuple(map(float, row)) for row in np.asarray(desc)[np.asarray(mask) > 0]}
    assert stored == valid  # 64 draws among 4 valid steps find them all; no invalid one


def test_qdpg_emitter_has_ga_qpg_and_a_dpg_with_its_own_reward() -> None:
    em = qdpg_emitter(10, nets.deterministic_policy(2, (8,), "tanh"), 3, 2, 2, PGConfig(td3=dataclasses.replace(PG_TD3, hidden=(8,))))
    ga, qpg, dpg = em.emitters
    assert (ga.batch_size, qpg.batch_size, dpg.batch_size) == (4, 3, 3)
    assert isinstance(qpg, PGEmitter) and qpg.relabel is None
    assert isinstance(dpg, PGEmitter) and isinstance(dpg.relabel, NoveltyReward)


SPEC = """
[experiment]
algorithm = "qdpg"
seed = 0

[task]
name = "point_maze"
episode_length = 20
policy_hidden = [8, 8]

[repertoire]
kind = "grid"
grid_shape = [8, 8]

[emitter]
batch_size = 9

[pg]
num_critic_training_steps = 4
num_pg_training_steps = 3
training_batch_size = 16
replay_buffer_size = 1000
critic_hidden = [16, 16]

[dpg]
archive_max_size = 200
candidates_per_update = 32
acceptance_threshold = 0.05

[qd]
num_iterations = 4
log_every = 2
init_batch_size = 9

[log]
progress = false
plots = false
"""


def test_qdpg_runs_through_qdrl_run(tmp_path: Path) -> None:
    spec = tmp_path / "qdpg.toml"
    spec.write_text(SPEC)
    summary = run_spec(spec, [], tmp_path / "out")
    assert summary["evaluations"] == 9 + 4 * 9
    assert summary["critic_steps"] == 4 * 5
    assert 1 <= summary["novelty_archive_size"] <= 5 * 32
    assert summary["qd_score"] > 0


def test_bad_dpg_section_names_the_key(tmp_path: Path) -> None:
    from qdrl.config import ConfigError

    spec = tmp_path / "qdpg.toml"
    spec.write_text(SPEC)
    with pytest.raises(ConfigError, match=r"dpg\.shares"):
        run_spec(spec, ["dpg.shares=[1.0, 0.0, 1.0]"], tmp_path / "out")
