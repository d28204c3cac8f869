"""`qdrl run`: artefacts, overwrite protection, resume after SIGKILL, fast errors on bad specs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from qdrl import checkpoint
from qdrl.cli import main
from qdrl.config import ConfigError
from qdrl.experiment import run_spec

SPEC = """
[experiment]
algorithm = "{algorithm}"
seed = 3

[env]
name = "point"
episode_length = 20

[agent]
hidden = [16, 16]

[train]
total_env_steps = {steps}
num_envs = 4
batch_size = 32
buffer_size = 2000
learning_starts = 80
grad_steps_per_iter = 2
eval_every = 200
num_eval_envs = 4

[log]
checkpoint_every = 1
progress = false
plots = false  # the tests that read plots turn them on
"""


def write_spec(tmp_path: Path, algorithm: str = "sac", steps: int = 1000) -> Path:
    path = tmp_path / f"{algorithm}_point.toml"
    path.write_text(SPEC.format(algorithm=algorithm, steps=steps))
    return path


# TD3's run writes through the same driver and plots as SAC's: -m slow.
@pytest.mark.parametrize("algorithm", ["sac", pytest.param("td3", marks=pytest.mark.slow)])
def test_run_writes_every_artefact(tmp_path: Path, algorithm: str) -> None:
    out = tmp_path / "out"
    summary = run_spec(write_spec(tmp_path, algorithm), ["train.total_env_steps=600", "log.plots=true"], out)
    for key in ("algorithm", "task", "seed", "env_steps", "wall_s", "compile_s", "env_steps_per_s", "eval_return"):
        assert key in summary, key
    assert summary["algorithm"] == algorithm and summary["task"] == "point"
    assert summary["env_steps"] == 600 and summary["seed"] == 3
    assert summary["env_steps_per_s"] > 0 and summary["compile_s"] > 0
    rows = (out / "metrics.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert {"env_steps", "wall_s", "eval_return"} <= set(header)
    assert len(rows) == 1 + 3  # three log points
    assert json.loads((out / "summary.json").read_text())["env_steps"] == 600
    assert "total_env_steps = 600" in (out / "config.toml").read_text()
    # plots/: the one-figure summary (every metric column), the passive archive and the return's
    # learning curve; nothing else
    plots = sorted(p.name for p in (out / "plots").iterdir())
    assert plots == ["archive.png", "eval_return.png", "summary.png"]
    for name in ("summary.png", "archive.png", "eval_return.png"):
        assert (out / "plots" / name).stat().st_size > 1000
    assert checkpoint.latest(out / "checkpoints") is not None


def test_existing_run_is_not_overwritten(tmp_path: Path) -> None:
    spec, out = write_spec(tmp_path, steps=200), tmp_path / "out"
    run_spec(spec, [], out)
    with pytest.raises(ConfigError, match="already holds a run"):
        run_spec(spec, [], out)
    run_spec(spec, [], out, overwrite=True)
    with pytest.raises(ConfigError, match="spec differs"):
        run_spec(spec, ["agent.tau=0.01"], out, resume=True)
    with pytest.raises(ConfigError, match="no checkpoint found"):
        run_spec(spec, [], tmp_path / "empty", resume=True)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "qdrl.cli", *args]


@pytest.mark.slow  # the driver is shared: tests/test_qd_run.py kills a MAP-Elites run in the default run
def test_resume_after_sigkill_matches_an_uninterrupted_run(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, steps=4000)  # 20 log points
    full = run_spec(spec, [], tmp_path / "full")

    out = tmp_path / "killed"
    proc = subprocess.Popen(_cli("run", str(spec), "--out", str(out)), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline:
        latest = checkpoint.latest(out / "checkpoints")
        if latest is not None and checkpoint.step_of(latest) >= 4:  # log points, 200 env steps each
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = checkpoint.step_of(checkpoint.latest(out / "checkpoints"))  # type: ignore[arg-type]
    assert 4 <= killed_at < 20, killed_at
    assert not (out / "summary.json").exists()

    resumed = run_spec(spec, [], out, resume=True)
    for key in ("env_steps", "eval_return", "eval_return_std", "critic_loss", "grad_steps", "train_return"):
        assert resumed[key] == full[key], key
    lines = (out / "metrics.csv").read_text().splitlines()
    assert len(lines) == 1 + 20
    steps = [line.split(",")[1] for line in lines[1:]]
    assert steps == [str(200 * (i + 1)) for i in range(20)]  # integer columns as integers


@pytest.mark.slow
def test_extending_an_rl_run_equals_a_longer_run_from_scratch(tmp_path: Path) -> None:
    # `--resume --set train.total_env_steps=N` extends a finished SAC run.
    spec = write_spec(tmp_path, steps=1000)  # 5 log points
    full = run_spec(spec, [], tmp_path / "full")
    out = tmp_path / "extended"
    assert run_spec(spec, ["train.total_env_steps=600"], out)["env_steps"] == 600
    extended = run_spec(spec, ["train.total_env_steps=1000"], out, resume=True)
    for key in ("env_steps", "eval_return", "eval_return_std", "critic_loss", "grad_steps", "train_return", "qd_score"):
        assert extended[key] == full[key], key
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 5


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("train.batch_size=-4", "train.batch_size: expected a positive integer, got -4"),
        ("train.batch_sise=4", "train.batch_sise: unknown key; did you mean 'batch_size'?"),
        ("agent.tau=\"fast\"", "agent.tau: expected a number in (0, 1], got 'fast'"),
        ("env.name=\"cheetah\"", "env.name: expected one of ["),
        ("experiment.algorithm=\"ppo\"", "experiment.algorithm: expected one of ["),
        ("agent.hidden=[0]", "agent.hidden"),
        ("envs.name=\"ant\"", "envs: unknown section for algorithm 'sac'; did you mean 'env'?"),
    ],
)
def test_bad_spec_fails_fast_with_the_key(
    tmp_path: Path, override: str, message: str, capsys: pytest.CaptureFixture[str], compilations: Any
) -> None:
    with compilations() as compiled:
        code = main(["run", str(write_spec(tmp_path)), "--set", override, "--out", str(tmp_path / "o")])
    assert code == 2
    assert message in capsys.readouterr().err
    assert compiled.count == 0
    assert not (tmp_path / "o" / "checkpoints").exists()


def test_bad_spec_fails_fast_from_a_fresh_process(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    res = subprocess.run(
        _cli("run", str(spec), "--set", "train.batch_size=-1"), capture_output=True, text=True, env=os.environ.copy()
    )
    assert res.returncode == 2
    assert "train.batch_size: expected a positive integer, got -1" in res.stderr


def test_list_shows_specs_algorithms_and_tasks(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "\n  default " in out and "sac" in out and "td3" in out and "halfcheetah" in out
    assert "map_elites" in out and "halfcheetah_uni" in out and "arm" in out
    assert "  cma_improvement: CMA-ME's improvement emitter" in out and "cma_mae" in out
