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

import jax

from qdrl.config import ConfigError, OneOf, build, check_table, coerce
from qdrl.qd.base import Emitter, ScoringFn
from qdrl.qd.emitters.cma import CMAEmitter, CMAEmitterConfig
from qdrl.qd.emitters.ga import GAConfig, ga_emitter
from qdrl.qd.emitters.mega import CMAMegaConfig, CMAMegaEmitter, OMGMegaConfig, OMGMegaEmitter
from qdrl.qd.emitters.scheduler import (
    BanditScheduler,
    SchedulerConfig,
    StatelessInstances,
)
from qdrl.types import Genotype

__all__ = [
    "CMA_KINDS",
    "EMITTER_KINDS",
    "GA_KINDS",
    "EmitterContext",
    "EmitterFamily",
    "EmitterKind",
    "EmitterPool",
    "build_emitter",
    "build_emitters",
    "build_pool",
    "check_gradients",
    "check_pool",
    "configs_of",
    "emitter_kind_names",
    "parse_emitter",
    "parse_emitters",
    "reads_gradients",
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

    @classmethod
    def of_task(cls, task: Any) -> EmitterContext:
        """What an emitter may read of `task` (`qdrl.tasks.Task`)."""
        return cls(
            genotype_example=task.example_genotype(),
            genotype_low=float(task.genotype_low),
            genotype_high=float(task.genotype_high),
            descriptor_low=tuple(task.descriptor_low),
            descriptor_high=tuple(task.descriptor_high),
            gradient_scoring_fn=task.gradient_scoring_fn,
            task_name=task.name,
        )


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

    return int(sum(int(x.size) for x in jax.tree.leaves(ctx.genotype_example)))


def _omg_mega(config: OMGMegaConfig, ctx: EmitterContext) -> OMGMegaEmitter:
    return OMGMegaEmitter(config)


def _cma_mega(config: CMAMegaConfig, ctx: EmitterContext) -> CMAMegaEmitter:
    assert ctx.gradient_scoring_fn is not None, "checked by the run"
    return CMAMegaEmitter(
        config, ctx.gradient_scoring_fn, _flat_size(ctx), ctx.descriptor_low, ctx.descriptor_high
    )


def _ga_instances(config: GAConfig, ctx: EmitterContext) -> StatelessInstances:
    """A GA in a pool: num_instances copies of one GA of batch_size offspring (it is stateless)."""
    ga = ga_emitter(config, ctx.genotype_low, ctx.genotype_high, config.batch_size)
    return StatelessInstances(ga, config.num_instances)


@dataclasses.dataclass(frozen=True)
class EmitterKind:
    """One name of the registry: its config, how it is built, and what it needs.

    `gradients`: "scoring" when the QD loop must evaluate with the task's
    `gradient_scoring_fn` (every offspring's gradients), "emitter" when the
    emitter calls it itself, "none" otherwise. `pool_build`: how the kind joins a
    bandit pool (`[[emitters]]`) as an instanced emitter; None: it cannot.
    `cma_es`: it runs CMA-ES (eigendecompositions, for which one LAPACK thread is faster).
    """

    config: type[Any]
    build: Callable[[Any, EmitterContext], Any]
    description: str
    gradients: Literal["none", "scoring", "emitter"] = "none"
    pool_build: Callable[[Any, EmitterContext], Any] | None = None
    cma_es: bool = False


EMITTER_KINDS: dict[str, EmitterKind] = {
    "isoline": EmitterKind(GAConfig, _ga, "GA: Iso+LineDD variation (MAP-Elites)", pool_build=_ga_instances),
    "polynomial": EmitterKind(
        GAConfig, _ga, "GA: polynomial mutation and crossover", pool_build=_ga_instances
    ),
    "cma_improvement": EmitterKind(
        CMAEmitterConfig, _cma, "CMA-ME's improvement emitter (ranker 2imp; CMA-MAE: imp)",
        pool_build=_cma, cma_es=True,
    ),
    "cma_optimizing": EmitterKind(
        CMAEmitterConfig, _cma, "CMA-ME's optimizing emitter (ranker obj)", pool_build=_cma, cma_es=True
    ),
    "cma_random_direction": EmitterKind(
        CMAEmitterConfig, _cma, "CMA-ME's random-direction emitter (ranker 2rd)", pool_build=_cma, cma_es=True
    ),
    "omg_mega": EmitterKind(
        OMGMegaConfig, _omg_mega, "OMG-MEGA: elites stepped along random gradient combinations",
        gradients="scoring",
    ),
    "cma_mega": EmitterKind(
        CMAMegaConfig, _cma_mega, "CMA-MEGA: CMA-ES over gradient coefficients (CMA-MAEGA: ranker imp)",
        gradients="emitter", pool_build=_cma_mega, cma_es=True,
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


def check_pool(configs: Sequence[Any], scheduler: SchedulerConfig, section: str = "emitters") -> None:
    """Raises ConfigError naming the key unless `configs` can form one bandit pool under `scheduler`."""
    if not configs:
        raise ConfigError(f"{section}: expected at least one [[{section}]] table")
    for i, config in enumerate(configs):
        if EMITTER_KINDS[config.kind].pool_build is None:
            instanced = sorted(k for k, v in EMITTER_KINDS.items() if v.pool_build is not None)
            raise ConfigError(f"{section}[{i}].kind: expected one of {instanced} in a pool, got {config.kind!r}")
    size = configs[0].instance_size
    for i, config in enumerate(configs[1:], start=1):
        if config.instance_size != size:
            extra = config.instance_size - config.batch_size
            raise ConfigError(
                f"{section}[{i}].batch_size: expected {size - extra} (every instance of a pool emits "
                f"{size} offspring, as {section}[0] does), got {config.batch_size}"
            )
    scheduler.check(sum(int(getattr(c, "num_instances", 1)) for c in configs))


def check_gradients(config: Any, ctx: EmitterContext, section: str = "emitter") -> None:
    """Raises ConfigError naming `section.kind` when the kind needs gradients the task lacks."""
    if EMITTER_KINDS[config.kind].gradients != "none" and ctx.gradient_scoring_fn is None:
        raise ConfigError(
            f"{section}.kind: {config.kind!r} needs the task's gradients; task {ctx.task_name!r} "
            "has none (tasks with gradients: lp_sphere, lp_rastrigin, lp_plateau, arm)"
        )


def build_emitter(config: Any, ctx: EmitterContext, section: str = "emitter") -> Any:
    """The emitter of a checked config; ConfigError when it needs gradients the task lacks."""
    check_gradients(config, ctx, section)
    return EMITTER_KINDS[config.kind].build(config, ctx)


def build_pool(
    configs: Sequence[Any], scheduler: SchedulerConfig, ctx: EmitterContext, section: str = "emitters"
) -> BanditScheduler:
    """The bandit scheduler over the instanced emitters of checked `configs`."""
    check_pool(configs, scheduler, section)
    pool = []
    for i, config in enumerate(configs):
        check_gradients(config, ctx, f"{section}[{i}]")
        build = EMITTER_KINDS[config.kind].pool_build
        assert build is not None, "checked by check_pool"
        pool.append(build(config, ctx))
    return BanditScheduler(tuple(pool), scheduler)


def uses_cma_es(configs: Sequence[Any]) -> bool:
    """Whether any of these emitters runs a CMA-ES (eigendecompositions: one LAPACK thread helps)."""
    return any(EMITTER_KINDS[c.kind].cma_es for c in configs)


@dataclasses.dataclass(frozen=True)
class EmitterFamily:
    """What a QD algorithm name means for its emitters: defaults and allowed kinds.

    `emitter`: the default `[emitter]` table (its `kind` and the values the algorithm
    sets, under the spec's keys); `kinds`: the kinds its `[emitter]` or `[[emitters]]`
    may name (None: all); `pool`: whether `[[emitters]]` is accepted.
    """

    emitter: Mapping[str, Any] = dataclasses.field(default_factory=lambda: {"kind": "isoline"})
    kinds: tuple[str, ...] | None = None
    pool: bool = True


@dataclasses.dataclass(frozen=True)
class EmitterPool:
    """A bandit pool of emitters (`[[emitters]]` and `[scheduler]`)."""

    emitters: tuple[Any, ...]
    scheduler: SchedulerConfig

    @property
    def offspring(self) -> int:
        """Offspring per iteration: the active instances' offspring."""
        return self.scheduler.num_active * self.emitters[0].instance_size


def configs_of(config: Any) -> list[tuple[Any, str]]:
    """(config, section) of one emitter's config, or of each member of a pool."""
    if isinstance(config, EmitterPool):
        return [(c, f"emitters[{i}]") for i, c in enumerate(config.emitters)]
    return [(config, "emitter")]


def parse_emitters(spec: Mapping[str, Any], family: EmitterFamily = EmitterFamily()) -> Any:
    """The checked `[emitter]` of a spec (its kind's config), or the `EmitterPool` of its
    `[[emitters]]` and `[scheduler]`; errors name `section.key`."""
    default = dict(family.emitter)
    kind = str(default.pop("kind"))

    def emitter_of(data: Any, section: str) -> Any:
        return parse_emitter(data, section, kind, family.kinds, default)

    if "emitters" not in spec:
        return emitter_of(spec.get("emitter", {}), "emitter")
    if not family.pool:
        raise ConfigError("emitters: this algorithm takes one [emitter], not a pool of [[emitters]]")
    if "emitter" in spec:
        raise ConfigError("emitter: give either one [emitter] or a pool of [[emitters]], not both")
    tables = spec["emitters"]
    if not (isinstance(tables, list) and tables and all(isinstance(t, Mapping) for t in tables)):
        raise ConfigError(
            "emitters: expected a list of tables ([[emitters]] followed by key = value lines), "
            f"got {tables!r}"
        )
    pool = tuple(emitter_of(t, f"emitters[{i}]") for i, t in enumerate(tables))
    scheduler = build(SchedulerConfig, spec.get("scheduler", {}), "scheduler")
    check_pool(pool, scheduler)
    return EmitterPool(pool, scheduler)


def build_emitters(config: Any, ctx: EmitterContext) -> Any:
    """The emitter of `parse_emitters`' result: one emitter, or the bandit over the pool."""
    if isinstance(config, EmitterPool):
        return build_pool(config.emitters, config.scheduler, ctx)
    return build_emitter(config, ctx)


def reads_gradients(config: Any) -> bool:
    """Whether the QD loop must evaluate with the task's gradients (OMG-MEGA reads every offspring's)."""
    return any(EMITTER_KINDS[c.kind].gradients == "scoring" for c, _ in configs_of(config))
