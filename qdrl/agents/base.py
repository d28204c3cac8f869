"""The interface every off-policy agent presents to the training loop.

An agent is a bundle of pure, jittable functions over an explicit state pytree.
The training loop, PBT and the actor-critic emitters only ever call these, so
one SAC and one TD3 serve all of them.

Hyperparameters that population-based training may change during a run
(learning rates, discount, reward scale, noise scales) live in the state as
scalar arrays (`state.hparams`), not in the static config: a population of
agents is a vmapped state, each member with its own values.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

from qdrl.types import Array, Metrics, Params, PRNGKey, Transition

AgentState = Any  # each agent's own NamedTuple; always has `.hparams: dict[str, Array]`


class Agent(NamedTuple):
    """Pure functions of one agent; `obs` arguments are batched on the leading axis.

    init(key) -> state
    act(state, obs, key) -> action            exploration action, in [-1, 1]
    policy(policy_params, obs) -> action      deterministic action, for evaluation
    policy_params(state) -> params            the parameters `policy` takes
    update(state, transitions, key) -> (state, metrics)
                                              one gradient step on a sampled batch
    """

    init: Callable[[PRNGKey], AgentState]
    act: Callable[[AgentState, Array, PRNGKey], Array]
    policy: Callable[[Params, Array], Array]
    policy_params: Callable[[AgentState], Params]
    update: Callable[[AgentState, Transition, PRNGKey], tuple[AgentState, Metrics]]
