"""Skill-discovery recipes: DIAYN, DADS, SMERL (and Reverse SMERL) on either, METRA, LSD, DOMiNO.

A run is SAC on a skill-conditioned environment (`qdrl.agents.skill_discovery`),
trained by the one off-policy loop with batches relabelled by the intrinsic
reward. Each log point evaluates every skill deterministically (`train.num_eval_envs`
episodes, skill i % K in episode i) through `run_episodes` on the task's own
environment, offers the episodes' (descriptor, return) to the task's passive archive,
and logs the same QD metrics as every other algorithm, plus the skill model's
metrics on the evaluation episodes (discriminator accuracy for DIAYN,
skill-dynamics log-likelihood for DADS, METRA's step ||phi(s') - phi(s)||^2), at every
step and at the episodes' last step. Skills are one-hot codes of K skills, or
continuous (METRA's and LSD's unit vectors; continuous DIAYN's [-1, 1]^d, the QDAC
paper's SMERL baselines), one per evaluation episode. On position tasks (final x-y) runs
also log METRA's state coverage (`cells_visited`: the 1x1 cells the evaluation paths
visit); on QDAC's feature tasks, the archive read as a library of skills for QDAC's
evaluation targets (`archive_distance_to_skill`, `archive_reached`;
`qdrl.skill_metrics.archive_skill_metrics`).

Besides the driver's outputs a run writes `skills.csv` (every evaluated episode of every
log point: its skill, return, length, descriptor and archive cell; `SkillLog`) and
`plots/skills.png` (the skills' paths at the first, middle and last log points beside
the archive). A loaded run acts with and replays any skill of its trained agent
(`Algorithm.agent`, `qdrl.load_run`).

Sections: `[env]` (a task of `SKILL_TASKS`), `[agent]` (SAC), `[train]`, `[skills]`
(the DIAYN, DADS or METRA config; DOMiNO's: its number of skills), `[domino]` (DOMiNO's
constraint and diversity reward), `[smerl]` (SMERL's target, margin and direction),
`[archive]` (defaults: the task's descriptor bounds and QD offset).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import inspect
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal

import jax
import numpy as np

from qdrl import plotting
from qdrl.agents.base import AgentState
from qdrl.agents.dads import DADSConfig
from qdrl.agents.diayn import DIAYNConfig
from qdrl.agents.domino import DOMiNOConfig
from qdrl.agents.metra import METRAConfig
from qdrl.agents.sac import SACConfig
from qdrl.agents.skill_discovery import (
    DiscreteSkills,
    SkillConfig,
    episode_descriptors,
    evaluate_skills,
    make_skill_discovery,
    skill_episodes,
    skill_policy,
    skill_space,
)
from qdrl.agents.smerl import SMERLConfig
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
from qdrl.config import ConfigError, OneOf, PositiveInt, build, check_keys, check_table
from qdrl.envs.base import Env
from qdrl.envs.brax import Backend
from qdrl.off_policy import STATE_AXES, TrainConfig, make_trainer
from qdrl.qd.repertoires import descriptor_columns
from qdrl.qd.repertoires.passive import feed
from qdrl.rollout import Episodes
from qdrl.skill_metrics import archive_skill_metrics, cells_visited
from qdrl.tasks import TASKS, Task
from qdrl.tasks.brax_features import FEATURE_TASKS, feature_space
from qdrl.types import Array, PRNGKey

__all__ = [
    "DADS",
    "DIAYN",
    "DOMINO",
    "LSD",
    "METRA",
    "SKILLS_CSV",
    "SKILL_TASKS",
    "SMERL_DADS",
    "SMERL_DIAYN",
    "SMERL_REVERSE",
    "SkillEnvConfig",
    "SkillLog",
    "skill_columns",
    "skill_task",
]

# The QD tasks (`qdrl.tasks`) a skill-discovery run can use: their environment,
# reward, episode descriptor, bounds and QD offset measure skills and QD algorithms
# on one scale.
SKILL_TASKS: tuple[str, ...] = (
    "point_maze", "ant_omni", "ant_trap", "ant_maze", "ant_uni", "halfcheetah_uni", "walker2d_uni",
    "halfcheetah_omni", *FEATURE_TASKS,
)
SkillTaskName = Annotated[str, OneOf(lambda: SKILL_TASKS)]
# The skill model's metric on the progress bar: its value at the evaluation episodes' last step.
_MODEL_METRIC = {
    DIAYNConfig: "discriminator_accuracy", DADSConfig: "dynamics_log_likelihood", METRAConfig: "phi_step_sq",
}
_CONTINUOUS_METRIC = {DIAYNConfig: "discriminator_log_likelihood", METRAConfig: "phi_step_sq"}
_CONFIGS = {
    "diayn": DIAYNConfig, "dads": DADSConfig, "metra": METRAConfig, "lsd": METRAConfig, "domino": DiscreteSkills,
}
Base = Literal["diayn", "dads", "metra", "lsd", "domino"]
SKILLS_CSV = "skills.csv"  # every evaluated episode of a run (`SkillLog`)


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


def skill_columns(names: Sequence[str]) -> list[str]:
    """skills.csv's descriptor columns, named as repertoire.csv's: `descriptor_<name>`, each name
    made an identifier ("final x" -> `descriptor_final_x`; `qdrl.qd.repertoires.descriptor_columns`)."""
    return [f"descriptor_{suffix}" for suffix in descriptor_columns(names, len(names))]


@dataclasses.dataclass
class SkillLog:
    """What a skill run keeps of its evaluations on the host: a row of skills.csv per episode
    of every log point of this session, and the trajectories of the log points its skills
    plot shows (at most `len(shown)` of them: bounded memory).

    skills.csv columns: `log_point`, `env_steps`, `episode` (episode i plays skill
    i % K), `skill`, `return`, `length`, the descriptor columns (`skill_columns`)
    and `cell` (the passive-archive cell of the episode's descriptor); for feature-space
    skills (episodes with `targets` and `distances`), the skill's target
    (`target_<name>`) and the episode's `distance` to it.
    """

    descriptor_names: Sequence[str]
    num_skills: int
    shown: frozenset[int]  # the log points whose trajectories are kept
    rows: list[Row] = dataclasses.field(default_factory=list)
    # log point -> (env steps, trajectories (T, B, D), mask (T, B))
    trajectories: dict[int, tuple[int, np.ndarray, np.ndarray]] = dataclasses.field(default_factory=dict)

    def add(self, log_point: int, env_steps: int, episodes: Mapping[str, Any], trajectories: Any, mask: Any) -> None:
        """One evaluation's episodes (host arrays `returns`, `lengths`, `descriptors`, `cells`)."""
        columns = skill_columns(self.descriptor_names)
        returns, lengths = np.asarray(episodes["returns"]), np.asarray(episodes["lengths"])
        descriptors, cells = np.asarray(episodes["descriptors"]), np.asarray(episodes["cells"])
        for i in range(len(returns)):
            row: Row = {
                "log_point": log_point, "env_steps": env_steps, "episode": i, "skill": i % self.num_skills,
                # float32 values as exact doubles: the csv reads back bit for bit
                "return": float(returns[i]), "length": int(lengths[i]),
            }
            row.update({c: float(v) for c, v in zip(columns, descriptors[i], strict=True)})
            row["cell"] = int(cells[i])
            if "targets" in episodes:  # feature-space skills: the target and its distance
                targets = np.asarray(episodes["targets"])[i]
                row.update({f"target_{c[len('descriptor_'):]}": float(v) for c, v in zip(columns, targets, strict=True)})
                row["distance"] = float(np.asarray(episodes["distances"])[i])
            self.rows.append(row)
        if log_point in self.shown:
            self.trajectories[log_point] = (env_steps, np.asarray(trajectories), np.asarray(mask))

    def write(self, path: Path, first_log_point: int) -> None:
        """Writes skills.csv: its rows of log points before `first_log_point` (the earlier
        sessions of a resumed run), then this session's, as metrics.csv keeps its rows."""
        header: list[str] = list(self.rows[0]) if self.rows else []
        kept: list[dict[str, str]] = []
        if path.is_file():
            with path.open(newline="") as f:
                reader = csv.DictReader(f)
                header = header or list(reader.fieldnames or [])
                kept = [r for r in reader if int(r["log_point"]) < first_log_point]
        if not header:
            return
        tmp = path.with_suffix(".tmp")
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=header)
            writer.writeheader()
            writer.writerows(kept)
            writer.writerows(self.rows)
        tmp.replace(path)


def parse_skills(
    spec: Mapping[str, Any], exp: ExperimentConfig, base: Base, smerl: bool, reverse: bool = False
) -> Sections:
    """The checked sections of a DIAYN / DADS / METRA / LSD (`base`) spec, SMERL on it if `smerl`
    (Reverse SMERL if `reverse`).

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
    if base == "lsd":  # METRA's code with spectral normalisation and no dual variable
        skills_data.setdefault("lsd", True)
    skills = build(_CONFIGS[base], skills_data, "skills")
    if base in ("metra", "lsd") and getattr(skills, "lsd", False) != (base == "lsd"):
        raise ConfigError(
            f"skills.lsd: expected {str(base == 'lsd').lower()} for {base} (LSD is experiment.algorithm = "
            f"'lsd'), got {str(base != 'lsd').lower()}"
        )
    archive = check_keys(ArchiveConfig, spec.get("archive", {}), "archive")
    sections: Sections = {"env": env, "agent": agent, "train": train, "skills": skills, "archive": archive}
    if base == "domino":
        sections["domino"] = build(DOMiNOConfig, spec.get("domino", {}), "domino")
    if smerl:
        smerl_data = dict(check_table(spec.get("smerl", {}), "smerl"))
        if reverse:
            smerl_data.setdefault("reverse", True)
        sections["smerl"] = build(SMERLConfig, smerl_data, "smerl")
        if sections["smerl"].reverse != reverse:
            raise ConfigError(
                f"smerl.reverse: expected {str(reverse).lower()} (Reverse SMERL is experiment.algorithm = "
                f"'smerl_reverse'), got {str(not reverse).lower()}"
            )
    k = skills.num_skills
    if skill_space(skills) is None and train.num_eval_envs % k:
        raise ConfigError(
            f"train.num_eval_envs: expected a multiple of skills.num_skills={k} (every "
            f"skill is evaluated the same number of times), got {train.num_eval_envs}"
        )
    return sections


def _build(sections: Sections, ctx: BuildContext) -> Algorithm:
    env_cfg: SkillEnvConfig = sections["env"]
    train_cfg: TrainConfig = sections["train"]
    skills_cfg: SkillConfig = sections["skills"]
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
        sd = make_skill_discovery(
            base_env, sections["agent"], skills_cfg, sections.get("smerl"), train_cfg.num_eval_envs,
            sections.get("domino"),
        )
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith("skills.") else f"agent: {msg}") from e
    trainer = make_trainer(sd.env, sd.agent, train_cfg, sd.storage, placement=ctx.placement)
    k, num_eval = sd.num_skills, train_cfg.num_eval_envs
    key0 = eval_key(ctx.seed)
    labels = tuple(task.descriptor_names)
    title = f"{ctx.algorithm} on {env_cfg.task}"
    metric = (_CONTINUOUS_METRIC if skill_space(skills_cfg) is not None else _MODEL_METRIC).get(type(skills_cfg))
    positions = archive_cfg.descriptor == "final"  # the state descriptor is a position (x-y)
    # Feature tasks (QDAC's): the archive read as a library of skills, as for every method there.
    space = feature_space(env_cfg.task)

    def evaluate(agent_state: AgentState, key: PRNGKey) -> dict[str, Array]:
        return evaluate_skills(sd, agent_state, key, num_eval, archive_cfg.descriptor, archive_cfg.low, archive_cfg.high)

    def init(key: jax.Array) -> RLState:
        return RLState(trainer.init(key), archive_cfg.empty(ctx.seed))

    def chunk(state: RLState) -> tuple[RLState, dict[str, Any]]:
        """Train for one log interval, evaluate every skill, and offer the episodes to the archive."""
        train, metrics = trainer.run_chunk(state.train)
        ev = evaluate(train.agent, jax.random.fold_in(key0, train.env_steps))
        descriptors, returns = ev.pop("descriptors"), ev.pop("returns")
        archive, qd = feed(state.archive, descriptors, returns, archive_cfg.qd_offset, archive_cfg.fitness_range)
        out: dict[str, Any] = dict(metrics)
        out.update(ev)
        out.update(qd)
        if positions:  # METRA's state coverage: the 1x1 cells the skills' paths visit
            out["cells_visited"] = cells_visited(ev["trajectories"], ev["mask"])
        if space is not None:
            out.update(archive_skill_metrics(archive.descriptors, archive.fitnesses, space))
        # Each episode, for skills.csv (log_row takes them out of the metrics row).
        out["episodes"] = {
            "returns": returns, "lengths": out.pop("lengths"), "descriptors": descriptors,
            "cells": archive.cell_index(descriptors),
        }
        return RLState(train, archive), out

    n = train_cfg.num_chunks
    skill_log = SkillLog(labels, k, frozenset({0, (n - 1) // 2, n - 1}))

    def log_row(state: RLState, metrics: Any) -> Row:
        metrics = dict(metrics)
        env_steps = int(state.train.env_steps)
        kept = jax.device_get({name: metrics.pop(name) for name in ("episodes", "trajectories", "mask")})
        # Every chunk runs `eval_every` env steps: the log point follows from the count (also on resume).
        log_point = env_steps // train_cfg.eval_every - 1
        skill_log.add(log_point, env_steps, kept["episodes"], kept["trajectories"], kept["mask"])
        counters = {"env_steps": env_steps, "grad_steps": int(state.train.grad_steps)}
        return rl_log_row(counters, metrics)

    def write_skills(out_dir: Path) -> None:
        """skills.csv after each log point: the rows of this session's log points, after those
        of the earlier sessions of a resumed run (as metrics.csv keeps them)."""
        if skill_log.rows:
            skill_log.write(out_dir / SKILLS_CSV, int(skill_log.rows[0]["log_point"]))

    def finish(state: RLState, rows: list[Row], out_dir: Path) -> dict[str, Any]:
        del rows
        write_archive(state.archive, out_dir)
        return {"grad_steps": int(np.asarray(state.train.grad_steps))}

    def policy(agent_state: AgentState, skill: int | None) -> Callable[[Array], Array]:
        if skill is None:
            raise ValueError(f"skill: expected an int in [0, {k}), got None")
        return skill_policy(sd, agent_state, skill)

    def evaluation(state: RLState, record: Any) -> tuple[Episodes, Array]:
        """The episodes of `evaluate` in the chunk that reached `state` (its key, width and descriptors)."""
        run_key = jax.random.split(jax.random.fold_in(key0, state.train.env_steps))[0]
        ep = skill_episodes(sd, state.train.agent, run_key, num_eval, record)
        return ep, episode_descriptors(ep, archive_cfg.descriptor, archive_cfg.low, archive_cfg.high)

    def plot(state: RLState, rows: list[Row], out_dir: Path) -> None:
        plot_archive(state.archive, archive_cfg, labels, out_dir, title, rows)
        shown = dict(skill_log.trajectories)
        last = int(state.train.env_steps) // train_cfg.eval_every - 1
        if last not in shown:  # a resumed run with no chunk left: its last evaluation once more
            ep, _ = jax.device_get(jax.jit(evaluation, static_argnums=1)(state, None))
            shown[last] = (int(state.train.env_steps), np.asarray(ep.transitions.next_desc), np.asarray(ep.mask))
        panels = {f"{steps:,} env steps": traj for _, (steps, traj, _) in sorted(shown.items())}
        masks = {f"{steps:,} env steps": mask for _, (steps, _, mask) in sorted(shown.items())}
        plotting.plot_skills(
            panels,
            np.arange(num_eval) % k,
            masks,
            out_dir / "plots" / "skills.png",
            archive_cfg.low,
            archive_cfg.high,
            archive=jax.device_get(state.archive),
            title=f"{title}: skills and passive archive",
            trajectories_are_positions=archive_cfg.descriptor == "final",
            walls=plotting.env_walls(base_env),
            labels=labels,
            num_skills=k,
        )

    return Algorithm(
        curves=RL_CURVES,
        task=env_cfg.task,
        sections={**sections, "archive": archive_cfg},
        num_chunks=train_cfg.num_chunks,
        progress=Progress(
            ("eval_return", "coverage", *([f"eval_final_{metric}"] if metric else [])), "env_steps",
            train_cfg.num_chunks * train_cfg.eval_every,
        ),
        init=init,
        chunk=chunk,
        log_row=log_row,
        finish=finish,
        plot=plot,
        placement=ctx.placement,
        state_axes=RLState(STATE_AXES, None),  # type: ignore[arg-type]
        descriptor_space=DescriptorSpace(archive_cfg.low, archive_cfg.high, labels),
        agent=AgentParts(base_env, k, lambda state: state.train.agent, policy, evaluation),
        on_log_point=write_skills,
    )


_VARIANTS: tuple[tuple[Base, bool, bool, str], ...] = (
    ("diayn", False, False, "DIAYN (Eysenbach et al. 2019): skills that a discriminator tells apart"),
    ("dads", False, False, "DADS (Sharma et al. 2020): skills with predictable dynamics"),
    ("diayn", True, False, "SMERL (Kumar et al. 2020) on DIAYN's diversity reward"),
    ("dads", True, False, "SMERL (Kumar et al. 2020) on DADS's diversity reward"),
    ("metra", False, False, "METRA (Park et al. 2024): skills that move far in a temporal-distance latent space"),
    ("lsd", False, False, "LSD (Park et al. 2022): METRA's reward with a spectrally normalised, 1-Lipschitz phi"),
    ("diayn", True, True, "Reverse SMERL (the QDAC paper's baseline): DIAYN's reward always, the task's below target"),
    ("domino", False, False, "DOMiNO (Zahavy et al. 2023): diverse skills held near the optimal one's return"),
)
DIAYN, DADS, SMERL_DIAYN, SMERL_DADS, METRA, LSD, SMERL_REVERSE, DOMINO = (
    Recipe(
        functools.partial(parse_skills, base=base, smerl=smerl, reverse=reverse), _build, "train.total_env_steps",
        description,
    )
    for base, smerl, reverse, description in _VARIANTS
)
