"""qdrl: reinforcement learning and Quality-Diversity in JAX."""

from qdrl._quiet import MujocoWarning, quiet

__version__ = "0.1.0"
__all__ = ["MujocoWarning", "__version__", "quiet"]

# Cheap (imports nothing) and narrow: see qdrl/_quiet.py for the messages it silences.
quiet()
