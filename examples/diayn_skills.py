"""DIAYN skills on the point maze from Python, one call away: `make_skill_discovery`.

    python examples/diayn_skills.py                          # about a minute on a laptop CPU
    QDRL_EXAMPLE_SIZE=small python examples/diayn_skills.py  # a tiny run (seconds)

DIAYN (Eysenbach et al. 2019) trains SAC on a skill-conditioned policy with the reward
log q(z|s') - log p(z): a discriminator must tell the skill z from the state reached, so
each skill learns to go somewhere else. `make_skill_discovery` builds the agent on the
skill-conditioned environment; the one off-policy loop (`make_trainer`) trains it, one
compiled chunk per log interval. `evaluate_skills` then plays every skill and a passive
archive over the final x-y position measures them with MAP-Elites' QD metrics.
`qdrl run diayn_point_maze_cpu` runs the same from a spec, with checkpoints and plots.
"""

import os

import jax
import numpy as np

from qdrl.agents import SACConfig
from qdrl.agents.diayn import DIAYNConfig
from qdrl.agents.skill_discovery import evaluate_skills, make_skill_discovery
from qdrl.off_policy import TrainConfig, make_trainer
from qdrl.qd.repertoires import passive_archive
from qdrl.qd.repertoires.passive import feed
from qdrl.tasks import make_task

small = os.environ.get("QDRL_EXAMPLE_SIZE") == "small"
num_skills, hidden = (4, (16, 16)) if small else (8, (128, 128))
task = make_task("point_maze", episode_length=20 if small else 100)
sd = make_skill_discovery(task.env, SACConfig(hidden=hidden), DIAYNConfig(num_skills=num_skills, hidden=hidden))
train = TrainConfig(
    total_env_steps=1600 if small else 60_000, eval_every=800 if small else 20_000, num_envs=4 if small else 16,
    batch_size=32 if small else 256, buffer_size=2000 if small else 60_000, learning_starts=160 if small else 2000,
    grad_steps_per_iter=2 if small else 16,
)
trainer = make_trainer(sd.env, sd.agent, train, sd.storage)
state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
chunk = jax.jit(trainer.run_chunk, donate_argnums=0)
evaluate = jax.jit(lambda agent, key: evaluate_skills(sd, agent, key, 2 * num_skills, "final",
                                                      task.descriptor_low, task.descriptor_high))
archive = passive_archive("grid", grid_shape=(8, 8), low=task.descriptor_low, high=task.descriptor_high)
for i in range(train.num_chunks):
    state, _ = chunk(state)
    ev = evaluate(state.agent, jax.random.PRNGKey(i))
    archive, qd = feed(archive, ev["descriptors"], ev["returns"], task.qd_offset)
print(f"{int(state.env_steps)} env steps: discriminator accuracy "
      f"{float(ev['eval_final_discriminator_accuracy']):.2f} at the episodes' ends (chance {1 / num_skills:.2f})")
final = np.asarray(ev["descriptors"])[:num_skills]  # episode i played skill i % K
print(f"the skills reached {int(qd['num_elites'])} archive cells (QD score {float(qd['qd_score']):.1f}); "
      f"final positions: " + ", ".join(f"z{z} ({x:.2f}, {y:.2f})" for z, (x, y) in enumerate(final)))
