"""`qdrl bench scaling`: throughput of the same run on 1 and on N devices, and its parallel efficiency.

jax fixes its device count when it starts, so the figures are measured in a child
process that sees `devices` CPU devices (`--xla_force_host_platform_device_count`;
on a GPU node, its GPUs). In that one process each case is built, compiled and
warmed up once per device count, then timed chunk by chunk, alternating the device
counts, so that both see the same machine load. Parallel efficiency is
throughput on N devices / (N x throughput on one). On a CPU, forced devices share
the same cores: the figure then shows what sharding costs, not what it gains.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import jax

from qdrl.experiment import build_run, compile_chunk, initial_state, run_chunk

# name -> spec at full size; QUICK: what `--quick` overrides (tiny, for tests).
_POLICY_QD = {"repertoire": {"kind": "cvt", "num_centroids": 256, "cvt_samples": 20_000}}
CASES: dict[str, dict[str, Any]] = {
    "map_elites_arm": {
        "experiment": {"algorithm": "map_elites"},
        "task": {"name": "arm", "num_dofs": 100},
        "repertoire": {"kind": "grid", "grid_shape": [32, 32]},
        "emitter": {"kind": "isoline", "batch_size": 1024, "iso_sigma": 0.05, "line_sigma": 0.1},
        "qd": {"num_iterations": 50, "log_every": 50, "init_batch_size": 1024},
    },
    "map_elites_halfcheetah_uni": {
        "experiment": {"algorithm": "map_elites"},
        "task": {"name": "halfcheetah_uni", "episode_length": 100, "backend": "spring"},
        **_POLICY_QD,
        "emitter": {"kind": "isoline", "batch_size": 128, "iso_sigma": 0.005, "line_sigma": 0.05},
        "qd": {"num_iterations": 5, "log_every": 5, "init_batch_size": 128},
    },
    "pga_me_halfcheetah_uni": {
        "experiment": {"algorithm": "pga_me"},
        "task": {"name": "halfcheetah_uni", "episode_length": 100, "backend": "spring"},
        **_POLICY_QD,
        "emitter": {"kind": "isoline", "batch_size": 64, "iso_sigma": 0.005, "line_sigma": 0.05},
        "pg": {"num_critic_training_steps": 50, "num_pg_training_steps": 20, "training_batch_size": 64,
               "replay_buffer_size": 100_000},
        "qd": {"num_iterations": 5, "log_every": 5, "init_batch_size": 64},
    },
    "sac_halfcheetah": {
        "experiment": {"algorithm": "sac"},
        "env": {"name": "halfcheetah", "backend": "spring", "episode_length": 1000},
        "train": {"total_env_steps": 4096, "num_envs": 16, "batch_size": 256, "buffer_size": 100_000,
                  "learning_starts": 0, "grad_steps_per_iter": 16, "eval_every": 2048, "num_eval_envs": 2},
    },
}
QUICK: dict[str, dict[str, Any]] = {
    "map_elites_arm": {"emitter": {"batch_size": 64}, "qd": {"num_iterations": 5, "log_every": 5, "init_batch_size": 64}},
    "map_elites_halfcheetah_uni": {
        "task": {"episode_length": 10}, "emitter": {"batch_size": 8},
        "repertoire": {"num_centroids": 32, "cvt_samples": 1000, "kmeans_iters": 5},
        "qd": {"num_iterations": 2, "log_every": 2, "init_batch_size": 8},
    },
    "pga_me_halfcheetah_uni": {
        "task": {"episode_length": 10}, "emitter": {"batch_size": 8},
        "repertoire": {"num_centroids": 32, "cvt_samples": 1000, "kmeans_iters": 5},
        "pg": {"num_critic_training_steps": 2, "num_pg_training_steps": 2, "training_batch_size": 16,
               "replay_buffer_size": 1000, "critic_hidden": [16, 16]},
        "qd": {"num_iterations": 2, "log_every": 2, "init_batch_size": 8},
    },
    "sac_halfcheetah": {
        "env": {"episode_length": 20}, "agent": {"hidden": [16, 16]},
        "train": {"total_env_steps": 64, "num_envs": 4, "batch_size": 16, "buffer_size": 1000,
                  "grad_steps_per_iter": 2, "eval_every": 32, "num_eval_envs": 2},
    },
}


def case_spec(name: str, quick: bool, devices: int, seed: int = 0) -> dict[str, Any]:
    """The spec of case `name` on `devices` devices (no files, no progress bar)."""
    spec = {k: dict(v) for k, v in CASES[name].items()}
    for section, values in (QUICK[name] if quick else {}).items():
        spec[section] = {**spec.get(section, {}), **values}
    spec["experiment"] = {**spec["experiment"], "seed": seed, "devices": devices}
    spec["log"] = {"plots": False, "progress": False, "compile_cache": False}
    return spec


def _count(run: Any, state: Any) -> tuple[str, float]:
    """What a case's throughput counts (evaluations on a task without environment, else env
    steps) and how many its state has done so far."""
    if run.qd is not None:
        if run.qd.task.env is None:
            return "evaluations", float(state.evaluations)
        return "env_steps", float(state.env_steps)
    return "env_steps", float(state.train.env_steps)


def measure(
    names: list[str], device_counts: list[int], quick: bool, repeats: int, seed: int = 0
) -> list[dict[str, Any]]:
    """In this process: each case on each device count, timed chunk by chunk, alternating."""

    records = []
    for name in names:
        runs, states, chunks, compile_s = {}, {}, {}, {}
        seconds = dict.fromkeys(device_counts, 0.0)
        done = dict.fromkeys(device_counts, 0.0)
        for d in device_counts:
            run, _, _ = build_run(case_spec(name, quick, d, seed))
            state = initial_state(run, seed)
            compiled = compile_chunk(run, state)
            compile_s[d], chunks[d] = compiled.seconds, compiled.fn
            runs[d] = run
            states[d] = jax.block_until_ready(run_chunk(run, compiled.fn, state))[0]  # warm-up chunk
        for _ in range(repeats):
            for d in device_counts:
                _, before = _count(runs[d], states[d])
                t0 = time.perf_counter()
                states[d] = jax.block_until_ready(run_chunk(runs[d], chunks[d], states[d]))[0]
                seconds[d] += time.perf_counter() - t0
                done[d] += _count(runs[d], states[d])[1] - before
        one = done[device_counts[0]] / seconds[device_counts[0]]
        for d in device_counts:
            rate = done[d] / seconds[d]
            records.append({
                "case": name, "devices": d, "unit": f"{_count(runs[d], states[d])[0]}_per_s",
                "throughput": round(rate, 1), "parallel_efficiency": round(rate / (d * one), 3),
                "compile_s": round(compile_s[d], 2), "timed_s": round(seconds[d], 3), "chunks": repeats,
            })
    return records


def bench_scaling(quick: bool, seed: int = 0, config: str | None = None) -> list[dict[str, Any]]:
    """MAP-Elites (arm, halfcheetah_uni), PGA-ME and SAC on 1 and 2 devices (`config`: "N" for
    1 and N devices, or "N:case" for one case), in a child process that sees N devices."""
    devices, names = 2, list(CASES)
    if config:
        count, _, case = config.partition(":")
        devices = int(count)
        if case:
            names = [case]
    unknown = [n for n in names if n not in CASES]
    if unknown or devices < 2:
        raise ValueError(f"scaling: expected config 'N' or 'N:case' with N >= 2 and case one of {sorted(CASES)}, got {config!r}")
    env = dict(os.environ)
    # The child imports this very qdrl (a source checkout as much as an installed one).
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH", "")) if p)
    if jax.devices()[0].platform == "cpu":
        env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()
    args = json.dumps({"names": names, "devices": [1, devices], "quick": quick, "repeats": 1 if quick else 3, "seed": seed})
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from qdrl.bench_scaling import _child; _child(sys.argv[1])", args],
        env=env, capture_output=True, text=True,
    )
    if done.returncode != 0:
        raise RuntimeError(f"scaling: the measuring process failed:\n{done.stderr[-3000:]}")
    line = next(x for x in done.stdout.splitlines() if x.startswith("SCALING "))
    return list(json.loads(line.removeprefix("SCALING ")))


def _child(args_json: str) -> None:
    args = json.loads(args_json)
    records = measure(args["names"], args["devices"], args["quick"], args["repeats"], args["seed"])
    print("SCALING " + json.dumps(records), flush=True)
