"""Emitters by name: the kinds a QD spec's `[emitter]` (or each `[[emitters]]` table) may name.

Each kind has its config dataclass (beside its emitter, with declared types and
ranges), the defaults it brings, and how it is built from what the run knows
of its task (`EmitterContext`):

| kind | emitter | config |
|---|---|---|
| `isoline`, `polynomial` | the GA of MAP-Elites (`ga.py`) | `GAConfig` |
| `cma_improvement`, `cma_optimizing`, `cma_random_direction` | CMA-ME's emitters (`cma.py`; rankers `2imp`, `obj`, `2rd` by default) | `CMAEmitterConfig` |
| `omg_mega` | OMG-MEGA (`mega.py`; evaluates with the task's gradients) | `OMGMegaConfig` |
| `cma_mega` | CMA-MEGA (`mega.py`; asks the task for its gradients at theta) | `CMAMegaConfig` |

A list of kinds is a pool under the bandit scheduler (`scheduler.py`): every
member must have an instance axis (all kinds but `omg_mega`; a GA's instances
are copies of it) and the same number of offspring per instance.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Annotated, Any, Literal

from qdrl.config import ConfigError, OneOf, build, check_table, coerce
from qdrl.qd.base import Emitter, ScoringFn
from qdrl.qd.emitters.cma import CMAEmitter, CMAEmitterConfig
from qdrl.qd.emitters.ga import GAConfig, ga_emitter
from qdrl.qd.emitters.mega import CMAMegaConfig, CMAMegaEmitter, OMGMegaConfig, OMGMegaEmitter
from qdrl.qd.emitters.scheduler import (
    BanditScheduler,
    InstancedEmitter,
    SchedulerConfig,
    StatelessInstances,
)
from qdrl.types import Genotype

__all__ = [
    "CMA_KINDS",
    "EMITTER_KINDS",
    "GA_KINDS",
    "EmitterContext",
    "EmitterKind",
    "build_emitter",
    "build_pool",
    "check_pool",
    "emitter_kind_names",
    "instance_size",
    "offspring_per_iteration",
    "parse_emitter",
    "uses_cma_es",
]


@dataclasses.dataclass(frozen=True)
class EmitterContext:
    """What an emitter may read of its run's task: genotypes, bounds, gradients."""

    genotype_example: Genotype  # one genotype, no batch axis
    genotype_low: float  # -inf / inf: unbounded (nothing is clipped)
    genotype_high: float
    descriptor_low: tuple[float, ...]
    descriptor_high: tuple[float, ...]
    gradient_scoring_fn: ScoringFn | None = None  # the task's, when it has gradients
    task_name: str = ""


def _bound(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _ga(config: GAConfig, ctx: EmitterContext) -> Emitter:
    try:
        return ga_emitter(config, ctx.genotype_low, ctx.genotype_high)
    except ValueError as e:
        raise ConfigError(str(e)) from e


def _cma(config: CMAEmitterConfig, ctx: EmitterContext) -> CMAEmitter:
    return CMAEmitter(
        config, ctx.genotype_example, _bound(ctx.genotype_low), _bound(ctx.genotype_high),
        ctx.descriptor_low, ctx.descriptor_high,
    )


def _flat_size(ctx: EmitterContext) -> int:
    import jax

    return int(sum(int(x.size) for x in jax.tree.leaves(ctx.genotype_example)))


def _omg_mega(config: OMGMegaConfig, ctx: EmitterContext) -> OMGMegaEmitter:
    return OMGMegaEmitter(config)


def _cma_mega(config: CMAMegaConfig, ctx: EmitterContext) -> CMAMegaEmitter:
    assert ctx.gradient_scoring_fn is not None, "checked by the run"
    return CMAMegaEmitter(
        config, ctx.gradient_scoring_fn, _flat_size(ctx), ctx.descriptor_low, ctx.descriptor_high
    )


@dataclasses.dataclass(frozen=True)
class EmitterKind:
    """One name of the registry: its config, its defaults and how it is built.

    `gradients`: "scoring" when the QD loop must evaluate with the task's
    `gradient_scoring_fn` (every offspring's gradients), "emitter" when the
    emitter calls it itself, "none" otherwise. `instanced`: may join a pool.
    """

    config: type[Any]
    build: Callable[[Any, EmitterContext], Any]
    description: str
    defaults: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    gradients: Literal["none", "scoring", "emitter"] = "none"
    instanced: bool = True


EMITTER_KINDS: dict[str, EmitterKind] = {
    "isoline": EmitterKind(GAConfig, _ga, "GA: Iso+LineDD variation (MAP-Elites)"),
    "polynomial": EmitterKind(GAConfig, _ga, "GA: polynomial mutation and crossover"),
    "cma_improvement": EmitterKind(
        CMAEmitterConfig, _cma, "CMA-ME's improvement emitter (ranker 2imp; CMA-MAE: imp)"
    ),
    "cma_optimizing": EmitterKind(CMAEmitterConfig, _cma, "CMA-ME's optimizing emitter (ranker obj)"),
    "cma_random_direction": EmitterKind(
        CMAEmitterConfig, _cma, "CMA-ME's random-direction emitter (ranker 2rd)"
    ),
    "omg_mega": EmitterKind(
        OMGMegaConfig, _omg_mega, "OMG-MEGA: elites stepped along random gradient combinations",
        gradients="scoring", instanced=False,
    ),
    "cma_mega": EmitterKind(
        CMAMegaConfig, _cma_mega, "CMA-MEGA: CMA-ES over gradient coefficients (CMA-MAEGA: ranker imp)",
        gradients="emitter",
    ),
}
GA_KINDS = ("isoline", "polynomial")
CMA_KINDS = ("cma_improvement", "cma_optimizing", "cma_random_direction")


def emitter_kind_names() -> list[str]:
    """Every kind an `[emitter]` may name."""
    return sorted(EMITTER_KINDS)


def parse_emitter(
    data: Any,
    section: str,
    default_kind: str = "isoline",
    allowed: Sequence[str] | None = None,
    defaults: Mapping[str, Any] | None = None,
) -> Any:
    """The checked config of an `[emitter]` table: its `kind`, then every key against that kind's config.

    `allowed` restricts the kinds (an algorithm's own); `defaults` (an
    algorithm's, e.g. CMA-MAE's ranker) apply to its default kind, under the
    keys the table gives. Errors name `section.key`.
    """
    table = dict(check_table(data, section))
    names = sorted(allowed) if allowed is not None else emitter_kind_names()
    kind = coerce(table.get("kind", default_kind), Annotated[str, OneOf(lambda: names)], f"{section}.kind")
    merged = {**(defaults or {}), **table} if kind == default_kind else table
    merged["kind"] = kind
    return build(EMITTER_KINDS[kind].config, merged, section)


def offspring_per_iteration(config: Any) -> int:
    """Offspring one `[emitter]` makes per iteration (CMA-MEGA: lambda + 1 per instance)."""
    if isinstance(config, CMAMegaConfig):
        return config.num_instances * (config.batch_size + 1)
    return int(getattr(config, "num_instances", 1)) * int(config.batch_size)


def instance_size(config: Any) -> int:
    """Offspring of one instance per iteration (a pool's arms all emit this many)."""
    return int(config.batch_size) + (1 if isinstance(config, CMAMegaConfig) else 0)


def _instances(config: Any) -> int:
    return int(getattr(config, "num_instances", 1))


def check_pool(configs: Sequence[Any], scheduler: SchedulerConfig, section: str = "emitters") -> None:
    """Raises ConfigError naming the key unless `configs` can form one bandit pool under `scheduler`."""
    if not configs:
        raise ConfigError(f"{section}: expected at least one [[{section}]] table")
    for i, config in enumerate(configs):
        if not EMITTER_KINDS[config.kind].instanced:
            instanced = sorted(k for k, v in EMITTER_KINDS.items() if v.instanced)
            raise ConfigError(f"{section}[{i}].kind: expected one of {instanced} in a pool, got {config.kind!r}")
    size = instance_size(configs[0])
    for i, config in enumerate(configs[1:], start=1):
        if instance_size(config) != size:
            extra = 1 if isinstance(config, CMAMegaConfig) else 0
            raise ConfigError(
                f"{section}[{i}].batch_size: expected {size - extra} (every instance of a pool emits "
                f"{size} offspring, as {section}[0] does), got {config.batch_size}"
            )
    scheduler.check(sum(_instances(c) for c in configs))


def build_emitter(config: Any, ctx: EmitterContext, section: str = "emitter") -> Any:
    """The emitter of a checked config; ConfigError when it needs gradients the task lacks."""
    kind = EMITTER_KINDS[config.kind]
    if kind.gradients != "none" and ctx.gradient_scoring_fn is None:
        raise ConfigError(
            f"{section}.kind: {config.kind!r} needs the task's gradients; task {ctx.task_name!r} "
            "has none (tasks with gradients: lp_sphere, lp_rastrigin, lp_plateau, arm)"
        )
    return kind.build(config, ctx)


def build_pool(
    configs: Sequence[Any], scheduler: SchedulerConfig, ctx: EmitterContext, section: str = "emitters"
) -> BanditScheduler:
    """The bandit scheduler over the emitters of checked `configs` (a GA: num_instances copies)."""
    check_pool(configs, scheduler, section)
    pool: list[InstancedEmitter] = []
    for i, config in enumerate(configs):
        if config.kind in GA_KINDS:  # stateless: copies of one GA of batch_size offspring
            ga = ga_emitter(config, ctx.genotype_low, ctx.genotype_high, config.batch_size)
            pool.append(StatelessInstances(ga, config.num_instances))
        else:
            pool.append(build_emitter(config, ctx, f"{section}[{i}]"))
    return BanditScheduler(tuple(pool), scheduler)


def uses_cma_es(configs: Sequence[Any]) -> bool:
    """Whether any of these emitters runs a CMA-ES (eigendecompositions: one LAPACK thread helps)."""
    return any(c.kind in CMA_KINDS or c.kind == "cma_mega" for c in configs)
