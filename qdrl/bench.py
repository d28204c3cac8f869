"""`qdrl bench`: throughput figures as JSON (env steps/s, gradient steps/s, compile time).

Each benchmark compiles its chunk function ahead of time (timed apart), runs one
warm-up chunk, then times `repeats` chunks. Figures depend on the machine: the
JSON records the device and the versions used.
"""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

BENCHES: dict[str, Callable[[bool], list[dict[str, Any]]]] = {}


def _register(name: str) -> Callable[[Callable[[bool], list[dict[str, Any]]]], Any]:
    def deco(fn: Callable[[bool], list[dict[str, Any]]]) -> Any:
        BENCHES[name] = fn
        return fn

    return deco


def machine() -> dict[str, Any]:
    """Where the figures were measured."""
    import brax

    return {
        "device": str(jax.devices()[0].device_kind),
        "platform": jax.devices()[0].platform,
        "cpu_count": __import__("os").cpu_count(),
        "machine": platform.machine(),
        "jax": jax.__version__,
        "brax": brax.__version__,
    }


def time_trainer(
    algorithm: str,
    env_name: str,
    *,
    backend: str = "spring",
    episode_length: int = 1000,
    num_envs: int = 16,
    grad_steps_per_iter: int = 16,
    batch_size: int = 256,
    hidden: tuple[int, ...] = (256, 256),
    iters_per_chunk: int = 250,
    repeats: int = 2,
    seed: int = 0,
) -> dict[str, Any]:
    """Compile and time the off-policy loop of `algorithm` on `env_name`."""
    from qdrl import envs
    from qdrl.agents import AGENTS
    from qdrl.off_policy import TrainConfig, make_trainer

    env = envs.make(env_name, backend=backend, episode_length=episode_length)
    config_cls, make_agent = AGENTS[algorithm]
    agent = make_agent(config_cls(hidden=hidden), env.observation_size, env.action_size)
    chunk_steps = iters_per_chunk * num_envs
    cfg = TrainConfig(
        total_env_steps=chunk_steps * (repeats + 1),
        num_envs=num_envs,
        batch_size=batch_size,
        buffer_size=max(chunk_steps * (repeats + 1), batch_size),
        learning_starts=batch_size,
        grad_steps_per_iter=grad_steps_per_iter,
        eval_every=chunk_steps,
    )
    trainer = make_trainer(env, agent, cfg)
    state = trainer.init(jax.random.PRNGKey(seed))
    t0 = time.perf_counter()
    chunk = jax.jit(trainer.run_chunk, donate_argnums=0).lower(state).compile()
    compile_s = time.perf_counter() - t0
    state, _ = chunk(state)  # warm-up chunk (fills the buffer past learning_starts)
    jax.block_until_ready(state)
    steps0, grads0 = int(state.env_steps), int(state.grad_steps)
    t0 = time.perf_counter()
    for _ in range(repeats):
        state, _ = chunk(state)
    jax.block_until_ready(state)
    elapsed = time.perf_counter() - t0
    return {
        "bench": f"{algorithm}/{env_name}",
        "algorithm": algorithm,
        "env": env_name,
        "backend": backend,
        "num_envs": num_envs,
        "grad_steps_per_iter": grad_steps_per_iter,
        "batch_size": batch_size,
        "hidden": list(hidden),
        "compile_s": round(compile_s, 2),
        "env_steps": int(state.env_steps) - steps0,
        "wall_s": round(elapsed, 3),
        "env_steps_per_s": round((int(state.env_steps) - steps0) / elapsed, 1),
        "grad_steps_per_s": round((int(state.grad_steps) - grads0) / elapsed, 1),
    }


@_register("rl")
def bench_rl(quick: bool) -> list[dict[str, Any]]:
    """SAC and TD3: halfcheetah (spring), 16 envs, 16 updates of batch 256 per iteration."""
    if quick:
        return [
            time_trainer(a, "point", episode_length=100, hidden=(32, 32), batch_size=64,
                         iters_per_chunk=50, repeats=1)
            for a in ("sac", "td3")
        ]
    return [time_trainer(a, "halfcheetah") for a in ("sac", "td3")]


def run_bench(name: str, quick: bool = False, out: str | Path | None = None) -> dict[str, Any]:
    """Run benchmark `name`; returns (and optionally writes) its JSON record."""
    if name not in BENCHES:
        raise ValueError(f"unknown benchmark {name!r}; expected one of {sorted(BENCHES)}")
    record = {"benchmark": name, "quick": quick, "machine": machine(), "results": BENCHES[name](quick)}
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(record, indent=2) + "\n")
    return record
