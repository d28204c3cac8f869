"""Differentiable QD's contract: where an evaluation hands back the gradients of a task.

Fontaine & Nikolaidis 2021, "Differentiable Quality Diversity". A differentiable
task's `gradient_scoring_fn` (e.g. `lp_sphere`'s, `arm`'s) puts, for n evaluated genotypes of
size d with D descriptors, the fitness gradients under `FITNESS_GRADIENT`
((n, d)) and the descriptor Jacobians under `DESCRIPTOR_GRADIENTS` ((n, D, d))
in `Evaluation.extras`; the MEGA emitters read them with `jacobian`.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from qdrl.types import Array

__all__ = ["DESCRIPTOR_GRADIENTS", "FITNESS_GRADIENT", "jacobian"]

FITNESS_GRADIENT = "fitness_gradient"
DESCRIPTOR_GRADIENTS = "descriptor_gradients"


def jacobian(extras: dict[str, Any]) -> Array:
    """(n, 1 + D, d): each evaluated solution's fitness gradient, then its descriptor gradients."""
    missing = {FITNESS_GRADIENT, DESCRIPTOR_GRADIENTS} - set(extras)
    if missing:
        raise ValueError(
            "MEGA emitters need the task's gradients in the evaluation extras "
            f"(missing {sorted(missing)}): evaluate with the task's gradient_scoring_fn"
        )
    return jnp.concatenate(
        [extras[FITNESS_GRADIENT][:, None, :], extras[DESCRIPTOR_GRADIENTS]], axis=1
    )
