"""PBT: search spaces, exploit/explore on a constructed population, a tiny run of each agent."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import pbt
from qdrl.config import ConfigError, build
from qdrl.experiment import run_spec
from qdrl.off_policy import TrainState


class FakeAgent(NamedTuple):
    params: jax.Array  # (P, 3): member i holds [i, i, i]
    hparams: dict[str, jax.Array]


def population(p: int) -> TrainState:
    ids = jnp.arange(p, dtype=jnp.float32)
    agent = FakeAgent(
        params=jnp.tile(ids[:, None], (1, 3)),
        hparams={
            "actor_lr": jnp.full((p,), 1e-3) * (1 + ids / 10),
            "discount": jnp.full((p,), 0.95),
            "tau": jnp.full((p,), 0.005),  # not tuned: copied, never explored
        },
    )
    return TrainState(
        agent=agent,
        buffer=ids[:, None] * jnp.ones((p, 4)),
        env=100 + ids,
        key=jax.vmap(jax.random.PRNGKey)(jnp.arange(p)),
        env_steps=jnp.full((p,), 7, jnp.int32),
        grad_steps=jnp.zeros((p,), jnp.int32),
    )


def config(**kw: object) -> pbt.PBTConfig:
    base: dict[str, object] = {
        "population_size": 6, "num_replace": 2, "num_best": 2,
        "hparams": ["actor_lr", "discount"], "low": [1e-4, 0.9], "high": [1e-2, 1.0],
    }
    base.update(kw)
    return build(pbt.PBTConfig, base, "pbt")


SPACE_HP = {"actor_lr": 0.0, "discount": 0.0, "tau": 0.0}


def test_exploit_replaces_the_worst_with_copies_of_the_best() -> None:
    cfg = config(resample_probability=0.0, perturb_factors=[0.8, 1.2])
    space = pbt.search_space("sac", cfg, SPACE_HP)
    pop = population(6)
    fitness = jnp.array([5.0, 1.0, 3.0, jnp.nan, 4.0, 2.0])  # NaN ranks last
    new, info = pbt.exploit_and_explore(jax.random.PRNGKey(0), pop, fitness, space, cfg)
    assert sorted(np.asarray(info.replaced).tolist()) == [1, 3]
    assert set(np.asarray(info.sources).tolist()) <= {0, 4}
    params = np.asarray(new.agent.params[:, 0])
    buffer = np.asarray(new.buffer[:, 0])
    for i in range(6):
        replaced = i in np.asarray(info.replaced).tolist()
        if replaced:
            src = int(np.asarray(info.sources)[list(np.asarray(info.replaced)).index(i)])
            assert params[i] == src and buffer[i] == src  # weights and buffer copied
            lr_src, lr = float(pop.agent.hparams["actor_lr"][src]), float(new.agent.hparams["actor_lr"][i])
            assert lr / lr_src == pytest.approx(0.8, rel=1e-5) or lr / lr_src == pytest.approx(1.2, rel=1e-5)
            assert np.float32(0.9) <= new.agent.hparams["discount"][i] <= np.float32(1.0)
        else:
            assert params[i] == i and buffer[i] == i
            for name in ("actor_lr", "discount"):
                assert float(new.agent.hparams[name][i]) == float(pop.agent.hparams[name][i])
        # Environments, keys and counters stay the member's own; untuned values are copied.
        assert float(new.env[i]) == 100 + i
        np.testing.assert_array_equal(np.asarray(new.key[i]), np.asarray(pop.key[i]))
        assert float(new.agent.hparams["tau"][i]) == pytest.approx(0.005)


def test_explore_keeps_values_in_range_and_resample_covers_it() -> None:
    cfg = config(explore="perturb", resample_probability=0.3)
    space = pbt.search_space("sac", cfg, SPACE_HP)
    values = jnp.tile(jnp.array([[9e-3, 0.99]]), (2000, 1))
    out = np.asarray(pbt.explore(jax.random.PRNGKey(1), space, values, cfg))
    assert (out[:, 0] >= np.float32(1e-4)).all() and (out[:, 0] <= np.float32(1e-2)).all()
    assert (out[:, 1] >= np.float32(0.9)).all() and (out[:, 1] <= 1.0).all()
    # x1.2 of 9e-3 is clipped to the 1e-2 bound; about 30% are resampled.
    resampled = ~np.isclose(out[:, 0], 9e-3 * 0.8) & ~np.isclose(out[:, 0], 1e-2)
    assert 0.25 < resampled.mean() < 0.35
    fresh = np.asarray(pbt.sample(jax.random.PRNGKey(2), space, 4000))
    # log-uniform: the median is near the geometric mean of the bounds (1e-3).
    assert np.median(fresh[:, 0]) == pytest.approx(1e-3, rel=0.15)
    assert np.median(fresh[:, 1]) == pytest.approx(0.95, abs=0.01)
    resample = np.asarray(pbt.explore(jax.random.PRNGKey(3), space, values, config(explore="resample")))
    assert np.median(resample[:, 0]) == pytest.approx(1e-3, rel=0.15)


def test_default_spaces_match_the_agents_hyperparameters() -> None:
    from qdrl.agents.sac import HPARAM_NAMES as SAC
    from qdrl.agents.td3 import HPARAM_NAMES as TD3

    for agent, names in (("sac", SAC), ("td3", TD3)):
        space = pbt.search_space(agent, pbt.PBTConfig(), dict.fromkeys(names, 0.0))
        assert set(space.names) <= set(names) and len(space.names) >= 5


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"num_replace": 4, "num_best": 3}, "expected at most pbt.population_size=6"),
        ({"population_size": 0}, "pbt.population_size: expected a positive integer"),
        ({"resample_probability": 1.5}, "pbt.resample_probability: expected a number in"),
        ({"low": [1e-4]}, "expected lists of one length"),
        ({"perturb_factors": [0.8, -1.0]}, "pbt.perturb_factors"),
        ({"explore": "mutate"}, "pbt.explore: expected one of"),
    ],
)
def test_bad_pbt_config_is_refused(kw: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        config(**kw)


def test_unknown_or_bad_hyperparameter_is_refused() -> None:
    with pytest.raises(ValueError, match="'momentum' is not a hyperparameter of sac"):
        pbt.search_space("sac", config(hparams=["momentum"], low=[0.1], high=[0.2]), SPACE_HP)
    with pytest.raises(ValueError, match="actor_lr is sampled log-uniformly"):
        pbt.search_space("sac", config(hparams=["actor_lr"], low=[0.0], high=[0.2]), SPACE_HP)


SPEC = """
[experiment]
algorithm = "{algorithm}"
seed = 1

[env]
name = "point"
episode_length = 20

[agent]
hidden = [16, 16]

[train]
total_env_steps = 400
num_envs = 4
batch_size = 32
buffer_size = 1000
learning_starts = 80
grad_steps_per_iter = 2
eval_every = 100
num_eval_envs = 4

[pbt]
population_size = 4
num_replace = 1
num_best = 1

[archive]
grid_shape = [8, 8]
low = [-1.0, -1.0]
high = [1.0, 1.0]

[log]
checkpoint_every = 1
progress = false
"""


@pytest.fixture(scope="module")
def sac_pbt_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """The tiny SAC-PBT run, shared by the tests that read it."""
    tmp = tmp_path_factory.mktemp("sac_pbt")
    spec = tmp / "spec.toml"
    spec.write_text(SPEC.format(algorithm="sac_pbt"))
    return spec, run_spec(spec, [], tmp / "out")


def check_tiny_run(out: Path, summary: dict[str, Any]) -> None:
    assert summary["population_size"] == 4 and summary["exploits"] == 4  # one per log interval
    assert summary["env_steps"] == 4 * 400 and summary["member_env_steps"] == 400
    members = [summary[f"eval_return_m{i}"] for i in range(4)]
    assert summary["eval_return"] == max(members)  # the logged best is the best member's
    assert summary["eval_return_median"] == pytest.approx(float(np.median(members)))
    assert summary["coverage"] > 0
    # 1000 transitions of obs 2 + action 2 + reward, flags, descriptors 2 + 2, float32, plus the ring's counters.
    assert summary["buffer_bytes_per_member"] >= 1000 * 4 * (2 + 2 + 1 + 2 + 1 + 1 + 2 + 2)
    header = (out / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {f"eval_return_m{i}" for i in range(4)} <= set(header)
    assert (out / "plots" / "population.png").stat().st_size > 1000
    final = json.loads((out / "summary.json").read_text())["final_hparams"]
    assert all(len(v) == 4 for v in final.values())


def test_tiny_sac_pbt_run(sac_pbt_run: tuple[Path, dict[str, Any]]) -> None:
    spec, summary = sac_pbt_run
    check_tiny_run(spec.parent / "out", summary)


@pytest.mark.slow
def test_tiny_td3_pbt_run(tmp_path: Path) -> None:
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(algorithm="td3_pbt"))
    check_tiny_run(tmp_path / "out", run_spec(spec, [], tmp_path / "out"))


def test_pbt_resume_restores_the_whole_population(
    sac_pbt_run: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    # A 200-step run extended to 400 steps continues from its checkpoint (the whole
    # population, buffers, hyperparameters and keys) and ends where the 400-step run does.
    spec, full = sac_pbt_run
    out = tmp_path / "part"
    part = run_spec(spec, ["train.total_env_steps=200", "log.plots=false"], out)
    assert part["member_env_steps"] == 200
    resumed = run_spec(spec, ["log.plots=false"], out, resume=True)
    for key in ("eval_return", "eval_return_median", "exploits", "coverage", "best_actor_lr"):
        assert resumed[key] == full[key], key
