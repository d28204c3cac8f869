"""Multi-objective tasks: fitness is a vector of M objectives, every one maximised.

| task | M | genotype | descriptor | reference point (fitness space) |
|---|---|---|---|---|
| mo_rastrigin | 2 | [-2, 4]^100 | first two genes, [-2, 4]^2 | (-150, -150) |
| zdt1, zdt2, zdt3 | 2 | [0, 1]^30 | first two genes, [0, 1]^2 | (-1, -1) |
| dtlz2 | 3 (M) | [0, 1]^12 | first two genes, [0, 1]^2 | (-1, ..., -1) |
| halfcheetah_multi, walker2d_multi, ant_multi | 2 | MLP policy | feet-contact rates | see `brax_multi` |

- `mo_rastrigin` is QDax's MOME example (Pierrot et al. 2022): two rastrigin
  functions of the genotype shifted by 0 and 2.2, fitness -(10 n + sum(x_i^2 -
  10 cos(2 pi x_i))) of each shift.
- ZDT1-3 (Zitzler, Deb & Thiele 2000) and DTLZ2 (Deb, Thiele, Laumanns & Zitzler
  2002) are minimisation problems; qdrl scores minus their objectives, so the
  usual reference point (1, 1) is (-1, -1) here and hypervolumes are unchanged.
  Their true fronts (`true_front`) have hypervolumes 2/3 (ZDT1), 1/3 (ZDT2) and
  1 - pi/6 (DTLZ2 with 3 objectives) w.r.t. that reference (`TRUE_HYPERVOLUME`).
- The brax tasks (absent from QDax; MOME's follow-up, Janmohamed et al. 2023,
  "Improving the data efficiency of multi-objective quality-diversity through
  gradient assistance and crowding exploration") have two objectives: the episode's
  forward reward (brax's forward-velocity term) and its energy cost (brax's control
  reward, minus ctrl_cost_weight |a|^2 per step, so higher is less energy), with the
  feet-contact descriptors of the `*_uni` tasks, on the same policies and rollout.

Their registry entries (`MO_TASKS`) tell a spec's number of objectives without building
the task, so specs are checked before anything is built.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Annotated, Any

import jax.numpy as jnp
import numpy as np

from qdrl.config import PositiveInt, Range
from qdrl.envs.brax import FORWARD_REWARD_KEYS, Backend, BraxEnv
from qdrl.tasks.base import Task, TaskEntry, batched_scoring_fn
from qdrl.tasks.brax_qd import DEFAULT_BACKEND, REWARD_OFFSETS
from qdrl.tasks.policy import DEFAULT_EVAL_BATCH, policy_task
from qdrl.types import Array

__all__ = [
    "MO_TASKS",
    "TRUE_HYPERVOLUME",
    "ant_multi",
    "dtlz2",
    "halfcheetah_multi",
    "mo_rastrigin",
    "true_front",
    "walker2d_multi",
    "zdt1",
    "zdt2",
    "zdt3",
]

NumDims = Annotated[int, Range(low=2)]
NumObjectives = Annotated[int, Range(low=2)]
Shift = Annotated[float, Range()]  # any finite shift
# A reference point in fitness space (maximisation); None: the task's default.
ReferencePoint = tuple[Annotated[float, Range()], ...] | None


def _reference(
    name: str, given: Sequence[float] | None, default: Sequence[float]
) -> tuple[float, ...]:
    if given is None:
        return tuple(float(v) for v in default)
    if len(given) != len(default):
        raise ValueError(
            f"task.reference_point: expected {len(default)} numbers (one per objective of "
            f"{name!r}), got {list(given)}"
        )
    return tuple(float(v) for v in given)


def _rastrigin(x: Array) -> Array:
    return 10.0 * x.shape[-1] + jnp.sum(x * x - 10.0 * jnp.cos(2.0 * jnp.pi * x), axis=-1)


def mo_rastrigin(
    num_dims: NumDims = 100, lag: Shift = 2.2, reference_point: ReferencePoint = None
) -> Task:
    """QDax's multi-objective rastrigin (MOME example): -rastrigin(x) and -rastrigin(x - lag).

    Genotypes in [-2, 4]^num_dims, descriptor (x_0, x_1) in [-2, 4]^2, reference
    point (-150, -150) as in QDax. With many genes no solution reaches it: per gene,
    rastrigin(x) + rastrigin(x - lag) >= 6.24 (lag 2.2), so f1 + f2 <= -6.24
    num_dims, and both objectives above -150 need num_dims < 48; for 100 genes give
    a lower one (qdrl's specs use (-1500, -1500), 15 per gene).
    """
    minval, maxval = -2.0, 4.0

    def evaluate(x: Array) -> tuple[Array, Array]:
        fitness = -jnp.stack([_rastrigin(x), _rastrigin(x - lag)])
        return fitness, x[:2]

    return Task(
        name="mo_rastrigin",
        scoring_fn=batched_scoring_fn(evaluate, num_dims),
        descriptor_low=(minval, minval),
        descriptor_high=(maxval, maxval),
        genotype_size=num_dims,
        genotype_low=minval,
        genotype_high=maxval,
        qd_offset=0.0,
        num_objectives=2,
        reference_point=_reference("mo_rastrigin", reference_point, (-150.0, -150.0)),
    )


def _zdt_g(x: Array) -> Array:
    return 1.0 + 9.0 * jnp.sum(x[1:]) / (x.shape[0] - 1)


def _zdt_h(kind: str, f1: Array, g: Array) -> Array:
    r = f1 / g
    if kind == "zdt1":
        return 1.0 - jnp.sqrt(r)
    if kind == "zdt2":
        return 1.0 - r * r
    return 1.0 - jnp.sqrt(r) - r * jnp.sin(10.0 * jnp.pi * f1)


def _unit_task(
    name: str, evaluate: Callable[[Array], tuple[Array, Array]], num_dims: int, reference: tuple[float, ...],
    default_reference: tuple[float, ...],
) -> Task:
    m = len(reference)
    known = name in ("zdt1", "zdt2", "zdt3") or (name == "dtlz2" and m == 3)
    points = 900 if name == "dtlz2" else 400
    return Task(
        name=name,
        scoring_fn=batched_scoring_fn(evaluate, num_dims),
        descriptor_low=(0.0, 0.0),
        descriptor_high=(1.0, 1.0),
        genotype_size=num_dims,
        genotype_low=0.0,
        genotype_high=1.0,
        qd_offset=0.0,
        num_objectives=len(reference),
        reference_point=reference,
        true_front=(lambda: true_front(name, points)) if known else None,
        # The true front's hypervolume is known from the default reference point only.
        true_hypervolume=TRUE_HYPERVOLUME.get(name) if known and reference == default_reference else None,
        minimised=True,
    )


def _zdt(kind: str, num_dims: int, reference_point: Sequence[float] | None) -> Task:
    def evaluate(x: Array) -> tuple[Array, Array]:
        x = jnp.clip(x, 0.0, 1.0)
        g = _zdt_g(x)
        f1 = x[0]
        f2 = g * _zdt_h(kind, f1, g)
        return -jnp.stack([f1, f2]), x[:2]

    return _unit_task(kind, evaluate, num_dims, _reference(kind, reference_point, (-1.0, -1.0)), (-1.0, -1.0))


def zdt1(num_dims: NumDims = 30, reference_point: ReferencePoint = None) -> Task:
    """ZDT1: minimise f1 = x_1 and f2 = g (1 - sqrt(f1 / g)), g = 1 + 9 sum_{i>1} x_i / (n - 1).

    Convex front f2 = 1 - sqrt(f1) (g = 1); scored as (-f1, -f2).
    """
    return _zdt("zdt1", num_dims, reference_point)


def zdt2(num_dims: NumDims = 30, reference_point: ReferencePoint = None) -> Task:
    """ZDT2: as ZDT1 with h = 1 - (f1 / g)^2: the concave front f2 = 1 - f1^2."""
    return _zdt("zdt2", num_dims, reference_point)


def zdt3(num_dims: NumDims = 30, reference_point: ReferencePoint = None) -> Task:
    """ZDT3: h = 1 - sqrt(f1 / g) - (f1 / g) sin(10 pi f1): a front of five disconnected pieces."""
    return _zdt("zdt3", num_dims, reference_point)


def dtlz2(
    num_dims: NumDims = 12, num_objectives: NumObjectives = 3, reference_point: ReferencePoint = None
) -> Task:
    """DTLZ2: minimise f_j = (1 + g) prod cos(x_i pi / 2) ... sin(x_{M-j} pi / 2), g = sum_{i>=M} (x_i - 0.5)^2.

    The front is the unit sphere's positive orthant (g = 0); n = M + 9 by default
    (k = 10). Scored as minus the objectives.
    """
    m = num_objectives
    if num_dims < m:
        raise ValueError(f"task.num_dims: expected at least task.num_objectives={m}, got {num_dims}")

    def evaluate(x: Array) -> tuple[Array, Array]:
        x = jnp.clip(x, 0.0, 1.0)
        g = jnp.sum((x[m - 1 :] - 0.5) ** 2)
        # cos(x pi/2) as sin((1 - x) pi/2): exactly 0 at x = 1, where float32's cos(pi/2) is
        # -4.4e-8 and would put points with negative objectives beyond the true front.
        cos = jnp.sin((1.0 - x[: m - 1]) * (jnp.pi / 2.0))
        sin = jnp.sin(x[: m - 1] * (jnp.pi / 2.0))
        f = []
        for j in range(m):
            # f_j: the first M-1-j cosines, then the sine of the next angle (none for j = 0).
            term = jnp.prod(cos[: m - 1 - j])
            if j > 0:
                term = term * sin[m - 1 - j]
            f.append((1.0 + g) * term)
        return -jnp.stack(f), x[:2]

    default = (-1.0,) * m
    return _unit_task("dtlz2", evaluate, num_dims, _reference("dtlz2", reference_point, default), default)


TRUE_HYPERVOLUME: dict[str, float] = {
    "zdt1": 2.0 / 3.0,
    "zdt2": 1.0 / 3.0,
    "dtlz2": 1.0 - math.pi / 6.0,  # with 3 objectives: the unit cube less the sphere's octant
}


def true_front(name: str, num_points: int, num_objectives: int = 3) -> np.ndarray:
    """(k, M) points of the true Pareto front of a ZDT or DTLZ2 task, in fitness space (negated).

    ZDT: f1 on a regular grid of [0, 1] (ZDT3: only its non-dominated pieces);
    DTLZ2: about `num_points` points of the sphere's orthant (3 objectives: a grid
    of the two angles).
    """
    f1 = np.linspace(0.0, 1.0, num_points)
    if name == "zdt1":
        pts = np.stack([f1, 1.0 - np.sqrt(f1)], axis=1)
    elif name == "zdt2":
        pts = np.stack([f1, 1.0 - f1**2], axis=1)
    elif name == "zdt3":
        pts = np.stack([f1, 1.0 - np.sqrt(f1) - f1 * np.sin(10.0 * np.pi * f1)], axis=1)
        dominated = np.array([np.any(np.all(pts <= p, axis=1) & np.any(pts < p, axis=1)) for p in pts])
        pts = pts[~dominated]
    elif name == "dtlz2":
        if num_objectives != 3:
            raise ValueError(f"true_front: dtlz2 is drawn for 3 objectives, got {num_objectives}")
        side = max(2, int(math.sqrt(num_points)))
        grid_a, grid_b = np.meshgrid(np.linspace(0, np.pi / 2, side), np.linspace(0, np.pi / 2, side))
        a, b = grid_a.ravel(), grid_b.ravel()
        pts = np.stack([np.cos(a) * np.cos(b), np.cos(a) * np.sin(b), np.sin(a)], axis=1)
    else:
        raise ValueError(f"true_front: no known front for task {name!r}")
    return -pts


def _brax_multi(
    task: str,
    robot: str,
    episode_length: int,
    backend: str,
    policy_hidden: Sequence[int],
    eval_batch: int,
    reference_point: Sequence[float] | None,
) -> Task:
    env = BraxEnv(robot, backend, episode_length, state_descriptor="feet_contact")
    forward_key = FORWARD_REWARD_KEYS[robot]

    def objectives(state: Any) -> Array:
        metrics = state.inner.metrics
        return jnp.stack([metrics[forward_key], metrics["reward_ctrl"]], axis=-1)

    # Forward: the uni task's reward offset per step (QDax's bound below most returns);
    # energy: the largest control cost, ctrl_cost_weight x action_size per step.
    ctrl_weight = float(env.brax_env._ctrl_cost_weight)
    default = (
        -REWARD_OFFSETS[f"{robot}_uni"] * episode_length,
        -ctrl_weight * env.action_size * episode_length,
    )
    n_feet = env.descriptor_size
    return policy_task(
        task, env, "mean", (0.0,) * n_feet, (1.0,) * n_feet, qd_offset=0.0,
        policy_hidden=policy_hidden, eval_batch=eval_batch, objectives=objectives,
        reference_point=_reference(task, reference_point, default),
    )


def halfcheetah_multi(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    reference_point: ReferencePoint = None,
) -> Task:
    """HalfCheetah, feet-contact rates in [0, 1]^2; objectives: forward reward, -0.1 sum |a|^2.

    Default reference point (-9.231 T, -0.6 T) for episodes of T steps.
    """
    return _brax_multi(
        "halfcheetah_multi", "halfcheetah", episode_length, backend, policy_hidden, eval_batch,
        reference_point,
    )


def walker2d_multi(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    reference_point: ReferencePoint = None,
) -> Task:
    """Walker2d, feet-contact rates in [0, 1]^2; objectives: forward reward, -0.001 sum |a|^2.

    Episodes end when the walker falls. Default reference point (-1.413 T, -0.006 T).
    """
    return _brax_multi(
        "walker2d_multi", "walker2d", episode_length, backend, policy_hidden, eval_batch,
        reference_point,
    )


def ant_multi(
    episode_length: PositiveInt = 1000,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (64, 64),
    eval_batch: PositiveInt = DEFAULT_EVAL_BATCH,
    reference_point: ReferencePoint = None,
) -> Task:
    """Ant, feet-contact rates in [0, 1]^4; objectives: forward reward, -0.5 sum |a|^2.

    Episodes end when the torso leaves z in [0.2, 1]. Default reference point
    (-3.24 T, -4 T).
    """
    return _brax_multi(
        "ant_multi", "ant", episode_length, backend, policy_hidden, eval_batch, reference_point
    )


MO_TASKS: dict[str, TaskEntry] = {
    "mo_rastrigin": TaskEntry(mo_rastrigin, objectives=2),
    "zdt1": TaskEntry(zdt1, objectives=2),
    "zdt2": TaskEntry(zdt2, objectives=2),
    "zdt3": TaskEntry(zdt3, objectives=2),
    "dtlz2": TaskEntry(dtlz2, objectives=lambda table: int(table.get("num_objectives", 3))),
    "halfcheetah_multi": TaskEntry(halfcheetah_multi, policy=True, objectives=2),
    "walker2d_multi": TaskEntry(walker2d_multi, policy=True, objectives=2),
    "ant_multi": TaskEntry(ant_multi, policy=True, objectives=2),
}
