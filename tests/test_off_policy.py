"""The off-policy loop: compiles once, fills the buffer, and SAC/TD3 learn on the point task."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from qdrl.agents import AGENTS
from qdrl.envs.point import PointEnv
from qdrl.off_policy import TrainConfig, make_trainer

ENV = PointEnv(episode_length=50)
CFG = TrainConfig(
    total_env_steps=6_000,
    num_envs=8,
    batch_size=128,
    buffer_size=10_000,
    learning_starts=400,
    grad_steps_per_iter=8,
    eval_every=1_000,
    num_eval_envs=8,
)


def _trainer(name: str):  # type: ignore[no-untyped-def]
    config_cls, make_agent = AGENTS[name]
    agent = make_agent(config_cls(hidden=(64, 64)), ENV.observation_size, ENV.action_size)
    return make_trainer(ENV, agent, CFG)


def test_chunk_compiles_once_and_counts_steps() -> None:
    trainer = _trainer("sac")
    traces = []

    def chunk(ts):  # type: ignore[no-untyped-def]
        traces.append(1)
        return trainer.run_chunk(ts)

    run = jax.jit(chunk)
    ts = trainer.init(jax.random.PRNGKey(0))
    for _ in range(3):
        ts, metrics = run(ts)
    assert len(traces) == 1 and run._cache_size() == 1
    assert int(ts.env_steps) == 3_000
    assert int(ts.buffer.size) == 3_000
    # updates start once learning_starts env steps are in: 3000 - 400 steps, 8 envs per iteration
    assert int(ts.grad_steps) == (3_000 - 400) // 8 * 8 + 8
    assert np.isfinite(float(metrics["critic_loss"]))


@pytest.mark.slow  # learning
@pytest.mark.parametrize("name", ["sac", "td3"])
def test_agent_learns_point_task(name: str) -> None:
    trainer = _trainer(name)
    run = jax.jit(trainer.run_chunk)
    evaluate = jax.jit(trainer.evaluate)
    ts = trainer.init(jax.random.PRNGKey(1))
    before = float(evaluate(ts.agent, jax.random.PRNGKey(2))["eval_return"])
    for _ in range(CFG.num_chunks):
        ts, _ = run(ts)
    after = float(evaluate(ts.agent, jax.random.PRNGKey(2))["eval_return"])
    # Standing still scores about -0.7 x 50 = -35; heading to the goal (5 steps away) and
    # staying there scores about -1.7.
    assert before < -20.0
    assert after > -6.0, (before, after)


def test_bad_train_config() -> None:
    with pytest.raises(ValueError, match=r"train.batch_size: expected a positive integer, got -1"):
        TrainConfig(batch_size=-1).check()
    with pytest.raises(ValueError, match=r"train.eval_every: expected a multiple of train.num_envs"):
        TrainConfig(num_envs=16, eval_every=100).check()
