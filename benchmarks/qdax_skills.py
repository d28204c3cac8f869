"""QDax 0.5.0's DIAYN, DADS and their SMERL variants at the skill-discovery benchmark's settings.

The peer's side of `benchmarks/table2_vs_qdax.py` (the QDax paper's Table 2: environment steps
per hour). It runs in the virtual environment with QDax's old pins described in
`benchmarks/qdax_pga_me.py` (QDax's skill baselines use `qdax.tasks.brax.v1`, the brax v1 physics
of the study), as

    /path/to/qdax-venv/bin/python benchmarks/qdax_skills.py --algorithm smerl_diayn --task ant_omni

Settings of the study (Chalumeau, Boige et al. 2023; qdrl's agents/seed_benchmark/<algorithm>_<task>.toml):
200 environments, SAC 256x256, batch 256, buffer 1e6, one gradient step per environment step
(`grad_updates_per_step=1`: 200 updates per step of the 200 environments), lr 3e-4, tau 0.005,
discount 0.99, entropy temperature fixed at 0.1, 5 skills, episodes of 250, the skill model on the
full state on the `_uni` tasks and on the x-y position on ant_omni, the task's reward scaling,
diversity scale and SMERL target/margin. `--iterations` steps of the 200 environments (with
their updates) run as ONE `lax.scan` compiled ahead of time; compile and run are timed apart.
env steps/s = 200 x iterations / run time. Training only: no evaluation inside the timed scan.
"""

from __future__ import annotations

import argparse
import functools
import json
import time

import jax

# per task: reward scaling, diversity reward scale, SMERL target, SMERL margin (the study's configs)
TASKS = {
    "ant_uni": (10.0, 2.0, 1700.0, 170.0),
    "halfcheetah_uni": (5.0, 2.0, 2050.0, 205.0),
    "walker2d_uni": (10.0, 2.0, 1180.0, 118.0),
    "ant_omni": (1.0, 4.0, 249.0, 24.9),
}
ALGORITHMS = ("diayn", "dads", "smerl_diayn", "smerl_dads")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--algorithm", choices=ALGORITHMS, default="smerl_diayn")
    p.add_argument("--task", choices=sorted(TASKS), default="ant_omni")
    p.add_argument("--envs", type=int, default=200)
    p.add_argument("--episode-length", type=int, default=250)
    p.add_argument("--iterations", type=int, default=50)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    if args.iterations < 1 or args.envs % 5:
        p.error(f"expected --iterations >= 1 and --envs a multiple of 5 skills, got {args.iterations}, {args.envs}")

    import jax.numpy as jnp
    import qdax.tasks.brax.v1 as environments
    from qdax.core.neuroevolution.buffers.buffer import QDTransition, ReplayBuffer
    from qdax.core.neuroevolution.buffers.trajectory_buffer import TrajectoryBuffer
    from qdax.core.neuroevolution.sac_td3_utils import do_iteration_fn

    reward_scaling, diversity_scale, target, margin = TASKS[args.task]
    full_state = args.task.endswith("_uni")
    num_skills = 5
    env = environments.create(env_name=args.task, batch_size=args.envs, episode_length=args.episode_length,
                              auto_reset=True)
    key = jax.random.key(args.seed)
    key, env_key, init_key = jax.random.split(key, 3)
    env_state = jax.jit(env.reset)(rng=env_key)
    descriptor_size = env.observation_size if full_state else env.descriptor_length
    sac = dict(batch_size=256, episode_length=args.episode_length, tau=0.005, normalize_observations=False,
               learning_rate=3e-4, alpha_init=0.1, discount=0.99, reward_scaling=reward_scaling,
               critic_hidden_layer_size=(256, 256), policy_hidden_layer_size=(256, 256), fix_alpha=True,
               num_skills=num_skills, descriptor_full_state=full_state)
    smerl = dict(diversity_reward_scale=diversity_scale, smerl_target=target, smerl_margin=margin)
    agent: object
    if args.algorithm in ("diayn", "smerl_diayn"):
        if args.algorithm == "diayn":
            from qdax.baselines.diayn import DIAYN, DiaynConfig
            agent = DIAYN(config=DiaynConfig(**sac), action_size=env.action_size)
        else:
            from qdax.baselines.diayn_smerl import DIAYNSMERL, DiaynSmerlConfig
            agent = DIAYNSMERL(config=DiaynSmerlConfig(**sac, **smerl), action_size=env.action_size)
    else:
        dads = dict(omit_input_dynamics_dim=env.descriptor_length, dynamics_update_freq=1, normalize_target=True)
        if args.algorithm == "dads":
            from qdax.baselines.dads import DADS, DadsConfig
            agent = DADS(config=DadsConfig(**sac, **dads), action_size=env.action_size,
                         descriptor_size=descriptor_size)
        else:
            from qdax.baselines.dads_smerl import DADSSMERL, DadsSmerlConfig
            agent = DADSSMERL(config=DadsSmerlConfig(**sac, **dads, **smerl), action_size=env.action_size,
                              descriptor_size=descriptor_size)
    training_state = agent.init(init_key, action_size=env.action_size,  # type: ignore[attr-defined]
                                observation_size=env.observation_size, descriptor_size=descriptor_size)
    dummy = QDTransition.init_dummy(observation_dim=env.observation_size + num_skills,
                                    action_dim=env.action_size, descriptor_dim=descriptor_size)
    if args.algorithm.startswith("smerl"):
        buffer = TrajectoryBuffer.init(buffer_size=1_000_000, transition=dummy, env_batch_size=args.envs,
                                       episode_length=args.episode_length)
    else:
        buffer = ReplayBuffer.init(buffer_size=1_000_000, transition=dummy)
    skills = jnp.concatenate([jnp.eye(num_skills)] * (args.envs // num_skills), axis=0)
    play_step = functools.partial(agent.play_step_fn, skills=skills, env=env,  # type: ignore[attr-defined]
                                  deterministic=False)
    do_iteration = functools.partial(do_iteration_fn, env_batch_size=args.envs, grad_updates_per_step=1.0,
                                     play_step_fn=play_step, update_fn=agent.update)  # type: ignore[attr-defined]

    def body(carry, _):  # type: ignore[no-untyped-def]
        ts, es, rb, metrics = do_iteration(*carry)
        return (ts, es, rb), metrics

    def run(carry):  # type: ignore[no-untyped-def]
        carry, metrics = jax.lax.scan(body, carry, None, length=args.iterations)
        return carry, metrics

    # A first step (the buffer holds nothing yet: QDax samples from what it has), then the timed scan.
    carry = (training_state, env_state, buffer)
    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(carry).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    carry, metrics = compiled(carry)
    jax.block_until_ready(carry)
    run_s = time.perf_counter() - t0
    env_steps = args.envs * args.iterations
    print(json.dumps({
        "library": "qdax", "version": "0.5.0", "physics": "brax.v1 (0.10.4)",
        "algorithm": args.algorithm, "task": args.task, "seed": args.seed, "envs": args.envs,
        "episode_length": args.episode_length, "iterations": args.iterations, "env_steps": env_steps,
        "grad_steps": env_steps, "compile_s": round(compile_s, 2), "run_s": round(run_s, 3),
        "env_steps_per_s": round(env_steps / run_s, 2),
        "env_steps_per_hour": round(env_steps / run_s * 3600.0, 1),
        "mean_reward": float(jnp.mean(metrics["rewards"])) if "rewards" in metrics else None,
    }))


if __name__ == "__main__":
    main()
