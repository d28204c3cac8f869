"""Skill-discovery recipes: DIAYN, DADS, and SMERL on either.

A run is SAC on a skill-conditioned environment (`qdrl.agents.skill_discovery`),
trained by the one off-policy loop with batches relabelled by the intrinsic
reward. Each log point evaluates every skill deterministically (`train.num_eval_envs`
episodes, skill i % K in episode i) through `run_episodes` on the task's own
environment, offers the episodes' (descriptor, return) to the task's passive archive,
and logs the same QD metrics as every other algorithm, plus the skill model's
metrics on the evaluation episodes (discriminator accuracy for DIAYN,
skill-dynamics log-likelihood for DADS), at every step and at the episodes' last step.

Sections: `[env]` (a task of `SKILL_TASKS`), `[agent]` (SAC), `[train]`, `[skills]`
(the DIAYN or DADS config), `[smerl]` (SMERL's target and margin), `[archive]`
(defaults: the task's descriptor bounds and QD offset).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import jax
import numpy as np

from qdrl import plotting
from qdrl.agents.base import AgentState
from qdrl.agents.dads import DADSConfig
from qdrl.agents.diayn import DIAYNConfig
from qdrl.agents.sac import SACConfig
from qdrl.agents.skill_discovery import evaluate_skills, make_skill_discovery
from qdrl.agents.smerl import SMERLConfig
from qdrl.algorithms.base import (
    Algorithm,
    BuildContext,
    DescriptorSpace,
    ExperimentConfig,
    Progress,
    Recipe,
    Row,
    Sections,
)
from qdrl.algorithms.rl import (
    ArchiveConfig,
    RLState,
    check_train_devices,
    eval_key,
    plot_archive,
    rl_log_row,
    write_archive,
)
from qdrl.config import ConfigError, OneOf, PositiveInt, build, check_keys, check_table
from qdrl.envs.base import Env
from qdrl.envs.brax import Backend
from qdrl.off_policy import STATE_AXES, TrainConfig, make_trainer
from qdrl.qd.repertoires.passive import feed
from qdrl.tasks import TASKS, Task
from qdrl.types import Array, PRNGKey

__all__ = ["DADS", "DIAYN", "SKILL_TASKS", "SMERL_DADS", "SMERL_DIAYN", "SkillEnvConfig", "skill_task"]

# The QD tasks (`qdrl.tasks`) a skill-discovery run can use: their environment,
# reward, episode descriptor, bounds and QD offset measure skills and QD algorithms
# on one scale.
SKILL_TASKS: tuple[str, ...] = ("point_maze", "ant_omni", "ant_trap", "ant_maze", "halfcheetah_uni")
SkillTaskName = Annotated[str, OneOf(lambda: SKILL_TASKS)]
# The skill model's metric on the progress bar: its value at the evaluation episodes' last step.
_MODEL_METRIC = {DIAYNConfig: "discriminator_accuracy", DADSConfig: "dynamics_log_likelihood"}


@dataclasses.dataclass(frozen=True)
class SkillEnvConfig:
    """The `[env]` section: which task, on which physics backend (brax tasks)."""

    task: SkillTaskName = "ant_omni"  # one of SKILL_TASKS
    backend: Backend = "spring"  # brax physics pipeline (ignored by point_maze)
    episode_length: PositiveInt = 1000  # steps before truncation


def skill_task(name: str, episode_length: int, backend: str) -> Task:
    """The QD task `name` at this episode length (on this physics backend where it has one)."""
    builder = TASKS[name].build
    params = {"episode_length": episode_length, "backend": backend}
    accepted = inspect.signature(builder).parameters
    return builder(**{k: v for k, v in params.items() if k in accepted})


def parse_skills(
    spec: Mapping[str, Any], exp: ExperimentConfig, base: Literal["diayn", "dads"], smerl: bool
) -> Sections:
    """The checked sections of a DIAYN / DADS (`base`) spec, SMERL on it if `smerl`.

    `[archive]` stays a table of the keys the spec gives (each checked): the build
    completes it with its task's descriptor bounds and QD offset.
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


def _build(sections: Sections, ctx: BuildContext) -> Algorithm:
    env_cfg: SkillEnvConfig = sections["env"]
    train_cfg: TrainConfig = sections["train"]
    skills_cfg: DIAYNConfig | DADSConfig = sections["skills"]
    task = skill_task(env_cfg.task, env_cfg.episode_length, env_cfg.backend)
    archive_defaults = {
        "descriptor": task.episode_descriptor,
        "low": list(task.descriptor_low),
        "high": list(task.descriptor_high),
        "qd_offset": task.qd_offset,
    }
    archive_cfg = build(ArchiveConfig, {**archive_defaults, **sections["archive"]}, "archive")
    base_env: Env = task.env
    archive_cfg.check_size(base_env.descriptor_size, env_cfg.task)
    try:
        sd = make_skill_discovery(base_env, sections["agent"], skills_cfg, sections.get("smerl"))
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith("skills.") else f"agent: {msg}") from e
    trainer = make_trainer(sd.env, sd.agent, train_cfg, sd.storage, placement=ctx.placement)
    k, num_eval = skills_cfg.num_skills, train_cfg.num_eval_envs
    key0 = eval_key(ctx.seed)
    labels = tuple(task.descriptor_names)
    title = f"{ctx.algorithm} on {env_cfg.task}"
    metric = _MODEL_METRIC[type(skills_cfg)]

    def evaluate(agent_state: AgentState, key: PRNGKey) -> dict[str, Array]:
        return evaluate_skills(sd, agent_state, key, num_eval, archive_cfg.descriptor, archive_cfg.low, archive_cfg.high)

    def init(key: jax.Array) -> RLState:
        return RLState(trainer.init(key), archive_cfg.empty())

    def chunk(state: RLState) -> tuple[RLState, dict[str, Any]]:
        """Train for one log interval, evaluate every skill, and offer the episodes to the archive."""
        train, metrics = trainer.run_chunk(state.train)
        ev = evaluate(train.agent, jax.random.fold_in(key0, train.env_steps))
        archive, qd = feed(state.archive, ev.pop("descriptors"), ev.pop("returns"), archive_cfg.qd_offset)
        out = dict(metrics)
        out.update(ev)
        out.update(qd)
        return RLState(train, archive), out

    # The latest evaluation's trajectories (host arrays), for the skills plot at the end.
    last_eval: dict[str, Any] = {}

    def log_row(state: RLState, metrics: Any) -> Row:
        metrics = dict(metrics)
        last_eval.update(jax.device_get({k: metrics.pop(k) for k in ("trajectories", "mask") if k in metrics}))
        counters = {"env_steps": int(state.train.env_steps), "grad_steps": int(state.train.grad_steps)}
        return rl_log_row(counters, metrics)

    def finish(state: RLState, rows: list[Row], out_dir: Path) -> dict[str, Any]:
        del rows
        write_archive(state.archive, out_dir)
        return {"grad_steps": int(np.asarray(state.train.grad_steps))}

    def plot(state: RLState, rows: list[Row], out_dir: Path) -> None:
        del rows
        plot_archive(state.archive, archive_cfg, labels, out_dir, title)
        ev = last_eval
        if not ev:  # a resumed run with no chunk left: evaluate once more
            ev = jax.device_get(jax.jit(evaluate)(state.train.agent, jax.random.fold_in(key0, 0xF1)))
        plotting.plot_skills(
            np.asarray(ev["trajectories"]),
            np.arange(num_eval) % k,
            np.asarray(ev["mask"]),
            out_dir / "plots" / "skills.png",
            archive_cfg.low,
            archive_cfg.high,
            archive=jax.device_get(state.archive),
            title=f"{title}: skills and passive archive",
            trajectories_are_positions=archive_cfg.descriptor == "final",
            walls=plotting.env_walls(base_env),
            labels=labels,
        )

    return Algorithm(
        task=env_cfg.task,
        sections={**sections, "archive": archive_cfg},
        num_chunks=train_cfg.num_chunks,
        progress=Progress(
            ("eval_return", "coverage", f"eval_final_{metric}"), "env_steps", train_cfg.num_chunks * train_cfg.eval_every
        ),
        init=init,
        chunk=chunk,
        log_row=log_row,
        finish=finish,
        plot=plot,
        placement=ctx.placement,
        state_axes=RLState(STATE_AXES, None),  # type: ignore[arg-type]
        descriptor_space=DescriptorSpace(archive_cfg.low, archive_cfg.high, labels),
    )


_VARIANTS: tuple[tuple[Literal["diayn", "dads"], bool, str], ...] = (
    ("diayn", False, "DIAYN (Eysenbach et al. 2019): skills that a discriminator tells apart"),
    ("dads", False, "DADS (Sharma et al. 2020): skills with predictable dynamics"),
    ("diayn", True, "SMERL (Kumar et al. 2020) on DIAYN's diversity reward"),
    ("dads", True, "SMERL (Kumar et al. 2020) on DADS's diversity reward"),
)
DIAYN, DADS, SMERL_DIAYN, SMERL_DADS = (
    Recipe(functools.partial(parse_skills, base=base, smerl=smerl), _build, "train.total_env_steps", description)
    for base, smerl, description in _VARIANTS
)
