"""PGA-ME on a brax task from Python, one call away: `make_pga_me(task, config)`.

    python examples/pga_me_brax.py                          # a few minutes on a laptop CPU
    QDRL_EXAMPLE_SIZE=small python examples/pga_me_brax.py  # a tiny run (seconds after compiling)

PGA-ME (Nilsson & Cully 2021): half of each batch comes from the GA (iso+line
variation), the other half from TD3 policy-gradient steps on elites plus the greedy
actor. `make_pga_me` builds the emitter for the task's policy network; MAP-Elites
(`qdrl.qd.map_elites.MapElites`) runs it over a CVT repertoire, every log interval one
compiled scan. The best elite is then scored again: the task's evaluation of a policy
does not depend on the batch it is in, so its return equals the stored fitness.
`qdrl run pga_me_halfcheetah_uni_cpu` runs the same algorithm from a spec, with
checkpoints, plots and a replay.
"""

import dataclasses
import os

import jax
import numpy as np

from qdrl.qd.emitters.ga import GAConfig
from qdrl.qd.emitters.pg import PG_TD3, PGConfig
from qdrl.qd.emitters.qd_rl import PGAMEConfig, make_pga_me
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import cvt_centroids, cvt_repertoire
from qdrl.tasks import make_task

small = os.environ.get("QDRL_EXAMPLE_SIZE") == "small"
batch, episode, iterations, log_every = (8, 10, 2, 1) if small else (64, 100, 60, 20)

task = make_task("halfcheetah_uni", episode_length=episode, policy_hidden=(8,) if small else (64, 64), eval_batch=batch)
pg = PGConfig(
    num_critic_training_steps=4 if small else 100, num_pg_training_steps=2 if small else 50,
    training_batch_size=16 if small else 256, replay_buffer_size=batch * episode * 20,
    td3=dataclasses.replace(PG_TD3, hidden=(16,) if small else (256, 256)),  # the critic's widths
)
config = PGAMEConfig(ga=GAConfig(batch_size=batch, iso_sigma=0.005, line_sigma=0.05), pg=pg)
parts = make_pga_me(task, config)  # the emitter, the initial population, the scoring, a genotype

cvt_key, init_key, run_key = jax.random.split(jax.random.PRNGKey(0), 3)
centroids = cvt_centroids(cvt_key, 16 if small else 128, 1000 if small else 20_000, task.descriptor_low, task.descriptor_high)
repertoire = cvt_repertoire(parts.example_genotype, centroids, task.descriptor_low, task.descriptor_high)
me = MapElites(parts.scoring_fn, parts.emitter, repertoire, qd_offset=task.qd_offset)
state = jax.jit(me.init)(parts.init_genotypes(init_key, batch), run_key)
run = jax.jit(me.run, static_argnums=1)  # one compiled scan of `log_every` iterations
for _ in range(iterations // log_every):
    state, metrics = run(state, log_every)
    print(f"iteration {int(state.iteration)}: QD score {float(metrics['qd_score'][-1]):.1f}, "
          f"coverage {float(metrics['coverage'][-1]):.3f}, {int(state.env_steps)} env steps, "
          f"critic steps {int(state.emitter_state[1].td3.steps)}")

fitnesses = np.asarray(state.repertoire.fitnesses)
best = int(np.argmax(fitnesses))
genotype = jax.tree.map(lambda x: x[best : best + 1], state.repertoire.genotypes)
again = jax.jit(parts.scoring_fn)(genotype, jax.random.PRNGKey(1)).fitnesses[0]
print(f"best elite: cell {best}, return {fitnesses[best]:.2f}, scored again {float(again):.2f}")
assert float(again) == float(fitnesses[best])
