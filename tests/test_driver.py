"""The experiment driver around any run: checkpoints by log point, fallback on resume,
extension, Ctrl-C, one-line errors, the compile line. On a tiny MAP-Elites arm run
(compiles in seconds, deterministic)."""

from __future__ import annotations

import csv
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from qdrl import checkpoint, compile_cache, experiment
from qdrl.cli import main
from qdrl.config import ConfigError
from qdrl.experiment import run_spec

SPEC = """
[experiment]
algorithm = "map_elites"
seed = 1

[task]
name = "arm"
num_dofs = {dofs}

[repertoire]
kind = "grid"
grid_shape = [8, 8]

[emitter]
batch_size = {batch}
iso_sigma = 0.01

[qd]
num_iterations = {iterations}
log_every = {log_every}
init_batch_size = 32

[log]
progress = false
plots = false
keep_checkpoints = 2
"""
RESULT_KEYS = ("qd_score", "coverage", "max_fitness", "mean_fitness", "num_elites", "evaluations", "iteration")
TIMING = {"wall_s", "env_steps_per_s", "evaluations_per_s"}
ROOT = Path(__file__).resolve().parents[1]


def write_spec(directory: Path, iterations: int = 8, log_every: int = 2, dofs: int = 8, batch: int = 32) -> Path:
    path = directory / "arm_tiny.toml"
    path.write_text(SPEC.format(iterations=iterations, log_every=log_every, dofs=dofs, batch=batch))
    return path


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def assert_same_run(out: Path, summary: dict[str, Any], ref_out: Path, ref: dict[str, Any]) -> None:
    """Bit-identical results: summary metrics, repertoire and every non-timing metrics.csv cell."""
    for key in RESULT_KEYS:
        assert summary[key] == ref[key], key
    with np.load(out / "repertoire.npz") as a, np.load(ref_out / "repertoire.npz") as b:
        assert a.files == b.files
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    rows, ref_rows = read_csv(out / "metrics.csv"), read_csv(ref_out / "metrics.csv")
    assert len(rows) == len(ref_rows)
    for row, ref_row in zip(rows, ref_rows, strict=True):
        assert {k: v for k, v in row.items() if k not in TIMING} == {
            k: v for k, v in ref_row.items() if k not in TIMING
        }


@pytest.fixture(scope="module")
def full(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, Any]]:
    """The reference: 8 iterations, 4 log points, from scratch."""
    root = tmp_path_factory.mktemp("full")
    spec = write_spec(root)
    return spec, root / "out", run_spec(spec, [], root / "out")


def copy_run(full: tuple[Path, Path, dict[str, Any]], dest: Path) -> Path:
    shutil.copytree(full[1], dest)
    return dest


def test_checkpoints_are_named_by_log_point_and_keep_holds(full: tuple[Path, Path, dict[str, Any]]) -> None:
    # arm counts no env steps: naming by env_steps kept one checkpoint, step_0000000000.
    _, out, summary = full
    assert summary["env_steps"] == 0
    names = [p.name for p in checkpoint.checkpoints(out / "checkpoints")]
    assert names == ["step_0000000004", "step_0000000003"]
    assert checkpoint.read_metadata(out / "checkpoints" / "step_0000000003")["chunk"] == 2
    # Integer columns are written as integers.
    rows = read_csv(out / "metrics.csv")
    assert [r["log_point"] for r in rows] == ["0", "1", "2", "3"]
    assert [r["iteration"] for r in rows] == ["2", "4", "6", "8"]
    assert [r["evaluations"] for r in rows] == [str(32 + 32 * 2 * (i + 1)) for i in range(4)]
    assert rows[-1]["env_steps"] == "0" and rows[-1]["num_elites"] == str(summary["num_elites"])
    assert "." in rows[-1]["qd_score"] and "." in rows[-1]["coverage"]


def test_extending_a_finished_run_equals_a_longer_run_from_scratch(
    tmp_path: Path, full: tuple[Path, Path, dict[str, Any]]
) -> None:
    spec, ref_out, ref = full
    out = tmp_path / "out"
    half = run_spec(spec, ["qd.num_iterations=4"], out)
    assert half["iteration"] == 4
    extended = run_spec(spec, ["qd.num_iterations=8"], out, resume=True)
    assert_same_run(out, extended, ref_out, ref)
    assert "num_iterations = 8" in (out / "config.toml").read_text()
    assert json.loads((out / "summary.json").read_text())["iteration"] == 8


def test_resuming_a_finished_run_says_so_and_compiles_nothing(
    tmp_path: Path,
    full: tuple[Path, Path, dict[str, Any]],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    spec, ref_out, _ = full
    out = copy_run(full, tmp_path / "out")
    before = {p.name: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}

    def refuse(*args: object) -> None:
        raise AssertionError("a finished run was initialised or compiled again")

    monkeypatch.setattr(experiment, "initial_state", refuse)
    monkeypatch.setattr(experiment, "compile_chunk", refuse)
    again = run_spec(spec, [], out, resume=True)
    assert again == json.loads((ref_out / "summary.json").read_text())
    err = capsys.readouterr().err
    assert f"{out} is a finished run (4 of 4 log points); nothing to run" in err
    assert "--set qd.num_iterations=" in err
    assert {p.name: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before  # untouched


def test_a_time_limit_stops_at_a_log_point_and_a_larger_one_resumes(
    tmp_path: Path, full: tuple[Path, Path, dict[str, Any]], capsys: pytest.CaptureFixture[str]
) -> None:
    spec, ref_out, ref = full
    out = tmp_path / "out"
    # A limit already spent by the first log point: the run stops there, a result of its own.
    assert main(["run", str(spec), "--out", str(out), "--time-limit", "1e-6"]) == 0
    err = capsys.readouterr().err
    assert "stopped at the time limit (1e-06 s) after log point 1 of 4" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped_by"] == "time_limit" and (summary["log_points"], summary["num_log_points"]) == (1, 4)
    assert summary["iteration"] == 2 and len(read_csv(out / "metrics.csv")) == 1
    assert [p.name for p in checkpoint.checkpoints(out / "checkpoints")] == ["step_0000000001"]
    assert (out / "repertoire.npz").is_file()  # exports and plots as at the end of a run
    # The same limit again would stop at once: refused before anything compiles.
    with pytest.raises(ConfigError, match=r"stopped at its time limit after \d+ s; expected a larger "
                       r"experiment\.time_limit_s \(--time-limit\)"):
        run_spec(spec, ["experiment.time_limit_s=1e-6"], out, resume=True)
    # Without a limit (or a larger one) it continues to the end, as the uninterrupted run.
    resumed = run_spec(spec, [], out, resume=True)
    assert "stopped_by" not in resumed
    assert_same_run(out, resumed, ref_out, ref)
    # The limit compiles nothing different: the same compile record as without it.
    config = (out / "config.toml").read_text()
    assert compile_cache.spec_key(config) == compile_cache.spec_key(
        config.replace("[experiment]\n", "[experiment]\ntime_limit_s = 60.0\n", 1)
    )


def test_resume_names_each_differing_key(
    tmp_path: Path, full: tuple[Path, Path, dict[str, Any]], compilations: Any
) -> None:
    spec, _, _ = full
    out = copy_run(full, tmp_path / "out")
    counter = compilations()
    counter.__enter__()
    with pytest.raises(ConfigError) as info:
        run_spec(spec, ["qd.num_iterations=12", "emitter.iso_sigma=0.02"], out, resume=True)
    assert str(info.value).startswith(
        f"--resume: the spec differs from {out / 'config.toml'}: "
        "emitter.iso_sigma 0.01 -> 0.02, qd.num_iterations 8 -> 12; only qd.num_iterations "
        "(to extend the run), experiment.time_limit_s, experiment.env_steps_limit and [log] may change on resume"
    )
    with pytest.raises(ConfigError, match=r"--resume: expected a length of at least the 4 log points"):
        run_spec(spec, ["qd.num_iterations=4"], out, resume=True)
    counter.__exit__()
    assert counter.count == 0  # refused before anything compiles


@pytest.mark.parametrize(
    ("name", "mode"), [("state.npz", "truncate"), ("meta.json", "garbage"), ("manifest.json", "delete")]
)
def test_resume_falls_back_past_a_corrupt_checkpoint(
    tmp_path: Path, full: tuple[Path, Path, dict[str, Any]], name: str, mode: str,
    capsys: pytest.CaptureFixture[str],
) -> None:
    spec, ref_out, ref = full
    out = copy_run(full, tmp_path / "out")
    file = out / "checkpoints" / "step_0000000004" / name
    if mode == "delete":
        file.unlink()
    elif mode == "truncate":
        file.write_bytes(file.read_bytes()[:100])
    else:
        file.write_bytes(b"\x00garbage" * (file.stat().st_size // 8))
    (out / "summary.json").unlink()
    resumed = run_spec(spec, [], out, resume=True)
    err = capsys.readouterr().err
    assert f"qdrl: --resume: step_0000000004 is unusable ({name}" in err
    assert "qdrl: --resume: resuming from step_0000000003 (log point 3 of 4)" in err
    assert_same_run(out, resumed, ref_out, ref)


def test_resume_fails_in_one_line_when_no_checkpoint_is_usable(
    tmp_path: Path, full: tuple[Path, Path, dict[str, Any]], capsys: pytest.CaptureFixture[str]
) -> None:
    spec, _, _ = full
    out = copy_run(full, tmp_path / "out")
    (out / "checkpoints" / "step_0000000004" / "state.npz").write_bytes(b"")
    (out / "checkpoints" / "step_0000000003" / "meta.json").unlink()
    assert main(["run", str(spec), "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"qdrl: error: --resume: no usable checkpoint in {out / 'checkpoints'} (")
    assert "step_0000000004: state.npz has 0 bytes, the manifest says" in err
    assert "step_0000000003: meta.json is missing" in err


def _env(**extra: str) -> dict[str, str]:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", **extra}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


_KILL_INSIDE_SAVE = textwrap.dedent(
    """
    import os, sys
    from qdrl import checkpoint
    from qdrl.cli import main
    phase, step = sys.argv[1], int(sys.argv[2])
    save, saving = checkpoint.save, []
    def counting_save(directory, s, *args, **kwargs):
        saving.append(s)
        return save(directory, s, *args, **kwargs)
    def crash(p):
        if p == phase and saving[-1] == step:
            os._exit(17)  # no cleanup: what SIGKILL or a power cut leaves
    checkpoint.save, checkpoint._crash_point = counting_save, crash
    sys.exit(main(sys.argv[3:]))
    """
)


def test_a_run_killed_inside_a_checkpoint_save_resumes(
    tmp_path: Path, full: tuple[Path, Path, dict[str, Any]]
) -> None:
    # Killed while saving log point 3: before the new checkpoint is in place (resumes
    # from 2), and once it is in place but the old one not yet pruned (resumes from 3).
    spec, ref_out, ref = full
    cases = {"manifest_written": "step_0000000002", "renamed": "step_0000000003"}
    procs = {
        phase: subprocess.Popen(
            [sys.executable, "-c", _KILL_INSIDE_SAVE, phase, "3", "run", str(spec), "--out", str(tmp_path / phase)],
            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        for phase in cases
    }
    for phase, newest in cases.items():
        assert procs[phase].wait(timeout=300) == 17, phase
        out = tmp_path / phase
        assert checkpoint.latest(out / "checkpoints") == out / "checkpoints" / newest
        resumed = run_spec(spec, [], out, resume=True)
        assert_same_run(out, resumed, ref_out, ref)
        assert [p.name for p in checkpoint.checkpoints(out / "checkpoints")] == [
            "step_0000000004", "step_0000000003"
        ]


def _wait_for(predicate: Any, proc: subprocess.Popen[bytes], timeout: float = 300) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert proc.poll() is None, "the run ended early"
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def test_ctrl_c_checkpoints_the_last_chunk_and_says_how_to_resume(tmp_path: Path) -> None:
    # Chunks of 200 iterations of a 100-joint arm: long enough to press Ctrl-C in one.
    spec = write_spec(tmp_path, iterations=1000, log_every=200, dofs=100, batch=256)
    out = tmp_path / "out"
    args = ["run", str(spec), "--set", "log.checkpoint_every=100", "--out", str(out)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "qdrl.cli", *args], env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    metrics = out / "metrics.csv"
    _wait_for(lambda: metrics.exists() and len(metrics.read_text().splitlines()) >= 2, proc)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=300)
    err = stderr.decode()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and stdout == b""
    done = len(read_csv(metrics))
    assert 1 <= done < 5
    # No checkpoint was due (checkpoint_every=100): the one on disk is Ctrl-C's.
    assert [p.name for p in checkpoint.checkpoints(out / "checkpoints")] == [f"step_{done:010d}"]
    assert f"qdrl: interrupted at log point {done} of 5;" in err
    command = err.split("qdrl: resume with: ")[1].strip()
    assert command == shlex.join(["qdrl", *args, "--resume"])

    summary = run_spec(spec, ["log.checkpoint_every=100"], out, resume=True)
    assert summary["iteration"] == 1000 and len(read_csv(metrics)) == 5


def test_ctrl_c_while_compiling_exits_at_once(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    out = tmp_path / "out"
    # An empty compilation cache: a compile of a few seconds at least.
    env = _env(JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax"), QDRL_CACHE_DIR=str(tmp_path / "qdrl"))
    proc = subprocess.Popen(
        [sys.executable, "-m", "qdrl.cli", "run", str(spec), "--out", str(out), "--set", "log.progress=true"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )
    assert proc.stderr is not None
    os.set_blocking(proc.stderr.fileno(), False)
    seen = b""

    def compiling() -> bool:
        nonlocal seen
        seen += proc.stderr.read() or b""  # type: ignore[union-attr]
        return b"compiling map_elites on arm" in seen

    _wait_for(compiling, proc)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=120)
    os.set_blocking(proc.stderr.fileno(), True)
    err = (seen + proc.stderr.read()).decode()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert "qdrl: interrupted before the first log point of 4; nothing saved" in err
    assert "resume with" not in err
    assert "compiled map_elites on arm in" not in err  # it did not wait for the compilation to end
    assert not (out / "metrics.csv").exists()


def test_an_unexpected_error_prints_one_line_and_logs_the_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def broken_compile(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("XLA ran out of memory\nsecond line of detail")

    spec, out = write_spec(tmp_path), tmp_path / "out"
    monkeypatch.setattr("qdrl.compiling.compile_timed", broken_compile)
    assert main(["run", str(spec), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    log = out / "error.log"
    # The run had started (it says where it writes); the error is one line after it.
    assert err == f"qdrl: writing to {out}\nqdrl: error: RuntimeError: XLA ran out of memory (full traceback in {log})\n"
    text = log.read_text()
    assert "Traceback (most recent call last)" in text and "broken_compile" in text
    assert "second line of detail" in text

    # Before the run directory exists: a file in the temporary directory.
    def broken_build(spec: Any) -> Any:
        raise KeyError("lost")

    monkeypatch.setattr("qdrl.experiment.build_run", broken_build)
    assert main(["run", str(spec), "--out", str(tmp_path / "never")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("qdrl: error: KeyError: 'lost' (full traceback in ") and err.count("\n") == 1
    path = Path(err.split("full traceback in ")[1].rstrip(")\n"))
    assert path.name.startswith("qdrl-error-") and path.is_file()
    assert "broken_build" in path.read_text()
    path.unlink()

    # Any other command: the same.
    def broken_bench(*args: Any, **kwargs: Any) -> Any:
        raise OSError("disk full")

    monkeypatch.setattr("qdrl.bench.run_bench", broken_bench)
    assert main(["bench", "rl", "--quick"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("qdrl: error: OSError: disk full (full traceback in ") and err.count("\n") == 1
    Path(err.split("full traceback in ")[1].rstrip(")\n")).unlink()


def test_progress_line_counts_iterations_and_shows_the_last_compile_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("QDRL_CACHE_DIR", str(tmp_path / "cache"))
    spec, out = write_spec(tmp_path), tmp_path / "out"
    run_spec(spec, ["log.progress=true"], out)
    first = capsys.readouterr().err  # not a terminal: plain lines, no carriage returns
    assert "\r" not in first
    assert "compiling map_elites on arm (first run of this spec here: no estimate yet)\n" in first
    summary = json.loads((out / "summary.json").read_text())
    assert summary["startup_s"] >= summary["compile_s"] > 0  # the same two figures as the line's
    assert f"compiled map_elites on arm in {summary['compile_s']:.1f} s (started in " in first
    assert "map_elites on arm: 8/8 iteration (100%)" in first  # iterations, not log points
    times = json.loads((tmp_path / "cache" / "compile_times.json").read_text())
    (record,) = next(iter(times.values())).values()
    assert record["algorithm"] == "map_elites" and record["task"] == "arm" and record["seconds"] > 0

    # A longer run of the same spec compiles the same programs: same record.
    run_spec(spec, ["log.progress=true", "qd.num_iterations=10"], out, overwrite=True)
    second = capsys.readouterr().err
    assert f"(last run of this spec: {record['seconds']:.0f} s)" in second
    assert "map_elites on arm: 10/10 iteration" in second


def test_progress_on_a_terminal_is_one_line_and_elsewhere_a_few_plain_lines() -> None:
    import io

    from qdrl.progress import RunProgress

    tty = io.StringIO()
    bar = RunProgress(True, "sac on pendulum", "env_steps", 1000, stream=tty, plain=False)
    bar.compiling(None)
    bar.compiled(1.5, 2.0)
    bar.start(0)
    for done in range(100, 1001, 100):
        bar.update(done, {"eval_return": "1.0"})
    bar.close()
    assert "\r" in tty.getvalue() and "compiled sac on pendulum in 1.5 s (started in 2.0 s)" in tty.getvalue()

    log = io.StringIO()
    plain = RunProgress(True, "sac on pendulum", "env_steps", 1000, stream=log, plain_every=3600.0)
    assert plain.plain  # a StringIO is no terminal
    plain.compiling((12.0, True))
    plain.tick()  # within plain_every of the last line: nothing
    plain.compiled(1.5, 2.0)
    plain.start(0)
    for done in range(100, 1001, 100):
        plain.update(done, {"eval_return": "1.0"})
    plain.close()
    lines = log.getvalue().splitlines()
    assert lines[:2] == [
        "compiling sac on pendulum (last run of this spec: 12 s)",
        "compiled sac on pendulum in 1.5 s (started in 2.0 s)",
    ]
    # the first update, then none within plain_every, then the last
    assert [line.split(" (")[0] for line in lines[2:]] == [
        "sac on pendulum: 100/1000 env_steps", "sac on pendulum: 1000/1000 env_steps",
    ]
    assert lines[-1].endswith("eval_return=1.0")


def test_compile_records_give_a_new_spec_the_last_cold_compile_of_its_algorithm_and_task(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("QDRL_CACHE_DIR", str(tmp_path))
    assert compile_cache.estimate("a", "map_elites", "arm") is None
    compile_cache.record("a", "map_elites", "arm", 41.0, cold=True)
    compile_cache.record("b", "map_elites", "arm", 3.0, cold=False)
    compile_cache.record("c", "sac", "point", 9.0, cold=True)
    assert compile_cache.estimate("b", "map_elites", "arm") == (3.0, True)
    assert compile_cache.estimate("new", "map_elites", "arm") == (41.0, False)
    assert compile_cache.estimate("new", "td3", "point") is None
    # Keys that do not change what is compiled do not change the spec's key.
    base = "[experiment]\nseed = 0\nname = 'a'\n[qd]\nnum_iterations = 10\nlog_every = 5\n[log]\nprogress = true\n"
    same = base.replace("seed = 0", "seed = 3").replace("= 10", "= 20").replace("true", "false")
    assert compile_cache.spec_key(base, "qd.num_iterations") == compile_cache.spec_key(same, "qd.num_iterations")
    assert compile_cache.spec_key(base, "qd.num_iterations") != compile_cache.spec_key(same)
    assert compile_cache.spec_key(base) != compile_cache.spec_key(base.replace("= 5", "= 2"))
    # Every algorithm's length key is the one its recipe declares.
    from qdrl.algorithms import ALGORITHMS

    assert {r.length_key for r in ALGORITHMS.values()} == {
        "qd.num_iterations", "train.total_env_steps", "cma_es.num_generations"
    }


def test_compile_cache_goes_to_the_user_cache_unless_jax_has_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import jax
    import jax.numpy as jnp

    config: Any = jax.config
    before = config.jax_compilation_cache_dir
    monkeypatch.setenv("QDRL_CACHE_DIR", str(tmp_path / "qdrl"))
    jax.config.update("jax_compilation_cache_dir", None)
    min_time = config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    try:
        with compile_cache.enabled(True) as directory:
            assert directory == str(tmp_path / "qdrl" / "jax")
            jax.jit(lambda x: jnp.sin(x) * 3.25)(jnp.arange(7.0)).block_until_ready()
        assert any((tmp_path / "qdrl" / "jax").iterdir())  # an executable was written
        assert config.jax_compilation_cache_dir is None
        monkeypatch.setenv("QDRL_COMPILE_CACHE", "0")
        with compile_cache.enabled(True) as directory:
            assert directory is None and not config.jax_enable_compilation_cache
        assert config.jax_enable_compilation_cache
        monkeypatch.delenv("QDRL_COMPILE_CACHE")
        jax.config.update("jax_compilation_cache_dir", str(tmp_path / "mine"))
        with compile_cache.enabled(True) as directory:
            assert directory == str(tmp_path / "mine")  # JAX_COMPILATION_CACHE_DIR wins
    finally:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", min_time)
        jax.config.update("jax_compilation_cache_dir", before)
        from jax.experimental.compilation_cache import compilation_cache as cc

        cc.reset_cache()
