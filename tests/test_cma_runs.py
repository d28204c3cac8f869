"""`qdrl run` on the CMA family's specs: a tiny run of each, bit-exact resume, fast errors.

Every spec of agents/ whose algorithm is of the CMA family (MAP-Elites on the LP
tasks, CMA-ME, CMA-MAE, the bandit pool, OMG-MEGA, CMA-MEGA, CMA-MAEGA, CMA-ES)
runs shrunk to a few iterations on a small task; the run is then resumed from
its first checkpoint and must end bit-identical (every emitter's CMA-ES state,
the scheduler's statistics and the archive's thresholds are in the checkpoint).
"""

from __future__ import annotations

import json
import math
import shutil
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from qdrl.config import ConfigError, dump_toml, load_toml
from qdrl.experiment import build_run, check_spec, run_spec

AGENTS = Path(__file__).resolve().parents[1] / "agents"
FAMILY = ("cma_me", "cma_mae", "omg_mega", "cma_mega", "cma_maega", "cma_es")
SPECS = sorted(
    p for p in AGENTS.glob("*.toml")
    if (load_toml(p)["experiment"]["algorithm"] in FAMILY or "lp_sphere" in p.stem)
    and p.stem != "cma_es_sphere"  # run whole below (test_cma_es_reaches_1e_3_on_the_100d_sphere)
)
# One spec of each kind of state runs in the default suite (an archive with thresholds and
# CMA-ES instances, a bandit pool with a GA, CMA-MEGA, OMG-MEGA's stored gradients); the
# others compile programs of their own (20-30 s each on a loaded 2-core machine): -m slow.
DEFAULT = {
    "cma_mae_lp_sphere", "me_map_elites_lp_sphere", "cma_mega_lp_sphere", "omg_mega_lp_sphere",
    # search archives beside a result archive: NSLC's proximity archive, DMS's discount model and
    # its optimiser, DNS's population
    "nslc_lp_sphere", "dms_lp_sphere", "dns_lp_sphere_cpu",
}
PARAMS = [pytest.param(p, id=p.stem, marks=() if p.stem in DEFAULT else pytest.mark.slow) for p in SPECS]


def tiny(spec: dict[str, Any]) -> dict[str, Any]:
    """The spec shrunk to seconds: 6 genes, an 8x8 grid, 2 instances of 4, 2 log points of 2 iterations."""
    spec = {k: (dict(v) if isinstance(v, dict) else [dict(t) for t in v]) for k, v in spec.items()}
    task = spec["task"]
    task["num_dofs" if task["name"] == "arm" else "num_dims"] = 6
    if "repertoire" in spec:
        spec["repertoire"]["grid_shape"] = [8, 8]
    for table in [spec["emitter"]] if "emitter" in spec else spec.get("emitters", []):
        table["batch_size"] = 3 if table.get("kind") == "cma_mega" else 4
        if "num_instances" in table:
            table["num_instances"] = 2
    if "scheduler" in spec:
        spec["scheduler"]["num_active"] = 2
    if "qd" in spec:
        spec["qd"].update(num_iterations=4, log_every=2, init_batch_size=min(spec["qd"]["init_batch_size"], 8))
    if "cma_es" in spec:
        spec["cma_es"].update(num_generations=4, log_every=2, population_size=6)
    spec["log"] = {"progress": False, "plots": False, "checkpoint_every": 1, "keep_checkpoints": 2}
    return spec


def resumes_bit_identically(spec: Path, out: Path, summary: dict[str, Any], keys: Sequence[str]) -> None:
    """The finished run (two checkpoints) resumed from its first ends with the same `keys`."""
    checkpoints = sorted((out / "checkpoints").glob("step_*"))
    assert len(checkpoints) == 2
    shutil.rmtree(checkpoints[-1])
    exported = out / "repertoire.npz"
    before = dict(np.load(exported)) if exported.exists() else {}
    resumed = run_spec(spec, [], out, resume=True)
    written = json.loads((out / "summary.json").read_text())
    for key in keys:
        assert resumed[key] == summary[key] == written[key], key
    for name, array in before.items():  # every elite's genotype, fitness and descriptor
        np.testing.assert_array_equal(np.load(exported)[name], array, err_msg=name)


@pytest.mark.parametrize("path", PARAMS)
def test_a_tiny_run_of_each_spec_resumes_bit_identically(path: Path, tmp_path: Path) -> None:
    spec_file = tmp_path / path.name
    spec_file.write_text(dump_toml(tiny(load_toml(path))))
    out = tmp_path / "out"
    summary = run_spec(spec_file, [], out)
    rows = pd.read_csv(out / "metrics.csv")
    if "cma_es" in summary["algorithm"]:
        assert summary["generation"] == 4 and summary["evaluations"] == 4 * 6
        assert math.isfinite(summary["best_fitness"]) and (out / "best.npz").exists()
        keys: tuple[str, ...] = ("best_fitness", "sigma", "evaluations", "restarts")
    else:
        assert summary["iteration"] == 4 and summary["num_elites"] > 0
        # the normalised QD score is logged beside the QD score: per cell of the 8x8 grid
        assert list(rows.columns).index("normalised_qd_score") == list(rows.columns).index("qd_score") + 1
        assert summary["normalised_qd_score"] == pytest.approx(summary["qd_score"] / 64, rel=1e-5)
        keys = ("qd_score", "normalised_qd_score", "coverage", "num_elites", "evaluations")
        if "search_archive" in load_toml(path):  # the search archive's own figures, and the CQD score
            assert summary["search_size"] > 0 and math.isfinite(summary["cqd_score"])
            keys = (*keys, "search_size", "cqd_score", *(k for k in ("discount_loss",) if k in summary))
        if "restarts" in summary:  # CMA-ES instances (all but MAP-Elites and OMG-MEGA)
            keys = (*keys, "restarts")
    assert len(rows) == 2
    resumes_bit_identically(spec_file, out, summary, keys)


def _spec(name: str, **sections: dict[str, Any]) -> dict[str, Any]:
    spec = tiny(load_toml(AGENTS / f"{name}.toml"))
    for section, table in sections.items():
        spec[section] = {**spec.get(section, {}), **table}
    return spec


@pytest.mark.parametrize(
    ("name", "section", "table", "message"),
    [
        ("cma_me_lp_sphere", "emitter", {"sigma0": 0.0}, "emitter.sigma0: expected a number > 0, got 0.0"),
        ("cma_me_lp_sphere", "emitter", {"sigma0": -0.5}, "emitter.sigma0: expected a number > 0, got -0.5"),
        ("cma_mae_lp_sphere", "repertoire", {"learning_rate": 1.5}, "repertoire.learning_rate: expected a number in [0, 1], got 1.5"),
        ("cma_mae_lp_sphere", "repertoire", {"learning_rate": -0.1}, "repertoire.learning_rate: expected a number in [0, 1], got -0.1"),
        ("cma_mae_lp_sphere", "repertoire", {"threshold_min": -math.inf},
         "repertoire.threshold_min: expected a finite number when repertoire.learning_rate < 1 (CMA-MAE), got -inf"),
        ("cma_me_lp_sphere", "emitter", {"ranker": "3imp"}, "emitter.ranker: expected one of ['2imp', '2obj', '2rd', 'density', 'imp', 'nov', 'nslc', 'obj', 'rd'] or nothing (omit the key), got '3imp'"),
        ("cma_me_lp_sphere", "emitter", {"kind": "isoline"},
         "emitter.kind: expected one of ['cma_improvement', 'cma_optimizing', 'cma_random_direction'], got 'isoline'"),
        ("map_elites_lp_sphere", "emitter", {"kind": "cma_evolution"}, "emitter.kind: expected one of ['cma_improvement', 'cma_mega', "),
        ("cma_mega_lp_sphere", "emitter", {"optimizer": "sgd"}, "emitter.optimizer: expected one of 'gradient_ascent', 'adam', got 'sgd'"),
        ("cma_mega_lp_sphere", "emitter", {"restart_rule": 0}, "emitter.restart_rule: expected one of 'no_improvement', 'basic' or a positive integer, got 0"),
        ("me_map_elites_lp_sphere", "scheduler", {"num_active": 9}, "scheduler.num_active: expected an integer in [1, 8] (the pool's instances), got 9"),
        ("me_map_elites_lp_sphere", "scheduler", {"zeta": -1.0}, "scheduler.zeta: expected a number >= 0, got -1.0"),
        ("cma_es_sphere", "cma_es", {"sigma0": 0.0}, "cma_es.sigma0: expected a number > 0, got 0.0"),
        ("cma_mae_lp_sphere", "emitter", {"eigen_gap": "sometimes"},
         "emitter.eigen_gap: expected a positive integer or one of 'generations', 'evaluations', got 'sometimes'"),
        ("cma_es_sphere", "cma_es", {"eigen_gap": 0},
         "cma_es.eigen_gap: expected a positive integer or one of 'generations', 'evaluations', got 0"),
        ("cma_es_sphere", "cma_es", {"population_size": 1}, "cma_es.population_size: expected 0 (the default) or an integer >= 2, got 1"),
        # the search archives' keys
        ("nslc_lp_sphere", "search_archive", {"novelty_threshold": 0.0}, "search_archive.novelty_threshold: expected a number > 0, got 0.0"),
        ("nslc_lp_sphere", "search_archive", {"k_neighbors": 0}, "search_archive.k_neighbors: expected a positive integer, got 0"),
        ("nslc_lp_sphere", "search_archive", {"capacity": 4}, "search_archive.capacity: expected at least the 8 offspring of an iteration, got 4"),
        ("nslc_lp_sphere", "search_archive", {"threshold_decay_rate": 0.0}, "search_archive.threshold_decay_rate: expected a number in (0, 1], got 0.0"),
        ("dns_lp_sphere", "search_archive", {"k": 0}, "search_archive.k: expected a positive integer, got 0"),
        ("dns_lp_sphere", "search_archive", {"tie_rule": "pyribs"}, "search_archive.tie_rule: expected one of 'qdax', 'strict', got 'pyribs'"),
        ("dds_lp_sphere", "search_archive", {"bandwidth": 0.0}, "search_archive.bandwidth: expected a number > 0, got 0.0"),
        ("dds_lp_sphere", "search_archive", {"kind": "kde"}, "search_archive.kind: expected one of ['aurora', 'density', 'discount', 'dns', 'proximity'], got 'kde'"),
        ("dms_lp_sphere", "search_archive", {"learning_rate": 0.0}, "search_archive.learning_rate: expected a number in (0, 1], got 0.0"),
        ("dms_lp_sphere", "search_archive", {"discount_range": [1.0, 0.0]}, "search_archive.discount_range: expected [lo, hi] with lo < hi, got [1.0, 0.0]"),
        ("cma_me_lp_sphere", "emitter", {"ranker": "nslc"}, "emitter.ranker: 'nslc' ranks by the 'novelty' that a proximity archive gives"),
        ("dds_lp_sphere", "emitter", {"ranker": "nov"}, "emitter.ranker: 'nov' ranks by the 'novelty' that a proximity archive gives"),
    ],
)
def test_bad_values_are_refused_before_anything_is_built(
    name: str, section: str, table: dict[str, Any], message: str, compilations: Any
) -> None:
    with compilations() as compiled, pytest.raises(ConfigError) as info:
        check_spec(_spec(name, **{section: table}))
    assert str(info.value).startswith(message), str(info.value)
    assert compiled.count == 0


def test_pool_entries_are_checked_by_index() -> None:
    spec = _spec("me_map_elites_lp_sphere")
    spec["emitters"][1]["sigma0"] = 0.0
    with pytest.raises(ConfigError, match=r"^emitters\[1\]\.sigma0: expected a number > 0, got 0\.0$"):
        check_spec(spec)
    spec = _spec("me_map_elites_lp_sphere")
    spec["emitters"][3]["batch_size"] = 5
    with pytest.raises(ConfigError, match=r"^emitters\[3\]\.batch_size: expected 4 \(every instance of a pool emits 4"):
        check_spec(spec)
    spec = _spec("me_map_elites_lp_sphere")
    spec["emitters"][0] = {"kind": "omg_mega"}
    with pytest.raises(ConfigError, match=r"^emitters\[0\]\.kind: expected one of \['cma_improvement', 'cma_mega', .*\] in a pool, got 'omg_mega'$"):
        check_spec(spec)
    with pytest.raises(ConfigError, match=r"^emitter: give either one \[emitter\] or a pool of \[\[emitters\]\], not both$"):
        check_spec({**spec, "emitter": {"kind": "isoline"}})
    with pytest.raises(ConfigError, match=r"^emitters: this algorithm takes one \[emitter\]"):
        check_spec({**_spec("omg_mega_lp_sphere"), "emitters": [{"kind": "omg_mega"}]})
    with pytest.raises(ConfigError, match=r"^emitters: expected a list of tables \(\[\[emitters\]\] followed by"):
        check_spec({**spec, "emitters": [1, 2]})


@pytest.mark.parametrize("name", ["omg_mega_lp_sphere", "cma_mega_lp_sphere"])
def test_mega_emitters_refuse_a_task_without_gradients_before_compiling(name: str) -> None:
    spec = _spec(name)
    spec["task"] = {"name": "rastrigin", "num_dims": 6}
    # Refused while the run is built (the task's gradients are known then), before any compilation.
    with pytest.raises(
        ConfigError, match=rf"^emitter\.kind: '{name.split('_lp')[0]}' needs the task's gradients; task 'rastrigin' has none"
    ):
        build_run(spec)


def test_the_emitter_asks_for_the_gradients_it_needs() -> None:
    from qdrl.algorithms.base import BuildContext
    from qdrl.algorithms.qd import registry_source

    def loop_scoring(name: str) -> tuple[Any, Any]:
        run, _, _ = build_run(_spec(name))
        assert run.qd is not None
        parts = registry_source().build(run.sections["emitter"], run.qd.task, BuildContext(name, 0))
        return parts.scoring_fn, run.qd.task

    # OMG-MEGA reads every offspring's gradients: the loop evaluates with them
    scoring, task = loop_scoring("omg_mega_lp_sphere")
    assert scoring is task.gradient_scoring_fn
    # CMA-MEGA asks for the gradients at theta itself: the loop's evaluations carry none
    scoring, task = loop_scoring("cma_mega_lp_sphere")
    assert scoring is task.scoring_fn


def test_algorithm_names_are_defaults_of_one_run() -> None:
    """cma_mae is cma_me's improvement emitter with imp / mu / basic on an archive with alpha = 0.01."""
    base = {"experiment": {"algorithm": "cma_mae"}, "task": {"name": "lp_sphere", "num_dims": 6},
            "repertoire": {"grid_shape": [8, 8]}}
    run, _, _ = build_run(base)
    me, _, _ = build_run({**base, "experiment": {"algorithm": "cma_me"}})
    assert type(run) is type(me)
    emitter, rep = run.sections["emitter"], run.sections["repertoire"]
    assert (emitter.kind, emitter.ranker, emitter.selection_rule, emitter.restart_rule) == (
        "cma_improvement", "imp", "mu", "basic")
    assert (rep.learning_rate, rep.threshold_min) == (0.01, 0.0)
    assert me.sections["emitter"].ranker == "2imp" and me.sections["repertoire"].learning_rate == 1.0
    # the spec's keys win over the algorithm's defaults; another kind takes none of them
    opt, _, _ = build_run({**base, "emitter": {"kind": "cma_optimizing"}})
    assert (opt.sections["emitter"].ranker, opt.sections["emitter"].restart_rule) == ("obj", "no_improvement")
    assert "normalised_qd_score" in run.progress.keys
    # the covariance is decomposed on the generations rule unless the spec says otherwise
    assert emitter.eigen_gap == "generations"
    for gap in ("evaluations", 7):
        other, _, _ = build_run({**base, "emitter": {"eigen_gap": gap}})
        assert other.sections["emitter"].eigen_gap == gap


def test_the_resolved_pool_spec_reads_back_the_same(tmp_path: Path) -> None:
    from qdrl.experiment import check_spec_file

    spec_file = tmp_path / "pool.toml"
    spec_file.write_text(dump_toml(_spec("me_map_elites_lp_sphere")))
    resolved = check_spec_file(spec_file)
    again = tmp_path / "again.toml"
    again.write_text(resolved)
    assert check_spec_file(again) == resolved
    tables = tomllib.loads(resolved)["emitters"]
    assert [t["kind"] for t in tables] == ["cma_optimizing", "cma_random_direction", "cma_improvement", "isoline"]
    assert [t["ranker"] for t in tables[:3]] == ["obj", "2rd", "2imp"]


def test_cma_es_reaches_1e_3_on_the_100d_sphere(tmp_path: Path) -> None:
    """The baseline's spec: best fitness above -1e-3 (sum x^2 below 1e-3) in 500 generations; resumes."""
    spec = load_toml(AGENTS / "cma_es_sphere.toml")
    spec["cma_es"].update(num_generations=500, log_every=250)
    spec["log"] = {"progress": False, "plots": False}
    spec_file = tmp_path / "cma_es_sphere.toml"
    spec_file.write_text(dump_toml(spec))
    summary = run_spec(spec_file, [], tmp_path / "out")
    assert summary["best_fitness"] > -1e-3 and summary["evaluations"] == 500 * 17
    best = np.load(tmp_path / "out" / "best.npz")
    assert float(np.sum((10.0 * best["genotype"] - 5.0) ** 2)) < 1e-3
    assert summary["population_size"] == 17
    resumes_bit_identically(spec_file, tmp_path / "out", summary, ("best_fitness", "sigma", "restarts"))
