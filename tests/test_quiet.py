"""qdrl.quiet(): the dependencies' notices are gone from a run's output, other warnings are not."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import pytest

import qdrl
from qdrl import _quiet

ROOT = Path(__file__).resolve().parents[1]
NOISE = (
    "Failed to import warp",
    "Failed to import mujoco_warp",
    "not actively being maintained",
    "settotalmass",
)
# A tiny halfcheetah run: brax loads half_cheetah.xml (settotalmass, the maintenance warning)
# and imports mujoco-mjx (the warp notices).
TINY_HALFCHEETAH = (
    "task.episode_length=5", "task.policy_hidden=[4]", "qd.num_iterations=2", "qd.log_every=1",
    "qd.init_batch_size=4", "emitter.batch_size=4", "repertoire.num_centroids=8", "repertoire.cvt_samples=100",
)
# settotalmass is deprecated in MuJoCo 4; the free body is there to have degrees of freedom.
XML = '<mujoco><compiler settotalmass="3"/><worldbody><body><freejoint/><geom size="1"/></body></worldbody></mujoco>'


# The `qdrl` entry point (`list` imports brax.envs, hence mujoco-mjx), then what a brax run
# does first: load half_cheetah.xml. No compile, so this stays a few seconds.
ENTRY_THEN_LOAD = """
import sys
from qdrl.cli import main
assert main(["list"]) == 0
import brax.envs
brax.envs.get_environment("halfcheetah", backend="spring")
print("loaded", file=sys.stderr)
"""


def _cli() -> list[str]:
    script = Path(sys.executable).parent / "qdrl"
    return [str(script)] if script.exists() else [sys.executable, "-m", "qdrl.cli"]


def _assert_quiet(res: subprocess.CompletedProcess[str], cwd: Path) -> None:
    assert res.returncode == 0, res.stderr[-2000:]
    for notice in NOISE:
        assert notice not in res.stdout and notice not in res.stderr, notice
    assert not (cwd / "MUJOCO_LOG.TXT").exists()


def test_entry_point_and_model_loading_print_no_dependency_notices(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-c", ENTRY_THEN_LOAD], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    _assert_quiet(res, tmp_path)
    assert "algorithms:" in res.stdout and "loaded" in res.stderr


@pytest.mark.slow
def test_cli_run_prints_no_dependency_notices_and_writes_no_mujoco_log(tmp_path: Path) -> None:
    """The same through a whole `qdrl run` (about a minute of compiling; .ci/run's smoke legs do this too)."""
    sets = [arg for value in TINY_HALFCHEETAH for arg in ("--set", value)]
    spec = ROOT / "agents" / "map_elites_halfcheetah_uni_cpu.toml"
    res = subprocess.run([*_cli(), "run", str(spec), "--out", "run", *sets],
                         cwd=tmp_path, capture_output=True, text=True, timeout=900)
    _assert_quiet(res, tmp_path)
    assert (tmp_path / "run" / "metrics.csv").exists()


def test_mujoco_warnings_become_python_warnings_except_settotalmass(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    import mujoco

    monkeypatch.chdir(tmp_path)
    qdrl.quiet()  # again: idempotent, and installs the handler on an imported mujoco
    assert sum(isinstance(f, _quiet._QuietImports) for f in sys.meta_path) == 1
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = mujoco.MjModel.from_xml_string(XML)
        data = mujoco.MjData(model)
        data.qacc[:] = float("nan")
        mujoco.mj_checkAcc(model, data)
    messages = [str(w.message) for w in caught if issubclass(w.category, qdrl.MujocoWarning)]
    assert len(messages) == 1 and "Nan, Inf or huge value in QACC" in messages[0]
    # Warnings turned into errors: an exception must not escape into MuJoCo's C code (it
    # aborts the process), so the warning goes to stderr.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        data = mujoco.MjData(model)
        data.qacc[:] = float("nan")
        mujoco.mj_checkAcc(model, data)
    captured = capfd.readouterr()
    assert "MujocoWarning: MuJoCo: Nan, Inf or huge value in QACC" in captured.err
    assert "settotalmass" not in captured.out + captured.err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_only_the_warp_lines_are_dropped_from_stdout(capsys: pytest.CaptureFixture[str]) -> None:
    with _quiet._without_stdout_lines(_quiet._WARP_LINES):
        print("Failed to import warp: No module named 'warp'")
        print("kept 1")
        print("Failed to import mujoco_warp: No module named 'warp'")
        print("kept 2")
    assert capsys.readouterr().out == "kept 1\nkept 2\n"
