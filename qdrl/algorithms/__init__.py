"""THE table of algorithms: every name a spec's `experiment.algorithm` may give, and its recipe.

A recipe (`qdrl.algorithms.base.Recipe`) parses its spec sections into typed
configs and builds pure functions (`Algorithm`); the experiment driver
(`qdrl.experiment`) jits, places, times, checkpoints and logs them. Adding an
algorithm adds a row here (or, from outside the package, `register`); the driver
is never edited:

    from qdrl.algorithms import register
    from qdrl.algorithms.qd import EmitterSource, qd_recipe

    register("gauss_me", qd_recipe(EmitterSource.of_section("gauss", GaussConfig, make_gauss_emitter)))
"""

from __future__ import annotations

import difflib

from qdrl.algorithms import (
    cma_es,
    feature_skills,
    mo,
    multi_task,
    pbt,
    qd,
    rl,
    skills,
    uncertain,
    uncertain_sampling,
)
from qdrl.algorithms.base import Algorithm, BuildContext, ExperimentConfig, LogConfig, Recipe
from qdrl.config import ConfigError

__all__ = [
    "ALGORITHMS",
    "Algorithm",
    "BuildContext",
    "ExperimentConfig",
    "LogConfig",
    "Recipe",
    "algorithm_names",
    "length_keys",
    "recipe",
    "register",
]

ALGORITHMS: dict[str, Recipe] = {
    # RL and skill discovery, each measured by a passive archive
    "sac": rl.SAC,
    "td3": rl.TD3,
    "sac_pbt": pbt.SAC_PBT,
    "td3_pbt": pbt.TD3_PBT,
    "diayn": skills.DIAYN,
    "dads": skills.DADS,
    "smerl_diayn": skills.SMERL_DIAYN,
    "smerl_dads": skills.SMERL_DADS,
    "smerl_reverse": skills.SMERL_REVERSE,
    "domino": skills.DOMINO,
    "metra": skills.METRA,
    "lsd": skills.LSD,
    # skills as targets in a feature space, measured by distance to skill
    "qdac": feature_skills.QDAC,
    "uvfa": feature_skills.UVFA,
    # MAP-Elites with the emitters of the registry
    "map_elites": qd.MAP_ELITES,
    "cvt_map_elites": qd.CVT_MAP_ELITES,
    "cma_me": qd.CMA_ME,
    "cma_mae": qd.CMA_MAE,
    "omg_mega": qd.OMG_MEGA,
    "cma_mega": qd.CMA_MEGA,
    "cma_maega": qd.CMA_MAEGA,
    "ns_cma": qd.NS_CMA,
    "nslc": qd.NSLC,
    "nslc_cma_imp": qd.NSLC_CMA_IMP,
    "dds": qd.DDS,
    "dms": qd.DMS,
    "dns": qd.DNS,
    "aurora": qd.AURORA,
    # Uncertain QD: candidates evaluated several times, cells that keep more than one elite
    "me_sampling": uncertain.ME_SAMPLING,
    "me_ls": uncertain.ME_LS,
    "deep_grid": uncertain.DEEP_GRID,
    # Uncertain QD: elites that keep their samples, re-evaluated (Archive-, Adaptive-Sampling)
    "archive_sampling": uncertain_sampling.ARCHIVE_SAMPLING,
    "adaptive_sampling": uncertain_sampling.ADAPTIVE_SAMPLING,
    "parallel_adaptive_sampling": uncertain_sampling.PARALLEL_ADAPTIVE_SAMPLING,
    # QD-RL: MAP-Elites with actor-critic, evolution-strategy and PBT emitters
    "pga_me": qd.PGA_ME_RECIPE,
    "qdpg": qd.QDPG_RECIPE,
    "dcrl_me": qd.DCRL_ME_RECIPE,
    "me_es": qd.ME_ES_RECIPE,
    "me_pbt_sac": qd.ME_PBT_SAC,
    "me_pbt_td3": qd.ME_PBT_TD3,
    "pga_aurora": qd.PGA_AURORA,
    # one elite per task of a multi-task family (Mouret & Maguire 2020)
    "mt_me": multi_task.MT_ME,
    # multi-objective
    "mome": mo.MOME,
    "nsga2": mo.NSGA2,
    "spea2": mo.SPEA2,
    # optimisation without an archive
    "cma_es": cma_es.CMA_ES,
}


def algorithm_names() -> list[str]:
    """The algorithms a spec may name (`experiment.algorithm`)."""
    return sorted(ALGORITHMS)


def recipe(name: str) -> Recipe:
    """The recipe of algorithm `name`; ConfigError naming the closest names otherwise."""
    if name in ALGORITHMS:
        return ALGORITHMS[name]
    close = difflib.get_close_matches(name, ALGORITHMS, n=3, cutoff=0.6)
    hint = f" (close names: {', '.join(close)})" if close else ""
    raise ConfigError(f"experiment.algorithm: expected one of {algorithm_names()}, got {name!r}{hint}")


def register(name: str, entry: Recipe, replace: bool = False) -> None:
    """Adds algorithm `name` to the table (from outside the package); a name already there is
    refused unless `replace`."""
    if not isinstance(entry, Recipe):
        raise TypeError(f"register: expected a qdrl.algorithms.Recipe, got {type(entry).__name__}")
    if name in ALGORITHMS and not replace:
        raise ValueError(f"register: algorithm {name!r} is already in the table (pass replace=True)")
    ALGORITHMS[name] = entry


def length_keys() -> tuple[str, ...]:
    """The spec keys that set a run's length, over every algorithm of the table."""
    return tuple(dict.fromkeys(r.length_key for r in ALGORITHMS.values()))
