"""AURORA's archive: descriptors learnt by an autoencoder, kept apart by a threshold it adapts.

AURORA (Cully 2019, "Autonomous skill discovery with Quality-Diversity and unsupervised
descriptors"; Grillotti & Cully 2022, "Unsupervised Behaviour Discovery With Quality-Diversity
Optimisation") needs no hand-made descriptor. Each evaluated policy hands back the sequence
of what it observed (every `period` steps, `length` observations); an autoencoder
(`qdrl.qd.autoencoder`) is trained on the stored elites' sequences, and a policy's descriptor
is the latent code of its sequence. Elites live in an unstructured archive
(`qdrl.qd.repertoires.unstructured`): a candidate enters when its code is at least
`l_value` from every stored one, or replaces its nearest elite when fitter.

On a schedule that spreads out as the run goes on (after the initial population, then
`train_every` iterations later, then `2 x train_every` after that, ... as QDax's example), the
autoencoder is trained again and every stored elite is re-encoded and re-inserted (codes
change with the encoder). Between trainings, every `csc_every` iterations, container size
control moves `l_value` so that the archive holds about `target_size` elites (a PD
controller on the number of elites, QDax's gains): more elites than the target raise the
threshold, fewer lower it; the archive is then rebuilt with the new threshold.

The archive is a search archive (`qdrl.qd.repertoires.result`): the run's grid or CVT
repertoire over the task's hand-made descriptor is the result archive every metric reads
(the passive archive of Chalumeau et al. 2023's benchmark), so AURORA is measured as
MAP-Elites is. `add_evaluation` reads the evaluation's `extras["transitions"]` (a policy
task's episodes): what is observed is the state descriptor (`"state_descriptor"`, the
torso x-y or feet contacts, QDax's "only_sd"), the first `max_features` entries of the
observation (`"observation"`, "no_sd"), or both (`"full"`). Steps after an episode ended
repeat its last observation.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jnp

from qdrl.qd.autoencoder import Autoencoder, AutoencoderState
from qdrl.qd.base import AddResult, Evaluation
from qdrl.qd.repertoires.unstructured import UnstructuredRepertoire, unstructured_repertoire
from qdrl.types import Array, Descriptor, Fitness, Genotype, PRNGKey

__all__ = ["AuroraArchive", "AuroraSettings", "aurora_archive", "observation_sequences"]

ObservationKind = Literal["state_descriptor", "observation", "full"]


@dataclasses.dataclass(frozen=True)
class AuroraSettings:
    """AURORA's static settings (QDax's example and the skill-discovery benchmark's defaults)."""

    autoencoder: Autoencoder
    observation: ObservationKind = "state_descriptor"
    period: int = 10  # steps between two recorded observations
    length: int = 25  # observations per sequence (M)
    max_features: int = 25  # "observation", "full": the observation's first entries kept
    target_size: int = 1024  # container size control's target number of elites
    csc_every: int = 10  # iterations between two threshold adjustments
    csc_gain: float = 1e-5  # the controller's proportional and derivative gains (QDax: 1e-5 both)
    train_every: int = 10  # first gap between trainings; the k-th gap is k x train_every
    epochs: int = 100  # epochs of a training ...
    late_epochs: int = 25  # ... and after `late_after` iterations (QDax: 100, then 25)
    late_after: int = 500


def observation_sequences(extras: dict[str, object], settings: AuroraSettings) -> Array:
    """(n, M, O) float32: each episode's observations every `settings.period` steps, from a
    policy task's `extras["transitions"]` (time-major (T, n, ...)) and `extras["mask"]` (T, n);
    a step after the episode's end repeats the last valid one."""
    if "transitions" not in extras:
        raise ValueError(
            "AURORA: expected the evaluation's extras['transitions'] (a policy task's episodes), got extras "
            f"{sorted(extras)}: AURORA learns descriptors from what a policy observes"
        )
    transitions, mask = extras["transitions"], extras["mask"]
    desc = transitions.desc  # type: ignore[attr-defined]
    obs = transitions.obs[..., : settings.max_features]  # type: ignore[attr-defined]
    if settings.observation == "state_descriptor":
        seq = desc
    elif settings.observation == "observation":
        seq = obs
    else:
        seq = jnp.concatenate([desc, obs], axis=-1)
    steps = seq.shape[0]
    times = jnp.arange(settings.length) * settings.period
    # Index of the last valid step at or before each step (the episode's last one after its end).
    valid = jnp.asarray(mask) > 0  # type: ignore[arg-type]
    last_valid = jax.lax.cummax(jnp.where(valid, jnp.arange(steps)[:, None], 0), axis=0)
    picked = last_valid[jnp.minimum(times, steps - 1)]  # (M, n)
    out = jnp.take_along_axis(seq, picked[..., None], axis=0)  # (M, n, O)
    return jnp.swapaxes(out, 0, 1).astype(jnp.float32)


def sequence_size(observation: ObservationKind, max_features: int, descriptor_size: int, observation_size: int) -> int:
    """O, the width of one recorded observation of kind `observation` (see `AuroraSettings`)."""
    features = min(max_features, observation_size)
    return {"state_descriptor": descriptor_size, "observation": features, "full": descriptor_size + features}[
        observation
    ]


@dataclasses.dataclass(frozen=True, eq=False)
class AuroraArchive:
    """The unstructured archive of latent codes, the stored elites' sequences and the autoencoder.

    Attributes:
      archive: the unstructured archive; its genotypes are pairs (genotype, sequence (M, O)).
      model: the autoencoder's parameters, optimiser state and normalisation.
      iteration: () int32 batches added (the initial population is batch 0).
      next_training: () int32 the batch after which the autoencoder is trained next.
      trainings: () int32 trainings done.
      previous_error: () float32 container size control's last error (elites minus target).
      key: the key the trainings' minibatches are drawn from (split at each training).
      settings: the static settings.
    """

    archive: UnstructuredRepertoire
    model: AutoencoderState
    iteration: Array
    next_training: Array
    trainings: Array
    previous_error: Array
    key: PRNGKey
    settings: AuroraSettings

    @property
    def genotypes(self) -> Genotype:
        return self.archive.genotypes[0]

    @property
    def sequences(self) -> Array:
        """(K, M, O) the stored elites' observation sequences."""
        return self.archive.genotypes[1]  # type: ignore[no-any-return]

    @property
    def fitnesses(self) -> Array:
        return self.archive.fitnesses

    @property
    def descriptors(self) -> Array:
        """(K, L) the stored elites' latent codes."""
        return self.archive.descriptors

    @property
    def filled(self) -> Array:
        return self.archive.filled

    @property
    def num_filled(self) -> Array:
        return self.archive.num_filled

    @property
    def is_empty(self) -> Array:
        return self.archive.is_empty

    @property
    def l_value(self) -> Array:
        return self.archive.l_value

    @property
    def loss(self) -> Array:
        """The autoencoder's reconstruction loss at its last training."""
        return self.model.loss

    def sample(self, key: PRNGKey, num_samples: int) -> Genotype:
        """`num_samples` stored genotypes, uniformly with replacement."""
        return self.archive.sample(key, num_samples)[0]

    def own_metrics(self) -> dict[str, Array]:
        """What AURORA reports of itself on each log row."""
        return {
            "aurora_elites": self.num_filled,
            "l_value": self.l_value,
            "autoencoder_loss": self.model.loss,
            "autoencoder_trainings": self.trainings,
        }

    def add(self, genotypes: Genotype, descriptors: Descriptor, fitnesses: Fitness) -> tuple[AuroraArchive, AddResult]:
        del genotypes, descriptors, fitnesses
        raise TypeError(
            "AuroraArchive.add: AURORA reads the observations of an evaluation; call "
            "add_evaluation(genotypes, evaluation) (the QD loop does)"
        )

    def add_evaluation(self, genotypes: Genotype, evaluation: Evaluation) -> tuple[AuroraArchive, AddResult]:
        """Encodes the batch's observation sequences, offers the codes to the archive, then trains
        the autoencoder (and re-encodes every elite) or adjusts the threshold when it is time."""
        sequences = observation_sequences(evaluation.extras, self.settings)
        codes = self.settings.autoencoder.encode(self.model, sequences)
        archive, added = self.archive.add((genotypes, sequences), codes, evaluation.fitnesses)
        new = dataclasses.replace(self, archive=archive)
        new = jax.lax.cond(
            new.iteration == new.next_training,
            lambda a: a._train(),
            lambda a: jax.lax.cond(a.iteration % a.settings.csc_every == 0, lambda b: b.control_size(), lambda b: b, a),
            new,
        )
        return dataclasses.replace(new, iteration=new.iteration + 1), added

    def _rebuilt(self, codes: Array, l_value: Array) -> UnstructuredRepertoire:
        """The elites re-inserted, slot by slot, with new codes and threshold."""
        empty = dataclasses.replace(
            self.archive,
            genotypes=jax.tree.map(jnp.zeros_like, self.archive.genotypes),
            fitnesses=jnp.full_like(self.archive.fitnesses, -jnp.inf),
            descriptors=jnp.zeros_like(self.archive.descriptors),
            l_value=jnp.asarray(l_value, jnp.float32),
        )
        # Empty slots hold -inf fitnesses: `add` rejects them.
        rebuilt, _ = empty.add(self.archive.genotypes, codes, self.archive.fitnesses)
        return rebuilt

    def _train(self) -> AuroraArchive:
        s = self.settings
        key, train_key = jax.random.split(self.key)
        epochs = jnp.where(self.iteration <= s.late_after, s.epochs, s.late_epochs)
        model = s.autoencoder.train(self.model, self.sequences, self.filled, train_key, epochs)
        codes = s.autoencoder.encode(model, self.sequences)
        trainings = self.trainings + 1
        archive = self._rebuilt(codes, self.archive.l_value)
        # The controller's first error is the one after the first training (QDax's example).
        error = (archive.num_filled - s.target_size).astype(jnp.float32)
        return dataclasses.replace(
            self,
            archive=archive,
            model=model,
            trainings=trainings,
            next_training=self.iteration + s.train_every * trainings,
            previous_error=jnp.where(self.trainings == 0, error, self.previous_error),
            key=key,
        )

    def control_size(self) -> AuroraArchive:
        """Container size control: the threshold moved by the PD controller on the number of elites
        (elites minus `target_size`, and its change since the last call), the elites re-inserted."""
        s = self.settings
        error = (self.num_filled - s.target_size).astype(jnp.float32)
        l_value = self.archive.l_value + s.csc_gain * error + s.csc_gain * (error - self.previous_error)
        l_value = jnp.maximum(l_value, 1e-6)  # a threshold stays positive
        return dataclasses.replace(
            self, archive=self._rebuilt(self.archive.descriptors, l_value), previous_error=error
        )


jax.tree_util.register_dataclass(
    AuroraArchive,
    data_fields=["archive", "model", "iteration", "next_training", "trainings", "previous_error", "key"],
    meta_fields=["settings"],
)


def aurora_archive(
    genotype_example: Genotype, settings: AuroraSettings, capacity: int, l_value: float, key: PRNGKey
) -> AuroraArchive:
    """An empty AURORA archive of `capacity` slots, threshold `l_value`, and an untrained
    autoencoder initialised from `key` (which also seeds the trainings' minibatches)."""
    ae = settings.autoencoder
    if capacity < settings.target_size:
        raise ValueError(f"capacity: expected at least target_size={settings.target_size}, got {capacity}")
    init_key, train_key = jax.random.split(key)
    sequence = jax.ShapeDtypeStruct((ae.sequence_length, ae.observation_size), jnp.float32)
    return AuroraArchive(
        archive=unstructured_repertoire((genotype_example, sequence), capacity, ae.latent_size, l_value),
        model=ae.init(init_key),
        iteration=jnp.zeros((), jnp.int32),
        next_training=jnp.zeros((), jnp.int32),
        trainings=jnp.zeros((), jnp.int32),
        previous_error=jnp.asarray(-float(settings.target_size), jnp.float32),
        key=train_key,
        settings=settings,
    )
