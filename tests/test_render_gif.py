"""`qdrl render --out replay.gif`: a GIF video of a brax replay (an elite's, a skill's), or, where
MuJoCo can make no headless EGL context, a one-line error that says so.

The default run draws a GIF from an episode's poses (no compile); with -m slow, a tiny
MAP-Elites run on halfcheetah_uni (episodes of 5 steps) and a tiny DIAYN run on it are
rendered through the command (a brax rollout of their own to compile: 20-50 s).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from qdrl.cli import main
from qdrl.experiment import run
from qdrl.render import write_gif
from qdrl.runs import RunError, Trajectory, load_run

STEPS = 5
QD = {
    "experiment": {"algorithm": "map_elites", "seed": 0},
    "task": {"name": "halfcheetah_uni", "episode_length": STEPS, "policy_hidden": [4]},
    "repertoire": {"grid_shape": [2, 2]},
    "emitter": {"batch_size": 2},
    "qd": {"num_iterations": 1, "log_every": 1, "init_batch_size": 2},
    "log": {"progress": False, "plots": False},
}
NO_EGL = "render: write_video: no headless OpenGL (EGL) context"


def _egl_error() -> str | None:
    """Why MuJoCo can make no headless EGL context here, or None where it can."""
    try:
        from mujoco.egl import GLContext

        GLContext(8, 8).free()
    except Exception as e:
        return str(e) or type(e).__name__
    return None


def _frames(path: Path) -> tuple[list[np.ndarray], Any]:
    """The GIF's frames (RGB, float) and its frame time in ms."""
    with Image.open(path) as gif:
        frames = []
        for t in range(gif.n_frames):
            gif.seek(t)
            frames.append(np.asarray(gif.convert("RGB"), float))
        return frames, gif.info["duration"]


def _render(argv: list[str], out: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any] | None:
    """`qdrl render ... --out out`'s JSON; None, having checked the one-line error, without EGL."""
    code = main([*argv, "--out", str(out)])
    said = capsys.readouterr()
    if _egl_error() is not None:
        err = said.err.strip()
        assert code == 2 and not out.exists()
        assert err.startswith(f"qdrl: error: {NO_EGL}") and "\n" not in err, err
        return None
    assert code == 0, said.err
    return json.loads(said.out)


@pytest.fixture(scope="module")
def cheetah(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cheetah")
    run(QD, out)
    return out


@pytest.mark.slow
def test_render_writes_a_gif_of_the_elite_or_says_there_is_no_egl(
    cheetah: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "replay.gif"
    said = _render(["render", str(cheetah)], out, capsys)
    if said is None:
        return
    best = load_run(cheetah).best()
    assert said == {"out": str(out), "cell": best.cell, "fitness": best.fitness, "return": best.fitness, "length": STEPS}
    frames, duration = _frames(out)
    # halfcheetah's 0.05 s a step: a frame of every step, 50 ms each, real time
    assert len(frames) == STEPS and frames[0].shape == (360, 480, 3) and duration == 50
    assert frames[0].std() > 10  # a floor, a sky and a robot
    assert np.abs(frames[0] - frames[-1]).mean() > 0.1  # the robot moved


@pytest.mark.slow
def test_a_wrong_suffix_lists_gif(cheetah: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["render", str(cheetah), "--out", str(tmp_path / "replay.mp4")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--out: expected a file ending with .html or .gif for task 'halfcheetah_uni'" in err


def test_a_gif_of_short_steps_keeps_real_time_at_50_frames_a_second(tmp_path: Path) -> None:
    from brax.base import Transform

    from qdrl.envs.brax import BraxEnv

    env = BraxEnv("hopper", "spring", episode_length=10).brax_env  # 0.008 s a step
    links, length = len(env.sys.link_names), 7
    pos = np.zeros((10, links, 3), np.float32)
    pos[:, :, 0] = np.arange(10, dtype=np.float32)[:, None] * 0.2  # walks along x
    pos[:, :, 2] = 1.2
    rot = np.tile(np.asarray([1.0, 0.0, 0.0, 0.0], np.float32), (10, links, 1))
    episode = Trajectory(
        observations=np.zeros((10, 1)), actions=np.zeros((10, 1)), rewards=np.zeros(10),
        state_descriptors=pos[:, 0, :2], mask=np.arange(10) < length, length=length, return_=0.0,
        descriptor=pos[length, 0, :2], states=Transform(pos=pos, rot=rot),
    )
    out = tmp_path / "hopper.gif"
    if (why := _egl_error()) is not None:
        with pytest.raises(RunError, match=r"^render: write_video: no headless OpenGL \(EGL\) context"):
            write_gif(env.sys, episode, out, env.dt)
        assert why and not out.exists()
        return
    assert write_gif(env.sys, episode, out, env.dt) == out
    frames, duration = _frames(out)
    # every 3rd of the episode's 7 steps (0, 3, 6: not the 3 recorded after its end), 20 ms each
    assert len(frames) == 3 and duration == 20


@pytest.mark.slow
def test_render_writes_a_gif_of_a_skill(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A skill's GIF plays the skill as the run's last evaluation did (about 50 s of compiling)."""
    spec = {
        "experiment": {"algorithm": "diayn", "seed": 0},
        "env": {"task": "halfcheetah_uni", "episode_length": STEPS},
        "agent": {"hidden": [4]},
        "train": {"total_env_steps": 40, "num_envs": 2, "batch_size": 4, "buffer_size": 40,
                  "learning_starts": 20, "grad_steps_per_iter": 1, "eval_every": 40, "num_eval_envs": 2},
        "skills": {"num_skills": 2, "hidden": [4]},
        "archive": {"grid_shape": [2, 2]},
        "log": {"progress": False, "plots": False},
    }
    run(spec, tmp_path / "run")
    out = tmp_path / "skill1.gif"
    said = _render(["render", str(tmp_path / "run"), "--skill", "1"], out, capsys)
    if said is None:
        return
    skills = pd.read_csv(tmp_path / "run" / "skills.csv").set_index("episode")
    assert said == {"out": str(out), "skill": 1, "return": skills.loc[1, "return"], "length": STEPS}
    frames, _ = _frames(out)
    assert len(frames) == STEPS and frames[0].std() > 10
