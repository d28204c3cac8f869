"""The `qdrl` command: run experiment specs, list what exists, benchmark, replay and re-score runs."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import threading
import time
import traceback
from pathlib import Path

from qdrl import adapt, quiet, spec_schema, specs
from qdrl.config import ConfigError


def _report_crash(exc: BaseException, run_dir: Path | None, argv: list[str]) -> int:
    """Writes the traceback to `run_dir`/error.log (else a temporary file) and prints one line."""
    text = (
        f"=== {time.strftime('%Y-%m-%d %H:%M:%S')} qdrl {' '.join(argv)}\n"
        + "".join(traceback.format_exception(exc))
    )
    path = None
    if run_dir is not None and run_dir.is_dir():
        with contextlib.suppress(OSError), (run_dir / "error.log").open("a") as f:
            f.write(text)
            path = run_dir / "error.log"
    if path is None:
        fd, name = tempfile.mkstemp(prefix="qdrl-error-", suffix=".log")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        path = Path(name)
    lines = str(exc).strip().splitlines()
    what = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
    print(f"qdrl: error: {what} (full traceback in {path})", file=sys.stderr)
    return 1


def _interrupted() -> int:
    """Exit status 130 for Ctrl-C; at once if a worker thread still compiles or computes.

    Python's shutdown would stop that thread inside XLA, which aborts the process
    with a C++ error instead of exiting.
    """
    if any(t.name == "qdrl-worker" and t.is_alive() for t in threading.enumerate()):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    return 130


def _writing(out_dir: Path) -> None:
    print(f"qdrl: writing to {out_dir}", file=sys.stderr)


def _cmd_run(args: argparse.Namespace) -> int:
    if args.devices is not None:
        args.set = [*args.set, f"experiment.devices={args.devices}"]
    if args.time_limit is not None:
        args.set = [*args.set, f"experiment.time_limit_s={args.time_limit}"]
    try:  # keys, types, ranges and names, before jax is imported (qdrl.spec_schema); a program
        # that imported the table itself (to register algorithms) gets the full check at once
        spec = specs.load_spec(args.spec, args.set)
        if "qdrl.algorithms" not in sys.modules:
            spec_schema.precheck(spec)
    except ConfigError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    from qdrl import checkpoint, experiment, placement, sweeps  # jax and the algorithms: seconds

    out_dir = Path(args.out) if args.out else experiment.default_out_dir(args.spec)
    resume = experiment.resume_command(args.spec, args.set, out_dir, args.seeds)
    try:
        if args.distributed or any(v is not None for v in (args.coordinator, args.num_processes, args.process_id)):
            placement.initialize_distributed(args.coordinator, args.num_processes, args.process_id)
        specs.resolve(args.spec)
        seeds = sweeps.parse_seeds(args.seeds) if args.seeds is not None else None
        # Libraries print notices on stdout (mujoco-mjx: "Failed to import warp");
        # stdout carries only the JSON summary (with --check: the resolved spec).
        with contextlib.redirect_stdout(sys.stderr):
            if args.check:
                resolved = experiment.check_spec_file(args.spec, args.set)
            elif seeds is not None:
                summary = sweeps.run_seeds(
                    args.spec, seeds, args.set, out_dir, args.resume, args.overwrite, on_start=_writing
                )
            else:
                summary = experiment.run_spec(args.spec, args.set, out_dir, args.resume, args.overwrite, on_start=_writing)
    except ConfigError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    except experiment.RunInterrupted as e:
        print(f"qdrl: {e}", file=sys.stderr)
        if e.checkpoint is not None:
            print(f"qdrl: resume with: {resume}", file=sys.stderr)
        return _interrupted()
    except KeyboardInterrupt:
        newest = checkpoint.latest(out_dir / "checkpoints") if args.seeds is None else None
        if newest is None:
            print("qdrl: aborted; no checkpoint was saved", file=sys.stderr)
        else:
            print(f"qdrl: aborted; {newest} is the newest checkpoint", file=sys.stderr)
            print(f"qdrl: resume with: {resume}", file=sys.stderr)
        return _interrupted()
    except Exception as e:  # anything else: one line here, the traceback in a file
        return _report_crash(e, out_dir, args.argv)
    print(resolved if args.check else json.dumps(summary, indent=2))
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    with contextlib.redirect_stdout(sys.stderr):  # brax and mujoco-mjx print import notices
        from qdrl import catalogue
    print(catalogue.listing())
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from qdrl import bench

    try:
        with contextlib.redirect_stdout(sys.stderr):  # stdout carries only the JSON
            results = bench.run_bench(args.name, quick=args.quick, out=args.out, seed=args.seed, config=args.config)
    except ValueError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(results, indent=2))
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from qdrl import render, runs

    try:
        with contextlib.redirect_stdout(sys.stderr):  # stdout carries only the JSON
            result = render.render(runs.load_run(args.dir), args.cell, args.out, args.skill, offline=not args.cdn)
    except runs.RunError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0


def _cmd_reevaluate(args: argparse.Namespace) -> int:
    if args.samples < 1:
        print(f"qdrl: error: --samples: expected a positive integer, got {args.samples}", file=sys.stderr)
        return 2
    from qdrl import runs

    try:
        with contextlib.redirect_stdout(sys.stderr):  # stdout carries only the JSON
            report = runs.load_run(args.dir).reevaluate(args.samples, args.seed)
    except runs.RunError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(report, indent=2))
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    if not 0.0 < args.confidence < 1.0:
        print(f"qdrl: error: --confidence: expected a number in (0, 1), got {args.confidence}", file=sys.stderr)
        return 2
    from qdrl import report, runs

    try:
        result = report.report(args.dirs, args.out, confidence=args.confidence)
    except runs.RunError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0


def _cmd_suite(args: argparse.Namespace) -> int:
    from qdrl import experiment, suites  # jax and the algorithms: the specs are checked in full

    try:
        with contextlib.redirect_stdout(sys.stderr):
            suite = suites.load_suite(args.file, args.out)
    except ConfigError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    if args.action == "status":
        status = suites.suite_status(suite)
        for r in status["runs"]:
            done = "" if r["status"] == "not started" else (
                f" ({int(r.get('env_steps') or 0):,} env steps, {float(r.get('wall_s') or 0.0):.0f} s)"
            )
            print(f"{r['status']:>11}  {r['task']:<16} {r['algorithm']:<14} seed {r['seed']}{done}")
        c = status["counts"]
        print(f"{c['done']} done, {c['partial']} partial, {c['not started']} not started; in {suite.out}")
        return 0
    try:
        with contextlib.redirect_stdout(sys.stderr):
            status = suites.run_suite(suite, on_start=_writing)
    except ConfigError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    except experiment.RunInterrupted as e:
        print(f"qdrl: {e}", file=sys.stderr)
        print(f"qdrl: resume with: qdrl suite run {args.file}" + (f" --out {args.out}" if args.out else ""), file=sys.stderr)
        return _interrupted()
    except Exception as e:
        return _report_crash(e, suite.out, args.argv)
    print(json.dumps(status, indent=2))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `qdrl` console script."""
    quiet()  # dependencies' import notices and MUJOCO_LOG.TXT (qdrl/_quiet.py)
    parser = argparse.ArgumentParser(prog="qdrl", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p_run = sub.add_parser("run", help="run an experiment spec (TOML)")
    p_run.add_argument(
        "spec", help="a packaged spec's name (e.g. default; `qdrl list` shows them) or a path to a spec"
    )
    p_run.add_argument(
        "--seeds", default=None, metavar="SEEDS",
        help='run every seed of SEEDS ("0-4" or "0,3,7"), one after the other, into OUT/seed_<n>/; '
        "with --resume, finished seeds are skipped and interrupted ones resume",
    )
    p_run.add_argument(
        "--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
        help="override one spec value (repeatable); VALUE is read as TOML",
    )
    p_run.add_argument("--out", default=None, help="output directory (default: runs/<spec name>)")
    p_run.add_argument(
        "--resume", action="store_true",
        help="continue from the newest usable checkpoint; with a larger qd.num_iterations or "
        "train.total_env_steps (--set), extend a finished run",
    )
    p_run.add_argument("--overwrite", action="store_true", help="discard an existing run in --out")
    p_run.add_argument(
        "--check", action="store_true",
        help="check the spec and build its run without compiling or running it; "
        "print the resolved spec (every default filled in) as TOML",
    )
    p_run.add_argument(
        "--time-limit", type=float, default=None, metavar="SECONDS",
        help="stop at the first log point past SECONDS of wall time (experiment.time_limit_s), "
        "with a checkpoint and a summary; --resume with a larger limit continues",
    )
    p_run.add_argument(
        "--devices", type=int, default=None, metavar="N",
        help="devices to spread the batch over (experiment.devices; default: the spec's, 0 = all visible)",
    )
    p_run.add_argument(
        "--distributed", action="store_true",
        help="one process of a multi-host run (jax.distributed): the coordinator, process count "
        "and id come from the flags below, JAX_COORDINATOR_ADDRESS / JAX_NUM_PROCESSES / "
        "JAX_PROCESS_ID, or the cluster (Slurm, Open MPI); process 0 writes the run directory",
    )
    p_run.add_argument("--coordinator", default=None, metavar="HOST:PORT", help="process 0's address (implies --distributed)")
    p_run.add_argument("--num-processes", type=int, default=None, metavar="N", help="processes in the run (implies --distributed)")
    p_run.add_argument("--process-id", type=int, default=None, metavar="I", help="this process's index, 0 to N-1 (implies --distributed)")
    p_run.set_defaults(fn=_cmd_run)

    p_suite = sub.add_parser(
        "suite",
        help="run a suite file (specs x tasks x seeds under one budget; resumable) or say what of it is done",
    )
    p_suite.add_argument("action", choices=("run", "status"), help="run what is not done, or list each run's status")
    p_suite.add_argument("file", help="a suite file, or a packaged suite's name (qdrl list shows them: seed_benchmark, metra_cpu, qdac_cpu, ...)")
    p_suite.add_argument("--out", default=None, help="output directory (default: runs/<suite name>)")
    p_suite.set_defaults(fn=_cmd_suite)

    adapt.add_parser(sub)  # qdrl/adapt.py: its checks answer before jax is imported

    p_list = sub.add_parser("list", help="list specs, algorithms and tasks")
    p_list.set_defaults(fn=_cmd_list)

    p_bench = sub.add_parser("bench", help="throughput benchmarks; prints JSON")
    p_bench.add_argument("name", nargs="?", default="rl", help="which benchmark: rl, skills, pbt, map_elites, policy_map_elites, tasks, cli (start-up), scaling (1 vs N devices; --config N)")
    p_bench.add_argument("--quick", action="store_true", help="a small, fast version")
    p_bench.add_argument("--out", default=None, help="also write the JSON to this file")
    p_bench.add_argument("--seed", type=int, default=0, help="random seed")
    p_bench.add_argument(
        "--config", default=None,
        help="only one case: rl -> sac|td3; map_elites -> cvt1024|grid32|grid100; tasks -> a task name",
    )
    p_bench.set_defaults(fn=_cmd_bench)

    p_render = sub.add_parser(
        "render",
        help="replay an elite (QD runs) or a skill (skill-discovery runs): HTML viewer or GIF (brax) or PNG of the path (mazes)",
    )
    p_render.add_argument("dir", help="a run directory written by `qdrl run`")
    p_render.add_argument("--cell", type=int, default=None, help="QD runs: the elite's cell (default: the best)")
    p_render.add_argument(
        "--skill", type=int, default=None, metavar="Z",
        help="skill-discovery runs: the skill to replay (default: every skill's path on one PNG, skill 0 in HTML)",
    )
    p_render.add_argument(
        "--out", default=None,
        help="output file: .html, .gif (brax tasks: a GIF video, needs a headless EGL context) or .png (mazes) "
        "(default: DIR/plots/replay_cell<N>|replay_skill<Z>|replay_skills.html|png)",
    )
    p_render.add_argument(
        "--cdn", action="store_true",
        help="HTML: brax's viewer page, which loads its scripts from CDNs (default: a self-contained page that works offline)",
    )
    p_render.set_defaults(fn=_cmd_render)

    p_report = sub.add_parser(
        "report",
        help="compare runs and sweeps: mean and bootstrap band per metric, final-value table, heatmaps",
    )
    p_report.add_argument("dirs", nargs="+", metavar="DIR", help="run directories, sweeps or folders of runs")
    p_report.add_argument("--out", default="report", help="output directory (default: report)")
    p_report.add_argument(
        "--confidence", type=float, default=0.95, help="confidence level of the bands (default: 0.95)"
    )
    p_report.set_defaults(fn=_cmd_report)

    p_reeval = sub.add_parser(
        "reevaluate",
        help="re-score every elite N times from random start states; corrected QD metrics as JSON",
    )
    p_reeval.add_argument("dir", help="a QD run directory written by `qdrl run`")
    p_reeval.add_argument("--samples", type=int, required=True, metavar="N", help="evaluations per elite")
    p_reeval.add_argument("--seed", type=int, default=None, help="seeds the re-evaluations (default: the run's)")
    p_reeval.set_defaults(fn=_cmd_reevaluate)

    args = parser.parse_args(argv)
    args.argv = sys.argv[1:] if argv is None else argv
    try:
        return int(args.fn(args))
    except KeyboardInterrupt:
        print("qdrl: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # one line on the terminal, the traceback in a file
        return _report_crash(e, None, args.argv)


if __name__ == "__main__":
    sys.exit(main())
