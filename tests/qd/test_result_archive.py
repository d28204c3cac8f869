"""A search archive beside its result archive (`qdrl.qd.repertoires.result`): what each sees and
returns, where parents come from, and the metrics a run reads."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.algorithms.qd import range_cqd_score, with_range_score
from qdrl.qd.metrics import cqd_score
from qdrl.qd.repertoires import (
    density_archive,
    grid_repertoire,
    proximity_archive,
    with_result_archive,
)
from qdrl.qd.repertoires.result import result_archive

EXAMPLE = jnp.zeros((3,))


def _pair(capacity: int = 8) -> object:
    search = proximity_archive(EXAMPLE, capacity, 2, k_neighbors=2, novelty_threshold=0.5)
    return with_result_archive(search, grid_repertoire(EXAMPLE, (4, 4), 0.0, 1.0))


def test_both_archives_see_every_batch_and_the_search_archive_judges_it() -> None:
    pair = _pair()
    d = jnp.array([[0.1, 0.1], [0.12, 0.1], [0.9, 0.9]])
    f = jnp.array([1.0, 2.0, 3.0])
    g = jnp.arange(9.0).reshape(3, 3)
    pair, added = pair.add(g, d, f)
    # an empty proximity archive takes the whole batch (novelty = threshold); the grid keeps
    # the fitter of the two candidates of cell (0, 0)
    assert added.status is not None and added.info is not None
    assert np.asarray(added.status).tolist() == [2, 2, 2]
    assert int(pair.search.num_filled) == 3 and int(pair.result.num_filled) == 2
    # the run's figures read the result archive
    np.testing.assert_array_equal(np.asarray(pair.fitnesses), np.asarray(pair.result.fitnesses))
    assert float(with_range_score(pair, 0.0)["qd_score"]) == 5.0
    assert int(with_range_score(pair, 0.0)["search_size"]) == 3
    assert float(with_range_score(pair, 0.0)["novelty_threshold"]) == 0.5
    assert result_archive(pair) is pair.result and result_archive(pair.result) is pair.result
    # a second batch: (0.11, 0.1) lies within 0.5 of its 2 nearest members: not novel
    pair, added = pair.add(g[:1], jnp.array([[0.11, 0.1]]), jnp.array([0.5]))
    assert np.asarray(added.status).tolist() == [0] and int(pair.search.num_filled) == 3


def test_parents_come_from_the_search_archive_or_the_result_archive_while_it_is_empty() -> None:
    pair = _pair()
    result = pair.result.add(jnp.ones((1, 3)), jnp.array([[0.5, 0.5]]), jnp.array([1.0]))[0]
    pair = type(pair)(pair.search, result, pair.parents)
    drawn = jax.jit(lambda p, k: p.sample(k, 4))(pair, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(np.asarray(drawn), np.ones((4, 3)))  # search archive empty
    pair, _ = pair.add(jnp.full((1, 3), 7.0), jnp.array([[0.9, 0.9]]), jnp.array([1.0]))
    drawn = jax.jit(lambda p, k: p.sample(k, 4))(pair, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(np.asarray(drawn), np.full((4, 3), 7.0))
    # an archive without solutions gives its parents from the result archive
    density = with_result_archive(density_archive(2, 16, 0.1, key=jax.random.PRNGKey(0)), result)
    assert density.parents == "result"
    with pytest.raises(ValueError, match="parents"):
        with_result_archive(pair.search, result, "elsewhere")  # type: ignore[arg-type]


def test_the_runs_cqd_score_is_pyribs_formula_at_the_shared_targets() -> None:
    pair = _pair()
    d = jnp.array([[0.1, 0.1], [0.9, 0.9]])
    pair, _ = pair.add(jnp.zeros((2, 3)), d, jnp.array([20.0, 60.0]))
    got = float(range_cqd_score(pair, (10.0, 110.0), (0.0, 0.0), (1.0, 1.0)))
    # fitnesses shifted to the range's min and scaled by its width; distances on the diagonal
    targets = jax.random.uniform(jax.random.PRNGKey(42), (5, 200, 2))
    want = float(cqd_score(d, jnp.array([10.0, 50.0]), targets, 5, 0.0, 100.0, float(np.sqrt(2.0))))
    assert got == pytest.approx(want, rel=1e-5)
    assert 0.0 < got < 5 * 200 * 0.5


def test_sliding_and_categorical_repertoires_are_spec_kinds(tmp_path: object) -> None:
    from pathlib import Path

    from qdrl.config import ConfigError
    from qdrl.experiment import build_run, check_spec, run

    spec = {
        "experiment": {"algorithm": "map_elites"},
        "task": {"name": "lp_sphere", "num_dims": 6},
        "repertoire": {"kind": "sliding", "grid_shape": [8, 8], "remap_frequency": 20, "buffer_capacity": 40},
        "emitter": {"kind": "isoline", "batch_size": 16, "iso_sigma": 0.5, "line_sigma": 0.2},
        "qd": {"num_iterations": 4, "log_every": 2, "init_batch_size": 16},
        "log": {"progress": False, "plots": False},
    }
    summary = run(spec, Path(str(tmp_path)) / "sliding")
    assert summary["iteration"] == 4 and 0 < summary["num_elites"] <= 64
    with pytest.raises(ConfigError, match=r"repertoire\.categories: expected 2 lists"):
        build_run({**spec, "repertoire": {"kind": "categorical", "categories": [["a", "b"]]}})
    with pytest.raises(ConfigError, match=r"repertoire\.categories: expected a list of category names"):
        check_spec({**spec, "repertoire": {"kind": "categorical"}})


@pytest.mark.slow
@pytest.mark.parametrize("name", ["dns_walker2d_uni", "dns_baselines/map_elites_walker2d_uni"])
def test_the_dns_comparison_specs_run_a_tiny_version(tmp_path: object, name: str) -> None:
    """DNS on walker2d_uni and its MAP-Elites baseline, shrunk (10-step episodes, 8 offspring,
    2 log points): both read a CVT result archive of the same cells."""
    from pathlib import Path

    from qdrl import specs
    from qdrl.config import load_toml
    from qdrl.experiment import run

    spec = load_toml(specs.resolve(name))
    spec["task"].update(episode_length=10)
    spec["repertoire"].update(num_centroids=16, cvt_samples=1000)
    spec["emitter"]["batch_size"] = 8
    spec["qd"].update(num_iterations=4, log_every=2, init_batch_size=8)
    if "search_archive" in spec:
        spec["search_archive"]["capacity"] = 8
    spec["log"] = {"progress": False, "plots": False}
    summary = run(spec, Path(str(tmp_path)) / "run")
    assert summary["iteration"] == 4 and summary["num_elites"] > 0
    assert ("search_size" in summary) == ("search_archive" in spec)
