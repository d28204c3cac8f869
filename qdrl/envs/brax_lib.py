"""The brax modules qdrl uses, in one place: `qdrl.envs.brax` imports this on first use, so that
runs of other tasks never pay for importing brax (seconds)."""

from __future__ import annotations

from brax import contact, envs

from qdrl.envs.brax_walls import AntMaze, AntTrap

__all__ = ["AntMaze", "AntTrap", "contact", "envs"]
