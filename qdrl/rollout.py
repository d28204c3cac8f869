"""The one rollout loop of qdrl: step a batch of environments under a policy, in a scan.

Training collection (with automatic resets), evaluation of an agent, and the
evaluation of a batch of policy genotypes by QD tasks all call `unroll`; they
differ only by the policy function and by `auto_reset`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.envs.base import Env, EnvState, auto_reset, reset_batch, step_batch
from qdrl.types import Array, PRNGKey, Transition

# obs batch (B, obs_size), key -> action batch (B, action_size)
PolicyFn = Callable[[Array, PRNGKey], Array]
# batched env state after a step -> what is kept of it (leaves keep the batch axis first)
RecordFn = Callable[[EnvState], Any]


def env_step(
    env: Env, state: EnvState, policy: PolicyFn, key: PRNGKey, reset: bool = True
) -> tuple[EnvState, Transition]:
    """Act, step the batch and record the transition; then reset finished envs if `reset`.

    The transition keeps the true next observation of a finished episode: the
    reset happens after it is recorded.
    """
    next_state, transition = _act(env, state, policy, key)
    if reset:
        next_state = auto_reset(env, next_state)
    return next_state, transition


def _act(env: Env, state: EnvState, policy: PolicyFn, key: PRNGKey) -> tuple[EnvState, Transition]:
    """One step of the batch under `policy` (no reset) and its transition."""
    action = policy(state.obs, key)
    next_state = step_batch(env, state, action)
    transition = Transition(
        obs=state.obs,
        action=action,
        reward=next_state.reward,
        next_obs=next_state.obs,
        terminated=next_state.terminated,
        truncated=next_state.truncated,
        desc=state.desc,
        next_desc=next_state.desc,
    )
    return next_state, transition


def unroll(
    env: Env,
    state: EnvState,
    policy: PolicyFn,
    key: PRNGKey,
    num_steps: int,
    reset: bool = True,
) -> tuple[EnvState, Transition]:
    """`num_steps` steps of `env_step` in a `lax.scan`; transitions are stacked (T, B, ...)."""
    final, transitions, _ = unroll_recorded(env, state, policy, key, num_steps, _nothing, reset)
    return final, transitions


def _nothing(state: EnvState) -> None:
    del state


def unroll_recorded(
    env: Env,
    state: EnvState,
    policy: PolicyFn,
    key: PRNGKey,
    num_steps: int,
    record: RecordFn,
    reset: bool = True,
) -> tuple[EnvState, Transition, Any]:
    """`unroll`, also stacking `record(state)` of the states after each step (before any reset).

    E.g. `lambda s: s.inner.pipeline_state.x` keeps brax's link poses (what
    `brax.io.html` draws); the recorded leaves are (T, B, ...).
    """

    def body(s: EnvState, k: PRNGKey) -> tuple[EnvState, tuple[Transition, Any]]:
        stepped, transition = _act(env, s, policy, k)
        kept = record(stepped)
        if reset:
            stepped = auto_reset(env, stepped)
        return stepped, (transition, kept)

    final, (transitions, recorded) = jax.lax.scan(body, state, jax.random.split(key, num_steps))
    return final, transitions, recorded


class Episodes(NamedTuple):
    """Whole episodes of a batch of environments, one per batch entry."""

    returns: Array  # (B,) sum of rewards up to and including the episode's last step
    lengths: Array  # (B,) int32 number of steps taken before the episode ended
    final_desc: Array  # (B, D) state descriptor after the last step of the episode
    mean_desc: Array  # (B, D) state descriptor averaged over the episode's steps
    transitions: Transition  # (T, B, ...) every step, valid where `mask` is 1
    mask: Array  # (T, B) 1.0 for steps inside the episode
    recorded: Any = None  # (T, B, ...) what `run_episodes`'s `record` kept of each step's state


def run_episodes(
    env: Env,
    policy: PolicyFn,
    key: PRNGKey,
    num_envs: int,
    num_steps: int | None = None,
    record: RecordFn | None = None,
    start_state: EnvState | None = None,
) -> Episodes:
    """Roll out one episode per environment from fresh resets, masking steps after the end.

    Episodes last at most `num_steps` (default: the env's episode length). With
    `start_state` (one unbatched state, e.g. `fixed_start_state`: QDax's deterministic
    evaluation of policies), every environment starts from it; otherwise each starts
    from its own random initial state. With `record`, `Episodes.recorded` stacks what
    it keeps of the batch's state after each step (see `unroll_recorded`).
    """
    num_steps = env.episode_length if num_steps is None else num_steps
    reset_key, run_key = jax.random.split(key)
    if start_state is not None:
        state = jax.tree.map(lambda x: jnp.broadcast_to(x, (num_envs, *jnp.shape(x))), start_state)
    else:
        state = reset_batch(env, reset_key, num_envs)
    _, tr, recorded = unroll_recorded(
        env, state, policy, run_key, num_steps, _nothing if record is None else record, reset=False
    )
    done = jnp.maximum(tr.terminated, tr.truncated)
    # A step is valid if no earlier step ended the episode.
    ended_before = jnp.cumsum(done, axis=0) - done
    mask = (ended_before == 0).astype(jnp.float32)
    lengths = jnp.sum(mask, axis=0).astype(jnp.int32)
    returns = jnp.sum(tr.reward * mask, axis=0)
    last = jnp.clip(lengths - 1, 0, num_steps - 1)
    final_desc = jnp.take_along_axis(tr.next_desc, last[None, :, None], axis=0)[0]
    mean_desc = jnp.sum(tr.next_desc * mask[..., None], axis=0) / jnp.maximum(
        lengths[:, None], 1
    )
    return Episodes(returns, lengths, final_desc, mean_desc, tr, mask, recorded)


def fixed_start_state(env: Env, start_key: PRNGKey) -> EnvState:
    """The state `env` resets to from the concrete `start_key`, computed now by its own small
    compiled program, also while another program is being traced, as host (NumPy) arrays.

    Evaluations from one fixed start (QDax's deterministic scoring) broadcast it to
    the batch instead of resetting every environment inside the evaluation: the
    evaluation's program holds no reset (a third of a brax task's program), and
    every batch size starts from the same bits.
    """
    # Compiled as a program of its own (the env's traced reset), even inside another trace:
    # under `jax.ensure_compile_time_eval` every operation of the reset on brax's constant
    # arrays ran (and compiled) one by one, 137 small programs and 2.3 s for halfcheetah.
    reset = env.traced_reset(start_key).lower().compile()
    # NumPy leaves: programs that use it hold them as constants.
    return jax.device_get(reset(start_key))
