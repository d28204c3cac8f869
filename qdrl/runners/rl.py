"""Off-policy RL runs (SAC, TD3) for the experiment driver."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple

import jax
import numpy as np

from qdrl.compiling import compile_timed
from qdrl.config import ConfigError, OneOf, PositiveInt, build
from qdrl.envs import env_names, make
from qdrl.envs.brax import STATE_DESCRIPTORS, Backend
from qdrl.experiment import ExperimentConfig, Sections, register, scalar
from qdrl.off_policy import STATE_AXES, TrainConfig, TrainState, make_trainer
from qdrl.placement import check_divisible, make_placement
from qdrl.qd.metrics import qd_metrics
from qdrl.qd.repertoires import CellRepertoire, observe, passive_archive

EnvName = Annotated[str, OneOf(env_names)]
StateDescriptor = Annotated[str, OneOf(lambda: STATE_DESCRIPTORS)]


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """The `[env]` section: which brax environment, on which physics backend."""

    name: EnvName = "halfcheetah"  # "point" or a brax registry name (`qdrl list` shows them)
    backend: Backend = "spring"  # brax physics pipeline
    episode_length: PositiveInt = 1000  # steps before truncation
    state_descriptor: StateDescriptor = "xy"  # brax: state descriptor recorded with every transition


@dataclasses.dataclass(frozen=True)
class ArchiveConfig:
    """The `[archive]` section: the passive archive that measures the run with QD metrics.

    Each evaluation's episodes are offered to it as (episode descriptor, return).
    """

    descriptor: Literal["final", "mean"] = "final"  # last or episode-averaged state descriptor
    grid_shape: tuple[PositiveInt, ...] = (32, 32)  # cells per descriptor dimension
    low: tuple[float, ...] = (-50.0, -50.0)  # descriptor lower bounds (edge cells beyond)
    high: tuple[float, ...] = (50.0, 50.0)  # descriptor upper bounds
    qd_offset: float = 0.0  # QD score = sum over cells of (return - qd_offset)

    def check(self) -> None:
        if not self.grid_shape:
            raise ValueError("archive.grid_shape: expected a list of positive integers, got []")
        if len(self.low) != len(self.grid_shape) or len(self.high) != len(self.grid_shape):
            raise ValueError(
                f"archive.low / archive.high: expected {len(self.grid_shape)} entries each "
                f"(one per grid dimension), got {list(self.low)} and {list(self.high)}"
            )
        if any(lo >= hi for lo, hi in zip(self.low, self.high, strict=True)):
            raise ValueError(
                f"archive.low: expected every entry below archive.high, got {list(self.low)} "
                f"and {list(self.high)}"
            )


def parse_off_policy(spec: Mapping[str, Any], exp: ExperimentConfig, shard_envs: bool = True) -> Sections:
    """The checked sections of a SAC or TD3 spec (`exp.algorithm` names the agent); with
    `shard_envs`, `[train]`'s batches are checked to split over `experiment.devices`."""
    from qdrl.agents import AGENTS

    config_cls, _ = AGENTS[exp.algorithm]
    train = build(TrainConfig, spec.get("train", {}), "train")
    if shard_envs:
        check_train_devices(train, exp.num_devices)
    return {
        "env": build(EnvConfig, spec.get("env", {}), "env"),
        "agent": build(config_cls, spec.get("agent", {}), "agent"),
        "train": train,
        "archive": build(ArchiveConfig, spec.get("archive", {}), "archive"),
    }


def check_train_devices(train: TrainConfig, devices: int) -> None:
    """ConfigError unless `[train]`'s environments and gradient batch split evenly over `devices`."""
    check_divisible(train.num_envs, devices, "train.num_envs")
    check_divisible(train.batch_size, devices, "train.batch_size")


class RLState(NamedTuple):
    """A run's state: the trainer's, plus the passive archive of evaluated episodes."""

    train: TrainState
    archive: CellRepertoire


class OffPolicyRun:
    """A SAC or TD3 run: trainer chunks, then a deterministic evaluation fed to a passive archive."""

    progress_keys: tuple[str, ...] = ("eval_return", "coverage")
    # What the devices split: each iteration's environments and gradient batch; PBT
    # (False) splits its members instead and trains each on one device.
    shard_envs: bool = True

    def __init__(self, sections: Sections, exp: ExperimentConfig) -> None:
        """Builds the environment, agent and trainer of checked `sections` (`parse_off_policy`)."""
        from qdrl.agents import AGENTS

        _, make_agent = AGENTS[exp.algorithm]
        env_cfg, agent_cfg = sections["env"], sections["agent"]
        train_cfg, archive_cfg = sections["train"], sections["archive"]
        self.algorithm = exp.algorithm
        self.task = env_cfg.name
        self.sections = dict(sections)
        self.archive_cfg = archive_cfg
        from qdrl.envs import JUMANJI_ENVS, PURE_JAX_ENVS

        native = env_cfg.name in PURE_JAX_ENVS or env_cfg.name in JUMANJI_ENVS
        extra = {} if native else {"state_descriptor": env_cfg.state_descriptor}
        self.env = make(env_cfg.name, env_cfg.backend, env_cfg.episode_length, **extra)
        try:
            self.agent = make_agent(agent_cfg, self.env.observation_size, self.env.action_size)
        except ValueError as e:
            raise ConfigError(f"agent: {e}") from e
        if len(archive_cfg.grid_shape) != self.env.descriptor_size:
            raise ConfigError(
                f"archive.grid_shape: expected {self.env.descriptor_size} entries (the state "
                f"descriptor size of {env_cfg.name!r}), got {list(archive_cfg.grid_shape)}"
            )
        self.placement = make_placement(exp.devices)
        self.trainer = make_trainer(
            self.env, self.agent, train_cfg, placement=self.placement if self.shard_envs else None
        )
        self.num_chunks = train_cfg.num_chunks
        self.progress_unit, self.progress_total = "env_steps", train_cfg.num_chunks * train_cfg.eval_every
        self._eval_key = jax.random.fold_in(jax.random.PRNGKey(exp.seed), 0x5EED)
        self._chunk: Any = None

    def init(self, key: jax.Array) -> RLState:
        cfg = self.archive_cfg
        archive = passive_archive("grid", grid_shape=cfg.grid_shape, low=cfg.low, high=cfg.high)
        # jit gives every leaf its own buffer (eager init aliases target and online
        # parameters), which the donating chunk function requires.
        return jax.jit(lambda k: RLState(self.trainer.init(k), archive))(key)

    def chunk(self, state: RLState) -> tuple[RLState, dict[str, Any]]:
        """Train for one log interval, evaluate, and offer the episodes to the archive."""
        train, metrics = self.trainer.run_chunk(state.train)
        ev = self.trainer.evaluate(train.agent, jax.random.fold_in(self._eval_key, train.env_steps))
        desc = ev["eval_final_desc"] if self.archive_cfg.descriptor == "final" else ev["eval_mean_desc"]
        archive = observe(state.archive, desc, ev["eval_returns"])
        out = dict(metrics)
        out.update({k: ev[k] for k in ("eval_return", "eval_return_std", "eval_length")})
        out.update(qd_metrics(archive, self.archive_cfg.qd_offset))
        return RLState(train, archive), out

    def compile(self, state: RLState) -> float:
        compiled = compile_timed(self.chunk, self._placed(state), donate_argnums=0)
        self._chunk = compiled.fn
        return compiled.seconds

    # Which axis of each part of the state is split over the devices (None: replicated).
    state_axes: Any = RLState(STATE_AXES, None)  # type: ignore[arg-type]

    def _placed(self, state: Any) -> Any:
        """`state` on the run's devices (a restored checkpoint comes back on one)."""
        return self.placement.place(state, self.state_axes)

    def run_chunk(self, state: Any) -> tuple[Any, Any]:
        return self._chunk(self._placed(state))

    def log_row(self, state: RLState, chunk_metrics: Any, chunk: int) -> dict[str, float]:
        row: dict[str, float] = {"env_steps": int(state.train.env_steps), "grad_steps": int(state.train.grad_steps)}
        m = jax.device_get(chunk_metrics)
        for key in ("eval_return", "eval_return_std", "eval_length"):
            row[key] = float(m.pop(key))
        row.update({k: scalar(v) for k, v in m.items()})
        return row

    @property
    def archive_labels(self) -> tuple[str, ...]:
        """The passive archive's descriptor names, for plots (e.g. "final x", "back foot contact")."""
        from qdrl.tasks.brax_qd import FEET_NAMES

        env_cfg, kind = self.sections["env"], self.archive_cfg.descriptor
        size = len(self.archive_cfg.grid_shape)
        if getattr(env_cfg, "state_descriptor", "xy") == "feet_contact":
            from qdrl.envs.brax import robot_of

            names = FEET_NAMES.get(robot_of(env_cfg.name), ())
            names = tuple(f"{kind} {n}" for n in names)
        else:
            names = (f"{kind} x", f"{kind} y")
        return names if len(names) == size else tuple(f"descriptor {i}" for i in range(size))

    def write_archive(self, archive: CellRepertoire, out_dir: Path) -> None:
        """The passive archive as QD runs write their repertoire: archive.npz (every cell),
        archive.csv (one row per filled cell) and plots/archive.png."""
        from qdrl import plotting
        from qdrl.qd.repertoires import export_npz, write_csv

        cfg = self.archive_cfg
        archive = jax.device_get(archive)
        export_npz(archive, out_dir / "archive.npz")
        write_csv(archive, out_dir / "archive.csv")
        plotting.plot_repertoire(
            archive, out_dir / "plots" / "archive.png", cfg.low, cfg.high,
            title=f"{self.algorithm} on {self.task}: passive archive ({cfg.descriptor} descriptor)",
            labels=self.archive_labels,
        )

    def finish(self, state: RLState, rows: list[dict[str, float]], out_dir: Path) -> dict[str, Any]:
        self.write_archive(state.archive, out_dir)
        return {"grad_steps": int(np.asarray(state.train.grad_steps))}


register("sac", parse_off_policy, OffPolicyRun)
register("td3", parse_off_policy, OffPolicyRun)
