"""`qdrl bench skill_methods`: the throughput of today's skill methods next to SAC's.

QDAC, UVFA, DOMiNO and continuous SMERL on walker2d feet contact (QDAC's task), METRA, LSD and
DIAYN on ant_omni, each beside SAC on the same environment, with the same networks (256x256),
batch (256), environments (16) and updates (16 per iteration), as `qdrl bench skills` times
DIAYN and DADS. `relative_to_sac` is each one's environment steps per second over SAC's on
that environment. QDAC's update trains on its batch and as many relabelled transitions (its
`relabel_batches`), as its paper does: it is timed as configured.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qdrl.agents.diayn import DIAYNConfig
from qdrl.agents.domino import DOMiNOConfig
from qdrl.agents.metra import METRAConfig
from qdrl.agents.qdac import QDACConfig, make_qdac
from qdrl.agents.sac import SACConfig, make_sac
from qdrl.agents.skill_discovery import DiscreteSkills, SkillConfig, make_skill_discovery
from qdrl.agents.smerl import SMERLConfig
from qdrl.agents.uvfa import make_uvfa
from qdrl.envs.skills import ContinuousSkillEnv
from qdrl.off_policy import TrainConfig, make_trainer
from qdrl.tasks.brax_features import FEATURE_TASKS, feature_space
from qdrl.tasks.brax_qd import ant_omni

__all__ = ["bench_skill_methods", "method_trainer_builder"]

HIDDEN = (256, 256)
FEATURE_METHODS = ("sac", "qdac", "uvfa", "domino", "smerl_diayn")
POSITION_METHODS = ("sac", "metra", "lsd", "diayn")


def method_trainer_builder(algorithm: str, task: str) -> Callable[[Any, TrainConfig], Any]:
    """`(env, train_config) -> Trainer` of `algorithm` with its defaults at 256x256 on `env`, the
    environment of `task` (a feature task for QDAC and UVFA)."""
    sac = SACConfig(hidden=HIDDEN)

    def build(env: Any, config: TrainConfig) -> Any:
        if algorithm == "sac":
            return make_trainer(env, make_sac(sac, env.observation_size, env.action_size), config)
        if algorithm in ("qdac", "uvfa"):
            space = feature_space(task)
            if space is None:
                raise ValueError(f"{algorithm}: expected a feature task, got {task!r}")
            skill_env = ContinuousSkillEnv(env, space)
            obs, act = skill_env.observation_size, skill_env.action_size
            agent = make_qdac(sac, QDACConfig(), space, obs, act) if algorithm == "qdac" else make_uvfa(
                make_sac(sac, obs, act), space
            )
            return make_trainer(skill_env, agent, config)
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
        return make_trainer(sd.env, sd.agent, config, sd.storage)

    return build


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
        for a in methods:
            records.append(
                time_trainer(
                    a, task, env=env, seed=seed, build=method_trainer_builder(a, task),
                    iters_per_chunk=20 if quick else 200, repeats=1 if quick else 2,
                )
            )
    sac = {r["env"]: r["env_steps_per_s"] for r in records if r["algorithm"] == "sac"}
    for r in records:
        r["relative_to_sac"] = round(r["env_steps_per_s"] / sac[r["env"]], 3)
    return records
