"""Archive-, Adaptive- and Parallel-Adaptive-Sampling: accumulated samples, the rules on
constructed noisy evaluations, tiny CLI runs with corrected metrics, exact resume."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.cli import main
from qdrl.experiment import run_spec
from qdrl.qd.base import Evaluation
from qdrl.qd.repertoires import grid_repertoire
from qdrl.qd.repertoires.accumulating import AccumulatingRepertoire, accumulating_repertoire


def _cells() -> Any:
    """Two cells along x ([0, 0.5) and [0.5, 1]); genotypes of 2 genes."""
    return grid_repertoire(jnp.zeros(2), (2, 1), 0.0, 1.0)


def _ev(fitnesses: Sequence[float], xs: Sequence[float]) -> Evaluation:
    d = jnp.stack([jnp.asarray(xs, jnp.float32), jnp.full(len(xs), 0.5, jnp.float32)], axis=-1)
    return Evaluation(jnp.asarray(fitnesses, jnp.float32), d, {}, jnp.zeros((), jnp.int32))


def _step(rep: AccumulatingRepertoire, offspring: Any, fitnesses: Sequence[float], xs: Sequence[float]) -> Any:
    """One planned batch: the rows `rep.batch` builds, scored with the given values (row order)."""
    batch = rep.batch(offspring)
    return batch, *jax.jit(lambda r, b, e: r.add_evaluation(b, e))(rep, batch, _ev(fitnesses, xs))


def _genes(*values: float) -> Any:
    return jnp.stack([jnp.full(2, v, jnp.float32) for v in values])


def test_archive_sampling_keeps_the_mean_of_an_elites_samples() -> None:
    rep = accumulating_repertoire(_cells(), "archive_sampling", reevaluations=1)
    rep, _ = rep.add_evaluation(_genes(7.0), _ev([1.0], [0.1]))  # the elite, one sample
    assert int(np.asarray(rep.counts)[0]) == 1
    for f, x in ((3.0, 0.2), (5.0, 0.3)):  # row 0 re-evaluates the elite; row 1 an offspring far below
        batch, rep, result = _step(rep, _genes(0.0, 0.0), [f, -100.0], [x, 0.4])
        np.testing.assert_array_equal(np.asarray(batch[0]), [7.0, 7.0])  # the elite's genotype
        assert not bool(result.added[0]) and int(result.cell[0]) == -1  # a re-evaluation is no offspring
    assert int(np.asarray(rep.counts)[0]) == 3
    np.testing.assert_allclose(float(rep.fitnesses[0]), 3.0)  # (1 + 3 + 5) / 3
    np.testing.assert_allclose(np.asarray(rep.descriptors[0]), [0.2, 0.5], rtol=1e-6)
    np.testing.assert_allclose(float(np.asarray(rep.fitness_sums)[0]), 9.0)
    assert not bool(rep.filled[1])


def test_an_elite_whose_mean_descriptor_moves_changes_cell() -> None:
    rep = accumulating_repertoire(_cells(), "archive_sampling", reevaluations=1)
    rep, _ = rep.add_evaluation(_genes(7.0), _ev([1.0], [0.4]))
    # Re-evaluated at x = 0.8: mean x 0.6, in the second cell; the offspring row is rejected (NaN).
    _, rep, _ = _step(rep, _genes(0.0, 0.0), [2.0, jnp.nan], [0.8, 0.1])
    assert not bool(rep.filled[0]) and bool(rep.filled[1])
    assert int(np.asarray(rep.counts)[1]) == 2 and int(np.asarray(rep.counts)[0]) == 0
    np.testing.assert_allclose(float(rep.fitnesses[1]), 1.5)
    np.testing.assert_allclose(float(rep.descriptors[1, 0]), 0.6, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(rep.genotypes[1]), [7.0, 7.0])


def test_archive_sampling_compares_means_and_a_lucky_elite_falls() -> None:
    rep = accumulating_repertoire(_cells(), "archive_sampling", reevaluations=1)
    rep, _ = rep.add_evaluation(_genes(7.0), _ev([10.0], [0.1]))  # a lucky first draw
    # Its second sample is 0 (mean 5); an offspring at 6 in its cell now beats it.
    _, rep, result = _step(rep, _genes(3.0, 0.0), [0.0, 6.0], [0.1, 0.2])
    assert bool(result.added[1]) and not bool(result.new_cell[1])
    np.testing.assert_allclose(float(result.improvement[1]), 6.0 - 10.0)  # against the cell before the batch
    np.testing.assert_array_equal(np.asarray(rep.genotypes[0]), [3.0, 3.0])
    assert int(np.asarray(rep.counts)[0]) == 1 and float(rep.fitnesses[0]) == 6.0


def test_adaptive_sampling_rejects_a_truly_worse_challenger_after_its_samples() -> None:
    rep = accumulating_repertoire(_cells(), "adaptive_sampling", reevaluations=2)
    rep, _ = rep.add_evaluation(_genes(7.0), _ev([1.0], [0.1]))
    # An offspring lucky once (2.0 > 1.0) becomes the challenger; nothing is added yet.
    batch, rep, result = _step(rep, _genes(5.0, 6.0), [2.0, -1.0], [0.2, 0.3])
    assert not bool(result.added.any()) and int(np.asarray(rep.challenger_counts)[0]) == 1 and bool(np.asarray(rep.elite_due)[0])
    np.testing.assert_array_equal(np.asarray(rep.challenger_genotypes)[0], [5.0, 5.0])
    # The challenged elite's own re-evaluation (row 0) and the challenger's second (row 1): 1.0 and 0.4,
    # the challenger's mean 1.2 > the elite's 1.0 and 2 samples = the elite's 2: it wins the cell.
    batch, rep, _ = _step(rep, _genes(0.0, 0.0), [1.0, 0.4], [0.1, 0.2])
    np.testing.assert_array_equal(np.asarray(batch[:2, 0]), [7.0, 5.0])
    np.testing.assert_array_equal(np.asarray(rep.genotypes[0]), [5.0, 5.0])
    assert int(np.asarray(rep.counts)[0]) == 2 and int(np.asarray(rep.challenger_counts)[0]) == 0
    np.testing.assert_allclose(float(rep.fitnesses[0]), 1.2, rtol=1e-6)
    # A truly worse offspring (true fitness 0.5) with a lucky first draw 3.0 challenges the new elite...
    _, rep, _ = _step(rep, _genes(9.0, 0.0), [3.0, -5.0], [0.3, 0.3])
    assert int(np.asarray(rep.challenger_counts)[0]) == 1
    # ...the elite takes its sample (1.2: mean 1.2, 3 samples) and the challenger its second, 0.5:
    # mean 1.75 > 1.2 but 2 samples < 3, so it goes on; its third, -1.0, takes its mean to 0.83 < 1.2.
    _, rep, _ = _step(rep, _genes(0.0, 0.0), [1.2, 0.5], [0.2, 0.3])
    assert int(np.asarray(rep.challenger_counts)[0]) == 2 and int(np.asarray(rep.counts)[0]) == 3
    batch, rep, _ = _step(rep, _genes(0.0, 0.0), [-1.0, -9.0], [0.3, 0.1])
    np.testing.assert_array_equal(np.asarray(batch[0]), [9.0, 9.0])  # the challenger's third sample
    assert int(np.asarray(rep.challenger_counts)[0]) == 0  # rejected after 3 samples
    np.testing.assert_array_equal(np.asarray(rep.genotypes[0]), [5.0, 5.0])  # the elite stays
    np.testing.assert_allclose(float(rep.fitnesses[0]), 1.2, rtol=1e-6)


def test_adaptive_sampling_drops_a_challenger_that_leaves_the_cell() -> None:
    rep = accumulating_repertoire(_cells(), "adaptive_sampling", reevaluations=2)
    rep, _ = rep.add_evaluation(_genes(7.0), _ev([1.0], [0.1]))
    _, rep, _ = _step(rep, _genes(5.0, 6.0), [2.0, -1.0], [0.2, 0.3])
    _, rep, _ = _step(rep, _genes(0.0, 0.0), [1.0, 9.0], [0.1, 0.95])  # mean x 0.575: the other cell
    assert int(np.asarray(rep.challenger_counts)[0]) == 0
    np.testing.assert_array_equal(np.asarray(rep.genotypes[0]), [7.0, 7.0])
    assert not bool(rep.filled[1])


def test_parallel_adaptive_sampling_samples_offspring_the_median_count_times() -> None:
    cells = grid_repertoire(jnp.zeros(2), (4, 1), 0.0, 1.0)
    rep = accumulating_repertoire(cells, "parallel_adaptive_sampling", reevaluations=2)
    counts = jnp.asarray([3, 4, 0, 7], jnp.int32)
    rep = dataclasses.replace(rep, counts=counts, fitnesses=jnp.asarray([0.0, 0.0, -jnp.inf, 0.0]))
    assert int(rep.offspring_samples()) == 4  # median of 3, 4, 7
    plan = rep.plan(12)
    np.testing.assert_array_equal(np.asarray(plan.job[:2]), [0, 1])  # the two least-sampled elites
    # 10 rows left: offspring 0 and 1 on 4 rows each, the last 2 rows unused.
    np.testing.assert_array_equal(np.asarray(plan.group), [-1, -1, 0, 0, 0, 0, 1, 1, 1, 1, -1, -1])
    capped = dataclasses.replace(rep, max_samples=2)
    assert int(capped.offspring_samples()) == 2
    # An offspring's samples are averaged: 4 rows of fitness 1, 2, 3, 6 give mean 3 and count 4.
    genes = jnp.arange(12, dtype=jnp.float32)[:, None] * jnp.ones(2)
    batch = rep.batch(genes)
    np.testing.assert_array_equal(np.asarray(batch[2:6, 0]), [0.0] * 4)  # offspring 0, four times
    f = [0.0, 0.0, 1.0, 2.0, 3.0, 6.0, -9.0, -9.0, -9.0, -9.0, 0.0, 0.0]
    x = [0.1, 0.3, 0.6, 0.6, 0.6, 0.6, 0.9, 0.9, 0.9, 0.9, 0.1, 0.1]
    new, result = rep.add_evaluation(batch, _ev(f, x))
    assert bool(result.added[2]) and bool(result.new_cell[2]) and not bool(result.added[3:6].any())
    assert int(np.asarray(new.counts)[2]) == 4 and float(new.fitnesses[2]) == 3.0


def test_init_of_an_empty_repertoire_adds_every_row_once() -> None:
    for method in ("archive_sampling", "adaptive_sampling", "parallel_adaptive_sampling"):
        rep = accumulating_repertoire(_cells(), method, reevaluations=3)  # type: ignore[arg-type]
        rep, result = rep.add_evaluation(_genes(1.0, 2.0, 3.0), _ev([1.0, 2.0, 0.5], [0.1, 0.2, 0.9]))
        np.testing.assert_array_equal(np.asarray(result.added), [False, True, True])
        np.testing.assert_array_equal(np.asarray(rep.counts), [1, 1])
        np.testing.assert_allclose(np.asarray(rep.fitnesses), [2.0, 0.5])


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="method: expected one of"):
        accumulating_repertoire(_cells(), "sampling", 1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="reevaluations: expected a positive integer"):
        accumulating_repertoire(_cells(), "archive_sampling", 0)
    with pytest.raises(ValueError, match="CMA-MAE's thresholds"):
        accumulating_repertoire(_cells().with_learning_rate(0.1, 0.0), "archive_sampling", 1)


SPEC = """
[experiment]
algorithm = "{algorithm}"
seed = 1

[task]
name = "noisy_arm"
num_dofs = 8

[repertoire]
grid_shape = [8, 8]

[emitter]
batch_size = 32

[resampling]
reevaluations = 8

[qd]
num_iterations = 20
log_every = 10
init_batch_size = 32
reevaluate_samples = {samples}

[log]
progress = false
plots = false
"""

METHODS = ("archive_sampling", "adaptive_sampling", "parallel_adaptive_sampling")


def _spec(tmp_path: Path, algorithm: str, samples: int = 4) -> Path:
    path = tmp_path / f"{algorithm}.toml"
    path.write_text(SPEC.format(algorithm=algorithm, samples=samples))
    return path


@pytest.mark.parametrize("algorithm", METHODS)
def test_a_tiny_run_reports_finite_corrected_metrics(tmp_path: Path, algorithm: str) -> None:
    summary = run_spec(_spec(tmp_path, algorithm), [], tmp_path / "out")
    assert summary["evaluations"] == 32 + 20 * 32  # re-evaluations are rows of the batch
    assert summary["reevaluate_samples"] == 4
    for key in ("corrected_qd_score", "corrected_coverage", "corrected_max_fitness"):
        assert np.isfinite(summary[key]), key
    assert 0 < summary["corrected_num_elites"] <= summary["num_elites"]
    assert summary["corrected_qd_score"] <= summary["qd_score"] + 1e-3  # the stored means still flatter


def test_archive_sampling_resumes_bit_identically(
    tmp_path: Path, resumes_bit_identically: Callable[[Path, Path, dict[str, Any], Sequence[str]], None]
) -> None:
    spec = _spec(tmp_path, "archive_sampling", samples=0)
    out = tmp_path / "out"
    summary = run_spec(spec, [], out)
    resumes_bit_identically(
        spec, out, summary, ("qd_score", "coverage", "max_fitness", "mean_fitness", "num_elites")
    )


@pytest.mark.parametrize(
    ("algorithm", "override", "message"),
    [
        ("archive_sampling", "resampling.reevaluations=32",
         "resampling.reevaluations: expected below emitter.batch_size=32"),
        ("adaptive_sampling", "resampling.reevaluations=0", "resampling.reevaluations: expected a positive integer"),
        ("parallel_adaptive_sampling", 'resampling.statistic="mode"', "resampling.statistic: expected one of"),
        ("archive_sampling", 'repertoire.kind="sliding"', "repertoire.kind: archive_sampling keeps its samples"),
        ("adaptive_sampling", "repertoire.threshold_min=0.0", "repertoire.learning_rate: adaptive_sampling keeps no"),
        ("archive_sampling", 'emitter.kind="cma_improvement"', "emitter.kind: expected one of"),
    ],
)
def test_bad_specs_are_refused_before_compiling(
    tmp_path: Path, algorithm: str, override: str, message: str, capsys: pytest.CaptureFixture[str],
    compilations: Any,
) -> None:
    with compilations() as compiled:
        assert main(["run", str(_spec(tmp_path, algorithm)), "--set", override, "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err
    assert compiled.count == 0
