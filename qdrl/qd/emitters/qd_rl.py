"""The QD-RL algorithms one call away: the emitters of PGA-ME, QD-PG, DCRL-ME, ME-ES and ME-PBT
for a task, each from one nested config.

    task = make_task("halfcheetah_uni", episode_length=250, eval_batch=100)
    parts = make_pga_me(task, PGAMEConfig(ga=GAConfig(batch_size=100, iso_sigma=0.005, line_sigma=0.05)))
    me = MapElites(parts.scoring_fn, parts.emitter, cvt_repertoire(parts.example_genotype, ...))
    state = jax.jit(me.init)(parts.init_genotypes(key, 100), run_key)

Each config owns its number of offspring per iteration (`config.offspring`); the
spec sections of `qdrl run` map onto the same configs (`[emitter]` is the GA and
sets the batch size, `[pg]`, `[dpg]`, `[dcrl]`, `[es]`, `[me_pbt]` the rest).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Annotated, Any, NamedTuple

import jax
import jax.numpy as jnp

from qdrl import pbt
from qdrl.agents.base import Agent
from qdrl.config import Nested, NonNegativeInt, OtherSection, PositiveFloat, Range, check_fields
from qdrl.off_policy import make_trainer
from qdrl.placement import Placement
from qdrl.qd.base import Emitter, ScoringFn
from qdrl.qd.emitters.dcrl import DCRLConfig, dcrl_me_emitter
from qdrl.qd.emitters.es import ESConfig, ESEmitter
from qdrl.qd.emitters.ga import GAConfig, ga_emitter
from qdrl.qd.emitters.me_pbt import MEPBTConfig, MEPBTEmitter, agent_policy_network, to_genotype
from qdrl.qd.emitters.novelty import NoveltyConfig, NoveltyReward, qdpg_emitter
from qdrl.qd.emitters.pg import PGConfig, pga_me_emitter
from qdrl.tasks.base import PolicyNetwork, Task
from qdrl.types import Genotype, PRNGKey

__all__ = [
    "DCRLMEConfig",
    "PGAMEConfig",
    "QDPGConfig",
    "QDRLParts",
    "make_dcrl_me",
    "make_me_es",
    "make_me_pbt",
    "make_pga_me",
    "make_qdpg",
    "policy_of",
    "with_task_reward_offset",
]

Share = Annotated[float, Range(0.0, 1.0, low_open=True, high_open=True)]


class QDRLParts(NamedTuple):
    """What MAP-Elites needs to run a QD-RL algorithm on a task."""

    emitter: Emitter
    init_genotypes: Callable[[PRNGKey, int], Genotype]  # (key, n) -> the initial population
    scoring_fn: ScoringFn  # the task's scoring of these genotypes
    example_genotype: Genotype  # one genotype (no batch axis), for the empty repertoire
    # What genotypes act by when it is not the task's own policy network (ME-PBT: whole
    # agents): anything with `apply(genotype, obs) -> action`, for `task.policy_scoring`.
    policy: Any = None


def policy_of(task: Task, algorithm: str) -> PolicyNetwork:
    """The policy network of a policy task's genotypes; ValueError naming `task.name` otherwise."""
    if task.policy is None:
        raise ValueError(
            f"task.name: {algorithm} expects a policy task whose evaluations hand back transitions "
            f"(e.g. halfcheetah_uni, point_maze), got {task.name!r}"
        )
    return task.policy


def _ga_maker(config: GAConfig, task: Task) -> Callable[[int], Emitter]:
    return lambda n: ga_emitter(config, task.genotype_low, task.genotype_high, n)


def _parts(task: Task, emitter: Emitter) -> QDRLParts:
    return QDRLParts(emitter, task.init_genotypes, task.scoring_fn, task.example_genotype())


@dataclasses.dataclass(frozen=True)
class PGAMEConfig:
    """PGA-ME (Nilsson & Cully 2021): a GA and a Q-PG emitter share one batch.

    `ga` (a spec's `[emitter]`) sets the batch (`ga.batch_size` offspring per
    iteration) and the GA's variation; `pg` and the GA's share are the `[pg]` section.
    """

    pg: Annotated[PGConfig, Nested()] = PGConfig()
    # Share of the batch made by the GA; the rest by Q-PG (QDax's PGA-ME: 0.5).
    proportion_mutation_ga: Share = 0.5
    ga: Annotated[GAConfig, OtherSection("emitter")] = GAConfig()

    def check(self, section: str = "pg") -> None:
        check_fields(self, section)

    @property
    def offspring(self) -> int:
        """Offspring per iteration: the GA's batch, split between the GA and Q-PG."""
        return self.ga.offspring


def make_pga_me(task: Task, config: PGAMEConfig = PGAMEConfig()) -> QDRLParts:
    """PGA-ME's emitter on a policy task: the GA's share by `config.ga`, the rest by Q-PG."""
    policy = policy_of(task, "pga_me")
    emitter = pga_me_emitter(
        config.offspring, policy.network, policy.obs_size, policy.action_size, config.pg,
        proportion_mutation_ga=config.proportion_mutation_ga, make_ga=_ga_maker(config.ga, task),
    )
    return _parts(task, emitter)


@dataclasses.dataclass(frozen=True)
class QDPGConfig:
    """QD-PG (Pierrot et al. 2022): GA, Q-PG and D-PG share one batch by `shares`.

    The `[dpg]` section holds the shares and D-PG's novelty archive; `pg` (`[pg]`) is
    the TD3 of both policy-gradient emitters; `ga` (`[emitter]`) sets the batch.
    """

    # Shares of the batch for the GA, Q-PG and D-PG emitters.
    shares: tuple[PositiveFloat, ...] = (0.34, 0.33, 0.33)
    novelty: Annotated[NoveltyConfig, Nested()] = NoveltyConfig()
    pg: Annotated[PGConfig, OtherSection("pg")] = PGConfig()
    ga: Annotated[GAConfig, OtherSection("emitter")] = GAConfig()

    def check(self, section: str = "dpg") -> None:
        check_fields(self, section)
        if len(self.shares) != 3:
            raise ValueError(
                f"{section}.shares: expected 3 positive numbers (GA, Q-PG, D-PG), got {list(self.shares)}"
            )

    @property
    def offspring(self) -> int:
        return self.ga.offspring


def make_qdpg(task: Task, config: QDPGConfig = QDPGConfig()) -> QDRLParts:
    """QD-PG's emitter on a policy task: GA, Q-PG and D-PG (novelty reward) side by side."""
    policy = policy_of(task, "qdpg")
    reward = NoveltyReward(task.descriptor_size, config.novelty)
    shares = (config.shares[0], config.shares[1], config.shares[2])
    emitter = qdpg_emitter(
        config.offspring, policy.network, policy.obs_size, policy.action_size, task.descriptor_size,
        config.pg, shares, reward, _ga_maker(config.ga, task),
    )
    return _parts(task, emitter)


@dataclasses.dataclass(frozen=True)
class DCRLMEConfig:
    """DCRL-ME (Faldor et al. 2024): the DCRL emitter first, then a GA, in one batch.

    `dcrl` and the DCRL emitter's offspring counts are the `[dcrl]` section; the GA
    (`[emitter]`) makes the rest of `ga.batch_size`.
    """

    dcrl: Annotated[DCRLConfig, Nested()] = DCRLConfig()
    # Offspring per iteration made by descriptor-conditioned PG steps on parents (QDax: 64).
    dcrl_batch_size: NonNegativeInt = 64
    # Offspring per iteration made by injecting the DC actor at elites' descriptors (QDax: 64).
    ai_batch_size: NonNegativeInt = 64
    ga: Annotated[GAConfig, OtherSection("emitter")] = GAConfig()

    def check(self, section: str = "dcrl") -> None:
        check_fields(self, section)
        if self.dcrl_batch_size + self.ai_batch_size < 1:
            raise ValueError(
                f"{section}.dcrl_batch_size: expected dcrl_batch_size + ai_batch_size >= 1, got "
                f"{self.dcrl_batch_size} + {self.ai_batch_size}"
            )

    @property
    def offspring(self) -> int:
        return self.ga.offspring


def with_task_reward_offset(config: DCRLMEConfig, task: Task) -> DCRLMEConfig:
    """`config` with DCRL's reward offset set to the task's per-step offset when it gives none
    (-qd_offset / episode length: QDax's reward offsets; 0 for a task without episodes)."""
    if config.dcrl.reward_offset is not None:
        return config
    offset = 0.0 if task.env is None else -float(task.qd_offset) / int(task.env.episode_length)
    return dataclasses.replace(config, dcrl=dataclasses.replace(config.dcrl, reward_offset=offset))


def make_dcrl_me(task: Task, config: DCRLMEConfig = DCRLMEConfig()) -> QDRLParts:
    """DCRL-ME's emitter on a policy task (`with_task_reward_offset` completes the config)."""
    policy = policy_of(task, "dcrl_me")
    config = with_task_reward_offset(config, task)
    emitter = dcrl_me_emitter(
        config.offspring, policy.network, policy.obs_size, policy.action_size,
        task.descriptor_low, task.descriptor_high, config.dcrl,
        dcrl_batch_size=config.dcrl_batch_size, ai_batch_size=config.ai_batch_size,
        make_ga=_ga_maker(config.ga, task),
    )
    return _parts(task, emitter)


def make_me_es(task: Task, config: ESConfig = ESConfig()) -> QDRLParts:
    """ME-ES's emitter (Colas et al. 2020): OpenAI-ES around one elite of the task."""
    return _parts(task, ESEmitter(config, task.example_genotype(), task.descriptor_size))


def make_me_pbt(
    task: Task, agent: Agent, agent_name: str, config: MEPBTConfig = MEPBTConfig(),
    placement: Placement | None = None,
) -> QDRLParts:
    """ME-PBT's emitter (Pierrot & Flajolet 2023) of `agent` ("sac" or "td3", `agent_name`) agents
    trained on the task's environment; genotypes are whole agents, scored by their policy.

    Raises ValueError when the task has no environment or the search space names a
    hyperparameter the agent lacks.
    """
    if task.env is None or task.policy_scoring is None:
        raise ValueError(
            f"task.name: ME-PBT needs a policy task with an environment (e.g. ant_uni, "
            f"halfcheetah_uni, point_maze), got {task.name!r}"
        )
    example = jax.eval_shape(agent.init, jax.random.PRNGKey(0))
    space = pbt.search_space(agent_name, config.pbt_config(), example.hparams, "me_pbt")
    trainer = make_trainer(task.env, agent, config.train_config())
    emitter = MEPBTEmitter(agent, trainer, space, config, placement=placement)
    genotype = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), to_genotype(example))
    policy = agent_policy_network(agent)
    return QDRLParts(emitter, emitter.init_genotypes, task.policy_scoring(policy), genotype, policy)
