"""Adaptation to perturbed dynamics: every elite of a repertoire, or every skill of an agent,
replayed under scaled gravity or weakened actuators; the best of them is the few-shot answer.

Chalumeau, Boige, Lim, Macé, Allard, Flajolet, Cully & Pierrot 2023, "Neuroevolution is a
competitive alternative to reinforcement learning for skill discovery" (ICLR), its
adaptation experiments and the perturbation sets of its code (instadeepai/qd-skill-discovery-benchmark,
`qdbenchmark/adaptation/constants.py`): a repertoire (or a set of skills) adapts to a
changed environment by trying each of its policies once and keeping the best, so the
measure of adaptation is the best return among the policies under each perturbation.

    qdrl adapt runs/map_elites_halfcheetah_uni            # every set the task has
    qdrl adapt runs/diayn_halfcheetah_uni --perturbations gravity,actuator:fthigh

Perturbations (`PERTURBATIONS`), per task:

- `gravity`: gravity multiplied by 0.25 (i + 1), i = 0..19 (ant_uni, halfcheetah_uni, walker2d_uni);
- `actuator:<joint>`: the strength (brax's `actuator.gear`) of the actuator of one joint
  multiplied by 0.25 i, i = 0..19, one joint at a time: walker2d_uni's left leg
  (thigh_left_joint, leg_left_joint, foot_left_joint), halfcheetah_uni's front leg
  (fthigh, fshin, ffoot), ant_uni's 4th leg (hip_4, ankle_4);
- `actuator:leg`: those joints of the task all at once, as the study's code applies them
  (`qd_adaptation.py` wraps the environment with every joint of `ACTUATOR_UPDATES[task]`
  at each index).

The study ran brax v1; brax v2's ant (`brax/envs/assets/ant.xml`) names the joints of
its 4th leg (the body `aux_4` at (0.2, -0.2) from the torso, where v1's joint
"$ Torso_Aux 4" attaches "Aux 4") hip_4 and ankle_4 (`BRAX_V1_JOINTS`); both keep v1's
strength, 150.

Every policy plays one deterministic episode from the task's start state (the state
its fixed-start scoring resets to, `qdrl.rollout.fixed_start_state` with key 0) under
each perturbation value, through the one rollout loop (`qdrl.rollout.run_episodes`). The
values are parameters, not constants: one jitted program plays every value of every set
(`qdrl.envs.brax.BraxEnv.perturbed` builds the environment from the traced scales), a
block of policies at a time, by default the blocks of the run's own evaluation and one
value a call, so that multiplier 1 gives each elite its stored fitness bit for bit
(`evaluate`; `batch_size` vmaps blocks of values too). The study plays from random starts
(`num_init_state` of them); here the start is the task's one fixed start, as its scoring's.

Outputs, in DIR/adaptation/ (or `--out`): `adaptation.csv` (one row per perturbation
value: best, median and mean return over the policies), `adaptation.png` (best return
against the multiplier, one panel per kind, one line per joint) and `adaptation.json`
(the same numbers, with the unperturbed returns).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import json
import math
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from qdrl import plotting
from qdrl.config import ConfigError, load_toml

# qdrl.tasks.policy.DEFAULT_EVAL_BATCH (that module imports jax): a spec without task.eval_batch.
DEFAULT_EVAL_BATCH = 64

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "ACTUATOR_JOINTS",
    "ACTUATOR_MULTIPLIERS",
    "BRAX_V1_JOINTS",
    "GRAVITY_MULTIPLIERS",
    "PERTURBATIONS",
    "Adaptation",
    "Perturbation",
    "PerturbationSet",
    "Plan",
    "Row",
    "adapt",
    "add_parser",
    "check_run",
    "command",
    "evaluate",
    "perturbation_names",
    "perturbations_of",
    "report",
    "write",
]

# The study's multipliers (qdbenchmark/adaptation/constants.py).
GRAVITY_MULTIPLIERS: tuple[float, ...] = tuple(0.25 * (i + 1) for i in range(20))
ACTUATOR_MULTIPLIERS: tuple[float, ...] = tuple(0.25 * i for i in range(20))

# The joints whose actuators the study weakens, by their names in brax v2's MJCF files.
ACTUATOR_JOINTS: dict[str, tuple[str, ...]] = {
    "walker2d_uni": ("thigh_left_joint", "leg_left_joint", "foot_left_joint"),
    "halfcheetah_uni": ("fthigh", "fshin", "ffoot"),
    "ant_uni": ("hip_4", "ankle_4"),
}
# The study's names of joints (brax v1) that brax v2 names otherwise; the others are kept.
BRAX_V1_JOINTS: dict[str, dict[str, str]] = {
    "ant_uni": {"hip_4": "$ Torso_Aux 4", "ankle_4": "Aux 4_$ Body 13"},
}


class PerturbationSet(NamedTuple):
    """One perturbation kind on one task: its multipliers, and the joints it may weaken."""

    values: tuple[float, ...]
    joints: tuple[str, ...] = ()  # actuator sets: the joints, one at a time or all ("leg")


# kind -> task -> its set (the study's table).
PERTURBATIONS: dict[str, dict[str, PerturbationSet]] = {
    "gravity": {task: PerturbationSet(GRAVITY_MULTIPLIERS) for task in ACTUATOR_JOINTS},
    "actuator": {task: PerturbationSet(ACTUATOR_MULTIPLIERS, joints) for task, joints in ACTUATOR_JOINTS.items()},
}
ALL_JOINTS = "leg"  # `actuator:leg`: every joint of the task's set at once (the study's code)


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """One perturbation set: its name ("gravity", "actuator:fthigh", "actuator:leg"), its kind,
    the joints whose actuators it scales (none for gravity) and its multipliers."""

    name: str
    kind: str  # a key of PERTURBATIONS
    values: tuple[float, ...]
    joints: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        """Its line's label on the plot."""
        if self.kind == "gravity":
            return "gravity"
        return f"{ALL_JOINTS} ({', '.join(self.joints)})" if self.name.endswith(f":{ALL_JOINTS}") else self.joints[0]


def perturbation_names(task: str) -> list[str]:
    """Every perturbation set `task` supports, by name, in the table's order."""
    names = []
    for kind, tasks in PERTURBATIONS.items():
        if task not in tasks:
            continue
        joints = tasks[task].joints
        names += [*(f"{kind}:{j}" for j in joints), f"{kind}:{ALL_JOINTS}"] if joints else [kind]
    return names


def perturbations_of(task: str, names: Sequence[str] | None = None) -> tuple[Perturbation, ...]:
    """The perturbation sets `names` of `task` (default: every one it supports); a kind alone
    ("actuator") means each of its sets. ConfigError naming what was expected for an unknown
    task or name."""
    supported = perturbation_names(task)
    if not supported:
        tasks = sorted({t for sets in PERTURBATIONS.values() for t in sets})
        raise ConfigError(f"adapt: expected a run on a task of the adaptation study ({', '.join(tasks)}), got {task!r}")
    if names is not None and not names:
        raise ConfigError(f"--perturbations: expected at least one name, from {', '.join(supported)}")
    chosen: list[str] = []
    for name in supported if names is None else names:
        name = name.strip()
        matches = [n for n in supported if n == name or n.split(":")[0] == name]
        if not matches:
            raise ConfigError(
                f"--perturbations: expected names from {', '.join(supported)} (or a kind alone: "
                f"{', '.join(dict.fromkeys(n.split(':')[0] for n in supported))}) for task {task!r}, got {name!r}"
            )
        chosen += [m for m in matches if m not in chosen]
    out = []
    for name in chosen:
        kind, _, joint = name.partition(":")
        table = PERTURBATIONS[kind][task]
        joints = table.joints if joint == ALL_JOINTS else (joint,) if joint else ()
        out.append(Perturbation(name, kind, table.values, joints))
    return tuple(out)


@dataclasses.dataclass(frozen=True)
class Plan:
    """What `check_run` read of a run directory without jax: what `evaluate` will play."""

    path: Path
    algorithm: str
    task: str
    policies: str  # "elites" (a QD run's repertoire) or "skills" (a skill-discovery agent's)
    episode_length: int
    perturbations: tuple[Perturbation, ...]
    eval_batch: int | None = None  # QD runs: the width of the task's evaluation blocks (`task.eval_batch`)
    best: int | None = None  # QD runs: only the `best` fittest elites (None: every elite, the study's measure)


def check_run(
    path: str | Path, perturbations: Sequence[str] | None = None, episode_length: int | None = None,
    best: int | None = None,
) -> Plan:
    """The plan of adapting the run in `path`, from its config.toml and summary.json only (no
    jax, nothing compiled); ConfigError saying what was expected for a directory without a run,
    a run not on a task of the study, an unknown perturbation, a finished QD run without elites
    or a bad episode length."""
    path = Path(path)
    if not (path / "config.toml").is_file():
        inside = sorted(p.parent for p in path.rglob("config.toml")) if path.is_dir() else []
        if inside:
            raise ConfigError(f"{path} holds {len(inside)} runs, not one: expected a run directory (e.g. {inside[0]})")
        raise ConfigError(f"{path} holds no run: expected a run directory written by `qdrl run` (with config.toml)")
    config = load_toml(path / "config.toml")
    algorithm = str(config.get("experiment", {}).get("algorithm", "?"))
    task_section, env_section = config.get("task"), config.get("env")
    if isinstance(task_section, dict) and "name" in task_section:
        policies, section = "elites", task_section
        task = str(task_section["name"])
    elif isinstance(env_section, dict) and "task" in env_section:
        policies, section = "skills", env_section
        task = str(env_section["task"])
    else:
        raise ConfigError(
            f"{path}: expected a QD run (a [task] section) or a skill-discovery run (an [env] task); "
            f"this {algorithm} run has neither"
        )
    chosen = perturbations_of(task, perturbations)
    length = int(section.get("episode_length", 1000)) if episode_length is None else episode_length
    if isinstance(length, bool) or not isinstance(length, int) or length < 1:
        raise ConfigError(f"--episode-length: expected a positive integer, got {length!r}")
    summary = path / "summary.json"
    if policies == "elites" and summary.is_file() and json.loads(summary.read_text()).get("num_elites") == 0:
        raise ConfigError(f"{path}: expected a repertoire with elites; this {algorithm} run's holds none")
    eval_batch = int(section.get("eval_batch", DEFAULT_EVAL_BATCH)) if policies == "elites" else None
    if best is not None and (isinstance(best, bool) or not isinstance(best, int) or best < 1):
        raise ConfigError(f"--best: expected a positive integer (the number of elites), got {best!r}")
    return Plan(path, algorithm, task, policies, length, chosen, eval_batch, best if policies == "elites" else None)


class Row(NamedTuple):
    """One row of adaptation.csv: the returns of every policy under one perturbation value."""

    perturbation: str
    value: float
    best_return: float
    median_return: float
    mean_return: float
    num_policies: int


@dataclasses.dataclass(frozen=True)
class Adaptation:
    """Every policy's return under every perturbation value, and their summary rows."""

    plan: Plan
    policy_ids: tuple[int, ...]  # the cell of each elite, or each skill
    unperturbed: np.ndarray  # (P,) each policy's return on the task itself
    returns: dict[str, np.ndarray]  # perturbation name -> (num_values, P)
    actuators: dict[str, int]  # joint -> the index of its actuator
    rows: tuple[Row, ...]  # one per perturbation value, in the order of `plan.perturbations`
    unperturbed_row: Row
    programs: int  # programs the evaluation traced and compiled: 1, shared by every value and block


def evaluate(plan: Plan, batch_size: int | None = None) -> Adaptation:
    """Every elite (or skill) of the planned run, one deterministic episode from the task's start
    state under each perturbation value and unperturbed; one compiled program for all.

    The values (one unperturbed row, then each set's) and the policies are played in blocks
    of one shape, padded, so the program compiles once whatever the number of either: by
    default the policies in blocks of the task's `eval_batch` (a QD run's evaluation blocks;
    a skill run's K skills together), one value after another, so that under multiplier 1
    every elite's return is its stored fitness bit for bit. With `batch_size`, blocks of at
    most that many episodes, a block of values vmapped over a block of policies: fewer,
    larger calls for an accelerator, but brax's numerics depend on the batch's shape and
    the robots' contacts are chaotic, so multiplier 1 then gives other returns than the
    run's (20 steps of halfcheetah turn a last-bit difference into whole units).
    ConfigError (before anything compiles) when the run cannot be loaded or has nothing to play.
    """
    # Imported here: `qdrl adapt`'s checks (check_run) answer before jax loads.
    import jax
    import numpy as np

    from qdrl import rollout, runs

    if batch_size is not None and batch_size < 1:
        raise ConfigError(f"--batch-size: expected a positive integer, got {batch_size}")
    try:
        run = runs.load_run(plan.path)
        if plan.policies == "elites":
            task = run.require_qd("adapt").task
            rep = run.repertoire
            ids = np.flatnonzero(np.asarray(rep.fitnesses) > -np.inf)  # the cells of the elites
            if not len(ids):
                raise ConfigError(f"{plan.path}: expected a repertoire with elites; this {plan.algorithm} run's holds none")
            if plan.best is not None:  # the fittest, kept in cell order
                fitness = np.asarray(rep.fitnesses)[ids]
                ids = np.sort(ids[np.argsort(-fitness, kind="stable")[: plan.best]])
            template = None if task.policy is None else jax.tree.map(np.shape, task.genotype_template)
            if template is None or jax.tree.map(lambda x: np.shape(x)[1:], rep.genotypes) != template:
                raise ConfigError(
                    f"adapt: expected a QD run whose genotypes are its task's policy networks (map_elites, "
                    f"pga_me, ...); this {plan.algorithm} run's are not"
                )
            network = task.policy.network
            env, shared = task.env, None
            policies = jax.tree.map(lambda x: np.asarray(x)[ids], rep.genotypes)

            def act(shared: Any, params: Any, obs: Any) -> Any:
                return jax.vmap(network.apply)(params, obs)
        else:
            parts = run.require_agent("adapt")
            k = parts.num_skills
            if k < 1:
                raise ConfigError(f"adapt: expected a run of skills (skills.num_skills >= 1); this {plan.algorithm} run has none")
            env, shared = parts.env, run.agent()
            ids = policies = np.arange(k, dtype=np.int32)  # skill z plays skill z

            def act(shared: Any, params: Any, obs: Any) -> Any:
                branches = [parts.policy(shared, z) for z in range(k)]
                return jax.vmap(lambda z, o: jax.lax.switch(z, branches, o))(params, obs)
    except runs.RunError as e:
        raise ConfigError(str(e)) from e
    if not hasattr(env, "perturbed"):
        raise ConfigError(f"adapt: expected a run on a brax task, got {plan.task!r} ({type(env).__name__})")
    try:
        actuators = {j: env.actuator_index(j) for p in plan.perturbations for j in p.joints}
    except ValueError as e:
        raise ConfigError(f"adapt: {e}") from e

    # One row per value: (gravity scale, gear scale of every actuator); row 0 unperturbed.
    num_actuators = int(env.action_size)
    gravity, gear = [1.0], [np.ones(num_actuators, np.float32)]
    for p in plan.perturbations:
        for v in p.values:
            scales = np.ones(num_actuators, np.float32)
            scales[[actuators[j] for j in p.joints]] = v
            gravity.append(v if p.kind == "gravity" else 1.0)
            gear.append(scales)
    gravity_rows, gear_rows = np.asarray(gravity, np.float32), np.stack(gear)

    num_policies, num_rows = len(ids), len(gravity_rows)
    if batch_size is None:  # the run's own evaluation blocks, one value at a time
        width, depth = plan.eval_batch or num_policies, 1
    else:
        width = min(num_policies, batch_size)  # policies per block
        depth = max(1, min(num_rows, batch_size // width))  # values per block
    key = jax.random.PRNGKey(0)  # the task's fixed-start scoring's start; the policies draw nothing
    start = rollout.fixed_start_state(env, key)

    traces = [0]  # how many programs `block` became (one per shape of its arguments)

    def block(gravity_scale: Any, gear_scale: Any, params: Any, shared: Any) -> Any:
        """The returns (depth, width) of a block of policies under a block of values."""
        traces[0] += 1

        def under(g: Any, s: Any) -> Any:
            perturbed = env.perturbed(g, s, plan.episode_length)
            episodes = rollout.run_episodes(
                perturbed, lambda obs, _: act(shared, params, obs), key, width, plan.episode_length, start_state=start
            )
            return episodes.returns

        if depth == 1:  # one value a call: no vmap (half the trace, a smaller program; the same bits)
            return under(gravity_scale[0], gear_scale[0])[None]
        return jax.vmap(under)(gravity_scale, gear_scale)

    compiled = jax.jit(block)
    print(
        f"qdrl: adapt: {num_policies} {plan.policies} x {num_rows} dynamics of {plan.task}, "
        f"{plan.episode_length} steps, in blocks of {depth} x {width}",
        file=sys.stderr,
    )
    returns = np.empty((num_rows, num_policies), np.float32)
    with run.compiling():
        for p0 in range(0, num_policies, width):
            take = np.arange(p0, p0 + width) % num_policies  # the last block wraps round: dropped
            chunk = jax.tree.map(lambda x, take=take: np.asarray(x)[take], policies)
            for r0 in range(0, num_rows, depth):
                rows = np.arange(r0, r0 + depth) % num_rows
                out = np.asarray(jax.device_get(compiled(gravity_rows[rows], gear_rows[rows], chunk, shared)))
                kept_r, kept_p = min(depth, num_rows - r0), min(width, num_policies - p0)
                returns[r0 : r0 + kept_r, p0 : p0 + kept_p] = out[:kept_r, :kept_p]

    by_name: dict[str, Any] = {}
    table, r = [], 1
    for p in plan.perturbations:
        by_name[p.name] = returns[r : r + len(p.values)]
        table += [_row(p.name, v, list(ret)) for v, ret in zip(p.values, by_name[p.name], strict=True)]
        r += len(p.values)
    return Adaptation(
        plan=plan, policy_ids=tuple(int(i) for i in ids), unperturbed=returns[0], returns=by_name,
        actuators=actuators, rows=tuple(table), unperturbed_row=_row("none", 1.0, list(returns[0])),
        programs=traces[0],
    )


def _row(name: str, value: float, returns: Sequence[float]) -> Row:
    """The summary row of the returns of every policy under one value; NaN returns (rollouts
    that blew up) are left out of the statistics, which are NaN when every return is."""
    finite = [float(x) for x in returns if math.isfinite(x)]
    if not finite:
        return Row(name, float(value), math.nan, math.nan, math.nan, len(returns))
    return Row(name, float(value), max(finite), statistics.median(finite), statistics.fmean(finite), len(returns))


def _number(x: float) -> float | None:
    return x if math.isfinite(x) else None


def report(adaptation: Adaptation) -> dict[str, Any]:
    """adaptation.json's content: the run, the unperturbed returns and every set's rows."""
    plan = adaptation.plan
    u = adaptation.unperturbed_row
    sets = []
    for p in plan.perturbations:
        rows = [r for r in adaptation.rows if r.perturbation == p.name]
        v1 = BRAX_V1_JOINTS.get(plan.task, {})
        sets.append({
            "perturbation": p.name,
            "kind": p.kind,
            "joints": list(p.joints),
            "study_joints": [v1.get(j, j) for j in p.joints],
            "actuators": [adaptation.actuators[j] for j in p.joints],
            "values": [r.value for r in rows],
            **{key: [_number(getattr(r, key)) for r in rows] for key in ("best_return", "median_return", "mean_return")},
        })
    return {
        "run": str(plan.path),
        "algorithm": plan.algorithm,
        "task": plan.task,
        "policies": plan.policies,
        "num_policies": u.num_policies,
        "best_elites": plan.best,  # None: every elite
        "episode_length": plan.episode_length,
        "unperturbed": {key: _number(getattr(u, key)) for key in ("best_return", "median_return", "mean_return")},
        "perturbations": sets,
    }


def write(adaptation: Adaptation, out: str | Path) -> dict[str, Any]:
    """Writes adaptation.csv, adaptation.json and adaptation.png into `out`; returns the JSON
    content, with the paths written under "files"."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {name: out / f"adaptation.{name}" for name in ("csv", "json", "png")}
    with files["csv"].open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(Row._fields)
        writer.writerows(adaptation.rows)
    content = report(adaptation)
    files["json"].write_text(json.dumps(content, indent=2) + "\n")
    _plot(adaptation, files["png"])
    return {**content, "files": {k: str(v) for k, v in files.items()}}


_AXIS = {"gravity": "gravity multiplier", "actuator": "actuator strength multiplier"}


def _plot(adaptation: Adaptation, path: Path) -> None:
    """adaptation.png: best return against the multiplier, a panel per kind, a line per set."""
    plan = adaptation.plan
    kinds = list(dict.fromkeys(p.kind for p in plan.perturbations))
    fig = plotting._new_figure(len(kinds))
    axes = fig.subplots(1, len(kinds), squeeze=False)[0]
    for ax, kind in zip(axes, kinds, strict=True):
        for p in plan.perturbations:
            if p.kind == kind:
                rows = [r for r in adaptation.rows if r.perturbation == p.name]
                ax.plot([r.value for r in rows], [r.best_return for r in rows], marker="o", ms=3, label=p.label)
        ax.axhline(adaptation.unperturbed_row.best_return, ls="--", color="grey", lw=1, label="unperturbed")
        ax.set_xlabel(_AXIS[kind])
        ax.set_ylabel(f"best return of the {plan.policies}")
        ax.legend(fontsize="small")
    fig.suptitle(f"{plan.algorithm} on {plan.task}: {adaptation.unperturbed_row.num_policies} {plan.policies} adapting")
    fig.savefig(path, dpi=100)


def adapt(
    path: str | Path,
    perturbations: Sequence[str] | None = None,
    episode_length: int | None = None,
    out: str | Path | None = None,
    batch_size: int | None = None,
    best: int | None = None,
) -> dict[str, Any]:
    """`qdrl adapt`: checks the run (`check_run`), plays it under every perturbation value
    (`evaluate`) and writes the results into `out` (default: DIR/adaptation; `write`)."""
    plan = check_run(path, perturbations, episode_length, best)
    return write(evaluate(plan, batch_size), plan.path / "adaptation" if out is None else out)


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Registers `qdrl adapt` on the CLI's subcommands."""
    p = sub.add_parser(
        "adapt",
        help="replay every elite (QD runs) or skill (skill-discovery runs) under perturbed gravity and "
        "actuators (Chalumeau et al. 2023): best, median and mean return per perturbation value",
    )
    p.add_argument("dir", help="a run directory written by `qdrl run` (a brax task of the study)")
    p.add_argument(
        "--perturbations", default=None, metavar="NAMES",
        help="comma-separated sets: gravity, actuator:<joint>, actuator:leg, or a kind alone "
        "(default: every set the task supports)",
    )
    p.add_argument("--episode-length", type=int, default=None, help="steps per episode (default: the run's)")
    p.add_argument("--out", default=None, help="output directory (default: DIR/adaptation)")
    p.add_argument(
        "--best", type=int, default=None, metavar="N",
        help="QD runs: only the N fittest elites (a cheaper bound on a CPU; default: every elite, the study's measure)",
    )
    p.add_argument(
        "--batch-size", type=int, default=None, metavar="N",
        help="episodes rolled out together, values vmapped too (faster on accelerators; multiplier 1 "
        "then differs from the run's returns) (default: the run's evaluation blocks, one value at a time)",
    )
    p.set_defaults(fn=command)


def command(args: argparse.Namespace) -> int:
    """Runs `qdrl adapt` from its parsed arguments: 0 and the JSON on stdout, or 2 and one line
    `qdrl: error: ...` on stderr."""
    names = None if args.perturbations is None else [n for n in args.perturbations.split(",") if n.strip()]
    try:
        with contextlib.redirect_stdout(sys.stderr):  # stdout carries only the JSON
            result = adapt(args.dir, names, args.episode_length, args.out, args.batch_size, args.best)
    except ConfigError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0
