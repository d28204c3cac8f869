"""Load a run directory written by `qdrl run`: its config, metrics, summary and repertoire,
and the trained agent of RL and skill-discovery runs.

    run = qdrl.load_run("runs/map_elites_halfcheetah_uni_cpu")
    run.metrics.tail()                 # metrics.csv as a pandas DataFrame
    elite = run.best()                 # or run.elite(cell)
    episode = run.rollout(elite)       # its episode, through the task's own scoring
    assert episode.return_ == elite.fitness   # bit for bit

    skills = qdrl.load_run("runs/diayn_point_maze_cpu")
    act = skills.policy(skill=3)       # obs -> action of skill 3, deterministic, jittable
    episode = skills.rollout(skill=3)  # skill 3's episode of the run's last evaluation

The run is rebuilt from its resolved `config.toml` (no compilation until a rollout
or a re-evaluation asks for one). The repertoire comes from `repertoire.npz` (a
finished run) or from the latest checkpoint (an interrupted run), with genotypes
in the task's own pytree structure. RL, PBT and skill runs load too; their
passive archive stores no genotypes, which `Elite.genotype` says when asked. SAC,
TD3 and skill-discovery runs give their agent (`agent()`, `policy()`, `rollout()`)
from the latest checkpoint. Rollouts compile inside jax's persistent compilation
cache (`qdrl.compile_cache`), so a later process loads their programs.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import numpy as np
import pandas as pd

from qdrl import checkpoint, compile_cache
from qdrl.algorithms.base import AgentParts, Algorithm, QDParts
from qdrl.algorithms.qd import parts_reevaluation
from qdrl.config import ConfigError, load_toml
from qdrl.experiment import build_run
from qdrl.qd.reevaluate import write_reevaluation
from qdrl.qd.repertoires import passive_archive, to_table

if TYPE_CHECKING:
    from qdrl.qd.repertoires import CellRepertoire

__all__ = [
    "Elite",
    "LoadedRun",
    "RunError",
    "Trajectory",
    "find_runs",
    "load_metrics",
    "load_repertoires",
    "load_run",
]


class RunError(ValueError):
    """A run directory that cannot give what was asked; the message says what was expected."""


@dataclasses.dataclass(frozen=True)
class Elite:
    """One elite of a repertoire: its cell, stored fitness and descriptor, and genotype."""

    cell: int
    fitness: float
    descriptor: np.ndarray  # (D,)
    stored_genotype: Any = dataclasses.field(default=None, repr=False)
    # Why `stored_genotype` is None (a passive archive stores none).
    no_genotype: str = dataclasses.field(default="", repr=False)

    @property
    def genotype(self) -> Any:
        """The elite's genotype (the task's pytree, no batch axis); RunError if none is stored."""
        if self.stored_genotype is None:
            raise RunError(self.no_genotype or f"cell {self.cell}: no genotype stored")
        return self.stored_genotype


class Trajectory(NamedTuple):
    """One episode of an elite (as the task's scoring function rolled it out) or of an agent's
    skill (as the run's evaluation played it)."""

    observations: np.ndarray  # (T, obs_size) before each step (the environment's, no skill code)
    actions: np.ndarray  # (T, action_size)
    rewards: np.ndarray  # (T,)
    state_descriptors: np.ndarray  # (T + 1, D): at the start, then after each step
    mask: np.ndarray  # (T,) 1.0 for the steps inside the episode
    length: int  # steps inside the episode
    return_: float  # the episode's return: the elite's fitness, the evaluation's return
    descriptor: np.ndarray  # (D,) the task's descriptor of the elite, the episode's archive descriptor
    states: Any  # (T, ...) what `record` kept of each step's env state (brax: link poses)


def brax_link_poses(state: Any) -> Any:
    """What `brax.io.html` draws of a batched brax env state: the links' poses `pipeline_state.x`."""
    return state.inner.pipeline_state.x


def load_run(path: str | Path) -> LoadedRun:
    """The run in directory `path` (finished or interrupted); RunError if it is not one."""
    path = Path(path)
    if path.is_dir() and not (path / "config.toml").is_file():
        inside = find_runs([path])  # RunError when there is none
        some = ", ".join(str(p) for p in inside[:3]) + (", ..." if len(inside) > 3 else "")
        raise RunError(
            f"{path} holds {len(inside)} runs (a sweep or a folder of runs), not one: load one of "
            f"them ({some}), or all with qdrl.load_metrics / qdrl.load_repertoires"
        )
    return LoadedRun(path)


def find_runs(paths: Sequence[str | Path]) -> list[Path]:
    """The run directories (those holding a config.toml) at or under each of `paths`.

    A run directory is itself; a sweep (`qdrl run SPEC --seeds ...`) or a folder of
    runs gives every run below it, in path order. RunError names the first path
    that holds no run.
    """
    found: list[Path] = []
    for given in paths:
        root = Path(given)
        if not root.is_dir():
            raise RunError(f"{root}: no such directory; expected a run directory written by `qdrl run`")
        if (root / "config.toml").is_file():
            runs = [root]
        else:
            runs = sorted({p.parent for p in root.rglob("config.toml") if "checkpoints" not in p.parts})
        if not runs:
            raise RunError(
                f"{root} holds no run: expected a directory written by `qdrl run` (with config.toml), "
                "or a folder of them (e.g. a sweep's seed_<n>/)"
            )
        found.extend(r for r in runs if r not in found)
    return found


def _labels(run: LoadedRun) -> dict[str, Any]:
    """The columns that say which run a row comes from."""
    return {
        "spec": run.name,
        "algorithm": run.algorithm,
        "task": run.task_name,
        "seed": run.seed,
        "run": str(run.path),
    }


def load_metrics(*paths: str | Path) -> pd.DataFrame:
    """The metrics.csv of every run at or under `paths`, stacked into one DataFrame.

    Columns `spec` (the experiment's name), `algorithm`, `task`, `seed` and `run`
    (its directory) say where each row comes from, then the metrics; runs of
    different algorithms have different metric columns (NaN where a run has none).

        df = qdrl.load_metrics("runs/map_elites_arm", "runs/cvt_map_elites_arm")
        df.groupby(["spec", "evaluations"]).qd_score.mean()
    """
    frames = []
    for path in find_runs(list(paths)):
        run = LoadedRun(path)
        frame = run.metrics.copy()
        for i, (key, value) in enumerate(_labels(run).items()):
            frame.insert(i, key, value)
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def load_repertoires(*paths: str | Path) -> pd.DataFrame:
    """The final repertoire (QD runs) or passive archive (RL, PBT and skill runs) of every
    run at or under `paths`, one row per elite: `spec`, `algorithm`, `task`, `seed`,
    `run`, then `cell`, `fitness`, `descriptor_*` and `centroid_*` (`LoadedRun.table`).

    Reads repertoire.csv / archive.csv; a run without one (interrupted) is read from
    its latest checkpoint.
    """
    frames = []
    for path in find_runs(list(paths)):
        run = LoadedRun(path)
        csv_path = next((path / n for n in ("repertoire.csv", "archive.csv") if (path / n).is_file()), None)
        frame = pd.read_csv(csv_path) if csv_path is not None else run.table
        for i, (key, value) in enumerate(_labels(run).items()):
            frame.insert(i, key, value)
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


class LoadedRun:
    """A run directory: `config` (dict), `metrics` (DataFrame), `summary` (dict, None if
    the run did not finish), and on demand its `repertoire`, `table`, elites and rollouts."""

    def __init__(self, path: Path) -> None:
        if not path.is_dir():
            raise RunError(f"{path}: no such directory; expected a run directory written by `qdrl run`")
        if not (path / "config.toml").is_file():
            raise RunError(
                f"{path} is not a qdrl run directory: expected config.toml (written by `qdrl run` "
                "when a run starts)"
            )
        try:
            self.config: dict[str, Any] = load_toml(path / "config.toml")
        except ConfigError as e:
            raise RunError(str(e)) from e
        experiment = self.config.get("experiment")
        if not isinstance(experiment, dict) or "algorithm" not in experiment:
            raise RunError(f"{path / 'config.toml'}: expected an [experiment] section with an algorithm")
        self.path = path
        self.algorithm = str(experiment["algorithm"])
        self.seed = int(experiment.get("seed", 0))
        metrics = path / "metrics.csv"
        has_rows = metrics.is_file() and metrics.stat().st_size > 0
        self.metrics: pd.DataFrame = pd.read_csv(metrics) if has_rows else pd.DataFrame()
        summary = path / "summary.json"
        self.summary: dict[str, Any] | None = json.loads(summary.read_text()) if summary.is_file() else None
        self._run: Any = None
        self._repertoire: Any = None
        self._state: Any = None  # the latest checkpoint's state
        self._rollouts: dict[Any, Callable[..., Any]] = {}
        self._evaluations: dict[Any, Any] = {}  # record -> the agent's evaluation (host arrays)

    def __repr__(self) -> str:
        state = "finished" if self.finished else "interrupted"
        return f"LoadedRun({str(self.path)!r}, {self.algorithm} on {self.task_name}, {state})"

    @property
    def finished(self) -> bool:
        """Whether the run wrote its summary (an interrupted run has none)."""
        return self.summary is not None

    @property
    def task_name(self) -> str:
        """The task (QD and skill runs) or environment (RL runs) of the run."""
        for section, key in (("task", "name"), ("env", "task"), ("env", "name")):
            table = self.config.get(section)
            if isinstance(table, dict) and key in table:
                return str(table[key])
        return "?"

    @property
    def name(self) -> str:
        """The experiment's name (`experiment.name`: the spec's file stem by default)."""
        experiment = self.config.get("experiment", {})
        return str(experiment.get("name") or self.path.name)

    @property
    def run(self) -> Algorithm:
        """The algorithm rebuilt from config.toml (`qdrl.algorithms.base.Algorithm`; nothing
        compiled). A CVT repertoire takes its cells from repertoire.npz when there is one."""
        if self._run is None:
            npz = self.path / "repertoire.npz"
            centroids = None
            if npz.is_file():
                with np.load(npz) as f:
                    centroids = f["centroids"] if "centroids" in f.files else None
            try:
                self._run = build_run(self.config, centroids=centroids)[0]
            except ConfigError as e:
                raise RunError(f"{self.path / 'config.toml'}: {e}") from e
        return self._run

    @property
    def is_qd(self) -> bool:
        """Whether the run is a QD run (its repertoire stores genotypes)."""
        return self.run.qd is not None

    @property
    def qd_task(self) -> Any:
        """The task of a QD run (`qdrl.tasks.Task`); RunError for other runs."""
        return self.require_qd("qd_task").task

    def require_qd(self, what: str) -> QDParts:
        """The rebuilt QD run's task and repertoire; RunError, saying `what` needed it, for other runs."""
        qd = self.run.qd
        if qd is None:
            raise RunError(f"{what}: expected a QD run whose repertoire stores genotypes; {self._no_genotype()}")
        return qd

    def _no_genotype(self) -> str:
        return (
            f"this {self.algorithm} run's passive archive stores no genotypes (only each cell's "
            "best episode return and descriptor)"
        )

    # -- the repertoire --

    @property
    def repertoire(self) -> CellRepertoire:
        """The final (or, for an interrupted run, the latest checkpointed) repertoire.

        QD runs: genotypes in the task's pytree structure, leaves (C, ...). RL, PBT and
        skill runs: their passive archive (genotypes None).
        """
        if self._repertoire is None:
            npz = self.path / "repertoire.npz"
            rep = None
            if self.is_qd and npz.is_file():
                rep = self._from_npz(npz)
            elif not self.is_qd and (self.path / "archive.npz").is_file():
                rep = self._archive_from_npz(self.path / "archive.npz")
            self._repertoire = jax.device_get(rep if rep is not None else self._from_checkpoint())
        return self._repertoire

    def _from_npz(self, path: Path) -> Any:
        """The repertoire of `repertoire.npz`, or None if the file holds no genotypes."""
        qd = self.require_qd("repertoire")
        with np.load(path) as f:
            arrays = {k: f[k] for k in f.files}
        if not {"centroids", "fitnesses", "descriptors"} <= set(arrays):
            raise RunError(f"{path}: expected the export of a cell repertoire (centroids, fitnesses, descriptors)")
        empty = qd.empty_repertoire(arrays["centroids"])
        named = jax.tree_util.tree_flatten_with_path(empty.genotypes)[0]
        names = ["genotypes" + jax.tree_util.keystr(p) for p, _ in named]
        if not all(n in arrays for n in names):
            return None  # an export without genotypes (ME-PBT before they were exported)
        rep = dataclasses.replace(
            empty,
            genotypes=jax.tree_util.tree_unflatten(
                jax.tree.structure(empty.genotypes), [arrays[n] for n in names]
            ),
            fitnesses=arrays["fitnesses"],
            descriptors=arrays["descriptors"],
        )
        shapes = [np.shape(x) for x in jax.tree.leaves(rep)]
        if shapes != [np.shape(x) for x in jax.tree.leaves(empty)] or not np.array_equal(
            np.asarray(empty.centroids), arrays["centroids"]
        ):
            raise RunError(f"{path}: expected the repertoire of the run in config.toml; its cells or shapes differ")
        return rep

    def _archive_from_npz(self, path: Path) -> Any:
        """The passive archive of an RL, PBT or skill run from its `archive.npz` (no genotypes)."""
        with np.load(path) as f:
            arrays = {k: f[k] for k in f.files}
        if not {"fitnesses", "descriptors", "grid_shape", "low", "high"} <= set(arrays):
            raise RunError(f"{path}: expected the export of a grid passive archive")
        empty = passive_archive(
            "grid", grid_shape=tuple(int(n) for n in arrays["grid_shape"]),
            low=tuple(float(v) for v in arrays["low"]), high=tuple(float(v) for v in arrays["high"]),
        )
        return dataclasses.replace(empty, fitnesses=arrays["fitnesses"], descriptors=arrays["descriptors"])

    def _checkpoint_state(self, missing: str) -> Any:
        """The run's state at its latest checkpoint (restored once); RunError saying `missing`
        (what the run lacks) when there is none."""
        if self._state is None:
            latest = checkpoint.latest(self.path / "checkpoints")
            if latest is None:
                raise RunError(f"{self.path} holds no {missing}")
            # The state's shapes and dtypes; nothing is evaluated or compiled.
            template = jax.eval_shape(self.run.init, jax.random.PRNGKey(self.seed))
            try:
                self._state, _ = checkpoint.restore(latest, template)
            except ValueError as e:
                raise RunError(f"{latest}: expected a checkpoint of the run in config.toml; {e}") from e
        return self._state

    def _from_checkpoint(self) -> Any:
        state = self._checkpoint_state(
            "repertoire yet: expected repertoire.npz (a finished run) or a checkpoint in "
            "checkpoints/ (an interrupted run)"
        )
        for name in ("repertoire", "archive"):
            if hasattr(state, name):
                return getattr(state, name)
        raise RunError(f"{self.path}: a {self.algorithm} state holds no repertoire or archive")

    @property
    def table(self) -> pd.DataFrame:
        """One row per elite: `cell`, `fitness`, `descriptor_*` and `centroid_*` (cell order),
        named as repertoire.csv / archive.csv name them."""

        names = self.run.qd.task.descriptor_names if self.run.qd is not None else ()
        return pd.DataFrame(to_table(self.repertoire, names))

    @property
    def num_cells(self) -> int:
        return int(np.shape(self.repertoire.fitnesses)[0])

    def elite(self, cell: int) -> Elite:
        """The elite of `cell`; RunError if the cell does not exist or holds none."""
        rep = self.repertoire
        fitnesses = np.asarray(rep.fitnesses)
        if not 0 <= cell < len(fitnesses):
            raise RunError(f"cell {cell}: expected a cell in [0, {len(fitnesses)}) of the repertoire")
        if not fitnesses[cell] > -np.inf:
            filled = np.flatnonzero(fitnesses > -np.inf)
            some = ", ".join(str(c) for c in filled[:8]) + (", ..." if len(filled) > 8 else "")
            raise RunError(
                f"cell {cell} holds no elite; expected one of the {len(filled)} filled cells"
                + (f" ({some})" if len(filled) else "")
            )
        genotype = None if rep.genotypes is None else jax.tree.map(lambda x: np.asarray(x)[cell], rep.genotypes)
        return Elite(
            cell=int(cell),
            fitness=float(fitnesses[cell]),
            descriptor=np.asarray(rep.descriptors)[cell],
            stored_genotype=genotype,
            no_genotype="" if genotype is not None else self._no_genotype(),
        )

    def best(self) -> Elite:
        """The elite of highest fitness (the lowest cell among ties)."""
        fitnesses = np.asarray(self.repertoire.fitnesses)
        if not np.any(fitnesses > -np.inf):
            raise RunError(f"{self.path}: the repertoire holds no elite")
        return self.elite(int(np.argmax(fitnesses)))

    # -- replaying and re-scoring elites --

    def compiling(self) -> AbstractContextManager[str | None]:
        """The context the run's rollouts compile in: jax's persistent compilation cache, on
        unless the run's `log.compile_cache` (or `QDRL_COMPILE_CACHE=0`) turns it off."""
        log = self.config.get("log", {})
        return compile_cache.enabled(bool(log.get("compile_cache", True)) if isinstance(log, dict) else True)

    def rollout(
        self, elite: Elite | None = None, record: Callable[[Any], Any] | None = None, *, skill: int | None = None
    ) -> Trajectory:
        """An elite's episode (QD runs), or an episode of the trained agent (`skill` z of a
        skill-discovery run; the one policy of a SAC or TD3 run, without `skill`).

        An elite is rolled out by the task's own scoring function, with the same start
        state and evaluation block width (`eval_batch`) as during the run, so `return_`
        and `descriptor` equal the stored fitness and descriptor bit for bit. An agent's
        episode is the one the run's evaluation after its latest checkpoint played for
        that skill: episode z of that evaluation (episode 0 without skills), played
        with the same keys and batch width, so `return_` is skills.csv's return of
        episode z at that log point. `record` (a function of the batched env state
        after each step, as in `qdrl.rollout.unroll_recorded`) fills `states`; brax
        tasks keep the link poses by default (`brax_link_poses`), enough to render.
        """
        if elite is not None:
            if skill is not None:
                raise RunError("rollout: expected an elite or a skill, not both")
            return self._rollout_elite(elite, record)
        if self.is_qd:
            raise RunError("rollout: expected an elite of this QD run (run.best() or run.elite(cell))")
        parts = self.require_agent("rollout")
        episode = self._skill(parts, skill) or 0  # episode z plays skill z
        if record is None and hasattr(parts.env, "brax_env"):
            record = brax_link_poses
        ep, descriptors = self._evaluation(parts, record)
        tr, mask = ep.transitions, np.asarray(ep.mask)[:, episode]
        return Trajectory(
            observations=np.asarray(tr.obs)[:, episode],
            actions=np.asarray(tr.action)[:, episode],
            rewards=np.asarray(tr.reward)[:, episode],
            state_descriptors=np.concatenate([np.asarray(tr.desc)[:1, episode], np.asarray(tr.next_desc)[:, episode]]),
            mask=mask,
            length=int(np.asarray(ep.lengths)[episode]),
            return_=float(np.asarray(ep.returns)[episode]),
            descriptor=np.asarray(descriptors)[episode],
            states=jax.tree.map(lambda x: np.asarray(x)[:, episode], ep.recorded),
        )

    def _rollout_elite(self, elite: Elite, record: Callable[[Any], Any] | None) -> Trajectory:
        qd = self.require_qd("rollout")
        task = qd.task
        if task.env is None or task.policy_scoring is None:
            raise RunError(
                f"rollout: expected a run of a policy task (brax tasks, point_maze), got task {task.name!r}"
            )
        genotype = elite.genotype
        if record is None and hasattr(task.env, "brax_env"):
            record = brax_link_poses
        if record not in self._rollouts:
            self._rollouts[record] = jax.jit(qd.scoring(fixed_start=True, record=record))
        batch = jax.tree.map(lambda x: np.asarray(x)[None], genotype)
        with self.compiling():
            ev = jax.device_get(self._rollouts[record](batch, jax.random.PRNGKey(0)))
        tr, mask = ev.extras["transitions"], np.asarray(ev.extras["mask"])[:, 0]
        first = jax.tree.map(lambda x: np.asarray(x)[:, 0], ev.extras.get("recorded"))
        return Trajectory(
            observations=np.asarray(tr.obs)[:, 0],
            actions=np.asarray(tr.action)[:, 0],
            rewards=np.asarray(tr.reward)[:, 0],
            state_descriptors=np.concatenate([np.asarray(tr.desc)[:1, 0], np.asarray(tr.next_desc)[:, 0]]),
            mask=mask,
            length=int(mask.sum()),
            return_=float(ev.fitnesses[0]),
            descriptor=np.asarray(ev.descriptors)[0],
            states=first,
        )

    # -- the trained agent (SAC, TD3 and skill-discovery runs) --

    def require_agent(self, what: str) -> AgentParts:
        """The rebuilt run's agent parts; RunError, saying `what` needed them, for runs without one."""
        parts = self.run.agent
        if parts is None:
            raise RunError(
                f"{what}: expected a run that trains one agent (SAC, TD3, DIAYN, DADS, SMERL); this "
                f"{self.algorithm} run has none"
            )
        return parts

    @property
    def num_skills(self) -> int:
        """The skills the run's agent is conditioned on (0 for SAC and TD3); RunError without an agent."""
        return self.require_agent("num_skills").num_skills

    def agent(self) -> Any:
        """The trained agent's state (parameters, optimiser and skill-model states:
        `qdrl.agents.base.AgentState`) at the run's latest checkpoint; nothing is run or compiled."""
        parts = self.require_agent("agent")
        return parts.agent_state(self._checkpoint_state(
            "checkpoint: expected one in checkpoints/ (written at every log point) to load the agent from"
        ))

    def policy(self, skill: int | None = None) -> Callable[[Any], Any]:
        """The trained agent's deterministic policy of `skill` (a skill-discovery run's skill id;
        none for SAC and TD3): observations (..., obs_size) of the task's environment -> actions
        (..., action_size), the skill's one-hot appended as in training; jittable."""
        parts = self.require_agent("policy")
        act = parts.policy(self.agent(), self._skill(parts, skill))
        size = parts.env.observation_size

        def policy(obs: Any) -> Any:
            if np.shape(obs)[-1:] != (size,):
                raise RunError(f"policy: expected observations (..., {size}), got shape {tuple(np.shape(obs))}")
            return act(obs)

        return policy

    def _skill(self, parts: AgentParts, skill: Any) -> int | None:
        """`skill` as an int (None for an agent without skills); RunError for a bad one."""
        k = parts.num_skills
        if k == 0:
            if skill is not None:
                raise RunError(f"skill: expected none, this {self.algorithm} run's agent has no skills; got {skill!r}")
            return None
        if isinstance(skill, bool) or not isinstance(skill, int | np.integer) or not 0 <= skill < k:
            raise RunError(
                f"skill: expected an int in [0, {k}) ({parts.skills_are} of this {self.algorithm} run), got {skill!r}"
            )
        return int(skill)

    def _evaluation(self, parts: AgentParts, record: Callable[[Any], Any] | None) -> tuple[Any, Any]:
        """The episodes of the run's evaluation at its latest checkpoint (host arrays), computed once per `record`."""
        if record not in self._evaluations:
            state = self._checkpoint_state(
                "checkpoint: expected one in checkpoints/ (written at every log point) to load the agent from"
            )
            with self.compiling():
                self._evaluations[record] = jax.device_get(jax.jit(lambda s: parts.evaluation(s, record))(state))
        return self._evaluations[record]  # type: ignore[no-any-return]

    def reevaluate(self, samples: int, seed: int | None = None, write: bool = True) -> dict[str, Any]:
        """Corrected QD metrics from `samples` random-start re-scorings of every elite.

        See `qdrl.qd.reevaluate`. Keys come from `seed` (default: the run's seed), so
        the figures equal those of the run's `qd.reevaluate_samples` option for the
        same number of samples. With `write`, also writes `reevaluation.json`.
        """
        if samples < 1:
            raise RunError(f"samples: expected a positive integer, got {samples}")
        qd = self.require_qd("reevaluate")
        seed = self.seed if seed is None else seed
        report = parts_reevaluation(qd, self.repertoire, samples, seed, {"algorithm": self.algorithm, "task": qd.task.name})
        if write:
            write_reevaluation(report, self.path)
        return report
