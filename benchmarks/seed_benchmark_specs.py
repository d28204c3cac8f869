"""Writes the skill-discovery benchmark's specs: agents/seed_benchmark/<algorithm>_<task>[_cpu].toml.

The settings are those of Chalumeau, Boige et al. 2023, "Neuroevolution is a competitive
alternative to reinforcement learning for skill discovery" (ICLR; its configs in
instadeepai/qd-skill-discovery-benchmark, qdbenchmark/training/config/<algorithm>/<task>.yaml),
one table per algorithm and one row per task below; the `_cpu` variants keep the tasks,
episode lengths, rewards, SMERL targets and archives (so their numbers read on the study's
scale) and shrink only what sets the cost per iteration on a 2-core CPU (batches, networks'
update counts, log intervals, time limit).

    python benchmarks/seed_benchmark_specs.py           # rewrite the specs
    python benchmarks/seed_benchmark_specs.py --check   # exit 1 if a spec differs from the table

tests/test_seed_benchmark.py checks that the packaged specs are the table's.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

OUT = Path(__file__).resolve().parents[1] / "agents" / "seed_benchmark"
STUDY = "Chalumeau, Boige et al. 2023 (instadeepai/qd-skill-discovery-benchmark)"

# task -> the study's row: episode length, SAC reward scaling, diversity reward scale, SMERL
# target and margin, fitness range (colour scale, range QD score), and whether the skill model
# reads the full observation (the `_uni` tasks) or the x-y position.
TASKS: dict[str, dict[str, Any]] = {
    "ant_uni": {"episode": 250, "reward_scale": 10.0, "diversity": 2.0, "smerl": (1700.0, 170.0), "range": (-1000.0, 2500.0), "full_state": True},
    "halfcheetah_uni": {"episode": 250, "reward_scale": 5.0, "diversity": 2.0, "smerl": (2050.0, 205.0), "range": (-1000.0, 2200.0), "full_state": True},
    "walker2d_uni": {"episode": 250, "reward_scale": 10.0, "diversity": 2.0, "smerl": (1180.0, 118.0), "range": (-200.0, 1500.0), "full_state": True},
    "ant_omni": {"episode": 250, "reward_scale": 1.0, "diversity": 4.0, "smerl": (249.0, 24.9), "range": (-500.0, 250.0), "full_state": False},
    "ant_trap": {"episode": 250, "reward_scale": 1.0, "diversity": 2.0, "smerl": (450.0, 45.0), "range": (-200.0, 2000.0), "full_state": False},
    "ant_maze": {"episode": 500, "reward_scale": 1.0, "diversity": 3.0, "smerl": (-6820.0, 682.0), "range": (-20000.0, 0.0), "full_state": False},
    "point_maze": {"episode": 250, "reward_scale": 1.0, "diversity": 2.0, "smerl": (-66.0, 6.6), "range": (-1000.0, 0.0), "full_state": False},
}
QD = ("map_elites", "pga_me", "aurora", "pga_aurora")
# The QD methods built on PGA-ME's emitters (their batch is its environment batch).
PG = ("pga_me", "pga_aurora")
# name -> (qdrl algorithm, skill model, SMERL, task reward added)
SKILLS: dict[str, tuple[str, str, bool, bool]] = {
    "diayn": ("diayn", "diayn", False, False),
    "dads": ("dads", "dads", False, False),
    "smerl_diayn": ("smerl_diayn", "diayn", True, False),
    "smerl_dads": ("smerl_dads", "dads", True, False),
    "diayn_reward": ("diayn", "diayn", False, True),
    "dads_reward": ("dads", "dads", False, True),
}
ALGORITHMS: tuple[str, ...] = (*QD, *SKILLS)
DESCRIPTION = {
    "map_elites": "MAP-Elites", "pga_me": "PGA-ME", "aurora": "AURORA", "pga_aurora": "PGA-AURORA",
    "diayn": "DIAYN", "dads": "DADS",
    "smerl_diayn": "DIAYN-SMERL", "smerl_dads": "DADS-SMERL", "diayn_reward": "DIAYN+reward",
    "dads_reward": "DADS+reward",
}
STUDY_CONFIG = {  # the study's config folder of each algorithm (pure DIAYN/DADS: +reward's, reward off)
    "map_elites": "map_elites", "pga_me": "pga_me", "aurora": "aurora", "pga_aurora": "pga_aurora",
    "diayn": "diayn_reward", "dads": "dads_reward",
    "smerl_diayn": "diayn_smerl", "smerl_dads": "dads_smerl", "diayn_reward": "diayn_reward",
    "dads_reward": "dads_reward",
}
STUDY_TASK = {"ant_trap": "anttrap", "ant_maze": "antmaze", "point_maze": "pointmaze"}


def time_limit(algorithm: str, task: str) -> float | None:
    """The study's wall-clock budget (seconds): 8400 s; 5400 s for DADS on every task but
    halfcheetah_uni and for DIAYN on the point maze; none for the QD methods on the point
    maze (fixed iterations there)."""
    if task == "point_maze":
        return None if algorithm in QD else 5400.0
    if algorithm in SKILLS and SKILLS[algorithm][1] == "dads" and task != "halfcheetah_uni":
        return 5400.0
    return 8400.0


def _archive(task: str, cpu: bool) -> dict[str, Any]:
    del cpu  # the study's archive in both
    return {"kind": "cvt", "num_centroids": 1024, "cvt_samples": 50_000, "fitness_range": list(TASKS[task]["range"])}


def _task_table(task: str) -> dict[str, Any]:
    out: dict[str, Any] = {"name": task, "episode_length": TASKS[task]["episode"]}
    if task != "point_maze":
        out["backend"] = "spring"
    out.update({"policy_hidden": [256, 256], "policy_activation": "relu"})
    return out


def qd_spec(algorithm: str, task: str, cpu: bool) -> dict[str, Any]:
    """The spec of MAP-Elites, PGA-ME, AURORA or PGA-AURORA on `task` (the study's settings; `cpu`:
    2-core sized)."""
    pg = algorithm in PG
    batch = (32 if pg else 100) if cpu else (100 if pg else 1000)
    iterations = (1000 if pg else 100) if task == "point_maze" else 100_000
    spec: dict[str, Any] = {
        "experiment": {"algorithm": algorithm, "name": algorithm, "seed": 0},
        "task": _task_table(task),
        "repertoire": {"kind": "cvt", "num_centroids": 1024, "cvt_samples": 50_000},
        "emitter": {"kind": "isoline", "batch_size": batch, "iso_sigma": 0.005, "line_sigma": 0.05},
    }
    if algorithm in ("aurora", "pga_aurora"):
        # The study's AURORA: an LSTM autoencoder of 5 latent units, 25 observations every 10 steps,
        # l from 0.2, AE batches of 128; on the `_uni` tasks it reads the observation's first 25
        # entries (its "no_sd"), elsewhere the x-y position (prior descriptor dimension 2, "only_sd").
        observation = "observation" if TASKS[task]["full_state"] else "state_descriptor"
        spec["search_archive"] = {
            "kind": "aurora", "encoder": "lstm", "latent_size": 5, "observation": observation,
            "max_features": 25,
            "sampling_period": 10, "num_observations": 25, "l_value": 0.2, "target_size": 1024,
            "batch_size": 128,
        }
    if pg:
        spec["pg"] = {
            "proportion_mutation_ga": 0.5,
            "num_critic_training_steps": 50 if cpu else 300,
            "num_pg_training_steps": 20 if cpu else 100,
            "policy_learning_rate": 1e-3, "critic_learning_rate": 3e-4, "greedy_learning_rate": 3e-4,
            "training_batch_size": 256, "replay_buffer_size": 200_000 if cpu else 1_000_000,
            "discount": 0.99, "tau": 0.005, "policy_noise": 0.2, "noise_clip": 0.5, "policy_delay": 2,
            "critic_hidden": [256, 256],
        }
    log_every = 10 if cpu or iterations % 40 else 40
    spec["qd"] = {"num_iterations": iterations, "log_every": log_every, "init_batch_size": batch}
    return spec


def skill_spec(algorithm: str, task: str, cpu: bool) -> dict[str, Any]:
    """The spec of a skill-discovery variant on `task` (the study's settings; `cpu`: 2-core sized)."""
    qdrl_algorithm, model, smerl, reward = SKILLS[algorithm]
    row = TASKS[task]
    envs = 16 if cpu else 200
    spec: dict[str, Any] = {
        "experiment": {"algorithm": qdrl_algorithm, "name": algorithm, "seed": 0},
        "env": {"task": task, "backend": "spring", "episode_length": row["episode"]},
        "agent": {
            "actor_lr": 3e-4, "critic_lr": 3e-4, "alpha_lr": 3e-4, "discount": 0.99, "tau": 0.005,
            "hidden": [256, 256], "learn_alpha": False, "init_alpha": 0.1, "reward_scale": row["reward_scale"],
        },
        "train": {
            "total_env_steps": 20_000_000,
            "num_envs": envs,
            "batch_size": 256,
            "buffer_size": 200_000 if cpu else 1_000_000,
            "learning_starts": 0,
            "grad_steps_per_iter": envs,  # one gradient step per environment step
            "eval_every": 20_000 if cpu else 100_000,
            "num_eval_envs": 20 if cpu else 200,
        },
        "skills": {
            "num_skills": 5,
            "model_input": "full" if row["full_state"] else "descriptor",
            "hidden": [256, 256],
            "learning_rate": 3e-4,
            "diversity_scale": row["diversity"],
            "extrinsic_scale": 1.0 if (smerl or reward) else 0.0,
        },
    }
    if model == "dads":
        spec["skills"].update({"model_update_every": 1, "normalize_targets": True, "num_components": 1})
    if smerl:
        target, margin = row["smerl"]
        spec["smerl"] = {"target": target, "margin": margin}
    return spec


def spec(algorithm: str, task: str, cpu: bool) -> dict[str, Any]:
    """The spec of `algorithm` on `task`, with the study's time limit (`cpu`: 10 minutes)."""
    out = qd_spec(algorithm, task, cpu) if algorithm in QD else skill_spec(algorithm, task, cpu)
    limit = 600.0 if cpu else time_limit(algorithm, task)
    if limit is not None:
        out["experiment"]["time_limit_s"] = limit
    out["archive"] = _archive(task, cpu)
    if algorithm in QD:  # a QD run's repertoire is its own archive: no [archive] section
        out["repertoire"]["fitness_range"] = out.pop("archive")["fitness_range"]
    out["log"] = {"checkpoint_every": 5}
    return out


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, int):
        return f"{v:_}" if abs(v) >= 10_000 else str(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"no TOML for {v!r}")


def header(algorithm: str, task: str, cpu: bool) -> list[str]:
    study = f"{STUDY_CONFIG[algorithm]}/{STUDY_TASK.get(task, task)}.yaml"
    lines = [
        f"# {DESCRIPTION[algorithm]} on {task}, the skill-discovery benchmark's settings ({STUDY}; "
        f"its config {study}).",
    ]
    if algorithm in ("diayn", "dads"):
        lines.append("# The study runs it with SMERL or the task reward; here alone (no task reward), otherwise as its +reward config.")
    if cpu:
        lines.append(
            "# Sized for a 2-core CPU (a 10-minute budget): the study's task, episodes, rewards, SMERL target and "
            "archive, smaller batches and update counts (agents/seed_benchmark/"
            f"{algorithm}_{task}.toml is the full setting)."
        )
    lines.append("# Written by benchmarks/seed_benchmark_specs.py from its table; edit the table, not this file.")
    return lines


def render(algorithm: str, task: str, cpu: bool) -> str:
    """The TOML text of one spec."""
    lines = header(algorithm, task, cpu)
    for section, table in spec(algorithm, task, cpu).items():
        lines += ["", f"[{section}]"]
        lines += [f"{key} = {_value(value)}" for key, value in table.items()]
    return "\n".join(lines) + "\n"


def files() -> dict[Path, str]:
    """Every spec of the benchmark: path -> text."""
    return {
        OUT / f"{alg}_{task}{'_cpu' if cpu else ''}.toml": render(alg, task, cpu)
        for alg in ALGORITHMS for task in TASKS for cpu in (False, True)
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a packaged spec differs from the table")
    args = parser.parse_args(argv)
    wanted = files()
    if args.check:
        stale = [p for p, text in wanted.items() if not p.is_file() or p.read_text() != text]
        extra = sorted(set(OUT.glob("*.toml")) - set(wanted))
        for p in [*stale, *extra]:
            print(f"stale: {p}", file=sys.stderr)
        return 1 if stale or extra else 0
    OUT.mkdir(parents=True, exist_ok=True)
    for p in set(OUT.glob("*.toml")) - set(wanted):
        p.unlink()
    for p, text in wanted.items():
        p.write_text(text)
    print(f"wrote {len(wanted)} specs into {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
