"""The planar arm (Cully et al. 2015, "Robots that can adapt like animals"), plain and noisy.

As in QDax's `arm_scoring_function` (after fast_map-elites): n joints with links
of length 1/n; genotype g in [0, 1]^n, joint angles theta_i = 2 pi g_i - pi in
[-pi, pi]. Fitness is minus the standard deviation of the (clipped) genes, so an
arm whose joints all bend alike is best; the descriptor is the end-effector
position mapped from [-1, 1]^2 to [0, 1]^2.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from qdrl.config import NonNegativeFloat, PositiveInt
from qdrl.qd.base import Evaluation
from qdrl.tasks.base import Task, batched_scoring_fn, check_genotypes
from qdrl.types import Array, PRNGKey


def _safe_sqrt(x: Array) -> Array:
    # sqrt has an infinite derivative at 0; give the subgradient 0 instead of NaN
    positive = x > 0.0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


# The descriptor: where the arm's end effector ends, x and y scaled to [0, 1].
ARM_DESCRIPTOR_NAMES = ("end-effector x", "end-effector y")


def arm_evaluate(genotype: Array) -> tuple[Array, Array]:
    """Fitness () and descriptor (2,) of one arm (QDax `arm`).

    g = clip(genotype, 0, 1); fitness = -sqrt(mean_i (g_i - mean(g))^2) in
    [-0.5, 0]; with phi_k = sum_{i<=k} (2 pi g_i - pi), descriptor =
    (sum_k cos(phi_k) / (2n) + 0.5, sum_k sin(phi_k) / (2n) + 0.5) in [0, 1]^2.
    g = 0.5 everywhere (all angles 0, arm stretched along +x) has fitness 0 and
    descriptor (1, 0.5).
    """
    g = jnp.clip(genotype, 0.0, 1.0)
    n = g.shape[0]
    fitness = -_safe_sqrt(jnp.mean(jnp.square(g - jnp.mean(g))))
    cum_angles = jnp.cumsum(2.0 * jnp.pi * g - jnp.pi)
    x = jnp.sum(jnp.cos(cum_angles)) / (2.0 * n) + 0.5
    y = jnp.sum(jnp.sin(cum_angles)) / (2.0 * n) + 0.5
    return fitness, jnp.stack([x, y])


def arm(num_dofs: PositiveInt = 100) -> Task:
    """Planar arm with `num_dofs` joints (QDax `arm_scoring_function`).

    qd_offset = -0.5: the standard deviation of numbers in [0, 1] is at most 0.5,
    so every fitness lies in [-0.5, 0]. `gradient_scoring_fn` also hands back the
    fitness gradient and descriptor Jacobian (`qdrl.qd.dqd`; zero along genes
    clipped to [0, 1]) for the MEGA emitters.
    """
    if num_dofs < 1:
        raise ValueError(f"arm: num_dofs must be >= 1, got {num_dofs}")
    return Task(
        name="arm",
        scoring_fn=batched_scoring_fn(arm_evaluate, num_dofs),
        gradient_scoring_fn=batched_scoring_fn(arm_evaluate, num_dofs, gradients=True),
        descriptor_low=(0.0, 0.0),
        descriptor_high=(1.0, 1.0),
        descriptor_names=ARM_DESCRIPTOR_NAMES,
        genotype_size=num_dofs,
        genotype_low=0.0,
        genotype_high=1.0,
        qd_offset=-0.5,
        max_fitness=0.0,
    )


def noisy_arm(
    num_dofs: PositiveInt = 100,
    fit_std: NonNegativeFloat = 0.1,
    desc_std: NonNegativeFloat = 0.1,
    params_std: NonNegativeFloat = 0.05,
) -> Task:
    """Planar arm with Gaussian noise (QDax `noisy_arm_scoring_function`).

    With k_f, k_d, k_p from the evaluation key: g' = g + params_std N(0, I) (then
    evaluated as `arm`, which clips g'), fitness = arm fitness + fit_std N(0, 1),
    descriptor = arm descriptor + desc_std N(0, I_2). QDax names the three
    standard deviations `*_variance` and multiplies by them as standard deviations;
    the defaults are those of QDax's MAP-Elites arm test. Noisy descriptors may
    leave [0, 1]^2; the repertoire decides what to do with them. qd_offset =
    -0.5 - 5 fit_std covers the noise at five standard deviations.
    """
    if num_dofs < 1:
        raise ValueError(f"noisy_arm: num_dofs must be >= 1, got {num_dofs}")
    batched = jax.vmap(arm_evaluate)

    def scoring_fn(genotypes: Array, key: PRNGKey) -> Evaluation:
        genotypes = check_genotypes(genotypes, num_dofs)
        f_key, d_key, p_key = jax.random.split(key, 3)
        genotypes = genotypes + params_std * jax.random.normal(
            p_key, genotypes.shape, genotypes.dtype
        )
        fitnesses, descriptors = batched(genotypes)
        fitnesses = fitnesses + fit_std * jax.random.normal(f_key, fitnesses.shape, fitnesses.dtype)
        descriptors = descriptors + desc_std * jax.random.normal(
            d_key, descriptors.shape, descriptors.dtype
        )
        return Evaluation(
            fitnesses=fitnesses.astype(jnp.float32),
            descriptors=descriptors.astype(jnp.float32),
            extras={},
            env_steps=jnp.zeros((), jnp.int32),
        )

    return Task(
        name="noisy_arm",
        scoring_fn=scoring_fn,
        descriptor_low=(0.0, 0.0),
        descriptor_high=(1.0, 1.0),
        descriptor_names=ARM_DESCRIPTOR_NAMES,
        genotype_size=num_dofs,
        genotype_low=0.0,
        genotype_high=1.0,
        qd_offset=-0.5 - 5.0 * fit_std,
        max_fitness=0.0,
    )
