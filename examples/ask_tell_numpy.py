"""MAP-Elites driving an objective written in NumPy (outside JAX) through ask / tell.

The objective here is the planar arm written with NumPy; any simulator or
external program fits the same place: `ask` gives genotypes, you evaluate them
however you like, `tell_values` gives back fitnesses and descriptors.

    python examples/ask_tell_numpy.py
"""

import jax
import numpy as np

from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire

DOF, BATCH = 20, 256


def numpy_arm(genotypes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fitness -std(genes) and end-effector x-y in [0, 1]^2 of a planar arm."""
    g = np.clip(genotypes, 0.0, 1.0)
    angles = np.cumsum(2 * np.pi * g - np.pi, axis=1)
    xy = np.stack([np.cos(angles).sum(1), np.sin(angles).sum(1)], axis=1) / (2 * DOF) + 0.5
    return -np.std(g, axis=1), xy


def main() -> None:
    repertoire = grid_repertoire(np.zeros(DOF, np.float32), (32, 32), 0.0, 1.0)
    # No scoring function in JAX: only ask / tell are used.
    me = MapElites(None, isoline_emitter(BATCH, 0.05, 0.1, 0.0, 1.0), repertoire, qd_offset=-0.5)
    init_key, key = jax.random.split(jax.random.PRNGKey(0))
    init = np.asarray(jax.random.uniform(init_key, (BATCH, DOF)))
    state = me.init_values(init, *numpy_arm(init), key)
    ask, tell = jax.jit(me.ask), jax.jit(me.tell_values)
    for it in range(1, 101):
        offspring, state = ask(state)
        fitnesses, descriptors = numpy_arm(np.asarray(offspring))  # any code, outside JAX
        state, metrics = tell(state, offspring, fitnesses, descriptors)
        if it % 25 == 0:
            print(f"iteration {it:3d}  qd_score {float(metrics['qd_score']):8.2f}  "
                  f"coverage {float(metrics['coverage']):.3f}")


if __name__ == "__main__":
    main()
