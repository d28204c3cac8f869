"""Environment adapters behind one small protocol (`qdrl.envs.base.Env`), and `make`."""

from __future__ import annotations

from typing import Any

from qdrl.envs.base import Env, EnvState, auto_reset, reset_batch, step_batch
from qdrl.envs.point import PointEnv
from qdrl.envs.point_maze import PointMazeEnv

PURE_JAX_ENVS = ("point", "point_maze")
JUMANJI_ENVS = ("snake",)


def env_names() -> list[str]:
    """Every name `make` accepts: qdrl's pure-JAX environments, then brax's registry."""
    from qdrl.envs.brax import brax_env_names

    return [*PURE_JAX_ENVS, *JUMANJI_ENVS, *brax_env_names()]


def make(
    name: str, backend: str = "spring", episode_length: int = 1000, state_descriptor: str = "xy", **kwargs: Any
) -> Env:
    """The environment called `name`, truncated at `episode_length`; brax ones on `backend`,
    recording `state_descriptor` ("xy", "feet_contact"; the others have their own)."""
    if name == "point":
        return PointEnv(episode_length=episode_length, **kwargs)
    if name == "point_maze":
        return PointMazeEnv(episode_length=episode_length, **kwargs)
    if name == "snake":
        from qdrl.envs.jumanji import snake_env

        return snake_env(episode_length=episode_length, **kwargs)
    from qdrl.envs.brax import BraxEnv

    return BraxEnv(name, backend, episode_length, state_descriptor=state_descriptor, **kwargs)


__all__ = ["Env", "EnvState", "auto_reset", "env_names", "make", "reset_batch", "step_batch"]
