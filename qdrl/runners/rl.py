"""Off-policy RL runs (SAC, TD3) for the experiment driver."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import jax
import numpy as np

from qdrl.config import ConfigError, build
from qdrl.envs import env_names, make
from qdrl.envs.brax import BACKENDS, STATE_DESCRIPTORS
from qdrl.experiment import ExperimentConfig, register
from qdrl.off_policy import TrainConfig, TrainState, make_trainer

Backend = Literal["spring", "positional", "generalized", "mjx"]
assert set(BACKENDS) == {"spring", "positional", "generalized", "mjx"}


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """The `[env]` section: which brax environment, on which physics backend."""

    name: str = "halfcheetah"  # "point" or a brax registry name (`qdrl list` shows them)
    backend: Backend = "spring"  # brax physics pipeline
    episode_length: int = 1000  # steps before truncation
    state_descriptor: str = "xy"  # brax: state descriptor recorded with every transition

    def check(self) -> None:
        names = env_names()
        if self.name not in names:
            raise ValueError(f"env.name: unknown environment {self.name!r}; expected one of {names}")
        if self.episode_length <= 0:
            raise ValueError(
                f"env.episode_length: expected a positive integer, got {self.episode_length}"
            )
        if self.state_descriptor not in STATE_DESCRIPTORS:
            raise ValueError(
                f"env.state_descriptor: expected one of {sorted(STATE_DESCRIPTORS)}, "
                f"got {self.state_descriptor!r}"
            )


class OffPolicyRun:
    """A SAC or TD3 run: trainer chunks plus a deterministic evaluation per log point."""

    progress_keys: tuple[str, ...] = ("eval_return",)

    def __init__(self, spec: Mapping[str, Any], exp: ExperimentConfig) -> None:
        from qdrl.agents import AGENTS

        config_cls, make_agent = AGENTS[exp.algorithm]
        env_cfg = build(EnvConfig, spec.get("env", {}), "env")
        agent_cfg = build(config_cls, spec.get("agent", {}), "agent")
        train_cfg = build(TrainConfig, spec.get("train", {}), "train")
        self.algorithm = exp.algorithm
        self.task = env_cfg.name
        self.sections = {"env": env_cfg, "agent": agent_cfg, "train": train_cfg}
        extra = {} if env_cfg.name == "point" else {"state_descriptor": env_cfg.state_descriptor}
        self.env = make(env_cfg.name, env_cfg.backend, env_cfg.episode_length, **extra)
        try:
            self.agent = make_agent(agent_cfg, self.env.observation_size, self.env.action_size)
        except ValueError as e:
            raise ConfigError(f"agent: {e}") from e
        self.trainer = make_trainer(self.env, self.agent, train_cfg)
        self.num_chunks = train_cfg.num_chunks
        self._eval_key = jax.random.fold_in(jax.random.PRNGKey(exp.seed), 0x5EED)
        self._chunk: Any = None
        self._eval: Any = None

    def init(self, key: jax.Array) -> TrainState:
        # jit gives every leaf its own buffer (eager init aliases target and online
        # parameters), which the donating chunk function requires.
        return jax.jit(self.trainer.init)(key)

    def compile(self, state: TrainState) -> float:
        import time

        t0 = time.perf_counter()
        self._chunk = jax.jit(self.trainer.run_chunk, donate_argnums=0).lower(state).compile()
        self._eval = jax.jit(self.trainer.evaluate).lower(state.agent, self._eval_key).compile()
        return time.perf_counter() - t0

    def run_chunk(self, state: TrainState) -> tuple[TrainState, Any]:
        return self._chunk(state)

    def log_row(self, state: TrainState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        ev = self._eval(state.agent, jax.random.fold_in(self._eval_key, chunk))
        row = {
            "env_steps": float(state.env_steps),
            "grad_steps": float(state.grad_steps),
            "eval_return": float(ev["eval_return"]),
            "eval_return_std": float(ev["eval_return_std"]),
            "eval_length": float(ev["eval_length"]),
        }
        row.update({k: float(v) for k, v in jax.device_get(chunk_metrics).items()})
        return row

    def finish(self, state: TrainState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        return {"grad_steps": int(np.asarray(state.grad_steps))}


@register("sac")
def _sac(spec: Mapping[str, Any], exp: ExperimentConfig) -> OffPolicyRun:
    return OffPolicyRun(spec, exp)


@register("td3")
def _td3(spec: Mapping[str, Any], exp: ExperimentConfig) -> OffPolicyRun:
    return OffPolicyRun(spec, exp)
