"""Replays of a brax episode that need no network: a self-contained HTML viewer, a GIF.

brax's own page (`brax.io.html`) imports three.js, lil-gui, pako and its viewer
script from public CDNs, and no installed package ships three.js, so a node
without internet shows a white page. `replay_html` writes one HTML file with
its own small WebGL viewer inline: the system's geoms (planes, spheres,
capsules, cylinders, boxes, meshes; `brax.io.json`'s dump of `sys`) placed at
each frame's link poses, play/pause, a frame slider, a speed selector, a camera
that follows the torso and orbits with the mouse. The scene is embedded as
brax's page embeds it, base64 of zlib-compressed JSON, and inflated by the
browser's own `DecompressionStream`.

`write_video` draws the same poses with MuJoCo's offscreen renderer on a
headless EGL context (Mesa's software rasteriser is enough) into a GIF.
"""

from __future__ import annotations

import base64
import copy
import html
import io
import json
import zlib
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from brax.io import json as brax_json
from PIL import Image

__all__ = ["VIEWER_JS", "replay_html", "scene_json", "write_video"]

# Decimals kept of link positions and quaternions: 0.1 mm, far below a pixel,
# and the JSON (hence the page) is about 3x smaller than at full float precision.
_DECIMALS = 4


def _check_poses(sys: Any, pos: Any, rot: Any) -> tuple[np.ndarray, np.ndarray]:
    """`pos` (T, L, 3) and `rot` (T, L, 4) as float arrays, L the links of `sys`; ValueError if not."""

    pos, rot = np.asarray(pos, np.float64), np.asarray(rot, np.float64)
    links = len(sys.link_names)
    if pos.ndim != 3 or pos.shape[1:] != (links, 3):
        raise ValueError(f"link positions: expected shape (T, {links}, 3), got {pos.shape}")
    if rot.shape != (*pos.shape[:2], 4):
        raise ValueError(f"link rotations: expected shape {(*pos.shape[:2], 4)}, got {rot.shape}")
    if pos.shape[0] == 0:
        raise ValueError("link poses: expected at least one frame, got 0")
    return pos, rot


def scene_json(sys: Any, pos: Any, rot: Any) -> str:
    """The system's geoms (`brax.io.json.dumps`) and the link poses of each frame, as JSON.

    Same layout as brax's own dump: `{"geoms": {link name: [geom, ...]},
    "states": {"x": [{"pos": (L, 3), "rot": (L, 4)}, ...]}, ...}`, quaternions
    (w, x, y, z), positions rounded to `_DECIMALS`.
    """
    pos, rot = _check_poses(sys, pos, rot)
    scene = json.loads(brax_json.dumps(sys, []))
    scene["states"] = {
        "x": [
            {"pos": np.round(p, _DECIMALS).tolist(), "rot": np.round(r, _DECIMALS).tolist()}
            for p, r in zip(pos, rot, strict=True)
        ]
    }
    return json.dumps(scene, separators=(",", ":"))


def replay_html(sys: Any, pos: Any, rot: Any, fps: float = 30.0, title: str = "qdrl replay") -> str:
    """One HTML page replaying the link poses `pos` (T, L, 3), `rot` (T, L, 4) of `sys`, offline.

    Nothing on the page is fetched: the viewer script and the scene are inline.
    `fps` is the playback rate at speed 1x.
    """
    if not fps > 0:
        raise ValueError(f"fps: expected a positive number, got {fps}")
    scene = scene_json(sys, pos, rot)
    blob = base64.b64encode(zlib.compress(scene.encode("utf-8"), 9)).decode("ascii")
    frames = len(pos)
    return _PAGE.format(
        title=html.escape(title),
        blob=blob,
        last=frames - 1,
        options=json.dumps({"fps": float(fps), "follow_link": 0}),
        script=VIEWER_JS,
    )


def write_video(
    sys: Any,
    pos: Any,
    rot: Any,
    path: str | Path,
    fps: float = 25.0,
    width: int = 480,
    height: int = 360,
    stride: int = 1,
    shadows: bool = False,
) -> Path:
    """A GIF of the link poses of `sys` (every `stride`-th frame), drawn by MuJoCo offscreen.

    Uses an EGL context of its own (MuJoCo's `Renderer` picks its GL backend from
    `MUJOCO_GL` when mujoco is first imported, which brax already did), so it runs
    on a headless machine with EGL (Mesa's software rasteriser suffices). The
    camera follows the torso, from the side. `shadows` are MuJoCo's (they take
    most of a software-rendered frame's time). RuntimeError when no EGL context
    can be made. GIF frame times are whole hundredths of a second, so `fps` is
    rounded to one (at most 50).
    """
    path = Path(path)
    if path.suffix != ".gif":
        raise ValueError(f"write_video: expected a path ending with .gif, got {str(path)!r}")
    if stride < 1 or width < 1 or height < 1 or not fps > 0:
        raise ValueError(
            f"write_video: expected stride, width, height >= 1 and fps > 0, got "
            f"stride={stride}, width={width}, height={height}, fps={fps}"
        )
    pos, rot = _check_poses(sys, pos, rot)
    pos, rot = pos[::stride], rot[::stride]
    model = copy.copy(sys.mj_model)  # its offscreen buffer is sized to the frames, not the caller's
    if model.nbody != pos.shape[1] + 1:
        raise ValueError(f"write_video: expected {model.nbody - 1} links (the model's bodies), got {pos.shape[1]}")
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    try:
        from mujoco.egl import GLContext

        context = GLContext(width, height)
    except Exception as e:  # no libEGL, no driver: say what to do instead
        raise RuntimeError(
            f"write_video: no headless OpenGL (EGL) context on this machine ({e}); "
            "write the HTML replay instead"
        ) from e
    try:
        context.make_current()
        render_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        try:
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, render_context)
            images = _draw_frames(model, pos, rot, render_context, width, height, shadows)
        finally:
            render_context.free()
    finally:
        context.free()
    gif = [Image.fromarray(image) for image in images]
    duration = 10 * max(2, round(100.0 / fps))  # browsers slow frames under 20 ms down to 100 ms
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    gif[0].save(buffer, format="GIF", save_all=True, append_images=gif[1:], duration=duration, loop=0)
    path.write_bytes(buffer.getvalue())
    return path


def _draw_frames(
    model: Any, pos: np.ndarray, rot: np.ndarray, context: Any, width: int, height: int, shadows: bool
) -> list[np.ndarray]:
    """One RGB image (height, width, 3) per frame, bodies placed at the given link poses."""

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)  # world geoms, lights and cameras at rest
    scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
    scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
    scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False  # a mirror floor only distracts
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.azimuth, camera.elevation = 90.0, -15.0
    camera.distance = max(3.0, 2.5 * float(np.ptp(pos[0], axis=0).max()))
    option, perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
    viewport = mujoco.MjrRect(0, 0, width, height)
    moving = model.geom_bodyid > 0
    geom_body = model.geom_bodyid[moving]
    height0 = pos[0, 0, 2]
    images = []
    mat, geom_quat = np.zeros(9), np.zeros(4)
    for p, q in zip(pos, rot, strict=True):
        # The renderer reads only the world poses of bodies and geoms, which the
        # episode gives for bodies; each geom sits at its fixed offset in its body.
        data.xpos[1:], data.xquat[1:] = p, q
        for body in range(1, model.nbody):
            mujoco.mju_quat2Mat(mat, q[body - 1])
            data.xmat[body] = mat
        for geom, body in zip(np.flatnonzero(moving), geom_body, strict=True):
            mujoco.mju_mulQuat(geom_quat, q[body - 1], model.geom_quat[geom])
            mujoco.mju_quat2Mat(mat, geom_quat)
            data.geom_xmat[geom] = mat
            data.geom_xpos[geom] = p[body - 1] + data.xmat[body].reshape(3, 3) @ model.geom_pos[geom]
        camera.lookat[:] = (p[0, 0], p[0, 1], height0)  # follow the torso in x-y, not its bobbing
        mujoco.mjv_updateScene(model, data, option, perturb, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
        mujoco.mjr_render(viewport, scene, context)
        image = np.zeros((height, width, 3), np.uint8)
        mujoco.mjr_readPixels(image, None, viewport, context)
        images.append(np.flipud(image))  # OpenGL's rows run bottom-up
    return images


# The viewer: plain ES2017 and WebGL 1, no module, no library. It reads the
# scene from the `scene` element and the options from `viewer-options`.
VIEWER_JS = r"""
"use strict";
(function () {
  // ---- 3-vectors, quaternions (w, x, y, z, brax's order), column-major 4x4 matrices ----
  function rotation(q) {  // the 3x3 rotation of unit quaternion q, column-major
    const w = q[0], x = q[1], y = q[2], z = q[3];
    return [
      1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y),
      2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x),
      2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y),
    ];
  }
  function quatMul(a, b) {
    return [
      a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
      a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
      a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
      a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ];
  }
  function rotate(q, v) {
    const r = rotation(q);
    return [
      r[0] * v[0] + r[3] * v[1] + r[6] * v[2],
      r[1] * v[0] + r[4] * v[1] + r[7] * v[2],
      r[2] * v[0] + r[5] * v[1] + r[8] * v[2],
    ];
  }
  function pose(p, q) {  // 4x4 rigid transform: rotate by q, then move to p
    const r = rotation(q);
    return new Float32Array([r[0], r[1], r[2], 0, r[3], r[4], r[5], 0, r[6], r[7], r[8], 0, p[0], p[1], p[2], 1]);
  }
  function mul(a, b) {
    const out = new Float32Array(16);
    for (let c = 0; c < 4; c++) {
      for (let r = 0; r < 4; r++) {
        let s = 0;
        for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
        out[c * 4 + r] = s;
      }
    }
    return out;
  }
  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function unit(a) { const n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; }
  function lookAt(eye, target) {  // view matrix, +z up
    const f = unit(sub(target, eye));
    const s = unit(cross(f, [0, 0, 1]));
    const u = cross(s, f);
    return new Float32Array([
      s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0,
      -dot(s, eye), -dot(u, eye), dot(f, eye), 1,
    ]);
  }
  function perspective(fovy, aspect, near, far) {
    const f = 1 / Math.tan(fovy / 2);
    return new Float32Array([
      f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1,
      0, 0, (2 * far * near) / (near - far), 0,
    ]);
  }

  // ---- triangle soups (positions, normals) of MuJoCo's geoms in their own frame ----
  function Soup() { this.p = []; this.n = []; }
  Soup.prototype.tri = function (a, b, c, na, nb, nc) {
    this.p.push(...a, ...b, ...c);
    this.n.push(...na, ...nb, ...nc);
  };
  function lathe(profile, segments) {
    // Revolves (radius, z, normal radius, normal z) points about the z axis.
    const soup = new Soup();
    for (let i = 0; i + 1 < profile.length; i++) {
      const a = profile[i], b = profile[i + 1];
      for (let j = 0; j < segments; j++) {
        const t0 = (2 * Math.PI * j) / segments, t1 = (2 * Math.PI * (j + 1)) / segments;
        const c0 = Math.cos(t0), s0 = Math.sin(t0), c1 = Math.cos(t1), s1 = Math.sin(t1);
        const pa0 = [a[0] * c0, a[0] * s0, a[1]], pa1 = [a[0] * c1, a[0] * s1, a[1]];
        const pb0 = [b[0] * c0, b[0] * s0, b[1]], pb1 = [b[0] * c1, b[0] * s1, b[1]];
        const na0 = [a[2] * c0, a[2] * s0, a[3]], na1 = [a[2] * c1, a[2] * s1, a[3]];
        const nb0 = [b[2] * c0, b[2] * s0, b[3]], nb1 = [b[2] * c1, b[2] * s1, b[3]];
        soup.tri(pa0, pa1, pb1, na0, na1, nb1);
        soup.tri(pa0, pb1, pb0, na0, nb1, nb0);
      }
    }
    return soup;
  }
  function cap(radius, z, sign, rings) {  // half a sphere, from the equator towards sign * z
    const points = [];
    for (let i = 0; i <= rings; i++) {
      const phi = (Math.PI / 2) * (i / rings), c = Math.cos(phi), s = Math.sin(phi);
      points.push([radius * c, z + sign * radius * s, c, sign * s]);
    }
    return points;
  }
  function sphere(r) { return lathe(cap(r, 0, -1, 8).reverse().concat(cap(r, 0, 1, 8)), 24); }
  function capsule(r, h) { return lathe(cap(r, -h, -1, 6).reverse().concat(cap(r, h, 1, 6)), 20); }
  function cylinder(r, h) {
    return lathe([[0, -h, 0, -1], [r, -h, 0, -1], [r, -h, 1, 0], [r, h, 1, 0], [r, h, 0, 1], [0, h, 0, 1]], 24);
  }
  function box(x, y, z) {
    const soup = new Soup();
    for (let axis = 0; axis < 3; axis++) {
      for (const side of [-1, 1]) {
        const u = (axis + 1) % 3, v = (axis + 2) % 3, half = [x, y, z];
        const corner = (a, b) => { const c = [0, 0, 0]; c[axis] = side * half[axis]; c[u] = a * half[u]; c[v] = b * half[v]; return c; };
        const n = [0, 0, 0]; n[axis] = side;
        soup.tri(corner(-1, -1), corner(1, -1), corner(1, 1), n, n, n);
        soup.tri(corner(-1, -1), corner(1, 1), corner(-1, 1), n, n, n);
      }
    }
    return soup;
  }
  function plane() {  // brax collides with planes as infinite ones, whatever their drawn size
    const a = 1000, b = 1000, n = [0, 0, 1], soup = new Soup();
    soup.tri([-a, -b, 0], [a, -b, 0], [a, b, 0], n, n, n);
    soup.tri([-a, -b, 0], [a, b, 0], [-a, b, 0], n, n, n);
    return soup;
  }
  function mesh(vert, face) {
    const soup = new Soup();
    for (const f of face) {
      const a = vert[f[0]], b = vert[f[1]], c = vert[f[2]], n = unit(cross(sub(b, a), sub(c, a)));
      soup.tri(a, b, c, n, n, n);
    }
    return soup;
  }
  function shape(geom) {
    const s = geom.size;
    switch (geom.name) {
      case "Plane": return plane();
      case "Sphere": return sphere(s[0]);
      case "Capsule": return capsule(s[0], s[1]);
      case "Cylinder": return cylinder(s[0], s[1]);
      case "Box": return box(s[0], s[1], s[2]);
      case "Mesh": return mesh(geom.vert, geom.face);
      default: return null;  // a height map: not drawn
    }
  }

  // ---- WebGL ----
  const VERTEX = [
    "attribute vec3 a_pos; attribute vec3 a_nrm;",
    "uniform mat4 u_model; uniform mat4 u_viewproj;",
    "varying vec3 v_nrm; varying vec3 v_world;",
    "void main() {",
    "  vec4 world = u_model * vec4(a_pos, 1.0);",
    "  v_world = world.xyz; v_nrm = (u_model * vec4(a_nrm, 0.0)).xyz;",
    "  gl_Position = u_viewproj * world;",
    "}",
  ].join("\n");
  const FRAGMENT = [
    "#ifdef GL_FRAGMENT_PRECISION_HIGH",
    "precision highp float;",
    "#else",
    "precision mediump float;",
    "#endif",
    "uniform vec4 u_color; uniform float u_checker; uniform vec3 u_eye; uniform vec3 u_sky;",
    "varying vec3 v_nrm; varying vec3 v_world;",
    "void main() {",
    "  vec3 n = normalize(v_nrm);",
    "  vec3 base = u_color.rgb;",  // planes: a grey 1 m checkerboard, as in brax's viewer
    "  if (u_checker > 0.5) base = vec3(0.6 + 0.08 * mod(floor(v_world.x) + floor(v_world.y), 2.0));",
    "  float sun = max(dot(n, normalize(vec3(0.4, -0.6, 0.8))), 0.0);",
    "  vec3 color = base * (0.3 + 0.2 * (0.5 + 0.5 * n.z) + 0.65 * sun);",
    "  float fog = clamp((distance(v_world, u_eye) - 20.0) / 60.0, 0.0, 1.0);",
    "  gl_FragColor = vec4(mix(color, u_sky, fog), u_color.a);",
    "}",
  ].join("\n");
  const SKY = [0.86, 0.9, 0.95];

  function compile(gl, type, source) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(shader));
    return shader;
  }
  function program(gl) {
    const prog = gl.createProgram();
    gl.attachShader(prog, compile(gl, gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(prog, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("program: " + gl.getProgramInfoLog(prog));
    const where = {};
    for (const name of ["u_model", "u_viewproj", "u_color", "u_checker", "u_eye", "u_sky"]) where[name] = gl.getUniformLocation(prog, name);
    where.a_pos = gl.getAttribLocation(prog, "a_pos");
    where.a_nrm = gl.getAttribLocation(prog, "a_nrm");
    return { prog: prog, where: where };
  }
  function upload(gl, data) {
    const buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(data), gl.STATIC_DRAW);
    return buffer;
  }

  // ---- the scene ----
  async function inflate(base64) {
    const bytes = Uint8Array.from(atob(base64), (c) => c.charCodeAt(0));
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
    return JSON.parse(await new Response(stream).text());
  }
  function geomsOf(scene, gl) {
    const geoms = [];
    for (const list of Object.values(scene.geoms)) {
      for (const geom of list) {
        const soup = shape(geom);
        if (soup === null || geom.rgba[3] <= 0) continue;
        geoms.push({
          link: geom.link_idx, pos: geom.pos, rot: geom.rot, rgba: geom.rgba,
          plane: geom.name === "Plane", count: soup.p.length / 3,
          positions: upload(gl, soup.p), normals: upload(gl, soup.n),
        });
      }
    }
    // Opaque first, so that blended geoms show what lies behind them.
    geoms.sort((a, b) => (a.rgba[3] < 1) - (b.rgba[3] < 1));
    return geoms;
  }
  function placed(geom, frame) {  // the geom's world transform at `frame`
    if (geom.link < 0) return pose(geom.pos, geom.rot);
    const p = frame.pos[geom.link], q = frame.rot[geom.link], o = rotate(q, geom.pos);
    return pose([p[0] + o[0], p[1] + o[1], p[2] + o[2]], quatMul(q, geom.rot));
  }
  function reach(scene, link) {  // how far the robot's geoms reach from the followed link at the start
    const frame = scene.states.x[0], centre = frame.pos[link];
    let far = 0.5;
    for (const list of Object.values(scene.geoms)) {
      for (const geom of list) {
        if (geom.link_idx < 0) continue;
        const p = frame.pos[geom.link_idx], d = Math.hypot(p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]);
        far = Math.max(far, d + Math.max(...geom.size));
      }
    }
    return far;
  }

  function show(message) {
    const box = document.getElementById("message");
    box.textContent = message;
    box.style.display = "block";
  }

  async function main() {
    const options = JSON.parse(document.getElementById("viewer-options").textContent);
    const canvas = document.getElementById("view");
    const gl = canvas.getContext("webgl", { antialias: true });
    if (!gl) { show("This browser gives no WebGL context: the replay cannot be drawn."); return; }
    if (typeof DecompressionStream === "undefined") {
      show("This browser lacks DecompressionStream (Chrome 80, Firefox 113, Safari 16.4 or later)."); return;
    }
    const scene = await inflate(document.getElementById("scene").textContent.trim());
    const frames = scene.states.x, follow = options.follow_link;
    const shader = program(gl), where = shader.where, geoms = geomsOf(scene, gl);
    const ui = {
      play: document.getElementById("play"), slider: document.getElementById("frame"),
      label: document.getElementById("label"), speed: document.getElementById("speed"),
      follow: document.getElementById("follow"),
    };
    const view = { azimuth: -Math.PI / 2, elevation: 0.35, distance: Math.max(2.5, 3.5 * reach(scene, follow)) };
    const height = frames[0].pos[follow][2];
    let frame = 0, playing = true, clock = 0, last = null, fixed = [0, 0, height];

    function setFrame(i) {
      frame = ((i % frames.length) + frames.length) % frames.length;
      ui.slider.value = String(frame);
      ui.label.textContent = "frame " + (frame + 1) + " / " + frames.length;
    }
    function setPlaying(on) { playing = on; ui.play.textContent = on ? "Pause" : "Play"; last = null; }
    ui.play.addEventListener("click", () => setPlaying(!playing));
    ui.slider.addEventListener("input", () => { setFrame(parseInt(ui.slider.value, 10)); clock = 0; });
    ui.follow.addEventListener("change", () => {  // unfollowing keeps the camera where it is
      const p = frames[frame].pos[follow];
      fixed = [p[0], p[1], height];
    });
    window.addEventListener("keydown", (e) => {
      if (e.key === " ") { setPlaying(!playing); e.preventDefault(); }
      if (e.key === "ArrowRight") setFrame(frame + 1);
      if (e.key === "ArrowLeft") setFrame(frame - 1);
    });
    let drag = null;
    canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; });
    window.addEventListener("pointerup", () => { drag = null; });
    window.addEventListener("pointermove", (e) => {
      if (drag === null) return;
      view.azimuth -= 0.008 * (e.clientX - drag[0]);
      view.elevation = Math.min(1.5, Math.max(-0.2, view.elevation + 0.008 * (e.clientY - drag[1])));
      drag = [e.clientX, e.clientY];
    });
    canvas.addEventListener("wheel", (e) => {
      view.distance = Math.min(200, Math.max(0.3, view.distance * Math.exp(0.001 * e.deltaY)));
      e.preventDefault();
    }, { passive: false });

    function target() {  // the torso in x-y at its starting height: the hopping stays visible
      if (!ui.follow.checked) return fixed;
      const p = frames[frame].pos[follow];
      return [p[0], p[1], height];
    }
    function draw() {
      const w = Math.max(1, Math.round(canvas.clientWidth * (window.devicePixelRatio || 1)));
      const h = Math.max(1, Math.round(canvas.clientHeight * (window.devicePixelRatio || 1)));
      if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
      gl.viewport(0, 0, w, h);
      gl.clearColor(SKY[0], SKY[1], SKY[2], 1);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
      gl.useProgram(shader.prog);
      const t = target(), c = Math.cos(view.elevation);
      const eye = [
        t[0] + view.distance * c * Math.cos(view.azimuth),
        t[1] + view.distance * c * Math.sin(view.azimuth),
        t[2] + view.distance * Math.sin(view.elevation),
      ];
      gl.uniformMatrix4fv(where.u_viewproj, false, mul(perspective(0.7, w / h, 0.05, 400), lookAt(eye, t)));
      gl.uniform3fv(where.u_eye, eye);
      gl.uniform3fv(where.u_sky, SKY);
      const x = frames[frame];
      for (const geom of geoms) {
        gl.uniformMatrix4fv(where.u_model, false, placed(geom, x));
        gl.uniform4fv(where.u_color, geom.rgba);
        gl.uniform1f(where.u_checker, geom.plane ? 1 : 0);
        gl.bindBuffer(gl.ARRAY_BUFFER, geom.positions);
        gl.enableVertexAttribArray(where.a_pos);
        gl.vertexAttribPointer(where.a_pos, 3, gl.FLOAT, false, 0, 0);
        gl.bindBuffer(gl.ARRAY_BUFFER, geom.normals);
        gl.enableVertexAttribArray(where.a_nrm);
        gl.vertexAttribPointer(where.a_nrm, 3, gl.FLOAT, false, 0, 0);
        gl.drawArrays(gl.TRIANGLES, 0, geom.count);
      }
    }
    function tick(now) {
      if (playing) {
        if (last !== null) {
          clock += ((now - last) / 1000) * options.fps * parseFloat(ui.speed.value);
          const steps = Math.floor(clock);
          if (steps > 0) { clock -= steps; setFrame(frame + steps); }
        }
        last = now;
      }
      draw();
      window.requestAnimationFrame(tick);
    }
    setFrame(0);
    window.requestAnimationFrame(tick);
  }

  main().catch((e) => show("The replay failed: " + e));
})();
"""

_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<link rel="icon" href="data:,">
<style>
  html, body {{ margin: 0; height: 100%; overflow: hidden; font: 14px sans-serif; background: #dbe6f2; }}
  #view {{ display: block; width: 100%; height: calc(100% - 44px); touch-action: none; cursor: grab; }}
  #bar {{ display: flex; align-items: center; gap: 10px; height: 44px; padding: 0 10px; box-sizing: border-box;
          overflow: hidden; white-space: nowrap; background: #f4f4f4; }}
  #frame {{ flex: 1; min-width: 80px; }}
  #title {{ min-width: 0; overflow: hidden; text-overflow: ellipsis; }}
  #label {{ min-width: 9em; font-variant-numeric: tabular-nums; }}
  #message {{ display: none; position: absolute; top: 20px; left: 20px; padding: 10px; background: #fff3cd; }}
</style>
</head>
<body>
<canvas id="view"></canvas>
<div id="bar">
  <button id="play">Pause</button>
  <input id="frame" type="range" min="0" max="{last}" value="0" step="1">
  <span id="label"></span>
  <select id="speed" title="playback speed">
    <option value="0.25">0.25x</option><option value="0.5">0.5x</option>
    <option value="1" selected>1x</option><option value="2">2x</option><option value="4">4x</option>
  </select>
  <label><input id="follow" type="checkbox" checked> follow the torso</label>
  <span id="title" title="drag to orbit, wheel to zoom, space to pause, arrows to step">{title}</span>
</div>
<div id="message"></div>
<script id="viewer-options" type="application/json">{options}</script>
<script id="scene" type="application/octet-stream">{blob}</script>
<script>{script}</script>
</body>
</html>
"""
