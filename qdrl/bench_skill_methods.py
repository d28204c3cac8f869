"""`qdrl bench skill_methods`: the throughput of today's skill methods next to SAC's.

QDAC, UVFA, DOMiNO and continuous SMERL on walker2d feet contact (QDAC's task), METRA, LSD and
DIAYN on ant_omni, each beside SAC on the same environment, with the same networks (256x256),
batch (256), environments (16) and updates (16 per iteration), as `qdrl bench skills` times
DIAYN and DADS. `relative_to_sac` is each one's environment steps per second over SAC's on
that environment. QDAC's update trains on its batch and as many relabelled transitions (its
`relabel_batches`), as its paper does: it is timed as configured.

One update per environment step makes the timing a measure of each update's arithmetic, which on
CPU is all that counts: QDAC's update evaluates two twin critics, the policy and lambda's
network on twice SAC's batch. The runs themselves update less often (QDAC's paper once per 256
environment steps, the `_cpu` specs once per 4 for QDAC and once per 8 for METRA), so the
benchmark also times each method beside SAC at its `_cpu` spec's environments and updates
(`SPEC_RATIOS`; rows `<method>@spec/<task>`, their SAC `sac@<method>-spec/<task>`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from qdrl.agents.base import Agent
from qdrl.agents.diayn import DIAYNConfig
from qdrl.agents.domino import DOMiNOConfig
from qdrl.agents.metra import METRAConfig
from qdrl.agents.qdac import QDACConfig, make_qdac
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.skill_discovery import DiscreteSkills, SkillConfig, make_skill_discovery
from qdrl.agents.smerl import SMERLConfig
from qdrl.agents.uvfa import make_uvfa
from qdrl.envs.skills import ContinuousSkillEnv
from qdrl.off_policy import REPLAY, Storage
from qdrl.tasks.brax_features import FEATURE_TASKS, feature_space
from qdrl.tasks.brax_qd import ant_omni

__all__ = ["bench_skill_methods", "method_parts"]

HIDDEN = (256, 256)
# (environments, updates per iteration) of the `_cpu` specs: qdac_walker2d_feet_contact_cpu,
# metra_ant_omni_cpu.
SPEC_RATIOS: dict[str, tuple[int, int]] = {"qdac": (16, 4), "metra": (32, 4)}
FEATURE_METHODS = ("sac", "qdac", "uvfa", "domino", "smerl_diayn")
POSITION_METHODS = ("sac", "metra", "lsd", "diayn")


def method_parts(algorithm: str, task: str, env: Any) -> tuple[Any, Agent, Storage]:
    """The environment `algorithm` trains on (a skill wrapper of `env`, the environment of
    `task`), its agent with its defaults at 256x256, and where its transitions go."""
    sac = SACConfig(hidden=HIDDEN)
    if algorithm == "sac":
        return env, make_sac(sac, env.observation_size, env.action_size), REPLAY
    if algorithm in ("qdac", "uvfa"):
        space = feature_space(task)
        if space is None:
            raise ValueError(f"{algorithm}: expected a feature task, got {task!r}")
        skill_env = ContinuousSkillEnv(env, space)
        obs, act = skill_env.observation_size, skill_env.action_size
        agent = make_qdac(sac, QDACConfig(), space, obs, act) if algorithm == "qdac" else make_uvfa(
            make_sac(sac, obs, act), space
        )
        return skill_env, agent, REPLAY
    skills: SkillConfig
    smerl, domino = None, None
    if algorithm == "domino":
        skills, domino = DiscreteSkills(10), DOMiNOConfig()
    elif algorithm == "smerl_diayn":
        skills, smerl = DIAYNConfig(num_skills=2, continuous=True, hidden=HIDDEN, extrinsic_scale=1.0), SMERLConfig()
    elif algorithm in ("metra", "lsd"):
        skills = METRAConfig(hidden=HIDDEN, model_input="descriptor", lsd=algorithm == "lsd")
    elif algorithm == "diayn":
        skills = DIAYNConfig(num_skills=10, hidden=HIDDEN, model_input="descriptor")
    else:
        raise ValueError(f"unknown skill method {algorithm!r}")
    sd = make_skill_discovery(env, sac, skills, smerl, domino=domino)
    return sd.env, sd.agent, sd.storage


def bench_skill_methods(
    quick: bool, seed: int = 0, config: str | None = None, *, time_trainer: Callable[..., dict[str, Any]]
) -> list[dict[str, Any]]:
    """Each method's env steps per second next to SAC's on its paper's environment (module doc);
    `config` times one method beside SAC. `time_trainer` is `qdrl.bench.time_trainer` (bench
    registers this benchmark with it)."""

    cases = [("walker2d_feet_contact", FEATURE_METHODS), ("ant_omni", POSITION_METHODS)]
    if config is not None:
        cases = [(task, ("sac", config)) for task, methods in cases if config in methods]
        if not cases:
            raise ValueError(f"unknown skill method {config!r}; expected one of {[*FEATURE_METHODS, *POSITION_METHODS]}")
    records = []
    for task, methods in cases:
        env = (FEATURE_TASKS[task](episode_length=1000) if task in FEATURE_TASKS else ant_omni(episode_length=1000)).env
        timings: list[tuple[str, str, int, int]] = [(a, a, 16, 16) for a in methods]
        for a in methods:
            if a in SPEC_RATIOS:  # SAC, then the method, at the method's spec ratio
                n, g = SPEC_RATIOS[a]
                timings += [(f"sac@{a}-spec", "sac", n, g), (f"{a}@spec", a, n, g)]
        for label, a, n, g in timings:
            iters = (20 if quick else 200) * 16 // n
            record = time_trainer(
                label, task, env=env, seed=seed, parts=functools.partial(method_parts, a, task),
                iters_per_chunk=iters, repeats=1 if quick else 2, num_envs=n, grad_steps_per_iter=g,
            )
            records.append(record)
    for r in records:
        label = r["algorithm"]
        sac_label = label if label.startswith("sac") else "sac" if "@" not in label else f"sac@{label.split('@')[0]}-spec"
        sac = next(x for x in records if x["algorithm"] == sac_label and x["env"] == r["env"])
        r["relative_to_sac"] = round(r["env_steps_per_s"] / sac["env_steps_per_s"], 3)
        # SAC's update's share of the method's arithmetic: the ratio one update per env step
        # would reach if time were arithmetic alone (the env step makes the ratio higher).
        r["sac_flops_share"] = round(sac["update_flops"] / r["update_flops"], 3)
    return records
