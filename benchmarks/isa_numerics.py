"""Does the CPU's vector instruction set change qdrl's numbers? Training and evaluation apart.

    python benchmarks/isa_numerics.py [--isas default AVX2 SSE4_2] [--out FILE]

Runs, once per `--isas` entry in a process of its own (`XLA_FLAGS=--xla_cpu_max_isa=ISA`;
`default`: no cap, the host's own), two small programs of qdrl's networks:

- *training*: 100 gradient steps (plain SGD, lr 1e-3) of a twin Q critic (256x256, batch 256)
  towards a constant target, as a TD3 or SAC critic is trained (what PGA-ME's critic does);
- *evaluation*: a deterministic 256x256 policy's forward pass on 256 observations, vmapped
  (what scoring a batch of policies does).

Prints one JSON object: per ISA, each program's digest (the exact float sum of the absolute
values of its outputs, as a hex string) and whether it equals the `default` one. A cap that
changes a digest shows that the code XLA generates for that CPU changes the rounding of
that program, so a run can part between two machines whose CPUs offer different instruction
sets (on a 2-core AMD EPYC with AVX-512, the AVX2 cap changed the evaluation's bits and the SSE4.2
cap both programs'; `benchmarks/results/isa_numerics_cpu.json`). The runtime
kernel libraries (XNNPACK, Eigen) pick their kernels from the CPU itself, which this cap
does not reach: equal digests here do not promise equal runs on another CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

_PROGRAM = r"""
import json
import jax, jax.numpy as jnp, numpy as np
from qdrl import nets

critic, policy = nets.twin_q_critic(), nets.deterministic_policy(6)
key = jax.random.key(0)
obs = jax.random.normal(key, (256, 17))
act = jax.random.normal(jax.random.key(1), (256, 6))
q_params, pi_params = critic.init(key, obs, act), policy.init(key, obs)

def loss(p):
    return jnp.mean((critic.apply(p, obs, act) - 1.0) ** 2)

def step(p, _):
    return jax.tree.map(lambda w, g: w - 1e-3 * g, p, jax.grad(loss)(p)), None

trained = jax.jit(lambda p: jax.lax.scan(step, p, None, length=100)[0])(q_params)
actions = jax.jit(jax.vmap(policy.apply, in_axes=(None, 0)))(pi_params, obs)
digest = lambda tree: float(sum(np.abs(np.asarray(x, np.float64)).sum() for x in jax.tree.leaves(tree))).hex()
print(json.dumps({"training": digest(trained), "evaluation": digest(actions)}))
"""


def digests(isa: str) -> dict[str, Any]:
    """The two programs' digests in a fresh process with XLA capped at `isa` ("default": no cap)."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + ("" if isa == "default" else f" --xla_cpu_max_isa={isa}")).strip()
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    proc = subprocess.run([sys.executable, "-c", _PROGRAM], env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"isa {isa}: the program failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--isas", nargs="+", default=["default", "AVX2", "SSE4_2"],
                        help="XLA's --xla_cpu_max_isa values to compare (default: no cap); the first is the reference")
    parser.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    args = parser.parse_args()
    runs: dict[str, dict[str, Any]] = {isa: digests(isa) for isa in args.isas}
    ref = runs[args.isas[0]]
    for d in runs.values():
        d["training_equal"] = d["training"] == ref["training"]
        d["evaluation_equal"] = d["evaluation"] == ref["evaluation"]
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.exists() else []
    flags = next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), [])
    out = {"reference": args.isas[0], "host_avx512f": "avx512f" in flags, "host_avx2": "avx2" in flags, "runs": runs}
    text = json.dumps(out, indent=2)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
