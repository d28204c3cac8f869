"""What an algorithm is to the experiment driver: a `Recipe` in the table, and the `Algorithm`
of pure functions it builds.

A recipe parses its spec sections into typed, nested configs (`parse`: pure Python,
every value checked, nothing built) and builds an `Algorithm` from them (`build`:
tasks, environments, networks; nothing compiled). An `Algorithm` is data: an `init`
(key -> state pytree) and a `chunk` (state -> state, metrics) that the driver alone
jits, places on the devices and times, a host-side `log_row` and `finish`, and the
facts the driver and `qdrl.load_run` read (progress, descriptor space, the task of a
QD run, the agent of an RL or skill run). Nothing here compiles or runs anything.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Annotated, Any, NamedTuple

import numpy as np

from qdrl import loggers
from qdrl.config import NonNegativeInt, PositiveFloat, PositiveInt, Range, check_fields
from qdrl.placement import Placement, make_placement, resolve_devices

__all__ = [
    "AgentParts",
    "Algorithm",
    "BuildContext",
    "DescriptorSpace",
    "ExperimentConfig",
    "LogConfig",
    "Progress",
    "QDParts",
    "Recipe",
    "Row",
    "Sections",
    "last_values",
    "scalar",
]

Seed = Annotated[int, Range(0, 2**32 - 1)]  # jax.random.PRNGKey keeps the low 32 bits
Sections = dict[str, Any]  # section name -> its checked config dataclass (or a tuple of them: [[name]])
Row = dict[str, Any]  # one row of metrics.csv


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """The `[experiment]` section: what to run and with which seed."""

    algorithm: str  # a name from `qdrl list` (checked against the table of algorithms)
    seed: Seed = 0  # seeds every random choice of the run
    name: str = ""  # a label for plots and summaries; default: the spec file's stem
    # Devices the run spreads its batch over (qdrl.placement); 0: every visible device
    # (of every process under jax.distributed). Batch sizes must divide by it.
    devices: NonNegativeInt = 0
    # A wall-clock budget (seconds, compilation and every earlier session of a resumed run
    # included): the run stops at the first log point past it, with a checkpoint and its
    # summary (`stopped_by = "time_limit"`); `--resume` with a larger limit continues it.
    time_limit_s: PositiveFloat | None = None
    # An environment-steps budget: the run stops at the first log point at or past this many
    # environment steps (`stopped_by = "env_steps_limit"`), as at its time limit; runs of
    # different algorithms compared at equal steps (`qdrl suite`) share one.
    env_steps_limit: PositiveInt | None = None

    def check(self) -> None:
        check_fields(self, "experiment")

    @property
    def num_devices(self) -> int:
        """`devices` resolved against the visible devices; ConfigError when too many are asked for."""
        return resolve_devices(self.devices)


@dataclasses.dataclass(frozen=True)
class LogConfig:
    """The `[log]` section: how the driver records a run.

    metrics.csv is always written and is the source of truth; TensorBoard and
    Weights & Biases receive the same rows as they are logged (`qdrl.loggers`).
    """

    checkpoint_every: PositiveInt = 1  # log points between checkpoints
    keep_checkpoints: PositiveInt = 2  # newest checkpoints kept on disk
    progress: bool = True  # show a progress bar
    plots: bool = True  # write plots/*.png at the end
    compile_cache: bool = True  # jax's persistent compilation cache (qdrl.compile_cache)
    tensorboard: bool = False  # also write TensorBoard event files to <run>/tensorboard/ (tensorboardX)
    wandb: bool = False  # also log to Weights & Biases (pip install "qdrl[wandb]")
    wandb_project: str = "qdrl"  # W&B project
    wandb_entity: str = ""  # W&B entity (user or team); default: the logged-in user's
    wandb_group: str = ""  # W&B group; default: the experiment's name, so seeds group together
    wandb_mode: loggers.WandbMode = "online"  # "offline" writes to <run>/wandb/ for `wandb sync`

    def check(self) -> None:
        check_fields(self, "log")


@dataclasses.dataclass(frozen=True)
class BuildContext:
    """What a recipe's `build` knows of the run besides its sections."""

    algorithm: str  # the name the spec gave (a recipe may serve several names)
    seed: int
    devices: int = 0  # `experiment.devices`
    # The cells of a CVT repertoire when they are known (a loaded run's export): no k-means.
    centroids: Any = None

    @functools.cached_property
    def placement(self) -> Placement:
        """The devices the run spreads over (`qdrl.placement`); one device by default."""
        return make_placement(self.devices)


class Progress(NamedTuple):
    """What the progress bar shows: row keys beside the bar, and what the bar counts."""

    keys: tuple[str, ...]
    unit: str  # a row key ("iteration", "env_steps"), or "log_point" for log points
    total: int  # its value at the end of the run


class DescriptorSpace(NamedTuple):
    """The bounds and names of a run's descriptor space (its repertoire or passive archive)."""

    low: tuple[float, ...]
    high: tuple[float, ...]
    names: tuple[str, ...]


class QDParts(NamedTuple):
    """What a QD run's repertoire needs to be read back, replayed and re-scored (`qdrl.load_run`)."""

    task: Any  # `qdrl.tasks.Task`
    # An empty repertoire of the run; a CVT repertoire's cells are the given centroids.
    empty_repertoire: Callable[[Any], Any]
    # (fixed_start=True, record=None) -> the scoring function of the run's genotypes
    # (random start states for re-evaluations, recorded env states for replays).
    scoring: Callable[..., Any]


class AgentParts(NamedTuple):
    """What the trained agent of an RL or skill-discovery run needs to be loaded, acted with and
    replayed (`qdrl.load_run`): pure functions, nothing compiled.

    `evaluation(state, record)` plays exactly the episodes the run's own evaluation
    plays after reaching `state` (same environment, keys and batch width; jittable,
    `record` as in `qdrl.rollout.run_episodes`) and returns them (`qdrl.rollout.Episodes`)
    with each episode's passive-archive descriptor (B, D). Episode i plays skill
    i % `num_skills`; a run without skills (`num_skills` 0) plays its one policy in every
    episode.
    """

    env: Any  # the environment the evaluations play (`qdrl.envs.base.Env`, no skill in its observation)
    num_skills: int  # skills the policy is conditioned on; 0: an agent without a skill input
    agent_state: Callable[[Any], Any]  # the run's state -> the agent's (`qdrl.agents.base.AgentState`)
    # (agent state, skill: an int in [0, num_skills), or None without skills) -> the
    # deterministic policy: observations (..., obs_size) -> actions (..., action_size); jittable.
    policy: Callable[[Any, int | None], Callable[[Any], Any]]
    evaluation: Callable[[Any, Callable[[Any], Any] | None], tuple[Any, Any]]
    # What the skills are, for messages: "skills.num_skills" skills, or feature-space runs' fixed
    # "train.num_eval_envs evaluation skills".
    skills_are: str = "skills.num_skills"


class Algorithm(NamedTuple):
    """A built algorithm: pure functions over one state pytree, and what the driver reads.

    `init(key)` and `chunk(state)` are pure and jittable: the driver jits both, the
    chunk once with its state donated, after placing the state with `state_axes` on
    `placement`'s devices; `chunk` runs one log interval (a `lax.scan` of iterations).
    `log_row(state, metrics)` turns a chunk's result into one row (host values; it
    must include `env_steps`); `finish(state, rows, out_dir)` writes the final
    artefacts (exports) and returns extra summary fields; `plot(state, rows, out_dir)`
    draws the final figures into out_dir/plots (called unless `log.plots` is off).
    `run_context`, when given, is entered around the compiled calls (CMA-ES: one
    LAPACK thread for its eigendecompositions).
    """

    task: str  # what the run runs on (a task or environment name)
    sections: Sections  # the resolved configs (defaults completed from the task), for config.toml
    num_chunks: int  # log points in the whole run
    progress: Progress
    init: Callable[[Any], Any]
    chunk: Callable[[Any], tuple[Any, Any]]
    log_row: Callable[[Any, Any], Row]
    finish: Callable[[Any, list[Row], Path], dict[str, Any]]
    placement: Placement
    plot: Callable[[Any, list[Row], Path], None] | None = None
    # The metrics the driver draws one PNG each (plots/<metric>.png); None: every column. RL and
    # skill runs draw their one summary figure (`plot`) and only the return apart.
    curves: tuple[str, ...] | None = None
    state_axes: Any = None  # which axis of each part of the state is split over the devices
    run_context: Callable[[], AbstractContextManager[Any]] | None = None
    descriptor_space: DescriptorSpace | None = None
    qd: QDParts | None = None  # QD runs: their task and repertoire
    agent: AgentParts | None = None  # RL and skill-discovery runs: their one trained agent
    # Called with the run directory after each log point's row is written (process 0 only):
    # per-log-point outputs of the algorithm's own (skills.csv), on disk as metrics.csv is.
    on_log_point: Callable[[Path], None] | None = None
    # (what it computes, the host computation): run once before anything compiles, with a
    # progress line of its own (a CVT's cells: k-means); the driver times it apart.
    prepare: tuple[str, Callable[[], Any]] | None = None


Parser = Callable[[Mapping[str, Any], ExperimentConfig], Sections]
Builder = Callable[[Sections, BuildContext], Algorithm]


@dataclasses.dataclass(frozen=True)
class Recipe:
    """One row of the table of algorithms: how a spec is parsed and checked, then built.

    `parse(spec, experiment)` returns the checked sections (pure Python: builds no
    task, environment or network); `build(sections, context)` the `Algorithm`.
    `length_key` is the spec key that sets the run's length (the only key besides
    `[log]` that `--resume` may change); `array_sections` are the sections written
    as arrays of tables (`[[emitters]]`).
    """

    parse: Parser
    build: Builder
    length_key: str
    description: str = ""
    array_sections: tuple[str, ...] = ()


def scalar(x: Any) -> int | float:
    """A 0-d metric as a Python number: an int for integer and bool dtypes, else a float."""
    a = np.asarray(x)
    return int(a) if a.dtype.kind in "biu" else float(a)


def last_values(metrics: Mapping[str, Any], keys: Any = None) -> Row:
    """Each metric's value at the last iteration of a chunk (the last entry of a scanned
    metric, or a 0-d metric itself), as Python numbers; `keys` limits and orders them."""
    names = metrics.keys() if keys is None else keys
    return {k: scalar(_last(metrics[k])) for k in names}


def _last(value: Any) -> Any:
    a = np.asarray(value)
    return a[-1] if a.ndim else a
