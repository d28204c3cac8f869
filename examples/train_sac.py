"""Train SAC with the library API (no spec file): build, compile once, run chunks, evaluate.

    python examples/train_sac.py                 # the pure-JAX point task, a few seconds
    python examples/train_sac.py halfcheetah     # a brax task (minutes)
"""

import sys

import jax

from qdrl import envs
from qdrl.agents import SACConfig, make_sac
from qdrl.off_policy import TrainConfig, make_trainer

name = sys.argv[1] if len(sys.argv) > 1 else "point"
env = envs.make(name, episode_length=50 if name == "point" else 1000)
agent = make_sac(SACConfig(hidden=(64, 64)), env.observation_size, env.action_size)
config = TrainConfig(
    total_env_steps=6_000, num_envs=8, batch_size=128, learning_starts=400,
    grad_steps_per_iter=8, eval_every=1_000, buffer_size=10_000,
)
trainer = make_trainer(env, agent, config)

state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
run_chunk = jax.jit(trainer.run_chunk)  # eval_every env steps per call, compiled once
evaluate = jax.jit(trainer.evaluate)
for chunk in range(config.num_chunks):
    state, metrics = run_chunk(state)
    result = evaluate(state.agent, jax.random.PRNGKey(chunk))
    print(f"env steps {int(state.env_steps):>6}  eval return {float(result['eval_return']):8.2f}")
