"""qdrl: reinforcement learning and Quality-Diversity in JAX."""

__version__ = "0.1.0"
