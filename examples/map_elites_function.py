"""MAP-Elites on your own JAX function: the README's quick start, as a script.

    python examples/map_elites_function.py

A scoring function takes a batch of genotypes and a key and returns an `Evaluation`:
one fitness per genotype (maximised; NaN marks a failed evaluation), one descriptor
row per genotype (where it lands in the archive), `extras` (a dict, for emitters that
learn from evaluations) and the environment steps it cost (0 here).
"""

import jax
import jax.numpy as jnp

from qdrl.qd.base import Evaluation
from qdrl.qd.emitters import isoline_emitter
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire


def score(x: jax.Array, key: jax.Array) -> Evaluation:
    """x: (n, 10) genotypes in [0, 1]."""
    fitness = -jnp.sum((x - 0.5) ** 2, axis=1)  # (n,), best at the centre
    descriptor = x[:, :2]  # (n, 2), inside [0, 1]^2
    return Evaluation(fitness, descriptor, extras={}, env_steps=jnp.int32(0))


repertoire = grid_repertoire(jnp.zeros(10), grid_shape=(32, 32), low=0.0, high=1.0)
emitter = isoline_emitter(256, iso_sigma=0.05, line_sigma=0.1, minval=0.0, maxval=1.0)
# The QD score sums fitness - qd_offset over filled cells: -10 is below any fitness here.
me = MapElites(score, emitter, repertoire, qd_offset=-10.0)
init_key, run_key = jax.random.split(jax.random.PRNGKey(0))
state = me.init(jax.random.uniform(init_key, (256, 10)), run_key)
run = jax.jit(me.run, static_argnums=1)  # the number of iterations is static
state, metrics = run(state, 100)  # 100 iterations in one compiled scan
print(f"QD score {float(metrics['qd_score'][-1]):.1f}, coverage {float(metrics['coverage'][-1]):.3f}")
