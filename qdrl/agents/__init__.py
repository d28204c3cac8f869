"""The RL core: off-policy agents as bundles of pure functions (`Agent`).

`AGENTS` maps an agent's name, as written in experiment specs, to its config
class and the function that builds it: `make(config, obs_size, action_size)`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qdrl.agents.base import Agent, AgentState
from qdrl.agents.sac import (
    SACConfig,
    SACLosses,
    SACNetworks,
    SACState,
    make_sac,
    make_sac_losses,
    make_sac_networks,
)
from qdrl.agents.td3 import (
    TD3Config,
    TD3Losses,
    TD3Networks,
    TD3State,
    make_td3,
    make_td3_losses,
    make_td3_networks,
    td3_actor_step,
)

AGENTS: dict[str, tuple[type[Any], Callable[..., Agent]]] = {
    "sac": (SACConfig, make_sac),
    "td3": (TD3Config, make_td3),
}

__all__ = [
    "AGENTS",
    "Agent",
    "AgentState",
    "SACConfig",
    "SACLosses",
    "SACNetworks",
    "SACState",
    "TD3Config",
    "TD3Losses",
    "TD3Networks",
    "TD3State",
    "make_sac",
    "make_sac_losses",
    "make_sac_networks",
    "make_td3",
    "make_td3_losses",
    "make_td3_networks",
    "td3_actor_step",
]
