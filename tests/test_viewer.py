"""Replays that work offline: `qdrl.viewer`'s HTML page and GIF, `write_html`'s two variants."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
import zlib
from pathlib import Path
from typing import Any, NamedTuple

import mujoco
import numpy as np
import pytest

from qdrl.cli import main
from qdrl.render import write_html
from qdrl.runs import Trajectory
from qdrl.viewer import VIEWER_JS, replay_html, write_video

STEPS = 6
NODE = shutil.which("node")


class Hopper(NamedTuple):
    sys: Any  # brax's System
    episode: Trajectory
    geom_pos: np.ndarray  # (T, geoms, 3) MuJoCo's world positions of the geoms at each frame
    geom_mat: np.ndarray  # (T, geoms, 9) and their rotations, row-major


@pytest.fixture(scope="module")
def hopper() -> Hopper:
    """hopper's brax system and an episode of STEPS steps of a fixed action, its link poses.

    MuJoCo steps brax's own model (`sys.mj_model`): its bodies' world poses are
    brax's link poses `pipeline_state.x` (link i is body i + 1), in milliseconds,
    where compiling brax's step would take most of this file's time.
    """
    from brax.base import Transform

    from qdrl.envs.brax import BraxEnv

    sys = BraxEnv("hopper", "spring", episode_length=STEPS).brax_env.sys
    model = sys.mj_model
    data = mujoco.MjData(model)
    data.ctrl[:] = 0.8
    pos, rot, geom_pos, geom_mat = [], [], [], []
    for _ in range(STEPS):
        for _ in range(20):  # 20 physics steps a frame: the hopper visibly falls and bends
            mujoco.mj_step(model, data)
        pos.append(data.xpos[1:].copy())
        rot.append(data.xquat[1:].copy())
        geom_pos.append(data.geom_xpos.copy())
        geom_mat.append(data.geom_xmat.copy())
    length = STEPS - 1  # an episode shorter than its recording: only its steps are drawn
    episode = Trajectory(
        observations=np.zeros((STEPS, 1)), actions=np.full((STEPS, model.nu), 0.8), rewards=np.zeros(STEPS),
        state_descriptors=np.zeros((STEPS + 1, 2)), mask=np.ones(STEPS), length=length, return_=0.0,
        descriptor=np.zeros(2), states=Transform(pos=np.stack(pos), rot=np.stack(rot)),
    )
    return Hopper(sys, episode, np.stack(geom_pos), np.stack(geom_mat))


def _scene(page: str) -> dict[str, Any]:
    """The scene a page embeds: base64 of zlib-compressed JSON, as brax's own page does."""
    blob = max(re.findall(r"[A-Za-z0-9+/=]{200,}", page), key=len)
    return json.loads(zlib.decompress(base64.b64decode(blob)))


def _script(page: str) -> str:
    """The page's one executable script (the others are data)."""
    scripts = re.findall(r"<script([^>]*)>(.*?)</script>", page, re.S)
    code = [body for attrs, body in scripts if "type=" not in attrs]
    assert len(code) == 1 and all("src=" not in attrs for attrs, _ in scripts)
    return code[0]


def test_offline_replay_fetches_nothing_and_holds_every_frame(
    hopper: Hopper, tmp_path: Path
) -> None:
    sys, episode, *_ = hopper
    page = write_html(sys, episode, tmp_path / "replay.html").read_text()
    # No URL anywhere (so none in a src, href, import or fetch): nothing is loaded from a network.
    assert not re.search(r"(src|href)\s*=\s*[\"']?\s*(https?:)?//", page)
    assert not re.search(r"\bimport\b[^;\n]*[\"'](https?:)?//", page)
    assert "http://" not in page and "https://" not in page
    scene = _scene(page)
    frames = scene["states"]["x"]
    assert len(frames) == episode.length
    np.testing.assert_allclose(frames[-1]["pos"], episode.states.pos[episode.length - 1], atol=1e-4)
    np.testing.assert_allclose(frames[2]["rot"], episode.states.rot[2], atol=1e-4)
    assert frames[-1]["pos"] != frames[0]["pos"]  # the hopper moved
    kinds = sorted(g["name"] for geoms in scene["geoms"].values() for g in geoms)
    assert kinds == ["Capsule"] * 4 + ["Plane"]


def test_cdn_variant_is_braxs_own_page(hopper: Hopper, tmp_path: Path) -> None:
    sys, episode, *_ = hopper
    page = write_html(sys, episode, tmp_path / "cdn.html", offline=False).read_text()
    assert "https://cdn.jsdelivr.net/gh/google/brax" in page
    assert len(_scene(page)["states"]["x"]) == episode.length


def test_render_cdn_flag_asks_for_braxs_page(monkeypatch: pytest.MonkeyPatch) -> None:
    from qdrl import render, runs

    asked: list[bool] = []

    def fake_render(run: Any, cell: Any, out: Any, skill: Any, offline: bool = True) -> dict[str, Any]:
        asked.append(offline)
        return {"out": "replay.html"}

    monkeypatch.setattr(runs, "load_run", lambda path: path)
    monkeypatch.setattr(render, "render", fake_render)
    assert main(["render", "some_run"]) == 0
    assert main(["render", "some_run", "--cdn"]) == 0
    assert asked == [True, False]


def test_poses_of_another_system_are_refused(hopper: Hopper) -> None:
    sys = hopper.sys
    with pytest.raises(ValueError, match=r"expected shape \(T, 4, 3\), got \(3, 7, 3\)"):
        replay_html(sys, np.zeros((3, 7, 3)), np.zeros((3, 7, 4)))
    with pytest.raises(ValueError, match="at least one frame"):
        replay_html(sys, np.zeros((0, 4, 3)), np.zeros((0, 4, 4)))


# Runs the page's script in node with a stand-in DOM and a WebGL context that
# counts draws: loading, inflating the scene, playing, pausing and the slider.
_HARNESS = r"""
const fs = require("fs");
const [script, blob, options] = process.argv.slice(2);
function element(props) {
  return Object.assign({
    style: {}, textContent: "", value: "", checked: false, handlers: {},
    addEventListener(type, fn) { (this.handlers[type] = this.handlers[type] || []).push(fn); },
    fire(type) { for (const fn of this.handlers[type] || []) fn({ preventDefault() {} }); },
  }, props);
}
let draws = 0, models = [];
const gl = new Proxy({}, { get(_, name) {
  if (name === "drawArrays") return (mode, first, count) => { if (count > 0) draws++; };
  if (name === "clear") return () => { models = []; };
  if (name === "getUniformLocation") return (program, uniform) => uniform;
  if (name === "uniformMatrix4fv") return (where, t, m) => { if (where === "u_model") models.push(Array.from(m)); };
  if (name === "getShaderParameter" || name === "getProgramParameter") return () => true;
  if (name === "getAttribLocation") return () => 0;
  if (typeof name === "string" && /^[A-Z0-9_]+$/.test(name)) return 1;
  return () => ({});
} });
const el = {
  view: element({ clientWidth: 640, clientHeight: 480, width: 0, height: 0, getContext: () => gl }),
  scene: element({ textContent: fs.readFileSync(blob, "utf8") }),
  "viewer-options": element({ textContent: options }),
  play: element({}), frame: element({ value: "0" }), label: element({}),
  speed: element({ value: "1" }), follow: element({ checked: true }), message: element({}),
};
const frames = [];
globalThis.document = { getElementById: (id) => el[id] };
globalThis.window = globalThis;
window.devicePixelRatio = 1;
window.addEventListener = () => {};
window.requestAnimationFrame = (fn) => { frames.push(fn); };
require(script);
const period = 1010 / JSON.parse(options).fps;  // a little over one frame per tick
let now = 0;
function tick(n) { const seen = []; for (let i = 0; i < n; i++) { frames.shift()(now); now += period; seen.push(el.label.textContent); } return seen; }
function wait(left) {
  if (frames.length === 0 && el.message.textContent === "" && left > 0) { setTimeout(() => wait(left - 1), 10); return; }
  const out = { message: el.message.textContent };
  if (frames.length > 0) {
    out.playing = tick(4);
    out.drawsPerTick = draws / 4;
    el.play.fire("click"); out.paused = tick(3); out.models = models;
    el.frame.value = "1"; el.frame.fire("input"); out.slider = el.label.textContent;
    el.play.fire("click"); out.resumed = tick(3);
  }
  console.log(JSON.stringify(out));
}
wait(300);
"""


@pytest.mark.skipif(NODE is None, reason="node is not installed: the viewer's script cannot be checked")
def test_viewer_script_parses_and_plays_in_node(hopper: Hopper, tmp_path: Path) -> None:
    sys, episode, *_ = hopper
    page = write_html(sys, episode, tmp_path / "replay.html").read_text()
    script = tmp_path / "viewer.js"
    script.write_text(_script(page))
    assert _script(page).strip() == VIEWER_JS.strip()
    assert NODE is not None
    subprocess.run([NODE, "--check", str(script)], check=True, capture_output=True, timeout=30)

    blob = tmp_path / "scene.b64"
    blob.write_text(re.search(r'<script id="scene"[^>]*>(.*?)</script>', page, re.S)[1])  # type: ignore[index]
    options = re.search(r'<script id="viewer-options"[^>]*>(.*?)</script>', page, re.S)[1]  # type: ignore[index]
    harness = tmp_path / "harness.js"
    harness.write_text(_HARNESS)
    done = subprocess.run(
        [NODE, str(harness), str(script), str(blob), options], capture_output=True, text=True, timeout=30
    )
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    n = episode.length
    assert out["message"] == ""
    # The first tick starts the clock, then one frame per tick; the plane and 4 capsules each tick.
    assert out["playing"] == [f"frame {i} / {n}" for i in (1, 2, 3, 4)]
    assert out["drawsPerTick"] == 5
    assert out["paused"] == [f"frame 4 / {n}"] * 3
    # Where the viewer put each geom at frame 4 (column-major 4x4) is where MuJoCo put it.
    models = np.asarray(out["models"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    np.testing.assert_allclose(models[:, :3, 3], hopper.geom_pos[3], atol=1e-3)
    np.testing.assert_allclose(models[:, :3, :3], hopper.geom_mat[3].reshape(-1, 3, 3), atol=1e-3)
    assert out["slider"] == f"frame 2 / {n}"
    assert out["resumed"] == [f"frame 2 / {n}", f"frame 3 / {n}", f"frame 4 / {n}"]


def test_gif_replay_draws_each_frame(hopper: Hopper, tmp_path: Path) -> None:
    from PIL import Image

    sys, episode, *_ = hopper
    poses = episode.states
    try:
        out = write_video(sys, poses.pos, poses.rot, tmp_path / "replay.gif", width=96, height=72)
    except RuntimeError as e:
        if "no headless OpenGL (EGL) context" not in str(e):
            raise
        pytest.skip(f"no GIF replay on this machine: {e}")
    with Image.open(out) as gif:
        assert getattr(gif, "n_frames", 1) == STEPS and gif.size == (96, 72)
        gif.seek(0)
        first = np.asarray(gif.convert("RGB"), float)
        gif.seek(STEPS - 1)
        last = np.asarray(gif.convert("RGB"), float)
    assert first.std() > 10  # not one flat colour: a floor, a sky and a robot
    assert np.abs(first - last).mean() > 0.1  # the robot moved between the frames
    with pytest.raises(ValueError, match=r"ending with \.gif"):
        write_video(sys, poses.pos, poses.rot, tmp_path / "replay.mp4")
