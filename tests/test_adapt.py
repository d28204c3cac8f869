"""`qdrl adapt`: a run's elites or skills under perturbed gravity and actuators (Chalumeau et al.
2023's adaptation study): the study's table, one-line errors before anything compiles, and
the elites of a halfcheetah_uni repertoire replayed under every value by one program.

The default run builds a repertoire of 3 random halfcheetah_uni policies by hand (no run to
compile) and adapts it: one brax program for every value, and the task's own rollout of each
elite as the reference (two brax compiles, about 30 s on 2 cores). With -m slow, a real
MAP-Elites run and a real SMERL-DIAYN run of the packaged CPU specs are adapted through the
command.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from qdrl import adapt
from qdrl.config import ConfigError, dump_toml

STEPS = 20
QD: dict[str, Any] = {
    "experiment": {"algorithm": "map_elites", "seed": 0},
    "task": {"name": "halfcheetah_uni", "episode_length": STEPS, "policy_hidden": [4], "eval_batch": 4},
    "repertoire": {"grid_shape": [2, 2]},
    "emitter": {"batch_size": 4},
    "qd": {"num_iterations": 1, "log_every": 1, "init_batch_size": 4},
    "log": {"progress": False, "plots": False},
}
FILLED = (0, 1, 3)  # the cells of the hand-made repertoire that hold an elite


def _handmade_run(out: Path, filled: tuple[int, ...] = FILLED) -> Path:
    """A QD run directory as `qdrl run` leaves it (config.toml, repertoire.npz) without running:
    random policies in the `filled` cells (their fitnesses are placeholders)."""
    import jax

    from qdrl.experiment import build_run, resolved_toml
    from qdrl.qd.repertoires import export_npz

    out.mkdir(parents=True, exist_ok=True)
    alg, exp, log = build_run(QD)
    (out / "config.toml").write_text(resolved_toml(alg, exp, log))
    assert alg.qd is not None
    empty = jax.device_get(alg.qd.empty_repertoire(None))
    rng = np.random.default_rng(0)
    genotypes = jax.tree.map(lambda x: rng.uniform(-1.0, 1.0, np.shape(x)).astype(np.float32), empty.genotypes)
    fitnesses = np.full(np.shape(empty.fitnesses), -np.inf, np.float32)
    fitnesses[list(filled)] = 0.0
    export_npz(dataclasses.replace(empty, genotypes=genotypes, fitnesses=fitnesses), out / "repertoire.npz")
    return out


def _config_only(out: Path, spec: dict[str, Any], summary: dict[str, Any] | None = None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.toml").write_text(dump_toml(spec))
    if summary is not None:
        (out / "summary.json").write_text(json.dumps(summary))
    return out


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="qdrl")
    adapt.add_parser(parser.add_subparsers())
    return parser.parse_args(argv)


# -- the table --


def test_the_perturbation_sets_are_the_studys() -> None:
    assert tuple(0.25 * (i + 1) for i in range(20)) == adapt.GRAVITY_MULTIPLIERS
    assert tuple(0.25 * i for i in range(20)) == adapt.ACTUATOR_MULTIPLIERS
    assert adapt.perturbation_names("halfcheetah_uni") == [
        "gravity", "actuator:fthigh", "actuator:fshin", "actuator:ffoot", "actuator:leg",
    ]
    assert adapt.perturbation_names("walker2d_uni")[1:4] == [
        "actuator:thigh_left_joint", "actuator:leg_left_joint", "actuator:foot_left_joint",
    ]
    # brax v1's 4th ant leg in brax v2's names
    assert adapt.perturbation_names("ant_uni") == ["gravity", "actuator:hip_4", "actuator:ankle_4", "actuator:leg"]
    assert adapt.BRAX_V1_JOINTS["ant_uni"] == {"hip_4": "$ Torso_Aux 4", "ankle_4": "Aux 4_$ Body 13"}
    # a kind alone names each of its sets; the study's protocol weakens the whole leg at once
    chosen = adapt.perturbations_of("ant_uni", ["actuator", "gravity", "actuator:hip_4"])
    assert [p.name for p in chosen] == ["actuator:hip_4", "actuator:ankle_4", "actuator:leg", "gravity"]
    assert chosen[2].joints == ("hip_4", "ankle_4") and chosen[0].joints == ("hip_4",) and chosen[3].joints == ()
    assert adapt.perturbation_names("hopper_uni") == []


def test_the_actuators_are_found_by_their_joints() -> None:
    from qdrl.envs.brax import BraxEnv

    ant = BraxEnv("ant", "spring", 10)
    # ant.xml's first two motors drive the 4th leg (hip_4, ankle_4), then legs 1, 2, 3
    assert [ant.actuator_index(j) for j in ("hip_4", "ankle_4", "hip_1", "ankle_3")] == [0, 1, 2, 7]
    with pytest.raises(ValueError, match="no actuator drives a joint 'tail'"):
        ant.actuator_index("tail")


# -- bad input: one line, before anything compiles --


def _bad_dirs(tmp_path: Path) -> dict[str, tuple[Path, list[str] | None, str]]:
    sweep = tmp_path / "sweep"
    for seed in (0, 1):
        _config_only(sweep / f"seed_{seed}", QD)
    return {
        "unknown name": (
            _config_only(tmp_path / "qd", QD), ["gravity", "wind"],
            r"--perturbations: expected names from gravity, actuator:fthigh, actuator:fshin, actuator:ffoot, "
            r"actuator:leg .* for task 'halfcheetah_uni', got 'wind'",
        ),
        "joint of another set": (tmp_path / "qd", ["actuator:bthigh"], "got 'actuator:bthigh'"),
        "no elites": (
            _config_only(tmp_path / "empty", QD, {"num_elites": 0}), None,
            "expected a repertoire with elites; this map_elites run's holds none",
        ),
        "not a task of the study": (
            _config_only(tmp_path / "arm", {**QD, "task": {"name": "arm"}}), None,
            r"expected a run on a task of the adaptation study \(ant_uni, halfcheetah_uni, walker2d_uni\), got 'arm'",
        ),
        "a skill run off brax": (
            _config_only(tmp_path / "maze", {"experiment": {"algorithm": "diayn"}, "env": {"task": "point_maze"}}),
            None, "got 'point_maze'",
        ),
        "an RL run": (
            _config_only(tmp_path / "sac", {"experiment": {"algorithm": "sac"}, "env": {"name": "halfcheetah"}}), None,
            "expected a QD run .* or a skill-discovery run .*; this sac run has neither",
        ),
        "no run": (tmp_path / "nothing", None, "holds no run: expected a run directory written by `qdrl run`"),
        "a sweep": (sweep, None, "holds 2 runs, not one: expected a run directory"),
        "bad episode length": (tmp_path / "qd", ["gravity"], "--episode-length: expected a positive integer, got 0"),
    }


@pytest.mark.parametrize(
    "case",
    ["unknown name", "joint of another set", "no elites", "not a task of the study", "a skill run off brax",
     "an RL run", "no run", "a sweep", "bad episode length"],
)
def test_bad_input_is_one_line_before_anything_compiles(
    case: str, tmp_path: Path, compilations: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    path, names, message = _bad_dirs(tmp_path)[case]
    length = 0 if case == "bad episode length" else None
    with compilations() as c, pytest.raises(ConfigError, match=message):
        adapt.check_run(path, names, length)
    assert c.count == 0
    argv = ["adapt", str(path)] + (["--perturbations", ",".join(names)] if names else [])
    argv += ["--episode-length", "0"] if length == 0 else []
    with compilations() as c:
        assert adapt.command(_parse(argv)) == 2
    assert c.count == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("qdrl: error: ") and "\n" not in err, err


def test_a_bad_name_exits_before_jax_is_imported(tmp_path: Path) -> None:
    run = _config_only(tmp_path / "qd", QD)
    code = (
        "import argparse, sys\n"
        "from qdrl import adapt\n"
        "p = argparse.ArgumentParser(prog='qdrl'); adapt.add_parser(p.add_subparsers())\n"
        f"code = adapt.command(p.parse_args(['adapt', {str(run)!r}, '--perturbations', 'wind']))\n"
        "assert not {'jax', 'numpy'} & set(sys.modules), sorted({'jax', 'numpy'} & set(sys.modules))\n"
        "sys.exit(code)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().startswith("qdrl: error: --perturbations: expected names from gravity")


def test_a_repertoire_without_elites_is_refused_before_its_rollouts_compile(tmp_path: Path) -> None:
    run = _handmade_run(tmp_path / "empty", filled=())  # no summary.json: found when the repertoire loads
    with pytest.raises(ConfigError, match="expected a repertoire with elites; this map_elites run's holds none"):
        adapt.evaluate(adapt.check_run(run))


# -- the elites of a repertoire under every value --


@pytest.fixture(scope="module")
def cheetah(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _handmade_run(tmp_path_factory.mktemp("cheetah"))


def test_every_value_plays_every_elite_in_one_program_and_multiplier_one_is_the_task_itself(cheetah: Path) -> None:
    from qdrl.runs import load_run

    plan = adapt.check_run(cheetah, ["gravity", "actuator:fthigh", "actuator:leg"])
    assert plan.episode_length == STEPS and plan.eval_batch == 4 and plan.policies == "elites"
    result = adapt.evaluate(plan)
    # 61 values (1 unperturbed + 3 x 20), in 61 calls of one program
    assert result.programs == 1 and len(result.rows) == 60
    assert result.policy_ids == FILLED
    gravity, fthigh, leg = (result.returns[n] for n in ("gravity", "actuator:fthigh", "actuator:leg"))
    assert gravity.shape == fthigh.shape == (20, 3)

    # Multiplier 1 is the task itself: each elite's return is its own fixed-start episode's (the
    # task's scoring, as the run scored it), bit for bit.
    run = load_run(cheetah)
    reference = np.asarray([run.rollout(run.elite(c)).return_ for c in FILLED], np.float32)
    np.testing.assert_array_equal(result.unperturbed, reference)
    np.testing.assert_array_equal(gravity[adapt.GRAVITY_MULTIPLIERS.index(1.0)], reference)
    np.testing.assert_array_equal(fthigh[adapt.ACTUATOR_MULTIPLIERS.index(1.0)], reference)
    np.testing.assert_array_equal(leg[adapt.ACTUATOR_MULTIPLIERS.index(1.0)], reference)

    # Other values change every elite's episode.
    low, high = gravity[0], gravity[-1]  # x0.25 and x5
    assert np.all(np.isfinite(gravity)) and np.all(np.abs(low - high) > 1e-3)
    assert np.all(np.abs(fthigh[0] - reference) > 1e-3)  # the front thigh without strength
    assert np.all(np.abs(leg[0] - fthigh[0]) > 1e-3)  # the whole front leg without strength
    assert result.actuators == {"fthigh": 3, "fshin": 4, "ffoot": 5}

    # The rows: best, median and mean over the elites of each value.
    row = result.rows[0]
    assert (row.perturbation, row.value, row.num_policies) == ("gravity", 0.25, 3)
    assert row.best_return == pytest.approx(float(low.max())) and row.median_return == pytest.approx(float(np.median(low)))
    assert row.mean_return == pytest.approx(float(low.mean()), rel=1e-6)
    assert result.unperturbed_row.best_return == pytest.approx(float(reference.max()))

    written = adapt.write(result, cheetah / "adaptation")
    with (cheetah / "adaptation" / "adaptation.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["perturbation", "value", "best_return", "median_return", "mean_return", "num_policies"]
    assert len(rows) == 60 and rows[20]["perturbation"] == "actuator:fthigh" and float(rows[20]["value"]) == 0.0
    assert float(rows[0]["best_return"]) == row.best_return
    on_disk = json.loads((cheetah / "adaptation" / "adaptation.json").read_text())
    assert on_disk == {k: v for k, v in written.items() if k != "files"}
    assert on_disk["unperturbed"]["best_return"] == pytest.approx(float(reference.max()))
    assert [p["perturbation"] for p in on_disk["perturbations"]] == ["gravity", "actuator:fthigh", "actuator:leg"]
    assert on_disk["perturbations"][2]["actuators"] == [3, 4, 5]
    assert (cheetah / "adaptation" / "adaptation.png").stat().st_size > 0


# -- real runs through the command (slow: each run compiles its own programs) --


def _command(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    code = adapt.command(_parse(argv))
    said = capsys.readouterr()
    assert code == 0, said.err
    result: dict[str, Any] = json.loads(said.out)
    return result


@pytest.mark.slow
def test_a_map_elites_run_adapts_through_the_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from qdrl.experiment import run
    from qdrl.runs import load_run
    from qdrl.specs import load_spec

    spec = load_spec("map_elites_halfcheetah_uni_cpu", [
        f"task.episode_length={STEPS}", "task.policy_hidden=[4]", "repertoire.num_centroids=8",
        "repertoire.cvt_samples=200", "emitter.batch_size=4", "qd.num_iterations=2", "qd.log_every=1",
        "qd.init_batch_size=4", "log.progress=false", "log.plots=false",
    ])
    run(spec, tmp_path / "me")
    said = _command(["adapt", str(tmp_path / "me"), "--perturbations", "gravity,actuator:ffoot"], capsys)
    loaded = load_run(tmp_path / "me")
    stored = np.asarray(loaded.repertoire.fitnesses)
    assert said["num_policies"] == int(np.sum(stored > -np.inf)) == loaded.summary["num_elites"]  # type: ignore[index]
    # unperturbed, the best elite's return is the run's max fitness, bit for bit
    assert said["unperturbed"]["best_return"] == float(stored.max())
    gravity = said["perturbations"][0]
    assert gravity["values"][3] == 1.0 and gravity["best_return"][3] == float(stored.max())
    assert gravity["best_return"][0] != gravity["best_return"][-1]
    assert Path(said["files"]["png"]).stat().st_size > 0


@pytest.mark.slow
def test_a_smerl_run_adapts_its_skills(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from qdrl.experiment import run
    from qdrl.specs import load_spec

    spec = load_spec("smerl_diayn_halfcheetah_uni_cpu", [
        "env.episode_length=5", "agent.hidden=[4]", "train.total_env_steps=40", "train.num_envs=2",
        "train.batch_size=4", "train.buffer_size=40", "train.learning_starts=20", "train.grad_steps_per_iter=1",
        "train.eval_every=40", "train.num_eval_envs=4", "skills.num_skills=2", "skills.hidden=[4]",
        "archive.grid_shape=[2,2]", "log.progress=false", "log.plots=false",
    ])
    run(spec, tmp_path / "smerl")
    plan = adapt.check_run(tmp_path / "smerl", ["gravity"], episode_length=10)
    assert plan.policies == "skills" and plan.episode_length == 10
    result = adapt.evaluate(plan)
    assert result.policy_ids == (0, 1) and result.programs == 1
    gravity = result.returns["gravity"]
    assert gravity.shape == (20, 2) and np.all(np.isfinite(gravity))
    assert result.unperturbed[0] != result.unperturbed[1]  # two skills, two policies
    np.testing.assert_array_equal(gravity[3], result.unperturbed)
    assert np.all(gravity[0] != gravity[-1])
    said = _command(["adapt", str(tmp_path / "smerl"), "--out", str(tmp_path / "out")], capsys)
    assert said["policies"] == "skills" and said["num_policies"] == 2 and said["episode_length"] == 5
    assert [p["perturbation"] for p in said["perturbations"]] == adapt.perturbation_names("halfcheetah_uni")
    assert (tmp_path / "out" / "adaptation.csv").is_file()


def test_best_keeps_the_fittest_elites_and_is_checked(tmp_path: Path) -> None:
    run = _handmade_run(tmp_path / "run")
    fitnesses = {0: 5.0, 1: -2.0, 3: 9.0}  # placeholders of the hand-made repertoire, made distinct
    with np.load(run / "repertoire.npz") as f:
        arrays = dict(f)
    for cell, value in fitnesses.items():
        arrays["fitnesses"][cell] = value
    np.savez(run / "repertoire.npz", **arrays)
    plan = adapt.check_run(run, ["gravity"], best=2)
    assert plan.best == 2
    result = adapt.evaluate(plan)
    assert result.policy_ids == (0, 3) and result.unperturbed_row.num_policies == 2
    with pytest.raises(ConfigError, match="--best: expected a positive integer"):
        adapt.check_run(run, ["gravity"], best=0)
