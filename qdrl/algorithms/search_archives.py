"""The `[search_archive]` section: an archive that steers the search, beside the result archive.

Novelty search and NSLC (a proximity archive, `qdrl.qd.repertoires.proximity`), Dominated
Novelty Search (a fixed-size population, `qdrl.qd.repertoires.dns`), Density Descent Search
(a density archive, `qdrl.qd.repertoires.density`) and Discount Model Search (a discount
archive, `qdrl.qd.repertoires.discount`) keep or judge solutions by rules of their own;
the run's `[repertoire]` (a grid or CVT) is then the passive result archive every metric,
plot and export reads, as in pyribs' examples (`qdrl.qd.repertoires.result`). Any QD
algorithm of the registry's emitters takes the section; the rows `ns_cma`, `nslc`,
`nslc_cma_imp`, `dds`, `dms` and `dns` set it, with their emitters, as pyribs' sphere
example and QDax's DNS example do.

    [search_archive]
    kind = "proximity"          # proximity | dns | density | discount
    k_neighbors = 15
    novelty_threshold = 3.7
    local_competition = true
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import jax

from qdrl.config import (
    ConfigError,
    NonNegativeFloat,
    NonNegativeInt,
    OneOf,
    PositiveFloat,
    PositiveInt,
    PositiveUnitFloat,
    build,
    check_table,
    coerce,
)
from qdrl.qd.autoencoder import make_autoencoder
from qdrl.qd.emitters.rankers import INFO_FIELDS
from qdrl.qd.emitters.registry import configs_of
from qdrl.qd.repertoires.aurora import AuroraArchive, AuroraSettings, aurora_archive, sequence_size
from qdrl.qd.repertoires.density import density_archive
from qdrl.qd.repertoires.discount import discount_archive
from qdrl.qd.repertoires.dns import dns_population
from qdrl.qd.repertoires.proximity import proximity_archive
from qdrl.qd.repertoires.result import Parents, ResultArchived, with_result_archive
from qdrl.tasks import TASKS, Task

__all__ = [
    "SEARCH_ARCHIVES",
    "AuroraConfig",
    "DNSConfig",
    "DensityConfig",
    "DiscountConfig",
    "ProximityConfig",
    "check_capacity",
    "check_rankers",
    "make_search_archive",
    "parse_search_archive",
]


@dataclasses.dataclass(frozen=True)
class ProximityConfig:
    """Novelty search's archive (Lehman & Stanley 2011), with NSLC's local competition."""

    kind: Literal["proximity"] = "proximity"
    capacity: PositiveInt = 10_000  # most solutions kept; novel ones past it are refused
    k_neighbors: PositiveInt = 15  # novelty: mean distance to this many nearest members
    novelty_threshold: PositiveFloat = 1.0  # a candidate at least this novel enters
    local_competition: bool = False  # NSLC: a fitter non-novel candidate replaces its nearest
    # pyribs' names: the threshold is multiplied by `threshold_decay_rate` every
    # `threshold_decay_itrs` iterations, down to `threshold_decay_min` (rate 1: no decay)
    threshold_decay_rate: PositiveUnitFloat = 1.0
    threshold_decay_itrs: PositiveInt = 1
    threshold_decay_min: NonNegativeFloat = 0.0
    parents: Parents = "search"  # where emitters draw parents and restart points


@dataclasses.dataclass(frozen=True)
class DNSConfig:
    """Dominated Novelty Search's population (Bahlous-Boldi et al. 2025)."""

    kind: Literal["dns"] = "dns"
    capacity: PositiveInt = 1024  # population size
    k: PositiveInt = 3  # fitter neighbours averaged by the competition fitness
    # "qdax": equal fitness counts as fitter (QDax, and pyribs 0.12's code); "strict": only
    # a higher fitness (the paper's definition, pyribs' docstring)
    tie_rule: Literal["qdax", "strict"] = "qdax"
    parents: Parents = "search"


@dataclasses.dataclass(frozen=True)
class DensityConfig:
    """Density Descent Search's archive (Lee et al. 2024): a descriptor reservoir and a KDE."""

    kind: Literal["density"] = "density"
    buffer_size: PositiveInt = 10_000
    bandwidth: PositiveFloat = 1.0  # the Gaussian kernel's width, in descriptor units
    parents: Literal["result"] = "result"  # it keeps no solutions


@dataclasses.dataclass(frozen=True)
class DiscountConfig:
    """Discount Model Search's archive (Tjanaka et al. 2026): an MLP discount surface."""

    kind: Literal["discount"] = "discount"
    hidden: tuple[PositiveInt, ...] = (128, 128)  # the discount model's ReLU layers
    learning_rate: PositiveUnitFloat = 0.1  # alpha of the threshold update the model is fitted to
    threshold_min: float = 0.0  # the discount of unexplored regions
    model_lr: PositiveFloat = 1e-3  # Adam's step size
    train_epochs: PositiveInt = 5
    train_cutoff_loss: NonNegativeFloat = 0.05  # training stops after an epoch at most this
    train_batch_size: PositiveInt = 32
    init_train_points: NonNegativeInt = 1000  # empty cells fitted to threshold_min at the start
    empty_points: NonNegativeInt = 100  # empty cells added to every training
    # [lo, hi] of the fitness: targets mapped to [0, 1] (pyribs' normalize_discount
    # "zero_one", its sphere example's (0, 100)); omit to fit raw values
    discount_range: tuple[float, float] | None = None
    parents: Literal["result"] = "result"  # it keeps no solutions

    def check(self) -> None:
        if self.discount_range is not None and not self.discount_range[0] < self.discount_range[1]:
            raise ValueError(
                f"search_archive.discount_range: expected [lo, hi] with lo < hi, got {list(self.discount_range)}"
            )


@dataclasses.dataclass(frozen=True)
class AuroraConfig:
    """AURORA's archive (Cully 2019; Grillotti & Cully 2022): codes of an autoencoder trained on
    the elites' observation sequences, an unstructured archive and container size control.
    Defaults: the skill-discovery benchmark's (Chalumeau et al. 2023) and QDax's example."""

    kind: Literal["aurora"] = "aurora"
    encoder: Literal["lstm", "mlp"] = "lstm"  # a sequence-to-sequence LSTM, or an MLP on the flat sequence
    latent_size: PositiveInt = 5  # the code's size: the learnt descriptor's dimension
    hidden: tuple[PositiveInt, ...] = (64, 64)  # mlp: the encoder's layers (the decoder mirrors them)
    # what is recorded: the task's state descriptor (QDax's "only_sd"), the observation's first
    # `max_features` entries ("no_sd") or both ("full")
    observation: Literal["state_descriptor", "observation", "full"] = "state_descriptor"
    sampling_period: PositiveInt = 10  # steps between two recorded observations
    num_observations: PositiveInt = 25  # observations per sequence
    max_features: PositiveInt = 25
    l_value: PositiveFloat = 0.2  # the distance threshold's start value, in code units
    capacity: PositiveInt = 2048  # most elites kept
    target_size: PositiveInt = 1024  # container size control's target
    csc_every: PositiveInt = 10  # iterations between two threshold adjustments
    csc_gain: PositiveFloat = 1e-5  # the controller's gains
    train_every: PositiveInt = 10  # first gap between trainings (the k-th is k times it)
    epochs: PositiveInt = 100  # epochs per training, then `late_epochs` after `late_after` iterations
    late_epochs: PositiveInt = 25
    late_after: NonNegativeInt = 500
    learning_rate: PositiveFloat = 1e-4  # Adam's step size
    batch_size: PositiveInt = 128  # sequences per gradient step
    parents: Literal["search"] = "search"

    def check(self) -> None:
        if self.target_size > self.capacity:
            raise ValueError(
                f"search_archive.target_size: expected at most search_archive.capacity={self.capacity}, "
                f"got {self.target_size}"
            )


# The per-candidate fields each kind's `add` gives the rankers (`AddResult.info`).
INFO_PROVIDED: dict[str, tuple[str, ...]] = {
    "proximity": ("novelty", "local_competition"), "dns": ("competition_fitness",), "density": ("density",),
    "discount": ("discount",),
}
SEARCH_ARCHIVES: dict[str, type[Any]] = {
    "proximity": ProximityConfig, "dns": DNSConfig, "density": DensityConfig, "discount": DiscountConfig,
    "aurora": AuroraConfig,
}
SearchArchiveConfig = ProximityConfig | DNSConfig | DensityConfig | DiscountConfig | AuroraConfig


def parse_search_archive(spec: Mapping[str, Any], defaults: Mapping[str, Any] | None = None) -> Any:
    """The checked `[search_archive]` over an algorithm's `defaults` (None when neither gives
    one); the kind first, then every key against that kind's config (errors name the key)."""
    if "search_archive" not in spec and not defaults:
        return None
    table = dict(check_table(spec.get("search_archive", {}), "search_archive"))
    base = dict(defaults or {})
    kind = coerce(
        table.get("kind", base.get("kind", "proximity")),
        Annotated[str, OneOf(lambda: sorted(SEARCH_ARCHIVES))], "search_archive.kind",
    )
    merged = {**base, **table} if kind == base.get("kind") else table
    merged["kind"] = kind
    return build(SEARCH_ARCHIVES[kind], merged, "search_archive")


def check_rankers(config: Any, emitters: Any) -> None:
    """Refuses an emitter whose ranker reads fields the search archive does not give (the
    novelty rankers without a proximity archive, `density` without a density archive)."""
    given = INFO_PROVIDED.get(getattr(config, "kind", ""), ())
    if not hasattr(emitters, "offspring"):
        return
    for emitter, section in configs_of(emitters):
        ranker = getattr(emitter, "ranker", None)
        missing = [f for f in INFO_FIELDS.get(ranker or "", ()) if f not in given]
        if missing:
            where = f"{section}.ranker"
            needs = "a proximity archive" if "novelty" in missing else "a density archive"
            raise ConfigError(
                f"{where}: {ranker!r} ranks by the {missing[0]!r} that {needs} gives ([search_archive] kind = "
                f"{'proximity' if 'novelty' in missing else 'density'}); got "
                f"{'no [search_archive]' if config is None else repr(config.kind)}"
            )


def check_capacity(config: Any, offspring: int) -> None:
    """Refuses a proximity archive or DNS population smaller than one iteration's batch."""
    capacity = getattr(config, "capacity", None)
    if capacity is not None and capacity < offspring:
        raise ConfigError(
            f"search_archive.capacity: expected at least the {offspring} offspring of an iteration, got {capacity}"
        )


def make_search_archive(config: Any, task: Task, example: Any, result: Any, seed: int | None) -> ResultArchived:
    """The empty search archive of `config` for `task`'s descriptors and genotypes `example`,
    beside the empty result archive `result` (the run's `[repertoire]`)."""
    dim = int(task.descriptor_size)
    key = jax.random.PRNGKey(0 if seed is None else seed)
    search: Any
    if isinstance(config, ProximityConfig):
        search = proximity_archive(
            example, config.capacity, dim, config.k_neighbors, config.novelty_threshold,
            local_competition=config.local_competition, threshold_decay=config.threshold_decay_rate,
            decay_every=config.threshold_decay_itrs, threshold_min=config.threshold_decay_min,
        )
    elif isinstance(config, DNSConfig):
        search = dns_population(example, config.capacity, dim, config.k, tie_rule=config.tie_rule)
    elif isinstance(config, DensityConfig):
        search = density_archive(dim, config.buffer_size, config.bandwidth, key=key)
    elif isinstance(config, DiscountConfig):
        passive = dataclasses.replace(result, genotypes=None)
        search = discount_archive(
            task.descriptor_low, task.descriptor_high, config.hidden, config.learning_rate,
            config.threshold_min, config.model_lr, config.train_epochs, config.train_cutoff_loss,
            config.train_batch_size, config.init_train_points, config.empty_points, cells=passive,
            discount_range=config.discount_range, key=key,
        )
    elif isinstance(config, AuroraConfig):
        search = make_aurora(config, task, example, key)
    else:
        raise TypeError(f"make_search_archive: unknown config {type(config).__name__}")
    return with_result_archive(search, result, config.parents)


def check_aurora(config: Any, task: Mapping[str, Any]) -> None:
    """Refuses AURORA on a task without episodes to observe, or sequences longer than an episode."""
    if not isinstance(config, AuroraConfig):
        return
    if not TASKS[task["name"]].policy:
        raise ConfigError(
            f"search_archive.kind: AURORA learns descriptors from what a policy observes; expected a policy "
            f"task (e.g. ant_omni, halfcheetah_uni, point_maze), got {task['name']!r}"
        )
    steps = int(task["episode_length"])
    span = (config.num_observations - 1) * config.sampling_period
    if span >= steps:
        raise ConfigError(
            f"search_archive.num_observations: expected (num_observations - 1) x sampling_period below "
            f"task.episode_length={steps}, got ({config.num_observations} - 1) x {config.sampling_period} = {span}"
        )


def make_aurora(config: AuroraConfig, task: Task, example: Any, key: jax.Array) -> AuroraArchive:
    """The empty AURORA archive of `config` for a policy task."""
    assert task.env is not None, "check_aurora refuses a task without an environment"
    settings = AuroraSettings(
        autoencoder=make_autoencoder(
            config.encoder, config.num_observations,
            sequence_size(config.observation, config.max_features, task.descriptor_size, task.env.observation_size),
            config.latent_size, hidden=config.hidden, learning_rate=config.learning_rate,
            batch_size=config.batch_size,
        ),
        observation=config.observation, period=config.sampling_period, length=config.num_observations,
        max_features=config.max_features, target_size=config.target_size, csc_every=config.csc_every,
        csc_gain=config.csc_gain, train_every=config.train_every, epochs=config.epochs,
        late_epochs=config.late_epochs, late_after=config.late_after,
    )
    return aurora_archive(example, settings, config.capacity, config.l_value, key)
