"""Runs on several devices give the metrics of one device (qdrl.placement).

Two CPU devices are forced with XLA_FLAGS in a subprocess (jax fixes its device
count at start-up), which runs every spec on 1 and on 2 devices one after the other.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

WORKER = Path(__file__).with_name("scale_worker.py")
ROOT = Path(__file__).resolve().parents[1]
NO_FILES = {"plots": False, "progress": False}

ARM = {
    "experiment": {"algorithm": "map_elites", "seed": 3},
    "task": {"name": "arm", "num_dofs": 8},
    "repertoire": {"kind": "grid", "grid_shape": [8, 8]},
    "emitter": {"kind": "isoline", "batch_size": 16},
    "qd": {"num_iterations": 6, "log_every": 3, "init_batch_size": 16},
    "log": NO_FILES,
}
PGA_ME = {
    "experiment": {"algorithm": "pga_me", "seed": 0},
    "task": {"name": "point_maze", "episode_length": 20, "policy_hidden": [8, 8]},
    "repertoire": {"kind": "cvt", "num_centroids": 32, "cvt_samples": 1000, "kmeans_iters": 5},
    "emitter": {"kind": "isoline", "batch_size": 8},
    "pg": {"num_critic_training_steps": 4, "num_pg_training_steps": 3, "training_batch_size": 16,
           "replay_buffer_size": 2000, "critic_hidden": [16, 16]},
    "qd": {"num_iterations": 4, "log_every": 2, "init_batch_size": 8},
    "log": NO_FILES,
}
_TRAIN = {"total_env_steps": 256, "num_envs": 4, "batch_size": 16, "buffer_size": 1000,
          "learning_starts": 32, "grad_steps_per_iter": 2, "eval_every": 128, "num_eval_envs": 4}
SAC = {
    "experiment": {"algorithm": "sac", "seed": 0},
    "env": {"name": "point", "episode_length": 20},
    "agent": {"hidden": [16, 16]},
    "train": _TRAIN,
    "log": NO_FILES,
}
PBT = {**SAC, "experiment": {"algorithm": "sac_pbt", "seed": 0},
       "pbt": {"population_size": 4, "num_replace": 1, "num_best": 1}}


def on_devices(spec: dict[str, Any], devices: int, **sections: dict[str, Any]) -> dict[str, Any]:
    """`spec` with `experiment.devices` set and sections updated."""
    new = {**spec, "experiment": {**spec["experiment"], "devices": devices}}
    for name, values in sections.items():
        new[name] = {**spec.get(name, {}), **values}
    return new


def run_worker(jobs: list[dict[str, Any]], devices: int = 2) -> list[dict[str, Any]]:
    """Runs `jobs` (scale_worker.py) in a subprocess that sees `devices` CPU devices."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()
    env["PYTHONPATH"] = f"{ROOT}{os.pathsep}{env.get('PYTHONPATH', '')}"
    done = subprocess.run(
        [sys.executable, str(WORKER), json.dumps(jobs)], env=env, capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stderr[-3000:]
    line = next(x for x in done.stdout.splitlines() if x.startswith("RESULT "))
    return json.loads(line.removeprefix("RESULT "))


def metrics(out: Path) -> dict[str, np.ndarray]:
    """metrics.csv's columns, without the timings."""
    rows = np.genfromtxt(out / "metrics.csv", delimiter=",", names=True)
    return {k: rows[k] for k in rows.dtype.names if not k.startswith("wall_s") and not k.endswith("_per_s")}


def repertoire(out: Path) -> dict[str, np.ndarray]:
    with np.load(out / "repertoire.npz") as z:
        return {k: z[k] for k in z.files}


Runs = tuple[Path, dict[str, dict[str, Any]]]


def _pairs(tmp: Path, specs: dict[str, dict[str, Any]], extra: dict[str, dict[str, Any]]) -> Runs:
    """Each spec on 1 and 2 devices (`<name>1`, `<name>2`), and the `extra` jobs, in one subprocess."""
    jobs = {f"{name}{d}": {"spec": on_devices(spec, d), "out": str(tmp / f"{name}{d}")}
            for name, spec in specs.items() for d in (1, 2)}
    jobs.update(extra)
    return tmp, dict(zip(jobs, run_worker(list(jobs.values())), strict=True))


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    """MAP-Elites and SAC on 1 and 2 devices, a 2-device run resumed, and batches that do not split."""
    tmp = tmp_path_factory.mktemp("scale")
    return _pairs(tmp, {"arm": ARM, "sac": SAC}, {
        "resumed": {"spec": on_devices(ARM, 2), "out": str(tmp / "arm2"), "resume": True, "drop_last": True},
        "odd_arm": {"spec": on_devices(ARM, 2, emitter={"batch_size": 15}), "out": str(tmp / "odd")},
        "odd_sac": {"spec": on_devices(SAC, 2, train={"num_envs": 3, "eval_every": 129}), "out": str(tmp / "odd")},
        "too_many": {"spec": on_devices(ARM, 3), "out": str(tmp / "odd")},
    })


@pytest.fixture(scope="module")
def slow_runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    """PGA-ME and PBT on 1 and 2 devices (each compiles programs of its own: `-m slow`)."""
    return _pairs(tmp_path_factory.mktemp("scale_slow"), {"pga_me": PGA_ME, "pbt": PBT}, {})


def _runs_of(name: str, request: pytest.FixtureRequest) -> Runs:
    runs_: Runs = request.getfixturevalue("slow_runs" if name in ("pga_me", "pbt") else "runs")
    return runs_


@pytest.mark.parametrize("name", ["arm", pytest.param("pga_me", marks=pytest.mark.slow)])
def test_map_elites_two_devices_bit_exact(request: pytest.FixtureRequest, name: str) -> None:
    """Offspring evaluated split over 2 devices, the repertoire replicated: the same repertoire
    and metrics, bit for bit, as on one device (the arm, and PGA-ME on the point maze)."""
    tmp, _ = _runs_of(name, request)
    one, two = tmp / f"{name}1", tmp / f"{name}2"
    for k, v in repertoire(one).items():
        np.testing.assert_array_equal(repertoire(two)[k], v, err_msg=k)
    m1, m2 = metrics(one), metrics(two)
    assert m1["qd_score"][-1] > 0
    for k, v in m1.items():
        np.testing.assert_array_equal(m2[k], v, err_msg=k)


@pytest.mark.parametrize("name", ["sac", pytest.param("pbt", marks=pytest.mark.slow)])
def test_off_policy_two_devices_match(request: pytest.FixtureRequest, name: str) -> None:
    """SAC with its environments and gradient batches split over 2 devices, and PBT with its
    members split: the same metrics to float32 rounding (rtol 1e-5). Not bit-exact: a mean
    over a split batch (SAC's losses; PBT's mean of member metrics) is summed in another order."""
    tmp, _ = _runs_of(name, request)
    m1, m2 = metrics(tmp / f"{name}1"), metrics(tmp / f"{name}2")
    assert m1["grad_steps"][-1] > 0
    for k, v in m1.items():
        np.testing.assert_allclose(m2[k], v, rtol=1e-5, atol=1e-6, err_msg=k)
    np.testing.assert_array_equal(m2["eval_return"], m1["eval_return"])  # a few rounding bits do not move it


def test_two_device_checkpoint_resumes(runs: Runs) -> None:
    """A checkpoint written on 2 devices resumes on 2 devices to the same end."""
    _, summaries = runs
    finished, resumed = summaries["arm2"], summaries["resumed"]
    for k in ("qd_score", "coverage", "max_fitness", "evaluations"):
        assert resumed[k] == finished[k], k


def test_batches_that_do_not_split_are_rejected(runs: Runs) -> None:
    _, summaries = runs
    assert summaries["odd_arm"] == {"error": (
        "emitter.batch_size: expected a multiple of the device count 2 (the batch is split "
        "evenly over the devices), got 15")}
    assert summaries["odd_sac"]["error"].startswith("train.num_envs: expected a multiple of the device count 2")
    assert summaries["too_many"] == {"error": "experiment.devices: expected 0 (all) or at most the 2 visible device(s), got 3"}


def test_two_processes_give_the_single_process_repertoire(runs: Runs) -> None:
    """MAP-Elites as 2 jax.distributed processes on localhost (one CPU device each, gloo
    collectives) fills the repertoire of a single-process run bit for bit; process 0 alone
    writes the run directory."""
    import socket

    tmp, _ = runs
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp / "two_processes"
    jobs = json.dumps([{"spec": on_devices(ARM, 0), "out": str(out)}])
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    procs = [
        subprocess.Popen(
            [sys.executable, str(WORKER), jobs, f"127.0.0.1:{port}", "2", str(i)],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        for i in range(2)
    ]
    results = [p.communicate(timeout=600) for p in procs]
    for p, (_, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err[-3000:]
    summaries = [json.loads(next(x for x in o.splitlines() if x.startswith("RESULT "))[7:])[0] for o, _ in results]
    assert summaries[0]["qd_score"] == summaries[1]["qd_score"]
    for k, v in repertoire(tmp / "arm1").items():
        np.testing.assert_array_equal(repertoire(out)[k], v, err_msg=k)
    assert (out / "summary.json").is_file() and (out / "metrics.csv").read_text().count("\n") == 3
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["step_0000000001", "step_0000000002"]


@pytest.mark.slow
def test_bench_scaling_reports_both_device_counts() -> None:
    """`qdrl bench scaling --quick --config 2:map_elites_arm`: a figure per device count, the
    one-device efficiency 1 by definition, the two-device one computed from both."""
    from qdrl.bench_scaling import bench_scaling

    one, two = bench_scaling(quick=True, config="2:map_elites_arm")
    assert (one["devices"], two["devices"]) == (1, 2)
    assert one["unit"] == two["unit"] == "evaluations_per_s"
    assert one["parallel_efficiency"] == 1.0
    assert two["parallel_efficiency"] == pytest.approx(two["throughput"] / (2 * one["throughput"]), abs=2e-3)
    for r in (one, two):  # one timed chunk (--quick) of a program compiled for its device count
        assert r["chunks"] == 1 and math.isfinite(r["compile_s"]) and r["compile_s"] > 0 and r["timed_s"] > 0
    with pytest.raises(ValueError, match="N:case"):
        bench_scaling(quick=True, config="2:nope")


@pytest.mark.slow
def test_brax_tasks_two_devices_bit_exact(tmp_path: Path) -> None:
    """MAP-Elites and PGA-ME on halfcheetah_uni (brax, spring): bit for bit on 2 devices as on 1
    when both roll out blocks of the same width (`task.eval_batch` = the per-device batch);
    brax's per-lane numerics depend on that width, not on the device a lane runs on."""
    task = {"name": "halfcheetah_uni", "episode_length": 20, "backend": "spring", "eval_batch": 4,
            "policy_hidden": [8, 8]}
    me = {**ARM, "task": task, "repertoire": PGA_ME["repertoire"], "emitter": {"kind": "isoline", "batch_size": 8},
          "qd": {"num_iterations": 4, "log_every": 2, "init_batch_size": 8}}
    pga = {**PGA_ME, "task": task}
    jobs = [{"spec": on_devices(spec, d), "out": str(tmp_path / f"{name}{d}")}
            for name, spec in (("me", me), ("pga", pga)) for d in (1, 2)]
    run_worker(jobs)
    for name in ("me", "pga"):
        for k, v in repertoire(tmp_path / f"{name}1").items():
            np.testing.assert_array_equal(repertoire(tmp_path / f"{name}2")[k], v, err_msg=f"{name} {k}")
