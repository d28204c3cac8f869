"""The `qdrl` command: run experiment specs, list what exists, benchmark."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
from pathlib import Path


def _spec_dirs() -> list[Path]:
    here = Path.cwd() / "agents"
    repo = Path(__file__).resolve().parents[1] / "agents"
    return [d for d in dict.fromkeys([here, repo]) if d.is_dir()]


def _cmd_run(args: argparse.Namespace) -> int:
    from qdrl.config import ConfigError
    from qdrl.experiment import run_spec

    try:
        # Libraries print notices on stdout (mujoco-mjx: "Failed to import warp");
        # stdout carries only the JSON summary.
        with contextlib.redirect_stdout(sys.stderr):
            summary = run_spec(args.spec, args.set, args.out, args.resume, args.overwrite)
    except ConfigError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    with contextlib.redirect_stdout(sys.stderr):  # mujoco-mjx prints import notices
        import brax.envs  # noqa: F401
    from qdrl.envs import PURE_JAX_ENVS
    from qdrl.envs.brax import BACKENDS, brax_env_names
    from qdrl.experiment import RUNS, _load_builtin_runs

    _load_builtin_runs()
    print("specs:")
    for d in _spec_dirs():
        for p in sorted(d.glob("*.toml")):
            print(f"  {os.path.relpath(p)}")
    print("algorithms:")
    for name in sorted(RUNS):
        print(f"  {name}")
    print("tasks:")
    from qdrl.tasks import TASKS

    print(f"  QD tasks (the [task] section of QD specs): {', '.join(sorted(TASKS))}")
    print(f"  pure-JAX environments: {', '.join(PURE_JAX_ENVS)}")
    print(f"  brax environments ({', '.join(BACKENDS)} backends): {', '.join(brax_env_names())}")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from qdrl.bench import run_bench

    try:
        with contextlib.redirect_stdout(sys.stderr):  # stdout carries only the JSON
            results = run_bench(args.name, quick=args.quick, out=args.out, seed=args.seed, config=args.config)
    except ValueError as e:
        print(f"qdrl: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(results, indent=2))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `qdrl` console script."""
    from qdrl import quiet

    quiet()  # dependencies' import notices and MUJOCO_LOG.TXT (qdrl/_quiet.py)
    parser = argparse.ArgumentParser(prog="qdrl", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p_run = sub.add_parser("run", help="run an experiment spec (TOML)")
    p_run.add_argument("spec", help="path to a spec, e.g. agents/default.toml")
    p_run.add_argument(
        "--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
        help="override one spec value (repeatable); VALUE is read as TOML",
    )
    p_run.add_argument("--out", default=None, help="output directory (default: runs/<spec name>)")
    p_run.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    p_run.add_argument("--overwrite", action="store_true", help="discard an existing run in --out")
    p_run.set_defaults(fn=_cmd_run)

    p_list = sub.add_parser("list", help="list specs, algorithms and tasks")
    p_list.set_defaults(fn=_cmd_list)

    p_bench = sub.add_parser("bench", help="throughput benchmarks; prints JSON")
    p_bench.add_argument("name", nargs="?", default="rl", help="which benchmark: rl, map_elites, tasks")
    p_bench.add_argument("--quick", action="store_true", help="a small, fast version")
    p_bench.add_argument("--out", default=None, help="also write the JSON to this file")
    p_bench.add_argument("--seed", type=int, default=0, help="random seed")
    p_bench.add_argument(
        "--config", default=None,
        help="only one case: rl -> sac|td3; map_elites -> cvt1024|grid32|grid100; tasks -> a task name",
    )
    p_bench.set_defaults(fn=_cmd_bench)

    args = parser.parse_args(argv)
    return int(args.fn(args))


if __name__ == "__main__":
    sys.exit(main())
