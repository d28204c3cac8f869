"""`qdrl bench`: throughput figures as JSON (env steps/s, gradient steps/s, compile time).

Each benchmark compiles its chunk function ahead of time (`qdrl.compiling.compile_timed`,
timed apart), runs one warm-up chunk, then times `repeats` chunks. Figures depend on
the machine: the JSON records the device and the versions used. The HLO profiles that
the MAP-Elites benchmarks record come from `qdrl.hlo_profile`.
"""

from __future__ import annotations

import functools
import json
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import brax
import jax
import jax.numpy as jnp

from qdrl import bench_scaling, bench_skill_methods, compiling, envs
from qdrl import hlo_profile as profiler
from qdrl.agents import AGENTS, SACConfig
from qdrl.agents.base import Agent
from qdrl.agents.dads import DADSConfig
from qdrl.agents.diayn import DIAYNConfig
from qdrl.agents.skill_discovery import make_skill_discovery
from qdrl.agents.smerl import SMERLConfig
from qdrl.off_policy import REPLAY, Storage, TrainConfig, make_trainer, transition_example
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.map_elites import MapElites, QDState
from qdrl.qd.repertoires import cvt_centroids, cvt_repertoire, grid_repertoire
from qdrl.tasks import Task, make_task

BenchFn = Callable[..., list[dict[str, Any]]]  # (quick, seed, config) -> records
# What an off-policy benchmark trains: (the environment it steps, its agent, its storage).
Parts = tuple[Any, Agent, Storage]
BENCHES: dict[str, BenchFn] = {}


def _register(name: str) -> Callable[[BenchFn], BenchFn]:
    def deco(fn: BenchFn) -> BenchFn:
        BENCHES[name] = fn
        return fn

    return deco


def machine() -> dict[str, Any]:
    """Where the figures were measured."""

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
    parts: Callable[[Any], Parts] | None = None,
    population: int = 1,
    env: Any = None,
) -> dict[str, Any]:
    """Compile and time the off-policy loop of `algorithm` on `env_name`.

    `population > 1` times PBT's step instead: that many independent members
    (each its own agent, buffer and environments) trained by one vmapped chunk;
    env steps then count every member's.

    `parts(env) -> (env, agent, storage)` replaces the default agent of the `AGENTS` entry
    `algorithm` (e.g. a skill-discovery agent on its skill wrapper of `env`; `algorithm` then
    only labels). `env`, when given, is the environment (e.g. a task's, with its state
    descriptor); `env_name` then only labels. The record also gives `update_flops`, the
    arithmetic of one agent update (`update_flops`).
    """

    if env is None:
        env = envs.make(env_name, backend=backend, episode_length=episode_length)
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
    if parts is None:
        config_cls, make_agent = AGENTS[algorithm]
        agent = make_agent(config_cls(hidden=hidden), env.observation_size, env.action_size)
        train_env, storage = env, REPLAY
    else:
        train_env, agent, storage = parts(env)
    trainer = make_trainer(train_env, agent, cfg, storage)
    flops = update_flops(train_env, agent, storage, batch_size)
    init, run_chunk = trainer.init, trainer.run_chunk
    if population > 1:
        init = lambda k: jax.vmap(trainer.init)(jax.random.split(k, population))  # noqa: E731
        run_chunk = jax.vmap(trainer.run_chunk)
    state = jax.jit(init)(jax.random.PRNGKey(seed))  # jit: distinct buffers for donation
    compiled = compiling.compile_timed(run_chunk, state, donate_argnums=0)
    chunk = compiled.fn
    state, _ = chunk(state)  # warm-up chunk (fills the buffer past learning_starts)
    jax.block_until_ready(state)
    steps0, grads0 = int(jnp.sum(state.env_steps)), int(jnp.sum(state.grad_steps))
    t0 = time.perf_counter()
    for _ in range(repeats):
        state, _ = chunk(state)
    jax.block_until_ready(state)
    elapsed = time.perf_counter() - t0
    steps, grads = int(jnp.sum(state.env_steps)) - steps0, int(jnp.sum(state.grad_steps)) - grads0
    return {
        "bench": f"{algorithm}/{env_name}",
        "algorithm": algorithm,
        "env": env_name,
        "backend": backend,
        "num_envs": num_envs,
        "grad_steps_per_iter": grad_steps_per_iter,
        "batch_size": batch_size,
        "hidden": list(hidden),
        "population": population,
        "compile_s": round(compiled.seconds, 2),
        "env_steps": steps,
        "wall_s": round(elapsed, 3),
        "env_steps_per_s": round(steps / elapsed, 1),
        "grad_steps_per_s": round(grads / elapsed, 1),
        "update_flops": flops,
    }


def update_flops(env: Any, agent: Agent, storage: Storage, batch_size: int) -> float:
    """Floating-point operations of one `agent.update` on a batch of `batch_size` from
    `storage`, as XLA's cost analysis of the compiled update counts them (a measure of its
    arithmetic that does not depend on the machine's load). A `lax.cond` counts as if its
    costlier branch ran: a skill model trained on one update in n (DADS's 8) counts on every
    update, so its share is then an upper bound."""
    key = jax.random.PRNGKey(0)
    batch = storage.sample(storage.init(transition_example(env), batch_size, 1), key, batch_size)
    cost = jax.jit(agent.update).lower(agent.init(key), batch, key).compile().cost_analysis()
    if isinstance(cost, list):  # older jax releases give one dict per program
        cost = cost[0]
    if not cost or "flops" not in cost:
        raise RuntimeError("XLA's cost analysis gave no flops for the agent's update")
    return float(cost["flops"])


@_register("pbt")
def bench_pbt(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """PBT's cost: populations of N SAC (or TD3) agents against N single-agent runs.

    halfcheetah (spring), per member 8 envs x 8 updates of batch 128, 64x64
    networks (a CPU-sized member). `cost_ratio` = wall time of the population /
    (N x wall time of one agent); below 1 means vmapping the population is cheaper
    than N separate runs.
    """
    algorithm = config or "sac"
    sizes: tuple[int, ...] = (1, 4, 8, 16)
    env = "halfcheetah"
    kw: dict[str, Any] = {
        "num_envs": 8, "grad_steps_per_iter": 8, "batch_size": 128, "hidden": (64, 64),
        "iters_per_chunk": 50, "repeats": 2,
    }
    if quick:
        sizes, env = (1, 2), "point"
        kw = {"num_envs": 4, "grad_steps_per_iter": 2, "batch_size": 32, "hidden": (16, 16),
              "iters_per_chunk": 10, "repeats": 1, "episode_length": 50}
    records = [time_trainer(algorithm, env, population=n, seed=seed, **kw) for n in sizes]
    one = records[0]["wall_s"] / records[0]["env_steps"]  # seconds per env step of one agent
    for r in records:
        r["cost_ratio"] = round(r["wall_s"] / (r["env_steps"] * one), 3)
    return records


@_register("rl")
def bench_rl(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """SAC and TD3: halfcheetah (spring), 16 envs, 16 updates of batch 256 per iteration."""
    algorithms = ("sac", "td3") if config is None else (config,)
    if quick:
        return [
            time_trainer(a, "point", episode_length=100, hidden=(32, 32), batch_size=64,
                         iters_per_chunk=50, repeats=1, seed=seed)
            for a in algorithms
        ]
    return [time_trainer(a, "halfcheetah", seed=seed) for a in algorithms]


# The containers of the MAP-Elites benchmark (the QDax paper's arm setting).
ME_CONTAINERS: dict[str, tuple[str, Any]] = {
    "cvt1024": ("cvt", 1024),
    "grid32": ("grid", (32, 32)),
    "grid100": ("grid", (100, 100)),
}


class TimedRun(NamedTuple):
    """A run of scanned MAP-Elites steps, timed apart from its compilation."""

    state: Any
    metrics: Any
    compile_s: float
    run_s: float
    compile_cpu_s: float  # process CPU time of the compilation (steadier than wall time on a shared machine)
    hlo: dict[str, str] | None  # `qdrl.hlo_profile.module_texts` of the run, when asked for


def _time_run(me: Any, state: Any, iterations: int, with_hlo: bool = False) -> TimedRun:
    """Compile `iterations` MAP-Elites steps as one scan ahead of time, then run it once."""
    jax.block_until_ready(state)
    compiled = compiling.compile_timed(lambda s: me.run(s, iterations), state)
    t0 = time.perf_counter()
    state, metrics = compiled.fn(state)
    jax.block_until_ready(state)
    run_s = time.perf_counter() - t0
    texts = profiler.module_texts(compiled.traced, compiled.fn) if with_hlo else None
    return TimedRun(state, metrics, compiled.seconds, run_s, compiled.cpu_seconds, texts)


def time_map_elites(
    container: str,
    *,
    num_dofs: int = 100,
    batch_size: int = 1024,
    iterations: int = 200,
    iso_sigma: float = 0.05,
    line_sigma: float = 0.1,
    cvt_samples: int = 50_000,
    seed: int = 0,
    hlo: bool = True,
) -> dict[str, Any]:
    """MAP-Elites on the arm: `iterations` iterations as one scan compiled ahead of time.

    With `hlo`, the record's "hlo" holds `qdrl.hlo_profile.hlo_summary` of the timed program (per step).
    """

    if container not in ME_CONTAINERS:
        raise ValueError(f"unknown container {container!r}; expected one of {sorted(ME_CONTAINERS)}")
    kind, size = ME_CONTAINERS[container]
    task = make_task("arm", num_dofs=num_dofs)
    key = jax.random.PRNGKey(seed)
    init_key, cvt_key, run_key = jax.random.split(key, 3)
    example = jax.numpy.zeros((num_dofs,), jax.numpy.float32)
    if kind == "cvt":
        centroids = cvt_centroids(cvt_key, size, cvt_samples, task.descriptor_low, task.descriptor_high)
        repertoire = cvt_repertoire(example, centroids, task.descriptor_low, task.descriptor_high)
    else:
        repertoire = grid_repertoire(example, size, task.descriptor_low, task.descriptor_high)
    emitter = isoline_emitter(batch_size, iso_sigma, line_sigma, task.genotype_low, task.genotype_high)
    me = MapElites(task.scoring_fn, emitter, repertoire, qd_offset=task.qd_offset)
    state = jax.jit(lambda k1, k2: me.init(task.init_genotypes(k1, batch_size), k2))(init_key, run_key)
    timed = _time_run(me, state, iterations, with_hlo=hlo)
    compile_s, run_s = timed.compile_s, timed.run_s
    last = {k: float(v[-1]) for k, v in jax.device_get(timed.metrics).items()}
    record = {
        "bench": f"map_elites/arm/{container}",
        "library": "qdrl",
        "container": kind,
        "cells": int(repertoire.fitnesses.shape[0]),
        "seed": seed,
        "dof": num_dofs,
        "batch": batch_size,
        "iterations": iterations,
        "compile_s": round(compile_s, 3),
        "compile_cpu_s": round(timed.compile_cpu_s, 3),
        "run_s": round(run_s, 4),
        "evals_per_s": round(batch_size * iterations / run_s, 1),
        "qd_score": last["qd_score"],
        "coverage": last["coverage"],
        "max_fitness": last["max_fitness"],
    }
    if timed.hlo is not None:
        record["hlo"] = profiler.hlo_summary(timed.hlo, iterations)
    return record


@_register("map_elites")
def bench_map_elites(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """MAP-Elites on the 100-DoF arm, batch 1024, 200 iterations, iso-line (0.05, 0.1).

    Each record also profiles the timed program's HLO (`qdrl.hlo_profile.hlo_summary`, per step).
    """
    containers = list(ME_CONTAINERS) if config is None else [config]
    kwargs: dict[str, Any] = {"iterations": 20, "cvt_samples": 10_000} if quick else {}
    return [time_map_elites(c, seed=seed, **kwargs) for c in containers]


def time_task(
    name: str,
    *,
    batches: tuple[int, ...] = (128, 1024),
    episode_length: int = 100,
    me_batch: int = 128,
    me_iterations: int = 10,
    num_centroids: int = 1024,
    seed: int = 0,
) -> dict[str, Any]:
    """A policy task's rollout throughput (the ceiling) and MAP-Elites' on the same task.

    Each batch is rolled out as one block (`eval_batch` = the batch), as a run does.
    """

    key = jax.random.PRNGKey(seed)
    record: dict[str, Any] = {"bench": f"task/{name}", "task": name, "episode_length": episode_length}
    for batch in batches:
        task = make_task(name, episode_length=episode_length, eval_batch=batch)
        genotypes = task.init_genotypes(key, batch)
        compiled = compiling.compile_timed(task.scoring_fn, genotypes, key)
        score = compiled.fn
        jax.block_until_ready(score(genotypes, key))
        times = []
        for i in range(3):  # best of three calls: one call is short enough to be noisy
            t0 = time.perf_counter()
            jax.block_until_ready(score(genotypes, jax.random.fold_in(key, i + 1)))
            times.append(time.perf_counter() - t0)
        elapsed = min(times)
        record[f"rollout_b{batch}_compile_s"] = round(compiled.seconds, 2)
        # Ceiling: every simulated step, the masked ones after an early termination included.
        record[f"rollout_b{batch}_env_steps_per_s"] = round(batch * episode_length / elapsed, 1)
    me = time_policy_map_elites(
        name, episode_length=episode_length, batch_size=me_batch, iterations=me_iterations,
        num_centroids=num_centroids, cvt_samples=20 * num_centroids, seed=seed,
    )
    record["map_elites_compile_s"] = me["compile_s"]
    record["map_elites_batch"] = me_batch
    record["map_elites_env_steps_per_s"] = me["env_steps_per_s"]
    ceiling = record.get(f"rollout_b{me_batch}_env_steps_per_s")
    if ceiling:
        record["map_elites_fraction_of_ceiling"] = round(me["env_steps_per_s"] / ceiling, 3)
    record["qd_score"] = me["qd_score"]
    return record


def policy_map_elites_setup(
    name: str,
    *,
    episode_length: int = 100,
    batch_size: int = 128,
    num_centroids: int = 1024,
    cvt_samples: int = 50_000,
    iso_sigma: float = 0.005,
    line_sigma: float = 0.05,
    seed: int = 0,
    eval_batch: int | None = 128,
) -> tuple[Task, MapElites, QDState]:
    """The task, the MAP-Elites and its initial state of `time_policy_map_elites` (same keys:
    `init_key, cvt_key, run_key = split(PRNGKey(seed), 3)`), for a caller that runs it itself."""
    task = make_task(name, episode_length=episode_length, eval_batch=eval_batch)
    init_key, cvt_key, run_key = jax.random.split(jax.random.PRNGKey(seed), 3)
    centroids = cvt_centroids(cvt_key, num_centroids, cvt_samples, task.descriptor_low, task.descriptor_high)
    repertoire = cvt_repertoire(task.example_genotype(), centroids, task.descriptor_low, task.descriptor_high)
    me = MapElites(task.scoring_fn, isoline_emitter(batch_size, iso_sigma, line_sigma), repertoire, task.qd_offset)
    state = jax.jit(lambda k1, k2: me.init(task.init_genotypes(k1, batch_size), k2))(init_key, run_key)
    return task, me, state


def time_policy_map_elites(
    name: str,
    *,
    episode_length: int = 100,
    batch_size: int = 128,
    iterations: int = 50,
    num_centroids: int = 1024,
    cvt_samples: int = 50_000,
    iso_sigma: float = 0.005,
    line_sigma: float = 0.05,
    seed: int = 0,
    blocks: bool = True,
    hlo: bool = False,
) -> dict[str, Any]:
    """MAP-Elites on a policy task: `iterations` iterations as one scan compiled ahead of time.

    `blocks`: the task rolls out in blocks of the run's batch (`eval_batch` =
    `batch_size`, one block per evaluation, as `qdrl run` does); False rolls the
    batch out without blocks (`eval_batch` None), to measure what blocks cost.
    With `hlo`, the record's "hlo" holds `qdrl.hlo_profile.hlo_summary` of the timed program.
    """

    eval_batch = batch_size if blocks else None
    _, me, state = policy_map_elites_setup(
        name, episode_length=episode_length, batch_size=batch_size, num_centroids=num_centroids,
        cvt_samples=cvt_samples, iso_sigma=iso_sigma, line_sigma=line_sigma, seed=seed, eval_batch=eval_batch,
    )
    timed = _time_run(me, state, iterations, with_hlo=hlo)
    compile_s, run_s, metrics = timed.compile_s, timed.run_s, timed.metrics
    record = {
        "bench": f"map_elites/{name}",
        "library": "qdrl",
        "task": name,
        "seed": seed,
        "episode_length": episode_length,
        "batch": batch_size,
        "eval_batch": eval_batch,
        "iterations": iterations,
        "cells": num_centroids,
        "evaluations": batch_size * (iterations + 1),
        "compile_s": round(compile_s, 2),
        "compile_cpu_s": round(timed.compile_cpu_s, 2),
        "run_s": round(run_s, 3),
        "env_steps_per_s": round(batch_size * iterations * episode_length / run_s, 1),
        "qd_score": float(metrics["qd_score"][-1]),
        "coverage": float(metrics["coverage"][-1]),
        "max_fitness": float(metrics["max_fitness"][-1]),
    }
    if timed.hlo is not None:
        record["hlo"] = profiler.hlo_summary(timed.hlo, iterations)
    return record


@_register("policy_map_elites")
def bench_policy_map_elites(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """MAP-Elites on a policy task (default halfcheetah_uni): ep 100, batch 128, CVT 1024."""
    name = config or "halfcheetah_uni"
    if quick:
        return [time_policy_map_elites(name, episode_length=10, batch_size=16, iterations=2,
                                       num_centroids=32, cvt_samples=2_000, seed=seed)]
    return [time_policy_map_elites(name, seed=seed)]


POLICY_TASKS = (
    "ant_uni", "halfcheetah_uni", "walker2d_uni", "hopper_uni", "humanoid_uni",
    "ant_omni", "humanoid_omni", "ant_maze", "ant_trap", "point_maze", "snake",
)


# (packaged spec, a bad value): the spec errors `qdrl bench cli` times, as a user meets them.
CLI_CASES = (
    ("map_elites_arm", "emitter.line_sigma=-1.0"),
    ("pga_me_halfcheetah_uni_cpu", "pg.discount=2.0"),
    ("sac_halfcheetah", "train.batch_size=0"),
)


def _timed_process(cmd: list[str]) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds of the child, exit status) of one process."""
    before, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    wall, after = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), res.returncode


@_register("cli")
def bench_cli(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """The CLI's start-up cost: `qdrl run SPEC --set <bad value>` in fresh processes, until its
    one-line error (exit status 2), and `python -c "import qdrl.experiment"` (the imports a run
    needs); the median of the repeats, wall and CPU seconds. `config`: one spec of CLI_CASES."""
    del seed
    repeats = 1 if quick else 3
    cases = [c for c in CLI_CASES if config in (None, c[0])]
    if not cases:
        raise ValueError(f"unknown spec {config!r} for the cli benchmark; expected one of {[c[0] for c in CLI_CASES]}")
    commands = {"import qdrl.experiment": [sys.executable, "-c", "import qdrl.experiment"]}
    with tempfile.TemporaryDirectory() as tmp:
        for spec, bad in cases:
            commands[f"qdrl run {spec} --set {bad}"] = [
                sys.executable, "-m", "qdrl.cli", "run", spec, "--set", bad, "--out", str(Path(tmp) / "never"),
            ]
        records = []
        for what, cmd in commands.items():
            runs = [_timed_process(cmd) for _ in range(repeats)]
            expected = 0 if what.startswith("import") else 2
            if any(code != expected for _, _, code in runs):
                raise RuntimeError(f"{what}: expected exit status {expected}, got {[c for _, _, c in runs]}")
            records.append({
                "bench": "cli", "command": what, "repeats": repeats,
                "wall_s": round(statistics.median(w for w, _, _ in runs), 2),
                "cpu_s": round(statistics.median(c for _, c, _ in runs), 2),
            })
    return records


@_register("tasks")
def bench_tasks(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """Per policy task: rollout env steps/s at batch 128 and 1024, and MAP-Elites' (batch 128)."""
    names = POLICY_TASKS if config is None else (config,)
    if quick:
        return [time_task(n, batches=(32,), me_batch=32, me_iterations=2, num_centroids=64,
                          episode_length=20, seed=seed) for n in names]
    return [time_task(n, seed=seed) for n in names]


def run_bench(
    name: str,
    quick: bool = False,
    out: str | Path | None = None,
    seed: int = 0,
    config: str | None = None,
) -> dict[str, Any]:
    """Run benchmark `name`; returns (and optionally writes) its JSON record."""

    BENCHES.setdefault("scaling", bench_scaling.bench_scaling)
    BENCHES.setdefault(
        "skill_methods", functools.partial(bench_skill_methods.bench_skill_methods, time_trainer=time_trainer)
    )
    if name not in BENCHES:
        raise ValueError(f"unknown benchmark {name!r}; expected one of {sorted(BENCHES)}")
    record = {
        "benchmark": name,
        "quick": quick,
        "machine": machine(),
        "results": BENCHES[name](quick, seed=seed, config=config),
    }
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(record, indent=2) + "\n")
    return record


def skill_parts(
    algorithm: str, hidden: tuple[int, ...] = (256, 256), num_skills: int = 10
) -> Callable[[Any], Parts]:
    """`env -> (skill env, agent, storage)` of a skill-discovery `algorithm` ("diayn", "dads",
    "smerl_diayn", "smerl_dads") with default settings; SAC and the skill model both use `hidden`."""
    if algorithm not in ("diayn", "dads", "smerl_diayn", "smerl_dads"):
        raise ValueError(f"unknown skill-discovery algorithm {algorithm!r}")
    smerl = SMERLConfig() if algorithm.startswith("smerl") else None
    cls = DADSConfig if algorithm.endswith("dads") else DIAYNConfig

    def parts(env: Any) -> Parts:
        skills = cls(num_skills=num_skills, hidden=hidden, extrinsic_scale=0.0 if smerl is None else 1.0)
        sd = make_skill_discovery(env, SACConfig(hidden=hidden), skills, smerl)
        return sd.env, sd.agent, sd.storage

    return parts


BENCH_SKILLS = 5  # the skill-discovery study's num_skills


@_register("skills")
def bench_skills(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """DIAYN, DADS, SMERL (on each) next to SAC: same env, networks, batch and update ratio.

    point_maze (and ant, spring, unless `quick`): 16 envs, 16 updates of batch 256 per
    iteration, (256, 256) networks, the skill-discovery study's 5 skills (Chalumeau et al.
    2023's configs); the skill models are (256, 256) too, with their configs' other defaults
    (DADS: the exact marginal over the 5 skills, the model trained on one update in 8). DADS's
    reward evaluates its model once per skill for every sampled transition, so its cost grows
    with the number of skills (records before 2026-12-06 used 10).
    """

    algorithms: tuple[str, ...] = ("sac", "diayn", "dads", "smerl_diayn", "smerl_dads")
    if config is not None:
        algorithms = ("sac", config)
    envs_ = (("point_maze", 100),) if quick else (("point_maze", 100), ("ant", 1000))
    records = []
    for env_name, episode_length in envs_:
        for a in algorithms:
            parts = None if a == "sac" else skill_parts(a, hidden=(256, 256), num_skills=BENCH_SKILLS)
            records.append(
                time_trainer(
                    a, env_name, episode_length=episode_length, seed=seed, parts=parts,
                    iters_per_chunk=50 if quick else 250, repeats=1 if quick else 2,
                )
            )
    sac = {r["env"]: r for r in records if r["algorithm"] == "sac"}
    for r in records:
        r["relative_to_sac"] = round(r["env_steps_per_s"] / sac[r["env"]]["env_steps_per_s"], 3)
        r["sac_flops_share"] = round(sac[r["env"]]["update_flops"] / r["update_flops"], 3)
        if r["algorithm"] != "sac":  # the skills, the skill model's schedule and (DADS) alternatives
            r["num_skills"] = BENCH_SKILLS
            skills = (DADSConfig if r["algorithm"].endswith("dads") else DIAYNConfig)()
            r["model_update_every"] = skills.model_update_every
            if isinstance(skills, DADSConfig):
                r["num_alt_skills"] = skills.num_alt_skills
    return records
