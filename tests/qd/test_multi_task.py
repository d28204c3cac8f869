"""Multi-task MAP-Elites (Mouret & Maguire 2020): UCB1 by hand, the closest-task tournament,
the parameterised arm's fitness by hand, a tiny `qdrl run` of mt_me and its exact resume."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.cli import main
from qdrl.config import ConfigError
from qdrl.experiment import check_spec, run_spec
from qdrl.qd.base import AddResult
from qdrl.qd.emitters.multi_task import (
    BanditState,
    MTMEConfig,
    closest_task_tournament,
    make_multi_task_emitter,
    ucb1_choose,
    ucb1_update,
    ucb1_values,
)
from qdrl.qd.repertoires import cvt_repertoire
from qdrl.specs import load_spec
from qdrl.tasks import make_task
from qdrl.tasks.multi_task import multi_task_arm_fitness


def _bandit(k: int) -> BanditState:
    return BanditState(jnp.zeros((k,), jnp.int32), jnp.zeros((k,), jnp.float32), jnp.zeros((), jnp.int32))


def test_ucb1_tries_each_arm_in_order_then_follows_the_hand_computed_index() -> None:
    state = _bandit(2)
    assert int(state.arm) == 0
    state = ucb1_update(state, 1.0)  # arm 0 earned 1; arm 1 untried: its index is +inf
    assert int(state.arm) == 1
    np.testing.assert_array_equal(np.asarray(ucb1_values(state.pulls, state.rewards)), [1.0 + math.sqrt(0.0), np.inf])
    state = ucb1_update(state, 3.0)  # n = 2: 1 + sqrt(2 ln 2) against 3 + sqrt(2 ln 2)
    np.testing.assert_allclose(
        np.asarray(ucb1_values(state.pulls, state.rewards)), [1 + math.sqrt(2 * math.log(2)), 3 + math.sqrt(2 * math.log(2))],
        rtol=1e-6,
    )
    assert int(state.arm) == 1
    state = ucb1_update(state, 0.0)  # n = 3: 1 + sqrt(2 ln 3) = 2.482 against 1.5 + sqrt(ln 3) = 2.548
    values = np.asarray(ucb1_values(state.pulls, state.rewards))
    np.testing.assert_allclose(values, [1 + math.sqrt(2 * math.log(3)), 1.5 + math.sqrt(math.log(3))], rtol=1e-6)
    assert int(state.arm) == 1
    state = ucb1_update(state, 0.0)  # n = 4: 1 + sqrt(2 ln 4) = 2.665 against 1 + sqrt(2 ln 4 / 3) = 1.961
    np.testing.assert_allclose(
        np.asarray(ucb1_values(state.pulls, state.rewards)),
        [1 + math.sqrt(2 * math.log(4)), 1 + math.sqrt(2 * math.log(4) / 3)], rtol=1e-6,
    )
    assert int(state.arm) == 0
    np.testing.assert_array_equal(np.asarray(state.pulls), [1, 3])


@pytest.mark.parametrize("jit", [False, True])
def test_ucb1_comes_to_prefer_the_arm_of_the_higher_mean_reward(jit: bool) -> None:
    probabilities = jnp.array([0.2, 0.8, 0.5])

    def step(state: BanditState, key: jax.Array) -> tuple[BanditState, jax.Array]:
        reward = jax.random.bernoulli(key, probabilities[state.arm]).astype(jnp.float32)
        return ucb1_update(state, reward), state.arm

    def play(key: jax.Array) -> tuple[BanditState, jax.Array]:
        return jax.lax.scan(step, _bandit(3), jax.random.split(key, 1000))

    state, arms = (jax.jit(play) if jit else play)(jax.random.PRNGKey(0))
    pulls = np.asarray(state.pulls)
    assert pulls.sum() == 1000 and list(np.asarray(arms[:3])) == [0, 1, 2]
    assert pulls[1] > 0.7 * 1000 and pulls[1] > pulls[2] > pulls[0]  # the best arm most, the worst least
    assert int(ucb1_choose(state.pulls, state.rewards)) == 1


def test_the_tournament_sends_each_child_to_the_closest_of_the_drawn_tasks() -> None:
    tasks = jax.random.uniform(jax.random.PRNGKey(1), (40, 2))
    parents = jnp.array([0, 5, 17, 39, 22, 22])
    key = jax.random.PRNGKey(3)
    drawn = np.asarray(jax.random.randint(key, (6, 8), 0, 40, jnp.int32))  # the draws, as documented
    for size in (1, 3, 8):
        won = np.asarray(jax.jit(closest_task_tournament, static_argnums=4)(key, parents, tasks, size, 8))
        for i, parent in enumerate(np.asarray(parents)):
            pool = drawn[i, :size]
            distances = np.linalg.norm(np.asarray(tasks)[pool] - np.asarray(tasks)[parent], axis=1)
            assert won[i] == pool[np.argmin(distances)]
    # a tournament far larger than the number of tasks draws the parent's own task: it wins
    assert np.array_equal(np.asarray(closest_task_tournament(key, parents, tasks, 400, 400)), np.asarray(parents))


@pytest.mark.parametrize("reward", ["count", "rate"])
def test_the_emitter_sends_children_to_their_parent_s_task_and_rewards_the_bandit(reward: str) -> None:
    centroids = jnp.linspace(0.0, 1.0, 20)[:, None] * jnp.ones((1, 2))  # 20 tasks on the diagonal
    empty = cvt_repertoire({"x": jnp.zeros((3,)), "task": jnp.zeros((), jnp.int32)}, centroids)
    elites = {"x": jax.random.uniform(jax.random.PRNGKey(0), (20, 3)), "task": jnp.arange(20, dtype=jnp.int32)}
    repertoire, _ = empty.add(elites, centroids, -jnp.ones((20,)))
    config = MTMEConfig(batch_size=16, tournament_sizes=(1, 1000), bandit_reward=reward)  # type: ignore[arg-type]
    emitter = make_multi_task_emitter(config, 0.0, 1.0)
    state = emitter.init(jax.random.PRNGKey(1), repertoire, None, None)  # type: ignore[arg-type]
    # a tournament of 1000 among 20 tasks draws the parent's own task (all but surely): it wins
    state = state._replace(arm=jnp.int32(1))
    key = jax.random.PRNGKey(2)
    children = jax.jit(emitter.emit)(state, repertoire, key)
    parents = repertoire.sample(jax.random.split(key, 3)[0], 32)  # the emitter's draw, as documented
    np.testing.assert_array_equal(np.asarray(children["task"]), np.asarray(parents["task"][:16]))
    assert children["x"].shape == (16, 3) and bool(jnp.all((children["x"] >= 0) & (children["x"] <= 1)))
    assert int(emitter.log_metrics(state)["tournament_size"]) == 1000
    added = jnp.zeros((16,), bool).at[jnp.array([3, 9, 11])].set(True)
    result = AddResult(added, added, jnp.zeros((16,)), jnp.zeros((16,), jnp.int32))
    after = emitter.update(state, repertoire, children, None, result, key)  # type: ignore[arg-type]
    np.testing.assert_array_equal(np.asarray(after.pulls), [0, 1])
    np.testing.assert_allclose(np.asarray(after.rewards), [0.0, 3.0 if reward == "count" else 3 / 16])
    assert int(after.arm) == 0  # size 1 untried: it comes next


def test_arm_fitness_on_hand_computed_configurations() -> None:
    def f(g: list[float], alpha: float, length: float) -> float:
        return float(multi_task_arm_fitness(jnp.asarray(g), jnp.asarray([alpha, length])))

    # every gene 0.5: all joints straight, the tip at (L, 0)
    assert f([0.5] * 10, 0.3, 1.0) == pytest.approx(-math.sqrt(0.5))
    assert f([0.5] * 10, 0.9, 0.5) == pytest.approx(-0.5)
    # two joints, alpha = 1 (each within [-pi/2, pi/2]), L = 1: g = (1, 0.5) bends the first by pi/2
    assert f([1.0, 0.5], 1.0, 1.0) == pytest.approx(-math.sqrt(0.5), abs=1e-6)  # tip (0, 1)
    assert f([1.0, 1.0], 1.0, 1.0) == pytest.approx(-1.0, abs=1e-6)  # tip (-0.5, 0.5)
    assert f([0.75, 0.75], 1.0, 1.0) == pytest.approx(  # angles pi/4, pi/4: tip (sqrt(1/8), 1/2 + sqrt(1/8))
        -math.hypot(math.sqrt(1 / 8) - 0.5, math.sqrt(1 / 8)), abs=1e-6
    )
    assert f([1.0, 1.0], 0.0, 1.0) == f([0.5, 0.5], 0.0, 1.0)  # alpha = 0: the joints cannot move


def test_the_arm_family_scores_each_genotype_on_its_task_with_the_task_as_descriptor() -> None:
    task = make_task("multi_task_arm", num_dofs=4, num_tasks=30, cvt_samples=300, kmeans_iters=5)
    genotypes = task.init_genotypes(jax.random.PRNGKey(0), 16)
    assert genotypes["x"].shape == (16, 4) and genotypes["task"].dtype == jnp.int32
    ev = task.scoring_fn(genotypes, jax.random.PRNGKey(1))
    from qdrl.tasks.multi_task import multi_task_family

    parameters = np.asarray(multi_task_family(30, 0, 300, 5).parameters())
    np.testing.assert_array_equal(np.asarray(ev.descriptors), parameters[np.asarray(genotypes["task"])])
    expected = [multi_task_arm_fitness(x, p) for x, p in zip(genotypes["x"], parameters[np.asarray(genotypes["task"])], strict=True)]
    np.testing.assert_allclose(np.asarray(ev.fitnesses), np.asarray(expected), rtol=1e-6)
    assert np.all(np.asarray(ev.fitnesses) >= task.qd_offset) and np.all(np.asarray(ev.fitnesses) <= 0.0)


SPEC = """
[experiment]
algorithm = "mt_me"
seed = 3

[task]
name = "multi_task_arm"
num_dofs = 5
num_tasks = 40
cvt_samples = 400
kmeans_iters = 10

[mt_me]
batch_size = 8
tournament_sizes = [1, 4, 16]

[qd]
num_iterations = 8
log_every = 4
init_batch_size = 8

[log]
progress = false
plots = false
checkpoint_every = 1
keep_checkpoints = 2
"""


def test_a_tiny_mt_me_run_keeps_one_elite_per_task_and_resumes_bit_identically(tmp_path: Path) -> None:
    spec = tmp_path / "mt_me.toml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    assert main(["run", str(spec), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["evaluations"] == 8 + 8 * 8 and summary["num_elites"] > 0
    exported = dict(np.load(out / "repertoire.npz"))
    filled = exported["filled"]
    # cell i is task i: each elite was scored on its cell's task, whose parameters are its descriptor
    np.testing.assert_array_equal(exported["genotypes['task']"][filled], np.flatnonzero(filled))
    np.testing.assert_array_equal(exported["descriptors"][filled], exported["centroids"][filled])
    rows = (out / "metrics.csv").read_text().splitlines()
    assert "tournament_size" in rows[0] and len(rows) == 3
    # the first checkpoint holds the bandit: the second half replayed from it ends where the run did
    checkpoints = sorted((out / "checkpoints").glob("step_*"))
    assert len(checkpoints) == 2
    shutil.rmtree(checkpoints[-1])
    resumed = run_spec(spec, [], out, resume=True)
    for key in ("qd_score", "mean_fitness", "coverage", "num_elites", "evaluations"):
        assert resumed[key] == summary[key], key
    for name, array in exported.items():
        np.testing.assert_array_equal(np.load(out / "repertoire.npz")[name], array, err_msg=name)
    # every logged column but the clock's (wall_s, evaluations_per_s), the bandit's choice included
    again = (out / "metrics.csv").read_text().splitlines()
    assert [r.split(",")[:12] for r in again] == [r.split(",")[:12] for r in rows]
    assert rows[0].split(",")[11] == "tournament_size"


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("mt_me.tournament_sizes=[]", "mt_me.tournament_sizes: expected at least one size, got []"),
        ("mt_me.tournament_sizes=[1, 4, 4]", "mt_me.tournament_sizes: expected distinct sizes, got [1, 4, 4]"),
        ("mt_me.tournament_sizes=[0, 4]", "mt_me.tournament_sizes"),
        ("mt_me.batch_size=0", "mt_me.batch_size: expected a positive integer, got 0"),
        ('mt_me.bandit_reward="sum"', "mt_me.bandit_reward: expected one of"),
        ('mt_me.variation="gauss"', "mt_me.variation: expected one of"),
        ('task.name="arm"', "task.name: expected one of ['multi_task_arm', 'multi_task_halfcheetah'], got 'arm'"),
        ("task.num_tasks=0", "task.num_tasks: expected a positive integer, got 0"),
        ("task.cvt_samples=10", "task.cvt_samples: expected at least task.num_tasks=40, got 10"),
        ("repertoire.num_centroids=64", "repertoire.num_centroids: expected 40 (set by task.num_tasks: mt_me keeps"),
        ('repertoire.kind="grid"', "repertoire.kind: expected 'cvt' (set by mt_me: mt_me keeps one elite per task"),
        ("repertoire.cvt_seed=5", "repertoire.cvt_seed: expected 0 (set by task.task_seed"),
        ('repertoire.kind="hex"', "repertoire.kind: expected one of 'grid', 'cvt'"),
    ],
)
def test_bad_mt_me_values_are_refused_before_anything_is_built(tmp_path: Path, override: str, message: str) -> None:
    spec = tmp_path / "mt_me.toml"
    spec.write_text(SPEC)
    with pytest.raises(ConfigError) as err:
        check_spec(load_spec(spec, [override]))  # pure Python: parses and checks, builds nothing
    assert message in str(err.value)


def test_sbx_is_refused_for_the_unbounded_policies_of_the_halfcheetah_family() -> None:
    spec = {"experiment": {"algorithm": "mt_me"}, "task": {"name": "multi_task_halfcheetah"}, "mt_me": {}}
    with pytest.raises(ConfigError, match=r"mt_me\.variation: expected 'isoline' for task 'multi_task_halfcheetah'"):
        check_spec(spec)
    assert check_spec({**spec, "mt_me": {"variation": "isoline"}}) is not None


def test_a_repertoire_that_agrees_with_the_tasks_is_accepted(tmp_path: Path) -> None:
    spec = tmp_path / "mt_me.toml"
    spec.write_text(SPEC)
    checked = check_spec(load_spec(spec, ["repertoire.num_centroids=40", 'repertoire.kind="cvt"']))
    assert checked is not None


@pytest.mark.slow  # compiles a brax rollout (about 30 s on 2 cores)
def test_the_halfcheetah_family_scores_one_policy_under_each_task_s_dynamics() -> None:
    task = make_task("multi_task_halfcheetah", episode_length=20, num_tasks=10, cvt_samples=200, policy_hidden=(8,))
    genotypes = task.init_genotypes(jax.random.PRNGKey(0), 1)
    one = jax.tree.map(lambda a: jnp.concatenate([a] * 4), genotypes["x"])  # one policy, four times
    tasks = jnp.array([0, 3, 7, 3], jnp.int32)
    ev = jax.jit(task.scoring_fn)({"x": one, "task": tasks}, jax.random.PRNGKey(1))
    returns = np.asarray(ev.fitnesses)
    assert returns[1] == returns[3]  # same policy, same task: the same episode
    assert len({float(returns[0]), float(returns[1]), float(returns[2])}) == 3  # other dynamics, other returns
    from qdrl.tasks.multi_task import multi_task_family

    np.testing.assert_array_equal(np.asarray(ev.descriptors), np.asarray(multi_task_family(10, 0, 200, 50).parameters())[np.asarray(tasks)])
    assert int(ev.env_steps) == 4 * 20
