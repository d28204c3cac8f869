"""Package list for setuptools (everything else is in pyproject.toml).

The experiment specs live in the repository's `agents/` directory and ship in the
wheel as the data package `qdrl._specs` (`package-dir` in pyproject.toml maps it),
so `qdrl run default` works outside a clone. pyproject.toml's `packages.find`
cannot add a mapped package to the ones it finds, hence this list.
"""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["qdrl", "qdrl.*"]), "qdrl._specs"])
