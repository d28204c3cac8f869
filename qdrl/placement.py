"""Where arrays live: the one module that decides placement across devices and hosts.

A run gets a `Placement` from `make_placement(devices)`: a one-axis mesh
(`jax.make_mesh`) over the first `devices` visible devices (every device of
every process under `jax.distributed`), whose axis `BATCH_AXIS` ("batch") is the
population / batch axis. Algorithms only say which of their arrays carry that
axis; this module turns it into `NamedSharding`s, `jit` sharding constraints and
`shard_map`. What each family shards:

| family | sharded over "batch" | replicated |
|---|---|---|
| MAP-Elites and every emitter | offspring (leading axis) and their evaluation | repertoire, emitter state, key |
| off-policy loop (SAC, TD3, DIAYN, DADS, SMERL) | environments, each gradient step's batch | agent, replay buffer |
| PBT | members (leading axis of the population) | the ranking and the PBT step's choices |
| ME-PBT | offspring's evaluation (as MAP-Elites) | the members |

With one device the mesh is None and every function here returns its input
unchanged: the one-device programs are exactly those of a run without this module.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from jax._src import distributed
from jax.experimental import multihost_utils
from jax.sharding import AxisType, Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from qdrl.config import ConfigError

BATCH_AXIS = "batch"  # the mesh axis of the population / batch


def visible_devices() -> int:
    """Devices jax sees (all processes' under `jax.distributed`)."""
    return jax.device_count()


def resolve_devices(devices: int, where: str = "experiment.devices") -> int:
    """The device count a run uses: `devices`, or every visible device for 0; ConfigError when
    more are asked for than there are."""
    visible = visible_devices()
    if devices < 0 or devices > visible:
        raise ConfigError(
            f"{where}: expected 0 (all) or at most the {visible} visible device(s), got {devices}"
        )
    if jax.process_count() > 1 and devices not in (0, visible):
        raise ConfigError(
            f"{where}: expected 0 or {visible} (every device of every process) in a run of "
            f"{jax.process_count()} processes, got {devices}"
        )
    return devices or visible


def check_divisible(size: int, devices: int, where: str) -> None:
    """ConfigError unless the batch `size` (the spec key `where`) divides by the device count."""
    if devices > 1 and size % devices:
        raise ConfigError(
            f"{where}: expected a multiple of the device count {devices} (the batch is split "
            f"evenly over the devices), got {size}"
        )


@dataclasses.dataclass(frozen=True)
class Placement:
    """The mesh of a run and the shardings built from it; `mesh` None: one device, nothing applied."""

    mesh: Mesh | None = None

    @property
    def num_devices(self) -> int:
        return 1 if self.mesh is None else int(self.mesh.devices.size)

    def _sharding(self, spec: P) -> NamedSharding:
        assert self.mesh is not None
        return NamedSharding(self.mesh, spec)

    def replicated(self, tree: Any) -> Any:
        """`tree` with every array replicated on every device (in or out of jit)."""
        return self._place(tree, lambda x: P())

    def batched(self, tree: Any, axis: int = 0) -> Any:
        """`tree` with every array's `axis` split over the devices (in or out of jit)."""
        return self._place(tree, lambda x: _spec(x.ndim, axis))

    def place(self, tree: Any, batched: Any) -> Any:
        """`tree` placed leaf by leaf: `batched` is a matching pytree (or a prefix of it) of
        None (replicated) or the axis split over the devices."""
        if self.mesh is None:
            return tree
        specs = jax.tree.map(
            lambda b, sub: jax.tree.map(lambda x: P() if b is None else _spec(x.ndim, b), sub),
            batched, tree, is_leaf=lambda b: b is None,
        )
        return jax.tree.map(lambda x, s: self._put(x, s), tree, specs)

    def _place(self, tree: Any, spec: Callable[[Any], P]) -> Any:
        if self.mesh is None:
            return tree
        return jax.tree.map(lambda x: self._put(x, spec(x)), tree)

    def _put(self, x: Any, spec: P) -> Any:
        sharding = self._sharding(spec)
        if isinstance(x, jax.core.Tracer):
            return jax.lax.with_sharding_constraint(x, sharding)
        if isinstance(x, jax.Array) and x.sharding == sharding:
            return x
        if jax.process_count() > 1:  # every process holds the same value: assemble the global array
            host = jax.device_get(x)
            return jax.make_array_from_callback(jnp.shape(host), sharding, lambda idx: host[idx])
        return jax.device_put(x, sharding)

    def map_batch(self, fn: Callable[..., Any], out_axes: Callable[[Any], Any] | None = None) -> Callable[..., Any]:
        """`fn(batch, key)` run on each device's share of `batch` (`shard_map`).

        `batch`'s leaves are split on their leading axis; `key` is replicated and each
        device folds its index into it, so devices draw different numbers. `out_axes`
        maps `fn`'s output structure (from `jax.eval_shape`) to a matching tree of specs
        (default: every leaf split on its leading axis).
        """
        if self.mesh is None:
            return fn
        mesh, n = self.mesh, self.num_devices

        def run(batch: Any, key: jax.Array) -> Any:
            local = jax.tree.map(lambda x: jax.ShapeDtypeStruct((x.shape[0] // n, *x.shape[1:]), x.dtype), batch)
            shapes = jax.eval_shape(fn, local, key)
            specs = jax.tree.map(lambda _: P(BATCH_AXIS), shapes) if out_axes is None else out_axes(shapes)

            def body(b: Any, k: jax.Array) -> Any:
                return fn(b, jax.random.fold_in(k, jax.lax.axis_index(BATCH_AXIS)))

            # check_vma off: a rollout's scan starts from a replicated carry (a fixed start
            # state) that becomes per-device; every output is per-device anyway.
            return jax.shard_map(
                body, mesh=mesh, in_specs=(P(BATCH_AXIS), P()), out_specs=specs, check_vma=False
            )(batch, key)

        return run

    def psum(self, x: Any) -> Any:
        """Sum over the devices, inside `map_batch`'s function only."""
        return x if self.mesh is None else jax.lax.psum(x, BATCH_AXIS)

    def fetch(self, tree: Any) -> Any:
        """`tree` as host NumPy arrays on every process (arrays split across processes gathered)."""
        if self.mesh is None or jax.process_count() == 1:
            return jax.device_get(tree)

        return jax.tree.map(
            lambda x: jax.device_get(x) if not isinstance(x, jax.Array) or x.is_fully_replicated
            else multihost_utils.process_allgather(x, tiled=True),
            tree,
        )


def _spec(ndim: int, axis: int) -> P:
    if ndim <= axis:
        return P()
    return P(*([None] * axis), BATCH_AXIS)


def make_placement(devices: int = 0) -> Placement:
    """The placement of a run on `devices` devices (0: all visible; `resolve_devices`)."""
    n = resolve_devices(devices)
    if n == 1:
        return Placement()
    return Placement(_mesh(n))


def _mesh(n: int) -> Mesh:
    # Auto axes: jit's sharding propagation (GSPMD) places what the constraints do not pin.
    return jax.make_mesh((n,), (BATCH_AXIS,), axis_types=(AxisType.Auto,), devices=jax.devices()[:n])


def fetch(tree: Any) -> Any:
    """`Placement.fetch` without a placement at hand: gathers what other processes hold."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    return Placement(_mesh(jax.device_count())).fetch(tree)


def is_distributed() -> bool:
    """True in a run of several processes (`jax.distributed`)."""
    return jax.process_count() > 1


def barrier(name: str, timeout_s: int = 3600) -> None:
    """Wait until every process of a jax.distributed run gets here (nothing with one process).

    The first collective of a program gives the other processes 30 s to arrive (gloo's
    context set-up); processes that compile at different speeds meet here first. It
    goes through the coordination service (the barrier jax's own checkpointing uses),
    not through a collective.
    """
    if jax.process_count() == 1:
        return

    client = distributed.global_state.client
    if client is not None:
        client.wait_at_barrier(f"qdrl_{name}", timeout_in_ms=timeout_s * 1000)


def is_primary() -> bool:
    """True in the process that writes a run's files (process 0; the only one without jax.distributed)."""
    return jax.process_index() == 0


def initialize_distributed(
    coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> None:
    """Join a multi-process run (`jax.distributed.initialize`), before anything touches a device.

    Each value not given is read from `JAX_COORDINATOR_ADDRESS`, `JAX_NUM_PROCESSES` and
    `JAX_PROCESS_ID`; when none is set either, jax detects the cluster (Slurm, Open MPI,
    Kubernetes, Cloud TPU). Every process then sees every process's devices; CPU
    collectives across processes go through gloo (jax's default).
    """

    env = os.environ
    coordinator = coordinator or env.get("JAX_COORDINATOR_ADDRESS") or None
    if num_processes is None and env.get("JAX_NUM_PROCESSES"):
        num_processes = int(env["JAX_NUM_PROCESSES"])
    if process_id is None and env.get("JAX_PROCESS_ID"):
        process_id = int(env["JAX_PROCESS_ID"])
    try:
        jax.distributed.initialize(coordinator, num_processes, process_id)
    except ValueError as e:  # e.g. no coordinator given and no cluster detected
        raise ConfigError(
            f"--distributed: expected --coordinator HOST:PORT, --num-processes and --process-id (or "
            f"JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID, or a Slurm / Open MPI job); {e}"
        ) from None
