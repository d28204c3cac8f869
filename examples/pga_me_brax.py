"""PGA-ME on a brax task, then a rollout of its best elite, from Python.

    python examples/pga_me_brax.py [OUT]                          # the CPU spec (minutes)
    QDRL_EXAMPLE_SIZE=small python examples/pga_me_brax.py [OUT]  # a tiny run (seconds after compiling)

The packaged spec `pga_me_halfcheetah_uni_cpu` (PGA-ME, Nilsson & Cully 2021: a GA and
TD3 policy-gradient offspring, on halfcheetah with a feet-contact descriptor) is run
by the same driver as `qdrl run`; the run directory is then loaded back, and the best
elite's episode replayed through the task's own scoring function: its return equals
the stored fitness bit for bit. `qdrl render OUT` writes the same replay as HTML.
"""

import os
import sys
from pathlib import Path

import qdrl
from qdrl.experiment import load_spec, run
from qdrl.render import render

SMALL = [  # every size cut down: a run that tests the script, not the algorithm
    "task.episode_length=10", "task.policy_hidden=[8]", "repertoire.num_centroids=16",
    "repertoire.cvt_samples=1000", "emitter.batch_size=8", "qd.init_batch_size=8",
    "qd.num_iterations=2", "qd.log_every=1", "pg.num_critic_training_steps=4",
    "pg.num_pg_training_steps=2", "pg.training_batch_size=16", "pg.replay_buffer_size=1000",
    "pg.critic_hidden=[16]", "log.progress=false", "log.plots=false",
]
small = os.environ.get("QDRL_EXAMPLE_SIZE") == "small"
out = sys.argv[1] if len(sys.argv) > 1 else "runs/example_pga_me"

spec = load_spec("pga_me_halfcheetah_uni_cpu", SMALL if small else [])
summary = run(spec, Path(out), overwrite=True)
print(f"QD score {summary['qd_score']:.1f}, coverage {summary['coverage']:.3f}, "
      f"{summary['evaluations']} evaluations, {summary['env_steps']} env steps")

loaded = qdrl.load_run(out)
elite = loaded.best()  # genotype: the policy's parameters, in the task's pytree
episode = loaded.rollout(elite)  # observations, actions, rewards, state descriptors, link poses
assert episode.return_ == elite.fitness  # the same start state and evaluation block: bit for bit
contact = ", ".join(f"{name} {value:.2f}" for name, value in zip(
    loaded.summary["descriptor_names"], episode.descriptor, strict=True))
print(f"best elite: cell {elite.cell}, return {episode.return_:.2f} over {episode.length} steps; {contact}")
print(f"replay: {render(loaded, elite.cell)['out']}")
