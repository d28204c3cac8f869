"""The Uncertain-QD methods that change a candidate's evaluation or what a cell keeps: repeated
evaluation (ME-Sampling), ME-LS and Deep-Grid; their rules against hand-computed values, and
tiny runs of their rows through the CLI (corrected metrics, bit-exact resume)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import qdrl.algorithms  # noqa: F401  (the full spec check, whatever the packaged schema lists)
from qdrl import checkpoint
from qdrl.cli import main
from qdrl.experiment import run_spec
from qdrl.qd.base import Evaluation, evaluations_spent
from qdrl.qd.repertoires.cells import grid_repertoire
from qdrl.qd.repertoires.deep_grid import DeepGrid, deep_grid, in_cell_weights
from qdrl.qd.repertoires.mels import MELSRepertoire, mels_repertoire, sample_cells, spread
from qdrl.qd.sampling import sampled_scoring
from qdrl.types import Array


def _noisy(genotypes: Array, key: Array) -> Evaluation:
    """Fitness sum(g) + N(0, 1), descriptor g[:, :2] + N(0, I) / 10, env steps n."""
    f_key, d_key = jax.random.split(key)
    n = genotypes.shape[0]
    return Evaluation(
        fitnesses=jnp.sum(genotypes, axis=1) + jax.random.normal(f_key, (n,)),
        descriptors=genotypes[:, :2] + 0.1 * jax.random.normal(d_key, (n, 2)),
        extras={"tag": jnp.arange(n)},
        env_steps=jnp.asarray(n, jnp.int32),
    )


@pytest.mark.parametrize("jit", [False, True])
def test_sampled_scoring_means_the_samples_of_independent_keys(jit: bool) -> None:
    genotypes = jnp.arange(12.0).reshape(4, 3) / 10
    key = jax.random.PRNGKey(3)
    scoring = sampled_scoring(_noisy, 5)
    ev = (jax.jit(scoring) if jit else scoring)(genotypes, key)
    samples = ev.extras["samples"]
    assert samples["fitnesses"].shape == (4, 5) and samples["descriptors"].shape == (4, 5, 2)
    assert ev.fitnesses.shape == (4,) and ev.descriptors.shape == (4, 2)
    # sample j is the plain evaluation with the j-th key of the split
    for j, k in enumerate(jax.random.split(key, 5)):
        one = _noisy(genotypes, k)
        np.testing.assert_allclose(samples["fitnesses"][:, j], one.fitnesses, rtol=1e-6)
        np.testing.assert_allclose(samples["descriptors"][:, j], one.descriptors, rtol=1e-6)
    np.testing.assert_allclose(ev.fitnesses, np.mean(samples["fitnesses"], axis=1), rtol=1e-6)
    np.testing.assert_allclose(ev.descriptors, np.mean(samples["descriptors"], axis=1), rtol=1e-6)
    assert int(ev.env_steps) == 5 * 4
    assert evaluations_spent(ev, 4) == 5 * 4 and evaluations_spent(_noisy(genotypes, key), 4) == 4
    np.testing.assert_array_equal(ev.extras["tag"], np.arange(4))  # other extras: the first sample's
    # the samples differ (independent keys) and their mean is closer to the truth than one sample
    assert float(np.std(samples["fitnesses"][0])) > 0.1
    assert sampled_scoring(_noisy, 1) is _noisy
    with pytest.raises(ValueError, match=r"sampling\.num_samples: expected a positive integer, got 0"):
        sampled_scoring(_noisy, 0)


def _grid() -> Any:
    return grid_repertoire(jnp.zeros(2), (4, 4), 0.0, 1.0)  # cells 0.25 wide; cell = 4 * row + column


def _sampled(fitnesses: Any, descriptors: Any) -> Evaluation:
    """An evaluation whose samples are given: fitnesses (n, N), descriptors (n, N, 2)."""
    fit, desc = jnp.asarray(fitnesses, jnp.float32), jnp.asarray(descriptors, jnp.float32)
    return Evaluation(
        fit.mean(1), desc.mean(1), {"samples": {"fitnesses": fit, "descriptors": desc}}, jnp.zeros((), jnp.int32)
    )


def test_mels_cell_is_the_most_frequent_and_spread_the_mean_pairwise_distance() -> None:
    a = [[0.1, 0.1], [0.1, 0.2], [0.2, 0.1]]  # cell 0 (three samples)
    b = [[0.6, 0.6], [0.6, 0.6]]  # cell 10 (two)
    ev = _sampled([[1.0, 2.0, 3.0, 4.0, 5.0]], [a + b])
    rep, result = mels_repertoire(_grid()).add_evaluation(jnp.ones((1, 2)), ev)
    # by hand: pairs within a: 0.1, 0.1, sqrt(0.02); a to b: 2 sqrt(0.5) + 4 sqrt(0.41); within b: 0
    want = (0.2 + math.sqrt(0.02) + 2 * math.sqrt(0.5) + 4 * math.sqrt(0.41)) / 10
    assert want == pytest.approx(0.4316884, abs=1e-6)
    assert int(result.cell[0]) == 0 and bool(result.added[0]) and bool(result.new_cell[0])
    assert float(rep.spreads[0]) == pytest.approx(want, rel=1e-5)
    assert float(rep.fitnesses[0]) == pytest.approx(3.0)  # the mean of the samples
    np.testing.assert_allclose(rep.descriptors[0], [0.125, 0.125])  # QDax: the mode cell's centroid
    assert int(rep.num_filled) == 1 and np.all(np.isinf(np.asarray(rep.spreads[1:])))
    # a tie of frequencies goes to the lowest cell; one sample has spread 0
    np.testing.assert_array_equal(sample_cells(jnp.array([[5, 0, 5, 0], [3, 3, 1, 2]]), 16), [0, 3])
    np.testing.assert_array_equal(spread(jnp.ones((2, 1, 2))), [0.0, 0.0])


def _pair(fitness: float, x: float, half_width: float) -> tuple[list[float], list[list[float]]]:
    """Two samples of mean fitness `fitness` at x +- half_width on one row of cell 0: spread 2 hw."""
    return [fitness - 0.5, fitness + 0.5], [[x - half_width, 0.1], [x + half_width, 0.1]]


@pytest.mark.parametrize(
    ("fitness", "half_width", "replaces"),
    [
        (3.0, 0.01, False),  # equal fitness, lower spread: QDax asks for a strictly higher fitness
        (4.0, 0.06, False),  # higher fitness, higher spread
        (4.0, 0.05, True),  # higher fitness, equal spread
        (4.0, 0.01, True),  # higher fitness, lower spread
    ],
)
def test_mels_replaces_an_elite_only_with_higher_fitness_and_no_higher_spread(
    fitness: float, half_width: float, replaces: bool
) -> None:
    f0, d0 = _pair(3.0, 0.12, 0.05)  # the elite: fitness 3, spread 0.1
    rep, _ = mels_repertoire(_grid()).add_evaluation(jnp.zeros((1, 2)), _sampled([f0], [d0]))
    f1, d1 = _pair(fitness, 0.12, half_width)
    new, result = jax.jit(rep.add_evaluation)(jnp.ones((1, 2)), _sampled([f1], [d1]))
    assert bool(result.added[0]) is replaces and not bool(result.new_cell[0])
    assert float(result.improvement[0]) == pytest.approx(fitness - 3.0)
    want_fit, want_spread, want_g = (fitness, 2 * half_width, 1.0) if replaces else (3.0, 0.1, 0.0)
    assert float(new.fitnesses[0]) == pytest.approx(want_fit)
    assert float(new.spreads[0]) == pytest.approx(want_spread, rel=1e-5)
    assert float(new.genotypes[0, 0]) == want_g


def test_mels_batch_of_one_cell_keeps_the_fittest_then_the_lowest_spread() -> None:
    rows = [_pair(2.0, 0.12, 0.01), _pair(4.0, 0.12, 0.04), _pair(4.0, 0.12, 0.02), _pair(4.0, 0.12, 0.02)]
    ev = _sampled([r[0] for r in rows], [r[1] for r in rows])
    rep, result = mels_repertoire(_grid()).add_evaluation(jnp.arange(4.0)[:, None] * jnp.ones((4, 2)), ev)
    np.testing.assert_array_equal(result.added, [False, False, True, False])  # then the lowest index
    assert float(rep.genotypes[0, 0]) == 2.0 and float(rep.spreads[0]) == pytest.approx(0.04, rel=1e-5)
    # a candidate with a non-finite sample is rejected; a plain evaluation is one sample (spread 0)
    bad = _sampled([[1.0, np.nan]], [[[0.1, 0.1], [0.1, 0.1]]])
    _, result = rep.add_evaluation(jnp.ones((1, 2)), bad)
    assert int(result.cell[0]) == -1 and not bool(result.added[0])
    plain = Evaluation(jnp.array([9.0]), jnp.array([[0.9, 0.9]]), {}, jnp.zeros((), jnp.int32))
    rep, result = rep.add_evaluation(jnp.ones((1, 2)), plain)
    assert bool(result.added[0]) and float(rep.spreads[15]) == 0.0
    assert isinstance(rep, MELSRepertoire) and float(rep.log_metrics()["mean_spread"]) == pytest.approx(0.02, rel=1e-5)


def _one(fitnesses: Any, descriptors: Any) -> Evaluation:
    return Evaluation(
        jnp.asarray(fitnesses, jnp.float32), jnp.asarray(descriptors, jnp.float32), {}, jnp.zeros((), jnp.int32)
    )


def test_deep_grid_keeps_at_most_depth_solutions_and_reports_the_fittest() -> None:
    rep = deep_grid(grid_repertoire(jnp.zeros(1), (2, 2), 0.0, 1.0), depth=3, seed=0)
    add = jax.jit(lambda r, g, e: r.add_evaluation(g, e))
    # five candidates in cell 0, one in cell 3: the first three of cell 0 take its slots
    rep, result = add(rep, jnp.arange(6.0)[:, None], _one([1, 5, 2, 9, 3, 7], [[0.1, 0.1]] * 5 + [[0.9, 0.9]]))
    np.testing.assert_array_equal(result.added, [True, True, True, False, False, True])
    np.testing.assert_array_equal(np.sort(np.asarray(rep.deep_fitnesses[0])), [1, 2, 5])
    assert float(rep.fitnesses[0]) == 5.0 and float(rep.genotypes[0, 0]) == 1.0
    assert float(rep.fitnesses[3]) == 7.0 and int(rep.num_filled) == 2
    # the cell is full: every new candidate replaces one of its solutions, fitter or not
    rng = np.random.default_rng(0)
    for step in range(20):
        fit = rng.normal(size=3).astype(np.float32)  # three: never more than depth in one cell
        rep, result = add(rep, jnp.full((3, 1), 10.0 + step), _one(fit, rng.uniform(0, 1, (3, 2))))
        stored = np.asarray(rep.deep_fitnesses)
        assert np.all(np.sum(stored > -np.inf, axis=1) <= 3)
        np.testing.assert_array_equal(rep.fitnesses, np.max(stored, axis=1))  # the reported elite
        assert np.all(np.asarray(result.added))  # valid candidates always enter
        assert np.isin(fit, stored).all()
    assert int(rep.log_metrics()["deep_solutions"]) == 12  # 4 cells x depth 3
    # the descriptors stored in a cell fall in it (re-drawn at every evaluation, so a genotype may move)
    cells = np.asarray(rep.cell_index(rep.deep_descriptors.reshape(-1, 2))).reshape(4, 3)
    np.testing.assert_array_equal(cells, np.repeat(np.arange(4)[:, None], 3, axis=1))


def test_deep_grid_draws_parents_in_proportion_to_fitness_above_the_cells_worst() -> None:
    np.testing.assert_allclose(
        in_cell_weights(jnp.array([[0.0, 1.0, 2.0, 3.0], [2.0, 2.0, -jnp.inf, -jnp.inf]])),
        [[0, 1 / 6, 2 / 6, 3 / 6], [0.5, 0.5, 0, 0]],
    )
    rep = deep_grid(grid_repertoire(jnp.zeros(1), (2, 1), 0.0, 1.0), depth=4, seed=0)
    # cell 0: four solutions of fitness 0..3 (genotypes 0..3); cell 1: one (genotype 9)
    rep, _ = rep.add_evaluation(
        jnp.array([[0.0], [1.0], [2.0], [3.0], [9.0]]), _one([0, 1, 2, 3, 5], [[0.2, 0.5]] * 4 + [[0.8, 0.5]])
    )
    parents = np.asarray(jax.jit(rep.sample, static_argnums=1)(jax.random.PRNGKey(1), 40_000))[:, 0]
    freq = np.array([np.mean(parents == g) for g in (0, 1, 2, 3, 9)])
    # a cell drawn uniformly (1/2), then a solution by fitness above the cell's worst
    np.testing.assert_allclose(freq, [0, 1 / 12, 2 / 12, 3 / 12, 1 / 2], atol=0.01)
    empty = deep_grid(grid_repertoire(jnp.zeros(1), (2, 1), 0.0, 1.0), depth=4)
    assert np.all(np.isnan(np.asarray(empty.sample(jax.random.PRNGKey(0), 3))))
    assert isinstance(rep, DeepGrid) and rep.depth == 4


SPEC = """
[experiment]
algorithm = "{algorithm}"
seed = 2

[task]
name = "noisy_arm"
num_dofs = 8
fit_std = 0.05
desc_std = 0.02
params_std = 0.0

[repertoire]
grid_shape = [8, 8]

[emitter]
batch_size = 8

[qd]
num_iterations = 6
log_every = 3
init_batch_size = 8
reevaluate_samples = 4

[log]
progress = false
plots = false
"""


def _spec(tmp_path: Path, algorithm: str) -> Path:
    path = tmp_path / f"{algorithm}.toml"
    path.write_text(SPEC.format(algorithm=algorithm))
    return path


@pytest.mark.parametrize(
    ("algorithm", "overrides", "own"),
    [
        ("me_sampling", ["sampling.num_samples=3"], None),
        ("me_ls", ["sampling.num_samples=3"], "mean_spread"),
        ("deep_grid", ["deep_grid.depth=4"], "deep_solutions"),
    ],
)
def test_uncertain_rows_run_through_the_cli_with_corrected_metrics(
    tmp_path: Path, algorithm: str, overrides: list[str], own: str | None
) -> None:
    out = tmp_path / "out"
    sets = [x for o in overrides for x in ("--set", o)]
    assert main(["run", str(_spec(tmp_path, algorithm)), *sets, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in ("corrected_qd_score", "corrected_coverage", "corrected_max_fitness", "qd_score"):
        assert math.isfinite(summary[key]), key
    assert summary["corrected_num_elites"] > 0 and summary["reevaluate_samples"] == 4
    assert summary["num_samples"] == (1 if algorithm == "deep_grid" else 3)
    # every evaluation counts: 8 candidates at init and 6 iterations of 8, each scored num_samples times
    assert summary["evaluations"] == (8 + 6 * 8) * summary["num_samples"]
    if own is not None:
        assert math.isfinite(summary[own]) and summary[own] > 0
    assert (out / "reevaluation.json").is_file() and (out / "repertoire.npz").is_file()


def test_me_ls_resumes_bit_for_bit(tmp_path: Path) -> None:
    spec = _spec(tmp_path, "me_ls")
    full = tmp_path / "full"
    full_summary = run_spec(spec, [], full)
    out = tmp_path / "stopped"  # the run a stop after its first checkpoint leaves
    shutil.copytree(full, out)
    shutil.rmtree(checkpoint.latest(out / "checkpoints"))  # type: ignore[arg-type]
    (out / "summary.json").unlink()
    rows = (out / "metrics.csv").read_text().splitlines()
    (out / "metrics.csv").write_text("\n".join(rows[:2]) + "\n")
    resumed = run_spec(spec, [], out, resume=True)
    for key in ("qd_score", "mean_spread", "corrected_qd_score", "evaluations", "num_elites"):
        assert resumed[key] == full_summary[key], key
    final = checkpoint.latest(full / "checkpoints")
    assert final is not None
    with np.load(final / "state.npz") as a, np.load(out / "checkpoints" / final.name / "state.npz") as b:
        assert a.files == b.files
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)


@pytest.mark.parametrize(
    ("algorithm", "override", "message"),
    [
        ("me_sampling", "sampling.num_samples=0", "sampling.num_samples: expected a positive integer, got 0"),
        ("deep_grid", "deep_grid.depth=0", "deep_grid.depth: expected a positive integer, got 0"),
        ("me_ls", 'repertoire.kind="sliding"', "repertoire.kind: me_ls keeps its cells on a grid or cvt"),
        ("deep_grid", "repertoire.threshold_min=0.0", "repertoire.threshold_min: deep_grid keeps no CMA-MAE"),
        ("me_ls", "deep_grid.depth=3", "deep_grid: only the deep_grid algorithm reads it"),
    ],
)
def test_bad_uncertain_specs_fail_before_compiling(
    tmp_path: Path, algorithm: str, override: str, message: str, capsys: pytest.CaptureFixture[str],
    compilations: Any,
) -> None:
    with compilations() as compiled:
        assert main(["run", str(_spec(tmp_path, algorithm)), "--set", override, "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err
    assert compiled.count == 0
