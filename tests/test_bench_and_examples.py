"""`qdrl bench` prints the figures it promises; the examples run."""

from __future__ import annotations

import json
import math
import runpy
import subprocess
import sys
from pathlib import Path
from typing import Any, NamedTuple

import pytest

from qdrl.cli import main

ROOT = Path(__file__).resolve().parents[1]


def run_example(script: str, args: list[str], monkeypatch: pytest.MonkeyPatch,
                capsys: pytest.CaptureFixture[str]) -> list[str]:
    """Runs examples/`script` as `python examples/script args...` would, in this process (no
    second start-up of jax), and returns the lines it printed."""
    path = ROOT / "examples" / script
    monkeypatch.setattr(sys, "argv", [str(path), *args])
    capsys.readouterr()
    runpy.run_path(str(path), run_name="__main__")
    return capsys.readouterr().out.strip().splitlines()


class Start(NamedTuple):
    """What a timed MAP-Elites run started from."""

    qd_score: float
    iteration: int
    evaluations: int
    env_steps: int


@pytest.fixture
def timed_runs(monkeypatch: pytest.MonkeyPatch) -> list[tuple[Start, Any]]:
    """Every `qdrl.bench._time_run` of the test: the state it started from and the `TimedRun` it returned."""
    from qdrl import bench

    runs: list[tuple[Start, Any]] = []
    real = bench._time_run

    def spy(me: Any, state: Any, iterations: int, with_hlo: bool = False) -> Any:
        qd = float(me.metrics_fn(state.repertoire, me.qd_offset)["qd_score"])
        start = Start(qd, int(state.iteration), int(state.evaluations), int(state.env_steps))
        timed = real(me, state, iterations, with_hlo)
        runs.append((start, timed))
        return timed

    monkeypatch.setattr(bench, "_time_run", spy)
    return runs


def positive_seconds(x: float) -> bool:
    return math.isfinite(x) and x > 0


def test_bench_map_elites_quick(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], timed_runs: list[tuple[Start, Any]]
) -> None:
    out = tmp_path / "me.json"
    assert main(["bench", "map_elites", "--quick", "--config", "grid32", "--out", str(out)]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record == json.loads(out.read_text())
    (result,) = record["results"]
    assert result["cells"] == 1024 and result["iterations"] == 20 and result["dof"] == 100
    # The timed scan ran every iteration: 20 batches of 1024 evaluated, and the
    # throughput is those evaluations over the timed run.
    ((start, timed),) = timed_runs
    done = int(timed.state.evaluations) - start.evaluations
    assert int(timed.state.iteration) - start.iteration == 20 and done == 20 * 1024
    assert result["evals_per_s"] == pytest.approx(done / timed.run_s, abs=0.051)
    assert result["run_s"] == round(timed.run_s, 4)
    assert positive_seconds(result["compile_s"]) and positive_seconds(result["compile_cpu_s"])
    assert result["compile_s"] == round(timed.compile_s, 3)
    assert result["qd_score"] > start.qd_score and 0 < result["coverage"] <= 1
    assert record["machine"]["jax"]
    # The timed program's HLO, per step: the GPU program has no conditional and no
    # loop inside the step (the one while is the scan over iterations).
    hlo = result["hlo"]
    assert set(hlo) == {"cpu_optimized", "cpu_lowered", "cuda_lowered"}
    cuda = hlo["cuda_lowered"]["ops"]
    assert "conditional" not in cuda and cuda["while"] == 1
    # Against the recorded comparison with QDax (same container): bounds, not exact
    # counts, so that an XLA upgrade passes and a step doing much more work fails.
    recorded = json.loads((ROOT / "benchmarks/results/map_elites_arm_vs_qdax.json").read_text())
    rec = recorded["summary"]["grid32"]["hlo_per_step"]["cuda_lowered"]
    scatters = cuda.get("scatter", 0)
    assert scatters <= rec["qdrl"]["scatter"] + 1 and scatters <= 1.5 * rec["qdax"]["scatter"], (scatters, rec)
    executed = hlo["cuda_lowered"]["kernels"]  # lowered: every executed op of a step
    assert abs(executed - rec["qdrl"]["kernels"]) <= 0.25 * rec["qdrl"]["kernels"], (executed, rec["qdrl"])
    assert 0 < hlo["cpu_optimized"]["kernels"] < hlo["cpu_optimized"]["instructions"]


@pytest.mark.slow  # a SAC run through `qdrl bench rl`: compiles an agent of its own
def test_bench_rl_quick(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "rl", "--quick", "--config", "td3"]) == 0
    (result,) = json.loads(capsys.readouterr().out)["results"]
    assert result["algorithm"] == "td3"
    # --quick times one chunk of 50 iterations of `num_envs` env steps and
    # `grad_steps_per_iter` updates each (the warm-up chunk filled the buffer).
    num_envs, updates = result["num_envs"], result["grad_steps_per_iter"]
    assert result["env_steps"] == 50 * num_envs
    wall = result["wall_s"]  # rounded to 1 ms
    rate = result["env_steps"] / wall
    assert result["env_steps_per_s"] == pytest.approx(rate, rel=1e-3 + 5e-4 / wall)
    # grad steps / env steps = (50 x updates) / (50 x num_envs): the same time divides both.
    assert result["grad_steps_per_s"] == pytest.approx(result["env_steps_per_s"] * updates / num_envs, rel=1e-3)
    assert positive_seconds(result["compile_s"]) and positive_seconds(wall)


def test_bench_unknown_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "nope"]) == 2
    assert "unknown benchmark 'nope'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "script", ["ask_tell_numpy.py", pytest.param("train_sac.py", marks=pytest.mark.slow)]  # SAC learning: slow
)
def test_example_runs(script: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    last = run_example(script, [], monkeypatch, capsys)[-1]
    if script == "ask_tell_numpy.py":
        assert "iteration 100" in last and float(last.split("coverage")[1]) > 0.3
    else:
        assert float(last.split("eval return")[1]) > -10.0


@pytest.mark.slow  # rollouts at two batches and a MAP-Elites run of their own
def test_bench_tasks_quick(capsys: pytest.CaptureFixture[str], timed_runs: list[tuple[Start, Any]]) -> None:
    assert main(["bench", "tasks", "--quick", "--config", "point_maze"]) == 0
    (result,) = json.loads(capsys.readouterr().out)["results"]
    assert result["task"] == "point_maze" and result["episode_length"] == 20
    assert result["rollout_b32_env_steps_per_s"] > 0
    assert positive_seconds(result["rollout_b32_compile_s"])
    # MAP-Elites (--quick: batch 32, 2 iterations): both iterations ran, its figure is
    # every simulated step of them over the timed run, and it improved on the start.
    ((start, timed),) = timed_runs
    assert int(timed.state.iteration) - start.iteration == 2
    assert int(timed.state.evaluations) - start.evaluations == 2 * 32
    assert 0 < int(timed.state.env_steps) - start.env_steps <= 2 * 32 * 20
    assert result["map_elites_env_steps_per_s"] == pytest.approx(2 * 32 * 20 / timed.run_s, abs=0.051)
    assert result["map_elites_compile_s"] == round(timed.compile_s, 2) and positive_seconds(timed.compile_s)
    assert result["map_elites_fraction_of_ceiling"] == round(
        result["map_elites_env_steps_per_s"] / result["rollout_b32_env_steps_per_s"], 3
    )
    assert result["qd_score"] > start.qd_score


@pytest.mark.slow
def test_bench_policy_map_elites_quick(
    capsys: pytest.CaptureFixture[str], timed_runs: list[tuple[Start, Any]]
) -> None:
    assert main(["bench", "policy_map_elites", "--quick", "--config", "point_maze"]) == 0
    (result,) = json.loads(capsys.readouterr().out)["results"]
    assert result["task"] == "point_maze" and result["evaluations"] == 16 * 3
    # --quick: batch 16, 2 iterations of episodes of 10 steps, after 16 initial evaluations.
    ((start, timed),) = timed_runs
    assert start.evaluations == 16 and int(timed.state.evaluations) == result["evaluations"]
    assert int(timed.state.iteration) - start.iteration == 2
    assert 0 < int(timed.state.env_steps) - start.env_steps <= 2 * 16 * 10
    assert result["env_steps_per_s"] == pytest.approx(2 * 16 * 10 / timed.run_s, abs=0.051)
    assert positive_seconds(result["compile_s"]) and positive_seconds(result["compile_cpu_s"])
    assert result["qd_score"] > start.qd_score and 0 < result["coverage"] <= 1


HLO = """HloModule m

%fused_scatter (p0: f32[8], p1: s32[2], p2: f32[2]) -> f32[8] {
  %p0 = f32[8]{0} parameter(0)
  %p1 = s32[2]{0} parameter(1)
  %p2 = f32[2]{0} parameter(2)
  ROOT %scatter.1 = f32[8]{0} scatter(f32[8]{0} %p0, s32[2]{0} %p1, f32[2]{0} %p2), update_window_dims={}, to_apply=%add
}

%body (t: (s32[], f32[8])) -> (s32[], f32[8]) {
  %t = (s32[], f32[8]{0}) parameter(0)
  %i = s32[] get-tuple-element((s32[], f32[8]{0}) %t), index=0
  %x = f32[8]{0} get-tuple-element((s32[], f32[8]{0}) %t), index=1
  %y = f32[8]{0} multiply(f32[8]{0} %x, f32[8]{0} %x)
  ROOT %r = (s32[], f32[8]{0}) tuple(s32[] %i, f32[8]{0} %y)
}

%cond (t: (s32[], f32[8])) -> pred[] {
  %t = (s32[], f32[8]{0}) parameter(0)
  ROOT %c = pred[] constant(true)
}

%cheap (a: f32[8]) -> f32[8] {
  ROOT %a = f32[8]{0} parameter(0)
}

%costly (a: f32[8]) -> f32[8] {
  %a = f32[8]{0} parameter(0)
  ROOT %d = f32[8]{0} dot(f32[8]{0} %a, f32[8]{0} %a)
}

ENTRY %main (x: f32[8], i: s32[2], u: f32[2], p: pred[]) -> f32[8] {
  %x = f32[8]{0} parameter(0)
  %i = s32[2]{0} parameter(1)
  %u = f32[2]{0} parameter(2)
  %p = pred[] parameter(3)
  %f = f32[8]{0} fusion(f32[8]{0} %x, s32[2]{0} %i, f32[2]{0} %u), kind=kLoop, calls=%fused_scatter
  %t0 = (s32[], f32[8]{0}) tuple(s32[] %z, f32[8]{0} %f)
  %w = (s32[], f32[8]{0}) while((s32[], f32[8]{0}) %t0), condition=%cond, body=%body, backend_config={"known_trip_count":{"n":"3"}}
  %g = f32[8]{0} get-tuple-element((s32[], f32[8]{0}) %w), index=1
  ROOT %k = f32[8]{0} conditional(pred[] %p, f32[8]{0} %g, f32[8]{0} %g), true_computation=%cheap, false_computation=%costly
}
"""


def test_hlo_profile_counts_loops_fusions_and_the_costliest_branch() -> None:
    from qdrl.hlo_profile import hlo_profile

    prof = hlo_profile(HLO)
    assert prof["instructions"] == 23
    # The while body runs 3 times; of the conditional, the branch with the dot counts.
    assert prof["ops"] == {
        "conditional": 1, "dot": 1, "multiply": 3, "scatter": 1, "while": 1, "while_iterations": 3
    }
    assert prof["kernels_by_kind"] == {"dot": 1, "fusion:scatter": 1, "multiply": 3}
    # Bytes: fusion 32 + 8 + 8 (in) + 32 (out); multiply 3 x (64 in + 32 out); dot 64 + 32.
    assert prof["bytes"] == 80 + 3 * 96 + 96



def test_hlo_profile_imports_only_jax_and_the_standard_library() -> None:
    """Benchmark scripts load it from the source tree in another library's environment."""
    code = (
        "import sys, jax; before = set(sys.modules); import qdrl.hlo_profile; "
        "new = set(sys.modules) - before; "
        "print(sorted(m for m in new if m.split('.')[0] not in sys.stdlib_module_names))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.replace("'", '"')) == ["qdrl", "qdrl._quiet", "qdrl._version", "qdrl.hlo_profile"]


def test_compile_timed_times_the_executable_it_returns() -> None:
    import jax
    import jax.numpy as jnp

    from qdrl.compiling import compile_timed
    from qdrl.hlo_profile import module_texts

    x = jnp.arange(4.0)
    compiled = compile_timed(lambda a, b: a * b + 1.0, x, x)
    assert compiled.fn(x, x).tolist() == [1.0, 2.0, 5.0, 10.0]
    assert positive_seconds(compiled.seconds) and math.isfinite(compiled.cpu_seconds)
    assert "multiply" in module_texts(compiled.traced, compiled.fn)[f"{jax.default_backend()}_lowered"]


def test_write_module_texts_writes_the_compiled_and_lowered_programs(tmp_path: Path) -> None:
    import jax
    import jax.numpy as jnp

    from qdrl.hlo_profile import write_module_texts

    traced = jax.jit(lambda x: jnp.sin(x) * 2.0).trace(jnp.ones(4))
    write_module_texts(tmp_path / "hlo", traced, traced.lower().compile())
    here = jax.default_backend()
    names = {p.name for p in (tmp_path / "hlo").iterdir()}
    assert {f"{here}_lowered.txt", f"{here}_optimized.txt"} <= names
    assert ("cuda_lowered.txt" in names) == (here != "gpu")
    assert "sine" in (tmp_path / "hlo" / f"{here}_lowered.txt").read_text()


def test_gpu_compile_only_describes_the_gpu_and_says_what_it_needs() -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import gpu_compile_only
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    text = gpu_compile_only.target_config("h200")
    assert "core_count: 132" in text and "cuda_compute_capability { major: 9 minor: 0 }" in text
    # Without jax's CUDA plugin: a one-line error naming it; with it, code that never
    # compiles a traced program is told so. Either way no traceback, exit status 1.
    out = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "gpu_compile_only.py"), "-c", "pass"],
        capture_output=True, text=True, timeout=120,
    )
    assert out.returncode == 1
    assert "CUDA plugin" in out.stderr or "never compiled" in out.stderr
    assert "Traceback" not in out.stderr


def test_kernel_summary_finds_the_scanned_program_and_counts_its_kernels_per_step(tmp_path: Path) -> None:
    import jax
    import jax.numpy as jnp

    from qdrl.hlo_profile import kernel_summary

    def scanned(x: jax.Array) -> jax.Array:
        def body(c: jax.Array, _: None) -> tuple[jax.Array, None]:
            return jnp.sort(jnp.sin(c) * 2.0 + c[::-1]), None

        return jax.lax.scan(body, x, None, length=7)[0]

    run, other = jax.jit(scanned), jax.jit(lambda x: jnp.cumsum(x) - 1.0)
    x = jnp.linspace(0.0, 1.0, 64)
    jax.block_until_ready((run(x), other(x)))  # compiled outside the trace
    with jax.profiler.trace(str(tmp_path)):
        jax.block_until_ready((run(x), other(x)))
    (path,) = tmp_path.glob("**/*.xplane.pb")
    summary = kernel_summary(path, steps=7, top=3)
    assert summary["source"] == "host" and summary["events"] > 0
    assert summary["main_module"].startswith("jit_scanned#")
    main = summary["modules"][summary["main_module"]]
    assert main["kernels"] >= 7  # at least one kernel per step
    assert summary["per_step"]["kernels"] == round(main["kernels"] / 7, 2)
    assert main["busy_us"] > 0 and main["span_us"] > 0
    assert len(main["top"]) <= 3 and sum(t["count"] for t in main["top"]) <= main["kernels"]
    assert any(m.startswith("jit__lambda#") for m in summary["modules"])

@pytest.mark.parametrize(
    # The brax example compiles halfcheetah's physics in three programs: slow.
    # DIAYN's example trains the agent tests/test_skills_run.py trains: slow too.
    "script", [
        "map_elites_function.py",
        pytest.param("diayn_skills.py", marks=pytest.mark.slow),
        pytest.param("pga_me_brax.py", marks=pytest.mark.slow),
    ]
)
def test_example_runs_at_its_small_size(
    script: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each example at the size its QDRL_EXAMPLE_SIZE=small gives (the brax one compiles brax
    physics three times: start, chunk, replay)."""
    monkeypatch.setenv("QDRL_EXAMPLE_SIZE", "small")
    monkeypatch.chdir(tmp_path)
    lines = run_example(script, [str(tmp_path / "out")], monkeypatch, capsys)
    if script == "map_elites_function.py":
        assert float(lines[-1].split("coverage")[1]) > 0.5
    elif script == "diayn_skills.py":
        assert lines[0].startswith("1600 env steps: discriminator accuracy")
        assert int(lines[1].split("reached ")[1].split()[0]) >= 1 and lines[1].count(" z") == 4
    else:  # 8 initial policies and 2 batches of 8, 10 steps each; the critic trained 3 times
        assert lines[1].startswith("iteration 2: QD score") and "240 env steps, critic steps 12" in lines[1]
        best, again = lines[2].split("return ")[1].split(", scored again ")
        assert best == again
