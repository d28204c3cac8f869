"""Brax adapter: any registered brax environment, on a backend chosen by name.

The raw brax environment (`brax.envs.get_environment`) has no time limit and no
automatic reset; qdrl's `Env` base adds both, keeping termination apart from
truncation. The state descriptor is a function of the brax pipeline state, picked
by name (`STATE_DESCRIPTORS`):

- "xy": the torso's x-y position (final-position tasks and skill discovery);
- "x": the torso's x position alone (the planar robots' final-position task, METRA's
  HalfCheetah coverage);
- "feet_contact": which feet touch the ground, 0/1 per foot (the feet-contact QD tasks);
- "velocity": the torso's linear velocity, x-y for the ant and the humanoid, x for
  the planar robots;
- "jump": the height of the lowest of the system's contact points (one dimension);
- "angle": the body's heading in the x-y plane as (cos, sin), "angle_raw" as the
  angle in [-pi, pi].

The last four, with feet contact, are the feature functions of QDAC (Grillotti,
Faldor, González León and Cully, ICML 2024, "Quality-Diversity Actor-Critic",
`dreamerv3/embodied/core/feat_wrappers.py`). The reward is brax's own, or a variant
of it (`reward="no_forward"`: brax's reward without its forward term, for the
omni-directional tasks).

Besides brax's registry, two walled ant environments are available by name:
"antmaze" and "anttrap" (`qdrl.envs.brax_walls`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any, Literal, get_args

import jax
import jax.numpy as jnp

from qdrl.envs.base import Env
from qdrl.types import Array, PRNGKey

# brax's physics pipelines (a spec's `backend` keys are declared as this type).
Backend = Literal["spring", "positional", "generalized", "mjx"]
BACKENDS: tuple[str, ...] = get_args(Backend)

# pipeline state -> state descriptor (D,)
DescriptorFn = Callable[[Any], Array]
# (environment name, brax env) -> DescriptorFn; lets a descriptor depend on the robot
DescriptorFactory = Callable[[str, Any], DescriptorFn]
# brax env State after a step -> reward ()
RewardFn = Callable[[Any], Array]

# qdrl's own brax environments (walls added to brax's ant), and the robot each is built on.
WALLED_ENVS = ("antmaze", "anttrap")
ROBOT = {"antmaze": "ant", "anttrap": "ant"}

# Links whose contacts make the feet-contact descriptor, by link name or index, in link
# order (QDax's FeetContactWrapper for brax v2 enumerates `sys.link_names` the same way).
# Ant: the four lower legs, which brax leaves unnamed (links 2, 4, 6, 8; each carries a
# foot sphere). Humanoid: the shins, into which brax fuses the joint-less foot bodies.
FEET: dict[str, tuple[str | int, ...]] = {
    "ant": (2, 4, 6, 8),
    "halfcheetah": ("bfoot", "ffoot"),
    "walker2d": ("foot", "foot_left"),
    "hopper": ("foot",),
    "humanoid": ("right_shin", "left_shin"),
}

# The metric holding the forward (velocity) term of each robot's reward in brax 0.14.
FORWARD_REWARD_KEYS = {
    "ant": "reward_forward",
    "halfcheetah": "reward_run",
    "walker2d": "reward_forward",
    "hopper": "reward_forward",
    "humanoid": "reward_linvel",
}


# Names of the feet-contact descriptor's dimensions, in the order of `FEET` (the ant's
# lower legs 2, 4, 6, 8 belong to its front-left, front-right, back-left and back-right
# legs in brax's ant.xml).
FEET_NAMES: dict[str, tuple[str, ...]] = {
    "ant": tuple(f"{leg} foot contact" for leg in ("front-left", "front-right", "back-left", "back-right")),
    "halfcheetah": ("back foot contact", "front foot contact"),
    "walker2d": ("right foot contact", "left foot contact"),
    "hopper": ("foot contact",),
    "humanoid": ("right foot contact", "left foot contact"),
}


# The link whose linear velocity is the velocity feature and whose heading is the angle feature
# (QDAC's `COG_NAMES`: "torso" for every robot), and the robots whose heading is another link's.
TORSO = "torso"
HEADING_LINK: dict[str, str] = {"humanoid": "pelvis"}

# Dimensions of the velocity feature: x-y for the robots that roam the plane, x for the planar
# ones (QDAC's `VELOCITY_BOUNDS`).
VELOCITY_DIMS: dict[str, int] = {
    "ant": 2,
    "humanoid": 2,
    "walker2d": 1,
    "halfcheetah": 1,
    "hopper": 1,
}

# Names of the dimensions of the QDAC features that do not depend on the robot's feet.
VELOCITY_NAMES = ("x velocity", "y velocity")
X_NAMES = ("x",)
JUMP_NAMES = ("lowest contact height",)
ANGLE_NAMES = ("heading cos", "heading sin")
ANGLE_RAW_NAMES = ("heading",)


def torso_xy(pipeline_state: Any) -> Array:
    """x-y position of the first body (the torso in every brax locomotion robot)."""
    return pipeline_state.x.pos[0, :2]


def torso_x(pipeline_state: Any) -> Array:
    """(1,) x position of the first body (the torso)."""
    return pipeline_state.x.pos[0, :1]


def robot_of(name: str) -> str:
    """The brax robot an environment is built on ("anttrap" -> "ant")."""
    return ROBOT.get(name, name)


def feet_links(name: str, link_names: Sequence[str]) -> tuple[int, ...]:
    """Link indices of the feet of environment `name`, given its system's `link_names`."""
    robot = robot_of(name)
    if robot not in FEET:
        raise ValueError(f"no feet known for brax environment {name!r}; known: {sorted(FEET)}")
    links = list(link_names)
    idx = []
    for foot in FEET[robot]:
        if isinstance(foot, int):
            if not 0 <= foot < len(links):
                raise ValueError(f"{name}: foot link {foot} out of range ({len(links)} links)")
            idx.append(foot)
        elif foot in links:
            idx.append(links.index(foot))
        else:
            raise ValueError(f"{name}: no link called {foot!r} in {links}")
    return tuple(idx)


def _contacts(sys: Any, pipeline_state: Any) -> Any:
    """The pipeline state's contacts, or those computed from its link transforms (spring,
    positional and generalized keep them only with `debug=True`); None without collision pairs."""
    c = pipeline_state.contact
    return _lib().contact.get(sys, pipeline_state.x) if c is None else c


def feet_contact(sys: Any, feet: Sequence[int], pipeline_state: Any) -> Array:
    """(n_feet,) 1.0 where a foot touches something (a contact with distance < 0), else 0.0.

    A brax contact involves two links, `link_idx = (link_1, link_2)` (-1 for the
    world: floor and static walls); a foot touches when it is either of them in a
    penetrating contact. brax's locomotion robots only collide with the floor, so
    on them this is ground contact. The mjx pipeline fills `pipeline_state.contact`
    at every step; the other pipelines keep it only with `debug=True`, so it is
    computed here from the link transforms: one extra collision pass per env step
    (the physics step makes n_frames of them): a noticeable share of an ant's env
    step, next to nothing on humanoid (figures in docs/benchmarks.md).
    """
    c = _contacts(sys, pipeline_state)
    if c is None:  # a system without any collision pair
        return jnp.zeros((len(feet),), jnp.float32)
    foot = jnp.asarray(feet, jnp.int32)[:, None]
    link_1, link_2 = (jnp.asarray(i)[None, :] for i in c.link_idx)
    involved = (link_1 == foot) | (link_2 == foot)  # (n_feet, n_contacts)
    touching = involved & (jnp.asarray(c.dist)[None, :] < 0.0)
    return jnp.any(touching, axis=1).astype(jnp.float32)


def lowest_contact_height(sys: Any, pipeline_state: Any) -> Array:
    """(1,) height of the lowest contact point among all of the system's contact candidates.

    QDAC's jump feature (`JumpWrapper`): brax places a candidate's point midway between
    its two geoms, so a foot `h` above the floor gives `h / 2`, and a foot sinking into
    it a negative height. brax's locomotion robots only collide with the floor, so this
    is half the lowest gap between a colliding body part and the floor.
    """
    c = _contacts(sys, pipeline_state)
    if c is None:
        raise ValueError("the jump descriptor needs contacts; this system has no collision pair")
    return jnp.min(jnp.asarray(c.pos)[..., 2], axis=-1, keepdims=True)


def heading(rot: Array) -> Array:
    """() angle in [-pi, pi] from the x-axis to the x-y projection of the x-axis rotated by `rot`.

    `rot` is a (4,) quaternion (w, x, y, z) of any non-zero norm. The rotated x-axis is
    (w^2 + x^2 - y^2 - z^2, 2 (xy + wz), 2 (xz - wy)) / |rot|^2, the first column of the
    rotation matrix; QDAC's `AngleWrapper` takes the angle of its x-y components.
    """
    w, x, y, z = (rot[..., i] for i in range(4))
    return jnp.arctan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)


def _link_index(name: str, link_names: Sequence[str], link: str) -> int:
    links = list(link_names)
    if link not in links:
        raise ValueError(f"{name}: no link called {link!r} in {links}")
    return links.index(link)


def _xy_factory(name: str, brax_env: Any) -> DescriptorFn:
    del name, brax_env
    return torso_xy


def _x_factory(name: str, brax_env: Any) -> DescriptorFn:
    del name, brax_env
    return torso_x


def _feet_contact_factory(name: str, brax_env: Any) -> DescriptorFn:
    sys = brax_env.sys
    feet = feet_links(name, sys.link_names)

    def descriptor(pipeline_state: Any) -> Array:
        return feet_contact(sys, feet, pipeline_state)

    return descriptor


def _velocity_factory(name: str, brax_env: Any) -> DescriptorFn:
    """QDAC's velocity feature: the torso's linear velocity, its first `VELOCITY_DIMS` components."""
    robot = robot_of(name)
    if robot not in VELOCITY_DIMS:
        raise ValueError(f"no velocity feature known for {name!r}; known: {sorted(VELOCITY_DIMS)}")
    torso, dims = _link_index(name, brax_env.sys.link_names, TORSO), VELOCITY_DIMS[robot]

    def descriptor(pipeline_state: Any) -> Array:
        return pipeline_state.xd.vel[torso, :dims]

    return descriptor


def _jump_factory(name: str, brax_env: Any) -> DescriptorFn:
    """QDAC's jump feature: `lowest_contact_height`."""
    del name
    sys = brax_env.sys

    def descriptor(pipeline_state: Any) -> Array:
        return lowest_contact_height(sys, pipeline_state)

    return descriptor


def _heading_factory(trigonometric: bool) -> DescriptorFactory:
    """QDAC's angle feature: the `heading` of the torso (the humanoid's pelvis), as (cos, sin)
    (QDAC's default, an `AngularSpace`) or as the angle (`trigonometric=False`)."""

    def factory(name: str, brax_env: Any) -> DescriptorFn:
        idx = _link_index(name, brax_env.sys.link_names, HEADING_LINK.get(robot_of(name), TORSO))

        def descriptor(pipeline_state: Any) -> Array:
            angle = heading(pipeline_state.x.rot[idx])
            return jnp.stack([jnp.cos(angle), jnp.sin(angle)]) if trigonometric else angle[None]

        return descriptor

    return factory


STATE_DESCRIPTORS: dict[str, DescriptorFactory] = {
    "xy": _xy_factory,
    "x": _x_factory,
    "feet_contact": _feet_contact_factory,
    "velocity": _velocity_factory,
    "jump": _jump_factory,
    "angle": _heading_factory(trigonometric=True),
    "angle_raw": _heading_factory(trigonometric=False),
}


def state_descriptor_names(descriptor: str, name: str) -> tuple[str, ...] | None:
    """Names of the dimensions of the state descriptor `descriptor` of environment `name`
    (None where `Env.descriptor_names` picks its defaults: "xy", unknown robots)."""
    robot = robot_of(name)
    if descriptor == "feet_contact":
        return FEET_NAMES.get(robot)
    if descriptor == "velocity":
        return VELOCITY_NAMES[: VELOCITY_DIMS[robot]] if robot in VELOCITY_DIMS else None
    return {"x": X_NAMES, "jump": JUMP_NAMES, "angle": ANGLE_NAMES, "angle_raw": ANGLE_RAW_NAMES}.get(descriptor)


def no_forward_reward(name: str) -> RewardFn:
    """brax's reward of `name` minus its forward term: survival minus control (and contact) costs.

    The reward of QDax's omni-directional tasks (`NoForwardRewardWrapper`).
    """
    robot = robot_of(name)
    if robot not in FORWARD_REWARD_KEYS:
        raise ValueError(
            f"no forward reward term known for {name!r}; known: {sorted(FORWARD_REWARD_KEYS)}"
        )
    key = FORWARD_REWARD_KEYS[robot]

    def reward(state: Any) -> Array:
        return state.reward - state.metrics[key]

    return reward


REWARDS: dict[str, Callable[[str], RewardFn]] = {"no_forward": no_forward_reward}


def scaled_system(sys: Any, gravity_scale: Array | float, gear_scale: Array | float) -> Any:
    """`sys` with its gravity multiplied by `gravity_scale` () and each actuator's strength by
    `gear_scale` (() or (num_actuators,)); jittable, so the scales may be traced.

    Both of brax's copies are scaled: `gravity` and `actuator.gear`, which the spring,
    positional and generalized pipelines read, and mjx's `opt.gravity` and
    `actuator_gear[:, 0]`, which the mjx pipeline reads (brax's halfcheetah sets its own
    gears for spring, so the two copies may differ; each is scaled by the same factors).
    """
    gravity_scale = jnp.asarray(gravity_scale, jnp.float32)
    gear_scale = jnp.broadcast_to(jnp.asarray(gear_scale, jnp.float32), jnp.shape(sys.actuator.gear))
    mjx_gear = jnp.asarray(sys.actuator_gear)
    sys = sys.replace(
        gravity=jnp.asarray(sys.gravity) * gravity_scale,
        actuator=sys.actuator.replace(gear=jnp.asarray(sys.actuator.gear) * gear_scale),
        actuator_gear=mjx_gear.at[:, 0].multiply(gear_scale.astype(mjx_gear.dtype)),
    )
    return sys.tree_replace({"opt.gravity": jnp.asarray(sys.opt.gravity) * gravity_scale})


def brax_env_names() -> list[str]:
    """Names `BraxEnv` accepts: brax's environment registry and qdrl's walled ants."""
    return sorted([*_lib().envs._envs, *WALLED_ENVS])


def make_brax_env(name: str, backend: str, **env_kwargs: Any) -> Any:
    """The raw brax environment `name` on `backend` (no time limit, no auto-reset)."""
    lib = _lib()
    if name in WALLED_ENVS:
        cls = {"antmaze": lib.AntMaze, "anttrap": lib.AntTrap}[name]
        return cls(backend=backend, **env_kwargs)
    return lib.envs.get_environment(name, backend=backend, **env_kwargs)


def _lib() -> Any:
    """brax's modules (`qdrl.envs.brax_lib`), imported on first use."""
    from qdrl.envs import brax_lib

    return brax_lib


def _strong(tree: Any) -> Any:
    """Cast floating leaves to strong float32 so reset and step states have one type.

    brax's reset returns strong float32 for `done` and some metrics while step returns
    weak types; without this, `jit(step)` compiles twice and `lax.cond` over the
    two states fails.
    """

    def cast(x: Any) -> Any:
        if isinstance(x, jax.Array | float) and jnp.issubdtype(jnp.result_type(x), jnp.floating):
            return jnp.asarray(x, jnp.float32)
        return x

    return jax.tree.map(cast, tree)


class BraxEnv(Env):
    """A brax environment behind qdrl's single-instance protocol.

    Args:
      name: a name from `brax_env_names()`.
      backend: brax physics pipeline, one of `BACKENDS`.
      episode_length: time limit (truncation).
      state_descriptor: a name from `STATE_DESCRIPTORS` ("xy", "feet_contact", "velocity",
        "x", "jump", "angle", "angle_raw") or a function of the pipeline state.
      reward: None (brax's reward), a name from `REWARDS` ("no_forward") or a
        function of the brax state after the step.
      env_kwargs: passed to the brax environment's constructor.
    """

    def __init__(
        self,
        name: str,
        backend: str = "spring",
        episode_length: int = 1000,
        state_descriptor: str | DescriptorFn = "xy",
        reward: str | RewardFn | None = None,
        **env_kwargs: Any,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"unknown brax backend {backend!r}; expected one of {BACKENDS}")
        names = brax_env_names()
        if name not in names:
            raise ValueError(f"unknown brax environment {name!r}; expected one of {names}")
        if episode_length <= 0:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        if isinstance(state_descriptor, str) and state_descriptor not in STATE_DESCRIPTORS:
            raise ValueError(
                f"unknown state descriptor {state_descriptor!r}; "
                f"expected one of {sorted(STATE_DESCRIPTORS)}"
            )
        if isinstance(reward, str) and reward not in REWARDS:
            raise ValueError(f"unknown reward {reward!r}; expected one of {sorted(REWARDS)}")

        self.name = name
        self.backend = backend
        self.episode_length = episode_length
        self.brax_env = make_brax_env(name, backend, **env_kwargs)
        self.action_size = int(self.brax_env.action_size)
        if isinstance(state_descriptor, str):
            self._descriptor_names = state_descriptor_names(state_descriptor, name)
            state_descriptor = STATE_DESCRIPTORS[state_descriptor](name, self.brax_env)
        self._descriptor = state_descriptor
        self._reward: RewardFn | None = REWARDS[reward](name) if isinstance(reward, str) else reward

    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        return self._traced("reset")(key)  # type: ignore[no-any-return]

    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        return self._traced("step")(inner, action)  # type: ignore[no-any-return]

    def _traced(self, which: str) -> Callable[..., Any]:
        """brax's reset or step (with the descriptor and reward) as a jitted function kept by
        this environment: inside a program it is an inner call that jax traces once per input
        type, so the many programs of a run (a rollout, its resets, the shapes of a task) share
        one trace of brax's Python (most of a second on the ant) and XLA inlines the call.

        Kept per brax environment object: `perturbed` copies the brax environment with another
        system, which gets functions of its own."""
        brax_env = self.brax_env
        kept = self.__dict__.get("_traced_fns")
        if kept is None or kept[0] is not brax_env:
            descriptor, reward_fn = self._descriptor, self._reward

            def reset(key: PRNGKey) -> tuple[Any, Array, Array]:
                state = _strong(brax_env.reset(key))
                return state, state.obs, descriptor(state.pipeline_state)

            def step(inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
                state = _strong(brax_env.step(inner, action))
                desc = descriptor(state.pipeline_state)
                reward = state.reward if reward_fn is None else reward_fn(state)
                return state, state.obs, reward, state.done, desc

            kept = (brax_env, {"reset": jax.jit(reset), "step": jax.jit(step)})
            self.__dict__["_traced_fns"] = kept
        return kept[1][which]  # type: ignore[no-any-return]

    # -- perturbed dynamics (qdrl.adapt) --

    def actuator_index(self, joint: str) -> int:
        """The index (in `sys.actuator`, and in the action) of the actuator that drives `joint`,
        by the joint's name in the robot's MJCF (brax leaves most actuators unnamed)."""
        model = self.brax_env.sys.mj_model
        joints = [model.joint(int(model.actuator_trnid[i, 0])).name for i in range(model.nu)]
        if joint not in joints:
            raise ValueError(f"{self.name}: no actuator drives a joint {joint!r}; actuated joints: {joints}")
        return joints.index(joint)

    def perturbed(
        self, gravity_scale: Array | float = 1.0, gear_scale: Array | float = 1.0, episode_length: int | None = None
    ) -> BraxEnv:
        """This environment with gravity and actuator strengths scaled (`scaled_system`), and
        another time limit if `episode_length` is given; self is unchanged.

        The scales may be traced: built inside a jitted (or vmapped) function, the new
        environment's steps read the traced system, so one program serves every value.
        A reset is unchanged: neither scale enters brax's reset.
        """
        brax_env = copy.copy(self.brax_env)
        brax_env.sys = scaled_system(self.brax_env.sys, gravity_scale, gear_scale)
        env = copy.copy(self)
        env.brax_env = brax_env
        env.__dict__.pop("_traced_resets", None)  # traced on the unperturbed system
        if episode_length is not None:
            if episode_length <= 0:
                raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
            env.episode_length = int(episode_length)
        return env
