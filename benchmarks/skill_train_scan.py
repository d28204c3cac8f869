"""qdrl's skill-discovery training alone, measured as QDax's side of Table 2 is measured.

    python benchmarks/skill_train_scan.py --algorithm diayn --task ant_omni --iterations 50

Builds the trainer of `agents/seed_benchmark/<algorithm>_<task>.toml` (the study's settings:
200 environments, 200 SAC updates of batch 256 per step of them, 256x256 networks, buffer 1e6)
exactly as `qdrl run` builds it, and times its off-policy loop (`Trainer.run_chunk`: act,
store, update) as ONE `lax.scan` of `--iterations` steps of the 200 environments, compiled
ahead of time; compile and run are timed apart, after one warm-up chunk that fills the buffer
past a batch. No evaluation and no passive archive inside the timed scan: the counterpart of
`benchmarks/qdax_skills.py`. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import jax

from qdrl.agents.skill_discovery import make_skill_discovery
from qdrl.algorithms.base import ExperimentConfig
from qdrl.algorithms.skills import parse_skills, skill_task
from qdrl.compiling import compile_timed
from qdrl.off_policy import make_trainer
from qdrl.specs import load_spec, resolve

ALGORITHMS = {"diayn": ("diayn", False), "dads": ("dads", False),
              "smerl_diayn": ("diayn", True), "smerl_dads": ("dads", True)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algorithm", choices=sorted(ALGORITHMS), required=True)
    p.add_argument("--task", required=True)
    p.add_argument("--iterations", type=int, default=50, help="steps of the environments timed")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    base, smerl = ALGORITHMS[args.algorithm]
    spec = load_spec(resolve(f"seed_benchmark/{args.algorithm}_{args.task}"))
    sections = parse_skills(spec, ExperimentConfig(algorithm=args.algorithm), base, smerl)
    env_cfg, train = sections["env"], sections["train"]
    # One chunk is the timed scan; learning_starts as in the spec (the study's 0).
    train = dataclasses.replace(train, eval_every=train.num_envs * args.iterations)
    task = skill_task(env_cfg.task, env_cfg.episode_length, env_cfg.backend)
    sd = make_skill_discovery(task.env, sections["agent"], sections["skills"], sections.get("smerl"))
    trainer = make_trainer(sd.env, sd.agent, train, sd.storage)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(args.seed))
    compiled = compile_timed(trainer.run_chunk, state, donate_argnums=0)
    state, _ = compiled.fn(state)  # warm-up: the buffer holds a batch and more from here on
    jax.block_until_ready(state)
    steps0 = int(state.env_steps)
    t0 = time.perf_counter()
    state, metrics = compiled.fn(state)
    jax.block_until_ready((state, metrics))
    run_s = time.perf_counter() - t0
    steps = int(state.env_steps) - steps0
    print(json.dumps({
        "library": "qdrl", "measure": "training scan", "algorithm": args.algorithm, "task": args.task,
        "seed": args.seed, "envs": train.num_envs, "grad_steps_per_iter": train.grad_steps_per_iter,
        "iterations": args.iterations, "env_steps": steps, "compile_s": round(compiled.seconds, 2),
        "run_s": round(run_s, 3), "env_steps_per_s": round(steps / run_s, 2),
        "env_steps_per_hour": round(steps / run_s * 3600.0, 1),
    }))


if __name__ == "__main__":
    main()
