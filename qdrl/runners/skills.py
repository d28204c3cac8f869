"""Skill-discovery runs (DIAYN, DADS, SMERL on either) for the experiment driver.

A run is SAC on a skill-conditioned environment (`qdrl.envs.skills.SkillEnv`),
trained by the one off-policy loop with batches relabelled by the intrinsic
reward (`qdrl.agents.intrinsic`). Each log point evaluates every skill
deterministically (`train.num_eval_envs` episodes, skill i % K in episode i)
through `run_episodes` on the task's own environment, offers the episodes'
(descriptor, return) to the task's passive archive, and logs the same QD metrics
as every other algorithm, plus the skill model's metrics on the evaluation
episodes (discriminator accuracy for DIAYN, skill-dynamics log-likelihood for
DADS), at every step and at the episodes' last step.

Algorithms: `diayn`, `dads`, `smerl_diayn`, `smerl_dads`. Sections: `[env]`
(a task of `SKILL_TASKS`), `[agent]` (SAC), `[train]`, `[skills]` (the DIAYN or
DADS config), `[smerl]` (SMERL's target and margin), `[archive]` (defaults: the
task's descriptor bounds and QD offset).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from qdrl import off_policy
from qdrl.agents.base import Agent, AgentState
from qdrl.agents.dads import DADSConfig, make_dads_module
from qdrl.agents.diayn import DIAYNConfig, make_diayn_module
from qdrl.agents.intrinsic import RewardModule, with_skill_model
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.smerl import SMERLConfig, smerl_gate
from qdrl.config import ConfigError, OneOf, PositiveInt, build, check_keys, check_table
from qdrl.envs.base import Env
from qdrl.envs.brax import Backend
from qdrl.envs.skills import SkillEnv, append_skill
from qdrl.experiment import ExperimentConfig, Sections, register
from qdrl.off_policy import TrainConfig, make_trainer
from qdrl.placement import make_placement
from qdrl.qd.metrics import qd_metrics
from qdrl.qd.repertoires import observe
from qdrl.rollout import run_episodes
from qdrl.runners.rl import ArchiveConfig, OffPolicyRun, RLState, check_train_devices
from qdrl.tasks import Task, make_task
from qdrl.types import Array, PRNGKey

SkillTaskName = Annotated[str, OneOf(lambda: SKILL_TASKS)]


# The QD tasks (`qdrl.tasks`) a skill-discovery run can use: their environment,
# reward, episode descriptor, bounds and QD offset measure skills and QD algorithms
# on one scale.
SKILL_TASKS: tuple[str, ...] = ("point_maze", "ant_omni", "ant_trap", "ant_maze", "halfcheetah_uni")


def skill_task(name: str, episode_length: int, backend: str) -> Task:
    """The QD task `name` at this episode length (brax tasks: on this physics backend)."""
    params: dict[str, Any] = {"episode_length": episode_length}
    if name != "point_maze":
        params["backend"] = backend
    return make_task(name, **params)


@dataclasses.dataclass(frozen=True)
class SkillEnvConfig:
    """The `[env]` section: which task, on which physics backend (brax tasks)."""

    task: SkillTaskName = "ant_omni"  # one of SKILL_TASKS
    backend: Backend = "spring"  # brax physics pipeline (ignored by point_maze)
    episode_length: PositiveInt = 1000  # steps before truncation


def _skill_module(
    skills: DIAYNConfig | DADSConfig, obs_size: int, descriptor_size: int
) -> RewardModule:
    if isinstance(skills, DIAYNConfig):
        return make_diayn_module(skills, obs_size, descriptor_size)
    return make_dads_module(skills, obs_size, descriptor_size)


class SkillRun(OffPolicyRun):
    """DIAYN / DADS / SMERL: trainer chunks, then every skill evaluated into a passive archive."""

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        """Builds the task, environment, agent and trainer of checked `sections` (`parse_skills`),
        completing `[archive]` with the task's descriptor bounds and QD offset."""
        env_cfg, agent_cfg, train_cfg = sections["env"], sections["agent"], sections["train"]
        skills_cfg = sections["skills"]
        task = skill_task(env_cfg.task, env_cfg.episode_length, env_cfg.backend)
        archive_defaults = {
            "descriptor": task.episode_descriptor,
            "low": list(task.descriptor_low),
            "high": list(task.descriptor_high),
            "qd_offset": task.qd_offset,
        }
        archive_cfg = build(ArchiveConfig, {**archive_defaults, **sections["archive"]}, "archive")
        self.sections = {**sections, "archive": archive_cfg}
        gate = None
        if "smerl" in sections:
            gate = smerl_gate(sections["smerl"].target, sections["smerl"].margin)
        k = skills_cfg.num_skills
        self.algorithm = exp.algorithm
        self.task = env_cfg.task
        self.archive_cfg = archive_cfg
        self.skills_cfg = skills_cfg
        self.base_env = task.env
        self.descriptor_names = task.descriptor_names
        if len(archive_cfg.grid_shape) != self.base_env.descriptor_size:
            raise ConfigError(
                f"archive.grid_shape: expected {self.base_env.descriptor_size} entries (the state "
                f"descriptor size of {env_cfg.task!r}), got {list(archive_cfg.grid_shape)}"
            )
        self.env = SkillEnv(self.base_env, k)
        obs_size, desc_size = self.base_env.observation_size, self.base_env.descriptor_size
        try:
            sac = make_sac(agent_cfg, self.env.observation_size, self.env.action_size)
            self.module = _skill_module(skills_cfg, obs_size, desc_size)
        except ValueError as e:
            msg = str(e)
            raise ConfigError(msg if msg.startswith("skills.") else f"agent: {msg}") from e
        self.agent: Agent = with_skill_model(sac, self.module, skills_cfg, gate)
        storage = off_policy.EPISODE_RETURNS if gate is not None else off_policy.REPLAY
        self.placement = make_placement(exp.devices)
        self.trainer = make_trainer(self.env, self.agent, train_cfg, storage, placement=self.placement)
        self.num_eval = train_cfg.num_eval_envs
        self.num_chunks = train_cfg.num_chunks
        self.progress_unit, self.progress_total = "env_steps", train_cfg.num_chunks * train_cfg.eval_every
        self.progress_keys = ("eval_return", "coverage", *self._model_metric_names()[:1])
        self._eval_key = jax.random.fold_in(jax.random.PRNGKey(exp.seed), 0x5EED)
        self._chunk: Any = None
        self._last_eval: dict[str, Any] | None = None

    @property
    def archive_labels(self) -> tuple[str, ...]:
        """The task's descriptor names (e.g. "final x", "back foot contact")."""
        return tuple(self.descriptor_names)

    def _model_metric_names(self) -> tuple[str, ...]:
        if isinstance(self.skills_cfg, DIAYNConfig):
            return ("eval_final_discriminator_accuracy", "eval_discriminator_accuracy")
        return ("eval_final_dynamics_log_likelihood", "eval_dynamics_log_likelihood")

    def evaluate(self, agent_state: AgentState, key: PRNGKey) -> dict[str, Array]:
        """Episode i plays skill i % K deterministically; returns metrics and the trajectories."""
        k = self.skills_cfg.num_skills
        params = self.agent.policy_params(agent_state)
        skills = jnp.arange(self.num_eval, dtype=jnp.int32) % k
        run_key, model_key = jax.random.split(key)

        def policy(obs: Array, _: PRNGKey) -> Array:
            return self.agent.policy(params, append_skill(obs, skills, k))

        ep = run_episodes(self.base_env, policy, run_key, self.num_eval)
        desc = ep.final_desc if self.archive_cfg.descriptor == "final" else ep.mean_desc
        desc = jnp.clip(desc, jnp.asarray(self.archive_cfg.low), jnp.asarray(self.archive_cfg.high))
        # The skill model's metrics on the evaluation steps, as the training batches see them.
        tr = ep.transitions
        steps = tr.obs.shape[0]
        per_step = jnp.broadcast_to(skills, (steps, self.num_eval))
        tr = tr._replace(
            obs=append_skill(tr.obs, per_step, k), next_obs=append_skill(tr.next_obs, per_step, k)
        )
        flat = jax.tree.map(lambda x: x.reshape((-1, *x.shape[2:])), tr)
        _, info = self.module.reward(agent_state.aux, flat, model_key)
        mask = ep.mask
        last = jax.nn.one_hot(ep.lengths - 1, steps, axis=0) * mask  # (T, B) the last step
        out: dict[str, Array] = {
            "eval_return": jnp.mean(ep.returns),
            "eval_return_std": jnp.std(ep.returns),
            "eval_return_min": jnp.min(ep.returns),
            "eval_length": jnp.mean(ep.lengths.astype(jnp.float32)),
            "returns": ep.returns,
            "descriptors": desc,
            "trajectories": tr.next_desc,
            "mask": mask,
        }
        for name, value in info.items():
            v = value.reshape(mask.shape)
            out[f"eval_{name}"] = jnp.sum(v * mask) / jnp.sum(mask)
            out[f"eval_final_{name}"] = jnp.sum(v * last) / jnp.sum(last)
        return out

    def chunk(self, state: RLState) -> tuple[RLState, dict[str, Any]]:
        """Train for one log interval, evaluate every skill, and offer the episodes to the archive."""
        train, metrics = self.trainer.run_chunk(state.train)
        ev = self.evaluate(train.agent, jax.random.fold_in(self._eval_key, train.env_steps))
        archive = observe(state.archive, ev.pop("descriptors"), ev.pop("returns"))
        out = dict(metrics)
        out.update(ev)
        out.update(qd_metrics(archive, self.archive_cfg.qd_offset))
        return RLState(train, archive), out

    def log_row(self, state: RLState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        """The row of `OffPolicyRun`; keeps the evaluation's trajectories for the skills plot."""
        metrics = dict(chunk_metrics)
        self._last_eval = jax.device_get(
            {k: metrics.pop(k) for k in ("trajectories", "mask") if k in metrics}
        )
        return super().log_row(state, metrics, chunk)

    def finish(self, state: RLState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        from qdrl import plotting

        out = super().finish(state, rows, out_dir)
        ev = self._last_eval
        if ev is None:  # a resumed run with no chunk left: evaluate once more
            ev = jax.device_get(
                jax.jit(self.evaluate)(state.train.agent, jax.random.fold_in(self._eval_key, 0xF1))
            )
        cfg = self.archive_cfg
        plotting.plot_skills(
            np.asarray(ev["trajectories"]),
            np.arange(self.num_eval) % self.skills_cfg.num_skills,
            np.asarray(ev["mask"]),
            out_dir / "plots" / "skills.png",
            cfg.low,
            cfg.high,
            archive=jax.device_get(state.archive),
            title=f"{self.algorithm} on {self.task}: skills and passive archive",
            trajectories_are_positions=cfg.descriptor == "final",
            walls=plotting.env_walls(self.base_env),
            labels=self.archive_labels,
        )
        return out


def skill_trainer_builder(
    algorithm: str,
    hidden: tuple[int, ...] = (256, 256),
    num_skills: int = 10,
    smerl: SMERLConfig | None = None,
) -> Callable[[Env, TrainConfig], off_policy.Trainer]:
    """`(env, train_config) -> Trainer` of a skill-discovery `algorithm` with default settings.

    SAC and the skill model both use `hidden`; for the throughput benchmark (`qdrl bench skills`).
    """
    if algorithm not in ("diayn", "dads", "smerl_diayn", "smerl_dads"):
        raise ValueError(f"unknown skill-discovery algorithm {algorithm!r}")
    is_smerl = algorithm.startswith("smerl")
    cls = DADSConfig if algorithm.endswith("dads") else DIAYNConfig

    def build(env: Env, config: TrainConfig) -> off_policy.Trainer:
        skill_env = SkillEnv(env, num_skills)
        skills = cls(num_skills=num_skills, hidden=hidden, extrinsic_scale=1.0 if is_smerl else 0.0)
        module = _skill_module(skills, env.observation_size, env.descriptor_size)
        sac = make_sac(SACConfig(hidden=hidden), skill_env.observation_size, env.action_size)
        s = smerl or SMERLConfig()
        gate = smerl_gate(s.target, s.margin) if is_smerl else None
        agent = with_skill_model(sac, module, skills, gate)
        storage = off_policy.EPISODE_RETURNS if is_smerl else off_policy.REPLAY
        return make_trainer(skill_env, agent, config, storage)

    return build


def parse_skills(
    spec: Mapping[str, Any], exp: ExperimentConfig, base: Literal["diayn", "dads"], smerl: bool
) -> Sections:
    """The checked sections of a DIAYN / DADS (`base`) spec, SMERL on it if `smerl`.

    `[archive]` stays a table of the keys the spec gives (each checked): the run
    completes it with its task's descriptor bounds and QD offset (`SkillRun`).
    """
    env = build(SkillEnvConfig, spec.get("env", {}), "env")
    agent = build(SACConfig, spec.get("agent", {}), "agent")
    train = build(TrainConfig, spec.get("train", {}), "train")
    check_train_devices(train, exp.num_devices)
    skills_data = dict(check_table(spec.get("skills", {}), "skills"))
    if smerl:
        # SMERL optimises the task reward (weight 1 in Kumar et al. 2020, eq. 3).
        skills_data.setdefault("extrinsic_scale", 1.0)
    skills = build(DIAYNConfig if base == "diayn" else DADSConfig, skills_data, "skills")
    archive = check_keys(ArchiveConfig, spec.get("archive", {}), "archive")
    sections: Sections = {"env": env, "agent": agent, "train": train, "skills": skills, "archive": archive}
    if smerl:
        sections["smerl"] = build(SMERLConfig, spec.get("smerl", {}), "smerl")
    k = skills.num_skills
    if train.num_eval_envs % k:
        raise ConfigError(
            f"train.num_eval_envs: expected a multiple of skills.num_skills={k} (every "
            f"skill is evaluated the same number of times), got {train.num_eval_envs}"
        )
    return sections


for _name in ("diayn", "dads", "smerl_diayn", "smerl_dads"):
    register(
        _name,
        functools.partial(
            parse_skills, base="dads" if _name.endswith("dads") else "diayn", smerl=_name.startswith("smerl")
        ),
        SkillRun,
    )
