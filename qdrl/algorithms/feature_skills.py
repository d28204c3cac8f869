"""Feature-space skill recipes: QDAC and UVFA, measured by distance to skill.

A skill z is a target for the episode's average feature phi-bar in a bounded feature space
(Grillotti et al. 2024, "Quality-Diversity Actor-Critic"): feet contact, velocity, jump,
heading (`qdrl.tasks.brax_features`). The agent acts on the observation followed by z's
code (`ContinuousSkillEnv`), trains through the one off-policy loop, and at each log point
plays a fixed set of evaluation skills (`train.num_eval_envs` of them, the same for every
method and seed: drawn from a fixed key, or a grid) deterministically. It logs

- `distance_to_skill`: the mean over those skills of ||phi-bar - z||_2 (QDAC's metric),
- `reached`: the share of skills within `evaluation.threshold` of their target, and
  `skill_qd_score` (the sum of their returns normalised by `evaluation.return_range`),
- the evaluation return, and the QD metrics of the passive archive the episodes are offered
  to as (phi-bar, return): a 1024-cell CVT over the feature space by default,

and the run's learner metrics (QDAC: the Lagrange multiplier, the constraint's estimated
distance). `skills.csv` keeps every evaluated episode (target, phi-bar, distance, return);
`profiles.json` and `plots/profiles.png` the last evaluation's distance and performance
profiles (21 bins, `qdrl.skill_metrics`); `plots/skills.png` each skill's phi-bar beside its
target.

Sections: `[env]` (a task of `FEATURE_SKILL_TASKS`), `[agent]` (SAC), `[train]`,
`[qdac]` (QDAC) or `[uvfa]` (UVFA), `[evaluation]`, `[archive]` (defaults: the task's feature
bounds and QD offset).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from qdrl import plotting, skill_metrics
from qdrl.agents.base import Agent, AgentState
from qdrl.agents.qdac import QDACConfig, make_qdac
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.uvfa import make_uvfa
from qdrl.algorithms.base import (
    AgentParts,
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
    RL_CURVES,
    ArchiveConfig,
    RLState,
    check_train_devices,
    eval_key,
    plot_archive,
    rl_log_row,
    write_archive,
)
from qdrl.algorithms.skills import SKILLS_CSV, SkillLog
from qdrl.config import (
    ConfigError,
    OneOf,
    PositiveFloat,
    PositiveInt,
    build,
    check_keys,
    check_table,
)
from qdrl.envs.base import Env
from qdrl.envs.brax import Backend
from qdrl.envs.point import PointEnv
from qdrl.envs.skills import ContinuousSkillEnv, SkillSpace
from qdrl.off_policy import STATE_AXES, TrainConfig, make_trainer
from qdrl.qd.repertoires.passive import feed
from qdrl.rollout import Episodes, RecordFn, run_episodes
from qdrl.tasks.brax_features import FEATURE_TASKS, feature_space
from qdrl.types import Array, PRNGKey

__all__ = [
    "FEATURE_SKILL_TASKS",
    "QDAC",
    "UVFA",
    "EvaluationConfig",
    "FeatureTask",
    "UVFAConfig",
    "feature_task",
]

POINT_TASK = "point_position"  # a point mass whose feature is its x-y position: tests, demos
FEATURE_SKILL_TASKS: tuple[str, ...] = (POINT_TASK, *FEATURE_TASKS)
FeatureTaskName = Annotated[str, OneOf(lambda: FEATURE_SKILL_TASKS)]


@dataclasses.dataclass(frozen=True)
class FeatureEnvConfig:
    """The `[env]` section: which feature task, on which physics backend (brax tasks)."""

    task: FeatureTaskName = "walker2d_feet_contact"  # one of FEATURE_SKILL_TASKS
    backend: Backend = "spring"  # brax physics pipeline (ignored by point_position)
    episode_length: PositiveInt = 1000  # steps before truncation (QDAC: 1000)


@dataclasses.dataclass(frozen=True)
class EvaluationConfig:
    """The `[evaluation]` section: which skills each log point plays, and what counts as reached.

    The skills are `train.num_eval_envs` targets in the feature space: "sample" draws them
    uniformly from a fixed key (heading tasks: evenly spaced angles), "grid" lays them on a
    regular grid (num_eval_envs must then be a D-th power, k^D, k >= 2).
    """

    skills: Literal["sample", "grid"] = "sample"
    # A skill is reached when ||phi-bar - z|| <= threshold; None: 5% of the feature space's
    # diagonal (a bound of the distance).
    threshold: PositiveFloat | None = None
    # [min, max] returns of the performance profile and of skill_qd_score; None: the archive's
    # fitness_range, else [qd_offset, max return of the last evaluation].
    return_range: tuple[float, float] | None = None

    def check(self) -> None:
        if self.return_range is not None and not self.return_range[0] < self.return_range[1]:
            raise ValueError(
                f"evaluation.return_range: expected [min, max] with min < max, got {list(self.return_range)}"
            )


@dataclasses.dataclass(frozen=True)
class UVFAConfig:
    """The `[uvfa]` section: the weights of UVFA's reward extrinsic_scale r - distance_scale ||phi - z||."""

    distance_scale: PositiveFloat = 1.0  # weight of minus the distance to the skill
    extrinsic_scale: float = 0.0  # weight of the task reward (0: the skill alone)


class FeatureTask(NamedTuple):
    """What a feature-skill run needs of its task."""

    env: Env  # its state descriptor is the feature phi(s)
    space: SkillSpace  # where skills are drawn, and how the agent sees them
    names: tuple[str, ...]  # the feature's dimensions
    qd_offset: float  # the passive archive's QD offset


def feature_task(name: str, episode_length: int, backend: str) -> FeatureTask:
    """The feature task `name` at this episode length (brax tasks on this backend)."""
    if name == POINT_TASK:
        env = PointEnv(episode_length=episode_length)
        # reward: minus the distance to the goal, at most 2 sqrt(2) in the box
        return FeatureTask(env, SkillSpace((-1.0, -1.0), (1.0, 1.0)), ("x", "y"), -2.0 * math.sqrt(2.0) * episode_length)
    task = FEATURE_TASKS[name](episode_length=episode_length, backend=backend)
    space = feature_space(name)
    assert space is not None  # every FEATURE_TASKS name has its space
    return FeatureTask(task.env, space, tuple(task.descriptor_names), task.qd_offset)


def parse_feature_skills(spec: Mapping[str, Any], exp: ExperimentConfig, method: Literal["qdac", "uvfa"]) -> Sections:
    """The checked sections of a QDAC or UVFA spec."""
    train = build(TrainConfig, spec.get("train", {}), "train")
    check_train_devices(train, exp.num_devices)
    sections: Sections = {
        "env": build(FeatureEnvConfig, spec.get("env", {}), "env"),
        "agent": build(SACConfig, spec.get("agent", {}), "agent"),
        "train": train,
        "evaluation": build(EvaluationConfig, spec.get("evaluation", {}), "evaluation"),
        "archive": check_keys(ArchiveConfig, spec.get("archive", {}), "archive"),
    }
    if method == "qdac":
        sections["qdac"] = build(QDACConfig, spec.get("qdac", {}), "qdac")
    else:
        sections["uvfa"] = build(UVFAConfig, dict(check_table(spec.get("uvfa", {}), "uvfa")), "uvfa")
    return sections


def _agent(sections: Sections, task: FeatureTask, obs_size: int, action_size: int) -> Agent:
    sac: SACConfig = sections["agent"]
    try:
        if "qdac" in sections:
            return make_qdac(sac, sections["qdac"], task.space, obs_size, action_size)
        uvfa: UVFAConfig = sections["uvfa"]
        return make_uvfa(make_sac(sac, obs_size, action_size), task.space, uvfa.distance_scale, uvfa.extrinsic_scale)
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith(("qdac.", "uvfa.")) else f"agent: {msg}") from e


def _build(sections: Sections, ctx: BuildContext) -> Algorithm:
    env_cfg: FeatureEnvConfig = sections["env"]
    train_cfg: TrainConfig = sections["train"]
    eval_cfg: EvaluationConfig = sections["evaluation"]
    task = feature_task(env_cfg.task, env_cfg.episode_length, env_cfg.backend)
    space = task.space
    archive_defaults = {
        "descriptor": "mean", "kind": "cvt", "low": list(space.low), "high": list(space.high),
        "qd_offset": task.qd_offset,
    }
    archive_cfg = build(ArchiveConfig, {**archive_defaults, **sections["archive"]}, "archive")
    if archive_cfg.descriptor != "mean":
        raise ConfigError("archive.descriptor: expected 'mean' (a skill targets the episode's average feature), "
                          f"got {archive_cfg.descriptor!r}")
    archive_cfg.check_size(space.size, env_cfg.task)
    num_eval = train_cfg.num_eval_envs
    try:
        skills = skill_metrics.evaluation_targets(space, num_eval, eval_cfg.skills)
    except ValueError as e:
        raise ConfigError(str(e)) from e
    skill_env = ContinuousSkillEnv(task.env, space)
    agent = _agent(sections, task, skill_env.observation_size, skill_env.action_size)
    trainer = make_trainer(skill_env, agent, train_cfg, placement=ctx.placement)
    diagonal = float(np.linalg.norm(np.subtract(space.high, space.low)))
    threshold = eval_cfg.threshold if eval_cfg.threshold is not None else skill_metrics.default_threshold(space)
    return_range = eval_cfg.return_range or archive_cfg.fitness_range
    targets = jnp.asarray(skills)
    codes = space.normalise(targets)
    key0 = eval_key(ctx.seed)
    labels = task.names
    title = f"{ctx.algorithm} on {env_cfg.task}"

    def episodes(agent_state: AgentState, key: PRNGKey, record: RecordFn | None = None) -> Episodes:
        """Episode i plays evaluation skill i deterministically, on the task's own environment."""
        params = agent.policy_params(agent_state)
        return run_episodes(
            task.env, lambda obs, _: agent.policy(params, jnp.concatenate([obs, codes], axis=-1)), key, num_eval,
            record=record,
        )

    def evaluate(agent_state: AgentState, key: PRNGKey) -> tuple[Episodes, dict[str, Array]]:
        ep = episodes(agent_state, key)
        dist = skill_metrics.distance_to_skill(ep.mean_desc, targets)
        out = {
            "eval_return": jnp.mean(ep.returns),
            "eval_return_std": jnp.std(ep.returns),
            "eval_length": jnp.mean(ep.lengths.astype(jnp.float32)),
            "distance_to_skill": jnp.mean(dist),
            "distance_to_skill_median": jnp.median(dist),
            "reached": jnp.mean((dist <= threshold).astype(jnp.float32)),
        }
        if return_range is not None:  # else only at the end, over the last evaluation's returns
            out["skill_qd_score"] = skill_metrics.skill_qd_score(ep.returns, dist, threshold, *return_range)
        return ep, out | {"distances": dist}

    def init(key: jax.Array) -> RLState:
        return RLState(trainer.init(key), archive_cfg.empty(ctx.seed))

    def chunk(state: RLState) -> tuple[RLState, dict[str, Any]]:
        """Train for one log interval, play every evaluation skill, offer the episodes to the archive."""
        train, metrics = trainer.run_chunk(state.train)
        ep, ev = evaluate(train.agent, jax.random.fold_in(key0, train.env_steps))
        descriptors = jnp.clip(ep.mean_desc, jnp.asarray(archive_cfg.low), jnp.asarray(archive_cfg.high))
        archive, qd = feed(state.archive, descriptors, ep.returns, archive_cfg.qd_offset, archive_cfg.fitness_range)
        out: dict[str, Any] = dict(metrics)
        out.update(ev)
        out.update(qd)
        out.update(skill_metrics.archive_skill_metrics(archive.descriptors, archive.fitnesses, space, threshold))
        out["episodes"] = {
            "returns": ep.returns, "lengths": ep.lengths, "descriptors": ep.mean_desc,
            "cells": archive.cell_index(descriptors), "targets": targets, "distances": out.pop("distances"),
        }
        return RLState(train, archive), out

    skill_log = SkillLog(labels, num_eval, frozenset())
    last: dict[str, Any] = {}

    def log_row(state: RLState, metrics: Any) -> Row:
        metrics = dict(metrics)
        env_steps = int(state.train.env_steps)
        kept = jax.device_get(metrics.pop("episodes"))
        skill_log.add(env_steps // train_cfg.eval_every - 1, env_steps, kept, None, None)
        last.update(kept)
        return rl_log_row({"env_steps": env_steps, "grad_steps": int(state.train.grad_steps)}, metrics)

    def write_skills(out_dir: Path) -> None:
        if skill_log.rows:
            skill_log.write(out_dir / SKILLS_CSV, int(skill_log.rows[0]["log_point"]))

    def last_evaluation(state: RLState) -> dict[str, Any]:
        """The last log point's episodes: kept from this session, or played again (a resumed run
        with no chunk left)."""
        if not last:
            ep, ev = jax.device_get(jax.jit(evaluate)(state.train.agent, jax.random.fold_in(key0, state.train.env_steps)))
            last.update({"returns": ep.returns, "descriptors": ep.mean_desc, "distances": ev["distances"]})
        return last

    def profiles(state: RLState) -> dict[str, Any]:
        ev = last_evaluation(state)
        returns, dist = jnp.asarray(ev["returns"]), jnp.asarray(ev["distances"])
        lo, hi = return_range if return_range is not None else (archive_cfg.qd_offset, float(np.max(returns)))
        hi = hi if hi > lo else lo + 1.0
        dp = skill_metrics.distance_profile(dist, diagonal)
        pp = skill_metrics.performance_profile(returns, dist, threshold, lo, hi)
        return {
            "threshold": threshold,
            "return_range": [float(lo), float(hi)],
            "distance_to_skill": float(np.mean(dist)),
            "reached": float(np.mean(dist <= threshold)),
            "skill_qd_score": float(skill_metrics.skill_qd_score(returns, dist, threshold, lo, hi)),
            "distance_score": float(skill_metrics.distance_score(dist, diagonal)),
            "distance_profile": {"distance": np.asarray(dp.thresholds).tolist(), "share": np.asarray(dp.share).tolist()},
            "performance_profile": {"return": np.asarray(pp.thresholds).tolist(), "share": np.asarray(pp.share).tolist()},
        }

    def finish(state: RLState, rows: list[Row], out_dir: Path) -> dict[str, Any]:
        del rows
        write_archive(state.archive, out_dir)
        prof = profiles(state)
        (out_dir / "profiles.json").write_text(json.dumps(prof, indent=2) + "\n")
        return {"grad_steps": int(np.asarray(state.train.grad_steps)), "distance_to_skill": prof["distance_to_skill"]}

    def plot(state: RLState, rows: list[Row], out_dir: Path) -> None:
        plot_archive(state.archive, archive_cfg, labels, out_dir, title, rows)
        ev = last_evaluation(state)
        prof = profiles(state)
        plotting.plot_feature_skills(
            np.asarray(targets), np.asarray(ev["descriptors"]), np.asarray(ev["returns"]),
            out_dir / "plots" / "skills.png", space.low, space.high, labels, f"{title}: skills and their targets",
        )
        plotting.plot_profiles(
            {ctx.algorithm: prof}, out_dir / "plots" / "profiles.png", title=f"{title}: profiles"
        )

    def policy(agent_state: AgentState, skill: int | None) -> Callable[[Array], Array]:
        if isinstance(skill, bool) or not isinstance(skill, int) or not 0 <= skill < num_eval:
            raise ValueError(f"skill: expected an evaluation skill's index, an int in [0, {num_eval}), got {skill!r}")
        params = agent.policy_params(agent_state)
        code = codes[skill]

        def act(obs: Array) -> Array:
            obs = jnp.asarray(obs, jnp.float32)
            return agent.policy(params, jnp.concatenate([obs, jnp.broadcast_to(code, (*obs.shape[:-1], code.shape[0]))], -1))

        return act

    def evaluation(state: RLState, record: Any) -> tuple[Episodes, Array]:
        ep = episodes(state.train.agent, jax.random.fold_in(key0, state.train.env_steps), record)
        return ep, jnp.clip(ep.mean_desc, jnp.asarray(archive_cfg.low), jnp.asarray(archive_cfg.high))

    return Algorithm(
        curves=(*RL_CURVES, "distance_to_skill"),
        task=env_cfg.task,
        sections={**sections, "archive": archive_cfg},
        num_chunks=train_cfg.num_chunks,
        progress=Progress(("eval_return", "distance_to_skill", "coverage"), "env_steps", train_cfg.num_chunks * train_cfg.eval_every),
        init=init,
        chunk=chunk,
        log_row=log_row,
        finish=finish,
        plot=plot,
        placement=ctx.placement,
        state_axes=RLState(STATE_AXES, None),  # type: ignore[arg-type]
        descriptor_space=DescriptorSpace(archive_cfg.low, archive_cfg.high, labels),
        agent=AgentParts(
            task.env, num_eval, lambda state: state.train.agent, policy, evaluation,
            skills_are="train.num_eval_envs evaluation skills",
        ),
        on_log_point=write_skills,
    )


QDAC = Recipe(
    functools.partial(parse_feature_skills, method="qdac"), _build, "train.total_env_steps",
    "QDAC (Grillotti et al. 2024): skills as feature targets, successor features and a Lagrange multiplier",
)
UVFA = Recipe(
    functools.partial(parse_feature_skills, method="uvfa"), _build, "train.total_env_steps",
    "UVFA: SAC on (s, z) with the reward -||phi(s') - z|| (QDAC's baseline)",
)
