"""qdrl: reinforcement learning and Quality-Diversity in JAX."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from qdrl._quiet import MujocoWarning, quiet

if TYPE_CHECKING:
    from qdrl.runs import load_metrics, load_repertoires, load_run

from qdrl._version import __version__

__all__ = ["MujocoWarning", "__version__", "load_metrics", "load_repertoires", "load_run", "quiet"]

# Cheap (imports nothing) and narrow: see qdrl/_quiet.py for the messages it silences.
quiet()


def __getattr__(name: str) -> Any:
    # `import qdrl` stays cheap: jax and pandas load on first use of `qdrl.load_run`.
    if name in ("load_run", "load_metrics", "load_repertoires"):
        from qdrl import runs

        return getattr(runs, name)
    raise AttributeError(f"module 'qdrl' has no attribute {name!r}")
