"""DIAYN skills on the point maze, from Python: train, then read what the skills learned.

    python examples/diayn_skills.py [OUT]                          # the CPU spec (minutes)
    QDRL_EXAMPLE_SIZE=small python examples/diayn_skills.py [OUT]  # a tiny run (seconds)

DIAYN (Eysenbach et al. 2018) trains SAC on a skill-conditioned policy with the reward
log q(z|s') - log p(z): a discriminator must tell the skill z from the state reached,
so each skill learns to go somewhere else. The packaged spec `diayn_point_maze_cpu` runs
8 skills. Every log point evaluates each skill and offers its episodes to a passive
archive over the final x-y position, so skills are measured with the QD metrics of
MAP-Elites. The run writes plots/skills.png: each skill's path over the maze's walls,
beside the archive.
"""

import os
import sys
from pathlib import Path

import qdrl
from qdrl.experiment import load_spec, run

SMALL = [  # every size cut down: a run that tests the script, not the algorithm
    "env.episode_length=20", "agent.hidden=[16, 16]", "skills.hidden=[16, 16]",
    "skills.num_skills=4", "train.total_env_steps=1600", "train.eval_every=800",
    "train.learning_starts=160", "train.num_envs=4", "train.batch_size=32",
    "train.buffer_size=2000", "train.grad_steps_per_iter=2", "train.num_eval_envs=8",
    "archive.grid_shape=[8, 8]", "log.progress=false",
]
small = os.environ.get("QDRL_EXAMPLE_SIZE") == "small"
out = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/example_diayn")

summary = run(load_spec("diayn_point_maze_cpu", SMALL if small else []), out, overwrite=True)
print(f"{summary['env_steps']} env steps: discriminator accuracy "
      f"{summary['eval_final_discriminator_accuracy']:.2f} at the episodes' ends "
      f"(chance {1 / (4 if small else 8):.2f})")

loaded = qdrl.load_run(out)
archive = loaded.table  # one row per filled cell: the best return reaching it, and where
print(f"the skills reached {len(archive)} archive cells (QD score {summary['qd_score']:.1f}); "
      f"farthest right: x = {archive.descriptor_0.max():.2f}")
print(f"skills plot: {out / 'plots' / 'skills.png'}")
