"""QDAC's feature functions (`qdrl.envs.brax`) against physics, and the tasks built on them.

One jitted rollout per robot (ant, humanoid) computes every feature at once; each
task of `FEATURE_TASKS` is evaluated once, 2 policies for 5 steps (the humanoid's
three tasks are the slow ones: one in the default run, the others with `-m slow`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.envs.brax import STATE_DESCRIPTORS, BraxEnv, heading, make_brax_env
from qdrl.tasks import TASKS, make_task
from qdrl.tasks.brax_features import FEATURE_SPACES, FEATURE_TASKS, FeatureSpace
from qdrl.tasks.brax_qd import REWARD_OFFSETS

STEPS = 30
FEATURES = ("velocity", "jump", "angle", "angle_raw", "feet_contact")


def _quaternion(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), *(math.sin(angle / 2) * np.asarray(axis))])


def _multiply(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = q
    w2, x2, y2, z2 = r
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


@pytest.mark.parametrize("jit", [False, True])
def test_heading_is_the_yaw_of_the_rotated_x_axis(jit: bool) -> None:
    from brax import math as brax_math

    fn = jax.jit(heading) if jit else heading
    # yaw by theta after a pitch or a roll (|angle| < pi/2): the heading is theta
    for theta in (0.0, 0.3, -2.0, 3.0):
        for tilt in (_quaternion((0, 1, 0), 0.7), _quaternion((1, 0, 0), -1.2)):
            q = _multiply(_quaternion((0, 0, 1), theta), tilt)
            assert float(fn(jnp.asarray(q))) == pytest.approx(theta, abs=1e-5)
            assert float(fn(jnp.asarray(3.0 * q))) == pytest.approx(theta, abs=1e-5)  # any norm
    # any rotation: the angle of brax's rotated x-axis in the x-y plane
    qs = jax.random.normal(jax.random.PRNGKey(0), (64, 4))
    x_axis = jax.vmap(
        lambda q: brax_math.rotate(jnp.array([1.0, 0.0, 0.0]), q / jnp.linalg.norm(q))
    )(qs)
    expected = np.arctan2(np.asarray(x_axis[:, 1]), np.asarray(x_axis[:, 0]))
    np.testing.assert_allclose(np.asarray(jax.vmap(fn)(qs)), expected, atol=1e-5)


def test_descriptor_sizes_names_and_errors() -> None:
    expected = {
        ("ant", "velocity"): ("x velocity", "y velocity"),
        ("ant", "jump"): ("lowest contact height",),
        ("ant", "angle"): ("heading cos", "heading sin"),
        ("ant", "angle_raw"): ("heading",),
        ("walker2d", "velocity"): ("x velocity",),
        ("antmaze", "velocity"): ("x velocity", "y velocity"),
    }
    for (name, descriptor), names in expected.items():
        env = BraxEnv(name, episode_length=5, state_descriptor=descriptor)
        assert env.descriptor_size == len(names) and env.descriptor_names == names, (
            name,
            descriptor,
        )
    assert BraxEnv("ant", state_descriptor="xy").descriptor_names == ("x", "y")
    with pytest.raises(ValueError, match="no velocity feature known for 'reacher'"):
        BraxEnv("reacher", state_descriptor="velocity")
    with pytest.raises(ValueError, match="no link called 'torso'"):
        BraxEnv("reacher", state_descriptor="angle")


def _features(name: str, steps: int = STEPS) -> Any:
    """A jitted, batched rollout of the raw brax robot `name` (thrown from (vx, vy, z), or from
    brax's reset where z <= 0) under random actions scaled by `scale`: the torso's x-y
    positions and every feature, at the start and after each step."""
    brax_env = make_brax_env(name, "spring")
    fns = {d: STATE_DESCRIPTORS[d](name, brax_env) for d in FEATURES}

    def features(pipeline_state: Any) -> dict[str, jax.Array]:
        return {d: fn(pipeline_state) for d, fn in fns.items()}

    def rollout(
        key: jax.Array, vx: jax.Array, vy: jax.Array, z: jax.Array, scale: jax.Array
    ) -> Any:
        state = brax_env.reset(key)
        # z > 0: thrown from the initial pose, z high, at (vx, vy); else brax's reset state
        thrown = jnp.asarray(brax_env.sys.init_q).at[2].set(z)
        q = jnp.where(z > 0, thrown, state.pipeline_state.q)
        qd = jnp.where(
            z > 0,
            jnp.zeros_like(state.pipeline_state.qd).at[0].set(vx).at[1].set(vy),
            state.pipeline_state.qd,
        )
        state = state.replace(pipeline_state=brax_env.pipeline_init(q, qd))
        actions = scale * jax.random.uniform(
            key, (steps, brax_env.action_size), minval=-1, maxval=1
        )

        def step(s: Any, a: jax.Array) -> tuple[Any, tuple[jax.Array, Any]]:
            s = brax_env.step(s, a)
            return s, (s.pipeline_state.x.pos[0, :2], features(s.pipeline_state))

        _, (xy, feats) = jax.lax.scan(step, state, actions)
        first = (state.pipeline_state.x.pos[0, :2], features(state.pipeline_state))
        return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, (xy, feats))

    return jax.jit(jax.vmap(rollout)), float(brax_env.dt)


def _check_shapes_and_bounds(feats: dict[str, np.ndarray], n_feet: int, n: int) -> None:
    shapes = {"velocity": 2, "jump": 1, "angle": 2, "angle_raw": 1, "feet_contact": n_feet}
    for d, size in shapes.items():
        assert feats[d].shape == (n, STEPS + 1, size), d
        assert np.all(np.isfinite(feats[d])), d
    # (cos, sin) of the raw angle, on the unit circle
    angle = feats["angle_raw"][..., 0]
    assert np.all(np.abs(angle) <= math.pi)
    np.testing.assert_allclose(
        feats["angle"], np.stack([np.cos(angle), np.sin(angle)], -1), atol=1e-5
    )
    np.testing.assert_allclose(np.linalg.norm(feats["angle"], axis=-1), 1.0, atol=1e-5)
    assert set(np.unique(feats["feet_contact"])) <= {0.0, 1.0}


def test_ant_features() -> None:
    run, dt = _features("ant")
    # thrown from 3 m at (3, -2) m/s without acting; standing (z <= 0: brax's reset) and acting
    vx, vy = jnp.array([3.0, 0.0]), jnp.array([-2.0, 0.0])
    z, scale = jnp.array([3.0, 0.0]), jnp.array([0.0, 1.0])
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    xy, feats = jax.device_get(run(keys, vx, vy, z, scale))
    _check_shapes_and_bounds(feats, 4, 2)
    velocity = feats["velocity"]
    assert np.all(np.abs(velocity) <= 5.0)
    displacement = np.diff(xy, axis=1) / dt  # (2, STEPS, 2)
    # in the air (about 12 steps before the ant lands) the velocity is constant and is the
    # finite difference of the torso's position
    np.testing.assert_allclose(velocity[0, :9], [[3.0, -2.0]] * 9, atol=1e-4)
    np.testing.assert_allclose(displacement[0, :8], velocity[0, 1:9], atol=1e-3)
    # on the ground, contacts change the velocity within a step (10 substeps): only the
    # episode's average velocity is the finite difference of the positions
    np.testing.assert_allclose(displacement[1].mean(0), velocity[1, 1:].mean(0), atol=0.05)
    assert np.abs(velocity[1]).max() > 0.3  # it moves
    # brax's reset turns the ant by up to about 0.22 rad (uniform noise on its quaternion)
    assert np.all(np.abs(feats["angle_raw"][:, 0, 0]) < 0.25)
    jump = feats["jump"][..., 0]
    assert np.all(np.diff(jump[0, :9]) < 0) and jump[0, 0] > 1.0  # falling, from high above
    assert np.all(jump[1, 5:] > -0.02) and np.all(jump[1, 5:] < 0.1)  # near the floor
    # a foot touching the floor lowers the lowest contact point below it
    touching = feats["feet_contact"].any(-1)
    np.testing.assert_array_equal(touching, jump < 0)


def test_humanoid_features() -> None:
    run, dt = _features("humanoid")
    zeros = jnp.zeros(2)
    keys = jax.random.split(jax.random.PRNGKey(2), 2)
    xy, feats = jax.device_get(run(keys, zeros, zeros, zeros, jnp.array([0.0, 1.0])))  # reset
    _check_shapes_and_bounds(feats, 2, 2)
    # brax's reset faces the pelvis along +x, up to its small reset noise
    np.testing.assert_allclose(feats["angle"][:, 0], [[1.0, 0.0]] * 2, atol=0.05)
    displacement = np.diff(xy, axis=1) / dt
    np.testing.assert_allclose(displacement.mean(1), feats["velocity"][:, 1:].mean(1), atol=0.01)
    jump = feats["jump"][..., 0]
    # the humanoid is dropped from just above the floor: its feet (the only bodies that
    # collide) start about 10 cm up, the contact point halfway
    assert np.all(jump[:, 0] > 0.04) and np.all(jump[:, 0] < 0.06)
    # it lands within 10 steps and then stands: the lowest contact point is at the floor
    assert np.all(jump[:, 10:20] > -0.005) and np.all(jump[:, 10:20] < 0.005)
    assert np.all(jump >= -0.005) and np.all(jump <= 0.06)
    np.testing.assert_array_equal(feats["feet_contact"].any(-1), jump < 0)


def test_feature_spaces() -> None:
    assert set(FEATURE_SPACES) == set(FEATURE_TASKS) <= set(TASKS)
    assert all(TASKS[name].policy for name in FEATURE_TASKS)
    assert [n for n, s in FEATURE_SPACES.items() if s.angular] == ["humanoid_angle"]
    assert FEATURE_SPACES["ant_velocity"] == FeatureSpace(
        "velocity", (-5.0, -5.0), (5.0, 5.0), False
    )
    assert FEATURE_SPACES["humanoid_jump"] == FeatureSpace("jump", (0.0,), (0.25,), False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        FEATURE_SPACES["humanoid_jump"].low = (1.0,)  # type: ignore[misc]


# The humanoid compiles slowly: its features are checked in the default run (test_humanoid_features),
# its tasks with -m slow.
SLOW = ("humanoid_angle", "humanoid_feet_contact", "humanoid_jump")


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in FEATURE_TASKS]
)
def test_task_scores_two_policies(name: str) -> None:
    episode = 5
    task = make_task(name, episode_length=episode, eval_batch=2, policy_hidden=(8,))
    space = FEATURE_SPACES[name]
    robot = name.split("_", 1)[0]
    assert task.name == name and task.episode_descriptor == "mean"
    assert (task.descriptor_low, task.descriptor_high) == (space.low, space.high)
    assert task.descriptor_size == len(space.low) == len(task.descriptor_names)
    assert task.qd_offset == pytest.approx(-REWARD_OFFSETS[f"{robot}_uni"] * episode)
    genotypes = task.init_genotypes(jax.random.PRNGKey(0), 2)
    ev = jax.device_get(jax.jit(task.scoring_fn)(genotypes, jax.random.PRNGKey(1)))
    fitnesses, descriptors = np.asarray(ev.fitnesses), np.asarray(ev.descriptors)
    assert fitnesses.shape == (2,) and descriptors.shape == (2, len(space.low))
    assert np.all(np.isfinite(fitnesses)) and np.all(np.isfinite(descriptors))
    assert np.all(descriptors >= np.asarray(space.low)) and np.all(
        descriptors <= np.asarray(space.high)
    )
    # the episode's average of the per-step features (clipped to the bounds)
    mask = np.asarray(ev.extras["mask"])
    steps = np.asarray(ev.extras["transitions"].next_desc)
    mean = (steps * mask[..., None]).sum(0) / mask.sum(0)[:, None]
    np.testing.assert_allclose(descriptors, np.clip(mean, space.low, space.high), atol=1e-5)
