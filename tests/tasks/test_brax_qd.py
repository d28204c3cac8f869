"""The brax QD tasks: feet links, bounds, and fitnesses checked against their definitions.

Every task is evaluated once (4 policies, 60-step episodes, spring) through its
scoring function and the result is shared by the tests. The XLA backend is asked
for a quick compile (optimisation level 0): it halves compile times here, and
the tests check semantics, not speed.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.envs.brax import FEET, BraxEnv, feet_links, no_forward_reward
from qdrl.qd.base import Evaluation
from qdrl.tasks import brax_qd
from qdrl.tasks.base import Task
from qdrl.tasks.policy import num_parameters

EPISODE = 60
FAST_COMPILE: dict[str, Any] = {
    "xla_backend_optimization_level": 0,
    "xla_llvm_disable_expensive_passes": True,
}
CONSTANT = 0.9  # the action of the second policy of each batch; the first one acts 0


def constant_policy(template: Any, action: float) -> Any:
    """Parameters of a policy whose output is `action` everywhere: zero weights, last bias."""
    params = jax.tree.map(jnp.zeros_like, template)
    last = sorted(params)[-1]
    params[last]["b"] = jnp.full_like(params[last]["b"], math.atanh(action))
    return params


def stack(*trees: Any) -> Any:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


class Evaluated:
    """Tasks built and evaluated on demand, each compiled once per test module."""

    def __init__(self) -> None:
        self.tasks: dict[str, Task] = {}
        self.results: dict[str, tuple[Task, Evaluation]] = {}

    def task(self, name: str) -> Task:
        if name not in self.tasks:
            self.tasks[name] = brax_qd.BRAX_TASKS[name](episode_length=EPISODE)
        return self.tasks[name]

    def __call__(self, name: str) -> tuple[Task, Evaluation]:
        if name not in self.results:
            task = self.task(name)
            genotypes = jax.tree.map(
                lambda c, r: jnp.concatenate([c, r]),
                stack(
                    constant_policy(task.genotype_template, 0.0),
                    constant_policy(task.genotype_template, CONSTANT),
                ),
                task.init_genotypes(jax.random.PRNGKey(0), 2),
            )
            key = jax.random.PRNGKey(1)
            compiled = jax.jit(task.scoring_fn).lower(genotypes, key).compile(FAST_COMPILE)
            self.results[name] = (task, jax.device_get(compiled(genotypes, key)))
        return self.results[name]


@pytest.fixture(scope="module")
def evaluated() -> Evaluated:
    return Evaluated()


def test_feet_are_the_links_named_in_the_literature() -> None:
    from brax import envs

    expected = {
        "ant": ((2, 4, 6, 8), ("", "", "", "")),
        "halfcheetah": ((3, 6), ("bfoot", "ffoot")),
        "walker2d": ((3, 6), ("foot", "foot_left")),
        "hopper": ((3,), ("foot",)),
        "humanoid": ((4, 6), ("right_shin", "left_shin")),
    }
    assert set(FEET) == set(expected)
    for robot, (idx, names) in expected.items():
        sys = envs.get_environment(robot, backend="spring").sys
        links = list(sys.link_names)
        assert feet_links(robot, links) == idx
        assert tuple(links[i] for i in idx) == names
        # each foot link owns a geom that collides (brax's robots only collide their feet
        # and a few body parts with the floor)
        colliding = set((np.asarray(sys.geom_bodyid) - 1)[np.asarray(sys.geom_contype) > 0])
        assert set(idx) <= colliding, robot
        if robot == "ant":  # the unnamed lower legs hang from aux_1 .. aux_4
            parents = [links[int(sys.link_parents[i])] for i in idx]
            assert parents == ["aux_1", "aux_2", "aux_3", "aux_4"]
    with pytest.raises(ValueError, match="no feet known"):
        feet_links("reacher", [])
    with pytest.raises(ValueError, match="no link called"):
        feet_links("hopper", ["torso"])
    with pytest.raises(ValueError, match="unknown reward"):
        BraxEnv("ant", reward="sideways")
    with pytest.raises(ValueError, match="no forward reward"):
        no_forward_reward("reacher")


def test_task_bounds_offsets_and_genotypes(evaluated: Evaluated) -> None:
    bounds = {
        "ant_uni": ([0.0] * 4, [1.0] * 4),
        "halfcheetah_uni": ([0.0] * 2, [1.0] * 2),
        "walker2d_uni": ([0.0] * 2, [1.0] * 2),
        "hopper_uni": ([0.0], [1.0]),
        "humanoid_uni": ([0.0] * 2, [1.0] * 2),
        "ant_omni": ([-30.0, -30.0], [30.0, 30.0]),
        "humanoid_omni": ([-30.0, -30.0], [30.0, 30.0]),
        "halfcheetah_omni": ([-0.75 * EPISODE], [0.75 * EPISODE]),
        "ant_trap": ([0.0, -8.0], [30.0, 8.0]),
        "ant_maze": ([-5.0, -5.0], [40.0, 40.0]),
    }
    offsets = {
        "ant_uni": 3.24,
        "halfcheetah_uni": 9.231,
        "walker2d_uni": 1.413,
        "hopper_uni": 0.9,
        "humanoid_uni": 0.0,
        "ant_omni": 3.0,
        "humanoid_omni": 0.0,
        "halfcheetah_omni": 0.6,
        "ant_trap": 3.38,
        "ant_maze": math.hypot(40.0, 40.0),
    }
    assert set(brax_qd.BRAX_TASKS) == set(bounds)
    for name, (low, high) in bounds.items():
        task = evaluated.task(name)
        assert task.name == name
        assert (list(task.descriptor_low), list(task.descriptor_high)) == (low, high)
        assert task.qd_offset == pytest.approx(-offsets[name] * EPISODE)
        assert (task.genotype_low, task.genotype_high) == (-math.inf, math.inf)
        assert task.genotype_size == num_parameters(task.genotype_template)
        genotypes = task.init_genotypes(jax.random.PRNGKey(0), 3)
        shapes = jax.tree.map(lambda x: x.shape[1:], genotypes)
        assert shapes == jax.tree.map(lambda x: x.shape, task.example_genotype())
    assert brax_qd.ant_uni(episode_length=10, policy_hidden=(8,)).genotype_size == (
        27 * 8 + 8 + 8 * 8 + 8
    )
    with pytest.raises(ValueError, match="backend"):
        brax_qd.hopper_uni(backend="warp")


# Each task compiles a brax rollout of its own; the default run checks the tasks that the
# fitness tests below evaluate anyway (three of the ant's four and halfcheetah_omni, sharing `evaluated`) and one
# feet-contact task (halfcheetah_uni); the other robots, and ant_trap (whose walls
# tests/test_brax_walls.py checks in the default run), run with `-m slow`.
DEFAULT = ("halfcheetah_uni", "ant_uni", "ant_omni", "ant_maze", "halfcheetah_omni")


def _cases(names: list[str]) -> list[Any]:
    return [n if n in DEFAULT else pytest.param(n, marks=pytest.mark.slow) for n in names]


@pytest.mark.parametrize("name", _cases(list(brax_qd.BRAX_TASKS)))
def test_batched_scoring_stays_in_bounds(evaluated: Evaluated, name: str) -> None:
    task, ev = evaluated(name)
    fitnesses, descriptors = np.asarray(ev.fitnesses), np.asarray(ev.descriptors)
    assert fitnesses.shape == (4,) and descriptors.shape == (4, task.descriptor_size)
    assert np.all(np.isfinite(fitnesses)) and np.all(np.isfinite(descriptors))
    assert np.all(descriptors >= np.asarray(task.descriptor_low))
    assert np.all(descriptors <= np.asarray(task.descriptor_high))
    lengths = np.asarray(ev.extras["mask"]).sum(0)
    assert int(ev.env_steps) == int(lengths.sum()) and np.all(lengths >= 1)
    # the first two policies act constantly, 0 and CONSTANT
    actions = np.asarray(ev.extras["transitions"].action)
    np.testing.assert_allclose(actions[:, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(actions[:, 1], CONSTANT, atol=1e-5)
    if name.endswith("_uni"):
        # a mean of 0/1 contact indicators over the episode's steps
        counts = descriptors * lengths[:, None]
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-3)


def test_a_standing_ant_touches_the_ground_with_all_feet(evaluated: Evaluated) -> None:
    _, ev = evaluated("ant_uni")
    descriptors = np.asarray(ev.descriptors)
    contacts = np.asarray(ev.extras["transitions"].next_desc)  # (T, 4, 4) per-step 0/1
    # zero action: once it has settled (it is dropped from 0.55 m and bounces), the ant
    # stands on its four feet
    assert np.all(contacts[-5:, 0] == 1.0) and np.all(descriptors[0] > 0.5)
    assert np.ptp(descriptors[2:]) > 0.05  # random policies lift their feet differently


def _survival_minus_control(
    actions: np.ndarray, mask: np.ndarray, healthy: float, ctrl_weight: float, scale: float = 1.0
) -> np.ndarray:
    cost = ctrl_weight * np.sum(np.square(scale * actions), axis=-1)
    return np.sum((healthy - cost) * mask, axis=0)


@pytest.mark.parametrize(
    ("name", "healthy", "ctrl_weight", "scale"),
    [
        ("ant_omni", 1.0, 0.5, 1.0),
        ("halfcheetah_omni", 0.0, 0.1, 1.0),
        pytest.param("humanoid_omni", 5.0, 0.1, 0.4, marks=pytest.mark.slow),
    ],
)
def test_omni_fitness_is_survival_minus_control_cost(
    evaluated: Evaluated, name: str, healthy: float, ctrl_weight: float, scale: float
) -> None:
    # humanoid maps actions in [-1, 1] onto its control range [-0.4, 0.4]
    _, ev = evaluated(name)
    tr, mask = ev.extras["transitions"], np.asarray(ev.extras["mask"])
    expected = _survival_minus_control(np.asarray(tr.action), mask, healthy, ctrl_weight, scale)
    np.testing.assert_allclose(np.asarray(ev.fitnesses), expected, rtol=1e-4, atol=1e-3)
    # large actions pay for themselves, whatever distance they cover
    f = np.asarray(ev.fitnesses) / mask.sum(0)
    assert f[0] > f[1] + 0.5 * ctrl_weight * len(tr.action[0, 0]) * (scale * CONSTANT) ** 2


@pytest.mark.slow
def test_trap_fitness_is_forward_progress_plus_survival_minus_control(evaluated: Evaluated) -> None:
    from qdrl.envs.brax_walls import TRAP_XY_CENTER, TRAP_XY_SCALE

    _, ev = evaluated("ant_trap")
    tr, mask = ev.extras["transitions"], np.asarray(ev.extras["mask"])
    lengths = mask.sum(0).astype(int)
    # observations start with the normalised torso x-y
    x0 = np.asarray(tr.obs[0, :, 0]) * TRAP_XY_SCALE[0] + TRAP_XY_CENTER[0]
    x_end = (
        np.asarray(tr.next_obs[lengths - 1, np.arange(4), 0]) * TRAP_XY_SCALE[0] + TRAP_XY_CENTER[0]
    )
    np.testing.assert_allclose(x0, 0.0, atol=0.11)
    dt = 0.05  # spring: 10 frames of 5 ms
    expected = (x_end - x0) / dt + _survival_minus_control(np.asarray(tr.action), mask, 1.0, 0.5)
    np.testing.assert_allclose(np.asarray(ev.fitnesses), expected, rtol=1e-3, atol=0.05)


def test_maze_fitness_is_minus_the_distance_to_the_target(evaluated: Evaluated) -> None:
    from qdrl.envs.brax_walls import MAZE_TARGET, MAZE_XY_CENTER, MAZE_XY_SCALE

    _, ev = evaluated("ant_maze")
    tr, mask = ev.extras["transitions"], np.asarray(ev.extras["mask"])
    xy = np.asarray(tr.next_obs[..., :2]) * np.asarray(MAZE_XY_SCALE) + np.asarray(MAZE_XY_CENTER)
    distance = np.linalg.norm(xy - np.asarray(MAZE_TARGET), axis=-1)
    np.testing.assert_allclose(np.asarray(ev.fitnesses), -np.sum(distance * mask, 0), rtol=1e-4)
    # the final descriptor is the torso x-y of the last step
    lengths = mask.sum(0).astype(int)
    np.testing.assert_allclose(np.asarray(ev.descriptors), xy[lengths - 1, np.arange(4)], atol=1e-4)


def test_uni_fitness_counts_forward_progress() -> None:
    """Ants thrown forwards, not at all and backwards, same random actions: return = dx/dt + sum(1 - 0.5|a|^2)."""
    env = BraxEnv("ant", "spring", EPISODE, state_descriptor="feet_contact")
    brax_env = env.brax_env
    actions = jax.random.uniform(jax.random.PRNGKey(3), (30, 8), minval=-0.5, maxval=0.5)

    def rollout(vx: jax.Array, z: jax.Array) -> tuple[jax.Array, ...]:
        state = env.reset(jax.random.PRNGKey(0))
        q = brax_env.sys.init_q.at[2].set(z)
        qd = jnp.zeros(brax_env.sys.qd_size()).at[0].set(vx)
        pipeline_state = jax.tree.map(
            lambda new, old: jnp.asarray(new, old.dtype),
            brax_env.pipeline_init(q, qd),
            state.inner.pipeline_state,
        )
        state = state._replace(inner=state.inner.replace(pipeline_state=pipeline_state))

        def step(s: Any, a: jax.Array) -> tuple[Any, tuple[jax.Array, jax.Array]]:
            s = env.step(s, a)
            return s, (s.reward, s.desc)

        end, (rewards, feet) = jax.lax.scan(step, state, actions)
        dx = end.inner.pipeline_state.x.pos[0, 0] - pipeline_state.x.pos[0, 0]
        return rewards.sum(), dx, feet

    # thrown from 1 m high, forwards, straight down and backwards; the last one falls from 2 m
    vx = jnp.array([5.0, 0.0, -5.0, 0.0])
    z = jnp.array([1.0, 1.0, 1.0, 2.0])
    run = jax.jit(jax.vmap(rollout)).lower(vx, z).compile(FAST_COMPILE)
    returns, dx, feet = jax.device_get(run(vx, z))
    ctrl = float(30 - 0.5 * np.sum(np.square(np.asarray(actions))))
    np.testing.assert_allclose(returns, dx / float(brax_env.dt) + ctrl, rtol=1e-3, atol=0.05)
    assert dx[0] > 0.5 and dx[2] < -0.5
    assert returns[0] > returns[1] + 10 > returns[2] + 20
    # a falling ant touches nothing at first, then lands
    assert np.all(feet[3, :5] == 0) and feet[3, -5:].max() == 1
    assert set(np.unique(feet)) <= {0.0, 1.0}
