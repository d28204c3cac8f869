"""brax's own SAC trainer against qdrl's SAC: same env, same budget, one process.

Usage (full comparison: roughly 10-15 minutes on a quiet 2-core CPU, about 3 minutes of
training per side at ~500 env steps/s plus ~80 s of compilation each)::

    python benchmarks/compare_brax_sac.py --env halfcheetah --backend spring \\
        --steps 100000 --num-envs 16 --grad-updates 16 --learning-starts 10000 \\
        --batch-size 256 --seed 0 --order brax,qdrl --out benchmarks/results/sac_vs_brax.json

    python benchmarks/compare_brax_sac.py --smoke   # tiny settings, a few minutes

What is matched
---------------
Both sides get the same environment (``brax.envs.get_environment(env, backend)``;
qdrl through ``qdrl.envs.make``), episode length, number of parallel envs, batch
size, hidden sizes of the policy and of the critics, learning rate (policy and
critic; the temperature uses 3e-4 on both, brax's hard-coded value), discount,
tau, reward scaling 1, initial temperature 1, replay capacity, warm-up length,
update ratio and number of environment steps, and the seed value. brax's
``grad_updates_per_step`` counts gradient steps per *actor step* (one step of all
``num_envs`` envs), which is exactly qdrl's ``grad_steps_per_iter``. Observation
normalisation is off on both; both evaluate the deterministic policy (tanh of the
Gaussian mean) on ``num_eval_envs`` fresh episodes of ``episode_length`` steps.

The run layout follows brax's own arithmetic: a prefill of
``ceil(learning_starts / num_envs)`` actor steps without updates, then ``epochs``
training epochs of equal length, each followed by an evaluation (brax also
evaluates once before training; so does the qdrl side here). brax is called with
``num_evals = epochs + 1`` and ``num_timesteps = prefill + epochs * epoch_steps``
so that its rounding gives exactly that layout. qdrl runs the same layout: its
chunk (``eval_every``) is one brax epoch; the warm-up is run with that chunk when
it is a whole number of epochs, otherwise with a second chunk function of the
warm-up's length (compiled and timed apart), so both sides take the same number
of environment steps.

How throughput is measured
--------------------------
brax: its ``training/sps`` of each epoch (reported to ``progress_fn``) is the
epoch's env steps over the wall time of the pmapped ``training_epoch`` call,
blocked on its metrics; it excludes the prefill and the evaluations. The first
epoch's time includes the compilation of ``training_epoch`` (brax offers no
ahead-of-time compile), so ``train_env_steps_per_s`` sums steps and times over
epochs 2..N only; ``first_epoch_s`` is reported as brax's compile figure, with
``compile_s_estimate = first_epoch_s - median(other epochs)``. With one epoch the
first is used, and the JSON says so.

qdrl: ``run_chunk`` (and ``evaluate``) are compiled ahead of time with
``jax.jit(...).lower(...).compile()`` and timed as ``compile_s``; each chunk is
timed until its state is ready. ``train_env_steps_per_s`` covers the chunks that
start after the warm-up (the counterpart of brax's epochs; warm-up steps, with no
updates, are far cheaper and are reported apart), and evaluations are timed
apart. ``ratio_qdrl_over_brax_sps`` is the quotient of the two
``train_env_steps_per_s``.

``total_wall_s`` on each side runs from building the environment to the last
evaluation, compilation, prefill and evaluations included.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import importlib.metadata
import json
import math
import platform
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

SMOKE_DEFAULTS: dict[str, Any] = {
    "env": "inverted_pendulum",
    "steps": 4096,
    "learning_starts": 1024,
    "hidden": "32,32",
    "num_envs": 8,
    "grad_updates": 8,
    "epochs": 3,
}


@dataclasses.dataclass(frozen=True)
class Settings:
    """The shared settings of both runs."""

    env: str
    backend: str
    steps: int  # requested env steps (the layout may round up, as brax does)
    num_envs: int
    grad_updates: int  # gradient steps per actor step (num_envs env steps)
    learning_starts: int
    batch_size: int
    hidden: tuple[int, ...]
    learning_rate: float
    alpha_learning_rate: float
    discount: float
    tau: float
    reward_scaling: float
    buffer_size: int
    episode_length: int
    num_eval_envs: int
    epochs: int
    seed: int
    order: tuple[str, ...]
    qdrl_target_entropy: str  # "qdrl": -action_size (qdrl default); "brax": -0.5 * action_size
    smoke: bool


@dataclasses.dataclass(frozen=True)
class Layout:
    """brax's split of the run into a prefill and equal epochs."""

    prefill_env_steps: int
    epochs: int
    epoch_env_steps: int

    @property
    def total_env_steps(self) -> int:
        return self.prefill_env_steps + self.epochs * self.epoch_env_steps

    @property
    def num_evals(self) -> int:
        return self.epochs + 1

    def as_dict(self) -> dict[str, int]:
        return {
            "prefill_env_steps": self.prefill_env_steps,
            "epochs": self.epochs,
            "epoch_env_steps": self.epoch_env_steps,
            "total_env_steps": self.total_env_steps,
            "brax_num_evals": self.num_evals,
        }


def make_layout(s: Settings) -> Layout:
    """The same arithmetic as brax.training.agents.sac.train (action_repeat 1, one device)."""
    prefill = -(-s.learning_starts // s.num_envs) * s.num_envs
    if prefill >= s.steps:
        raise ValueError(
            f"--learning-starts {s.learning_starts} leaves no training in {s.steps} steps"
        )
    iters = -(-(s.steps - prefill) // (s.epochs * s.num_envs))
    return Layout(prefill, s.epochs, iters * s.num_envs)


def log(msg: str) -> None:
    print(f"[compare_brax_sac {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def restore_device_put_replicated() -> None:
    """brax 0.14.2 calls `jax.device_put_replicated`, gone from jax 0.10's namespace.

    Put it back, for this process only: jax's own implementation if it still exists
    in `jax._src.api`, else an equivalent that stacks copies on a new leading axis
    and shards that axis over `devices`.
    """
    try:
        jax.device_put_replicated  # noqa: B018
        return
    except AttributeError:
        pass
    from jax._src import api as jax_api

    impl = getattr(jax_api, "device_put_replicated", None)
    if impl is None:

        def impl(x: Any, devices: Sequence[Any]) -> Any:
            mesh = jax.sharding.Mesh(list(devices), ("replica",))
            sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("replica"))
            return jax.tree.map(
                lambda a: jax.device_put(jnp.stack([jnp.asarray(a)] * len(devices)), sharding), x
            )

    jax.device_put_replicated = impl  # type: ignore[attr-defined]


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in ("qdrl", "jax", "jaxlib", "brax", "flax", "dm-haiku", "optax", "numpy", "mujoco"):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def _rate(steps: float, seconds: float) -> float | None:
    return round(steps / seconds, 1) if seconds > 0 else None


# --------------------------------------------------------------------------- brax


def run_brax(s: Settings, layout: Layout) -> dict[str, Any]:
    """brax.training.agents.sac.train.train on the shared settings; timings from its metrics."""
    restore_device_put_replicated()
    from brax import envs as brax_envs
    from brax.training.agents.sac import networks as sac_networks
    from brax.training.agents.sac import train as sac_train

    t_start = time.perf_counter()
    env = brax_envs.get_environment(s.env, backend=s.backend)
    records: list[dict[str, Any]] = []

    def progress(num_steps: int, metrics: dict[str, Any]) -> None:
        rec = {
            "env_steps": int(num_steps),
            "eval_return": float(metrics["eval/episode_reward"]),
            "eval_return_std": float(metrics["eval/episode_reward_std"]),
            "eval_s": float(metrics["eval/epoch_eval_time"]),
        }
        if "training/sps" in metrics:
            rec["sps"] = float(metrics["training/sps"])
            rec["training_walltime"] = float(metrics["training/walltime"])
            rec["alpha"] = float(metrics["training/alpha"])
        records.append(rec)
        sps = f", train sps {rec['sps']:.0f}" if "sps" in rec else ""
        log(f"brax  step {num_steps:>8}: eval return {rec['eval_return']:.1f}{sps}")

    sac_train.train(
        environment=env,
        num_timesteps=layout.total_env_steps,
        episode_length=s.episode_length,
        wrap_env=True,
        action_repeat=1,
        num_envs=s.num_envs,
        num_eval_envs=s.num_eval_envs,
        learning_rate=s.learning_rate,
        discounting=s.discount,
        seed=s.seed,
        batch_size=s.batch_size,
        num_evals=layout.num_evals,
        normalize_observations=False,
        reward_scaling=s.reward_scaling,
        tau=s.tau,
        min_replay_size=s.learning_starts,
        max_replay_size=s.buffer_size,
        grad_updates_per_step=s.grad_updates,
        deterministic_eval=True,
        network_factory=functools.partial(
            sac_networks.make_sac_networks, hidden_layer_sizes=s.hidden
        ),
        progress_fn=progress,
    )
    total_wall = time.perf_counter() - t_start

    epochs = [r for r in records if "sps" in r]
    epoch_s = [layout.epoch_env_steps / r["sps"] for r in epochs]
    if len(epoch_s) >= 2:
        timed, basis = (
            epoch_s[1:],
            "epochs 2..N (the first epoch includes compiling training_epoch)",
        )
        compile_est: float | None = epoch_s[0] - statistics.median(epoch_s[1:])
    else:
        timed, basis = epoch_s, "the only epoch, which includes compiling training_epoch"
        compile_est = None
    prefill_s = epochs[0]["training_walltime"] - epoch_s[0] if epochs else None
    final = records[-1]
    return {
        "train_env_steps_per_s": _rate(len(timed) * layout.epoch_env_steps, sum(timed)),
        "train_sps_basis": basis,
        "train_env_steps_per_s_all_epochs": _rate(
            len(epoch_s) * layout.epoch_env_steps, sum(epoch_s)
        ),
        "compile_kind": "first_epoch_s: first training epoch, compile of training_epoch included",
        "first_epoch_s": round(epoch_s[0], 2) if epoch_s else None,
        "compile_s_estimate": round(compile_est, 2) if compile_est is not None else None,
        "prefill_s": round(prefill_s, 2) if prefill_s is not None else None,
        "prefill_note": "prefill (no updates) incl. its compile, from training/walltime",
        "epoch_s": [round(t, 3) for t in epoch_s],
        "eval_s": [round(r["eval_s"], 3) for r in records],
        "eval_note": "the first two evaluations include compiling the evaluator (brax's "
        "evaluator compiles again for the parameters that come out of training_epoch)",
        "final_eval_return": round(final["eval_return"], 3),
        "final_eval_return_std": round(final["eval_return_std"], 3),
        "final_alpha": round(epochs[-1]["alpha"], 5) if epochs else None,
        "curve": [[r["env_steps"], round(r["eval_return"], 3)] for r in records],
        "env_steps": records[-1]["env_steps"],
        "total_wall_s": round(total_wall, 2),
    }


# --------------------------------------------------------------------------- qdrl


def run_qdrl(s: Settings, layout: Layout) -> dict[str, Any]:
    """qdrl's SAC through `make_trainer`, compiled ahead of time, same layout as brax."""
    from qdrl import envs
    from qdrl.agents import AGENTS
    from qdrl.off_policy import TrainConfig, make_trainer

    t_start = time.perf_counter()
    env = envs.make(s.env, backend=s.backend, episode_length=s.episode_length)
    config_cls, make_agent = AGENTS["sac"]
    target_entropy = -0.5 * env.action_size if s.qdrl_target_entropy == "brax" else None
    agent_cfg = config_cls(
        actor_lr=s.learning_rate,
        critic_lr=s.learning_rate,
        alpha_lr=s.alpha_learning_rate,
        discount=s.discount,
        tau=s.tau,
        reward_scale=s.reward_scaling,
        init_alpha=1.0,
        target_entropy=target_entropy,
        hidden=s.hidden,
    )
    agent = make_agent(agent_cfg, env.observation_size, env.action_size)

    def config(chunk_steps: int) -> TrainConfig:
        return TrainConfig(
            total_env_steps=layout.total_env_steps,
            num_envs=s.num_envs,
            batch_size=s.batch_size,
            buffer_size=s.buffer_size,
            learning_starts=s.learning_starts,
            grad_steps_per_iter=s.grad_updates,
            eval_every=chunk_steps,
            num_eval_envs=s.num_eval_envs,
        )

    trainer = make_trainer(env, agent, config(layout.epoch_env_steps))
    key = jax.random.PRNGKey(s.seed)
    state = jax.jit(trainer.init)(key)
    eval_keys = jax.random.split(jax.random.fold_in(key, 1), layout.num_evals)

    compile_parts: dict[str, float] = {}
    t0 = time.perf_counter()
    chunk = jax.jit(trainer.run_chunk, donate_argnums=0).lower(state).compile()
    compile_parts["run_chunk"] = time.perf_counter() - t0
    whole_warmup = layout.prefill_env_steps % layout.epoch_env_steps == 0
    if whole_warmup:
        warmup_chunks = [chunk] * (layout.prefill_env_steps // layout.epoch_env_steps)
    else:
        warm_trainer = make_trainer(env, agent, config(layout.prefill_env_steps))
        t0 = time.perf_counter()
        warm = jax.jit(warm_trainer.run_chunk, donate_argnums=0).lower(state).compile()
        compile_parts["warmup_chunk"] = time.perf_counter() - t0
        warmup_chunks = [warm]
    t0 = time.perf_counter()
    evaluate = jax.jit(trainer.evaluate).lower(state.agent, eval_keys[0]).compile()
    compile_parts["evaluate"] = time.perf_counter() - t0
    log(f"qdrl  compiled in {sum(compile_parts.values()):.1f} s ({compile_parts})")

    curve: list[list[float]] = []
    eval_s: list[float] = []
    last: dict[str, Any] = {}

    def run_eval(i: int) -> None:
        nonlocal last
        t = time.perf_counter()
        out = jax.device_get(evaluate(state.agent, eval_keys[i]))
        eval_s.append(time.perf_counter() - t)
        last = out
        steps = int(state.env_steps)
        curve.append([steps, round(float(out["eval_return"]), 3)])
        log(f"qdrl  step {steps:>8}: eval return {float(out['eval_return']):.1f}")

    run_eval(0)
    warmup_s = 0.0
    for fn in warmup_chunks:
        t = time.perf_counter()
        state, _ = fn(state)
        jax.block_until_ready(state)
        warmup_s += time.perf_counter() - t
    grad_steps0 = int(state.grad_steps)
    chunk_s: list[float] = []
    for i in range(layout.epochs):
        t = time.perf_counter()
        state, _ = chunk(state)
        jax.block_until_ready(state)
        chunk_s.append(time.perf_counter() - t)
        log(
            f"qdrl  chunk {i + 1}/{layout.epochs}: {layout.epoch_env_steps / chunk_s[-1]:.0f} env steps/s"
        )
        run_eval(i + 1)
    total_wall = time.perf_counter() - t_start

    train_steps = layout.epochs * layout.epoch_env_steps
    return {
        "train_env_steps_per_s": _rate(train_steps, sum(chunk_s)),
        "train_sps_basis": "every chunk after the warm-up (compiled ahead of time; evaluations timed apart)",
        "env_steps_per_s_incl_warmup": _rate(layout.total_env_steps, sum(chunk_s) + warmup_s),
        "train_grad_steps_per_s": _rate(int(state.grad_steps) - grad_steps0, sum(chunk_s)),
        "compile_kind": "compile_s: ahead-of-time compile of run_chunk and evaluate (not run)",
        "compile_s": round(sum(compile_parts.values()), 2),
        "compile_parts_s": {k: round(v, 2) for k, v in compile_parts.items()},
        "warmup_s": round(warmup_s, 2),
        "warmup_note": "uniform random actions, no updates"
        + ("" if whole_warmup else "; run with a separate chunk function of the warm-up's length"),
        "chunk_s": [round(t, 3) for t in chunk_s],
        "eval_s": [round(t, 3) for t in eval_s],
        "final_eval_return": round(float(last["eval_return"]), 3),
        "final_eval_return_std": round(float(last["eval_return_std"]), 3),
        "final_alpha": round(float(jnp.exp(state.agent.log_alpha)), 5),
        "target_entropy": target_entropy if target_entropy is not None else -float(env.action_size),
        "curve": curve,
        "env_steps": int(state.env_steps),
        "grad_steps": int(state.grad_steps),
        "total_wall_s": round(total_wall, 2),
    }


# --------------------------------------------------------------------------- main


DIFFERENCES = [
    "target entropy: brax -0.5*action_size; qdrl -action_size by default "
    "(--qdrl-target-entropy brax matches brax)",
    "policy std: brax softplus(raw)+0.001, unbounded above; qdrl exp(log_std), log_std squashed into [-5, 2]",
    "init: brax lecun_uniform kernels (flax); qdrl VarianceScaling(1, fan_avg, uniform) (haiku)",
    "warm-up actions: brax prefills with its randomly initialised stochastic policy; qdrl uses uniform random actions",
    "truncation: brax drops time-limit-truncated transitions from the critic loss; qdrl bootstraps through them",
    "critic loss scale: brax 0.5*mean over batch and both critics; qdrl 0.5*sum over critics, mean over batch (2x; Adam is nearly scale-invariant)",
    "update order: brax updates alpha, critic, actor all from the pre-step parameters (actor against the old critic); "
    "qdrl critic, then actor against the new critic, then alpha from the actor's log-probs",
    "sampling: brax draws batch*grad_updates transitions at once per actor step; qdrl draws a batch per gradient step",
    "auto-reset: brax's AutoResetWrapper restarts each training env from its first initial state; qdrl resets with a fresh key",
    "qdrl does one extra iteration of updates (the warm-up's last iteration already trains); brax does not",
]


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0] if __doc__ else None)
    p.add_argument("--smoke", action="store_true", help=f"tiny settings: {SMOKE_DEFAULTS}")
    p.add_argument("--env", default="halfcheetah")
    p.add_argument("--backend", default="spring")
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--grad-updates", type=int, default=16, help="gradient steps per actor step")
    p.add_argument("--learning-starts", type=int, default=10_000)
    p.add_argument("--batch-size", type=int, default=256)
    p.add_argument("--hidden", default="256,256", help="hidden widths, policy and critics")
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--discount", type=float, default=0.99)
    p.add_argument("--tau", type=float, default=0.005)
    p.add_argument("--reward-scaling", type=float, default=1.0)
    p.add_argument(
        "--buffer-size", type=int, default=None, help="default: every env step of the run"
    )
    p.add_argument("--episode-length", type=int, default=1000)
    p.add_argument("--num-eval-envs", type=int, default=16)
    p.add_argument("--epochs", type=int, default=9, help="brax training epochs (num_evals - 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--order", default="brax,qdrl", help="which side runs first")
    p.add_argument("--qdrl-target-entropy", choices=("qdrl", "brax"), default="qdrl")
    p.add_argument(
        "--platform", default="cpu", help="jax platform for both sides ('' = jax's choice)"
    )
    p.add_argument("--out", default="benchmarks/results/sac_vs_brax.json")
    pre, _ = p.parse_known_args(argv)
    if pre.smoke:
        p.set_defaults(**SMOKE_DEFAULTS)
    return p.parse_args(argv)


def settings_from(args: argparse.Namespace) -> Settings:
    order = tuple(x.strip() for x in args.order.split(",") if x.strip())
    if sorted(order) != ["brax", "qdrl"]:
        raise SystemExit(f"--order: expected a permutation of brax,qdrl, got {args.order!r}")
    if args.epochs < 1:
        raise SystemExit("--epochs: expected at least 1")
    return Settings(
        env=args.env,
        backend=args.backend,
        steps=args.steps,
        num_envs=args.num_envs,
        grad_updates=args.grad_updates,
        learning_starts=args.learning_starts,
        batch_size=args.batch_size,
        hidden=tuple(int(w) for w in args.hidden.split(",")),
        learning_rate=args.learning_rate,
        alpha_learning_rate=3e-4,
        discount=args.discount,
        tau=args.tau,
        reward_scaling=args.reward_scaling,
        buffer_size=args.buffer_size if args.buffer_size is not None else 0,  # 0: set in main
        episode_length=args.episode_length,
        num_eval_envs=args.num_eval_envs,
        epochs=args.epochs,
        seed=args.seed,
        order=order,
        qdrl_target_entropy=args.qdrl_target_entropy,
        smoke=args.smoke,
    )


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    if args.platform:
        jax.config.update("jax_platforms", args.platform)
    s = settings_from(args)
    layout = make_layout(s)
    if s.buffer_size == 0:
        s = dataclasses.replace(s, buffer_size=layout.total_env_steps)
    if layout.total_env_steps > s.buffer_size:
        log(
            f"note: replay capacity {s.buffer_size} < {layout.total_env_steps} env steps (FIFO on both)"
        )
    from qdrl.bench import machine

    log(f"settings {dataclasses.asdict(s)}; layout {layout.as_dict()}")
    results: dict[str, dict[str, Any]] = {}
    runners = {"brax": run_brax, "qdrl": run_qdrl}
    for side in s.order:
        log(f"running {side}")
        results[side] = runners[side](s, layout)
        log(
            f"{side}: {results[side]['train_env_steps_per_s']} env steps/s, "
            f"final return {results[side]['final_eval_return']}"
        )

    brax_sps, qdrl_sps = (
        results["brax"]["train_env_steps_per_s"],
        results["qdrl"]["train_env_steps_per_s"],
    )
    record = {
        "benchmark": "sac_vs_brax",
        "settings": {**dataclasses.asdict(s), "hidden": list(s.hidden), "order": list(s.order)},
        "layout": layout.as_dict(),
        "machine": machine(),
        "versions": versions(),
        "measurement": {
            "brax": "training/sps of epochs 2..N from progress_fn (wall time of the pmapped "
            "training_epoch, blocked on its metrics); excludes prefill, evaluations and the "
            "first epoch, which includes compilation",
            "qdrl": "env steps of the chunks after the warm-up over their wall time (state blocked "
            "after each chunk); compile ahead of time and evaluations timed apart",
            "eval": f"deterministic policy, mean return over {s.num_eval_envs} episodes of "
            f"{s.episode_length} steps, after every epoch and once before training",
        },
        "brax": results["brax"],
        "qdrl": results["qdrl"],
        "ratio_qdrl_over_brax_sps": (
            round(qdrl_sps / brax_sps, 3)
            if qdrl_sps and brax_sps and math.isfinite(brax_sps)
            else None
        ),
        "differences": DIFFERENCES,
    }
    text = json.dumps(record, indent=2)
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text + "\n")
    log(f"wrote {out}")
    return record


if __name__ == "__main__":
    main()
