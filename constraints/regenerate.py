"""Regenerate the constraints files CI installs: `python3 constraints/regenerate.py [3.11 3.12 3.13]`.

For each Python version, in a fresh virtual environment, installs qdrl with its test, docs and notebooks
extras and writes `pip freeze` (qdrl itself left out) to `constraints/py<version>.txt`. Versions in
LOWEST resolve qdrl's direct dependencies to the lower bounds of pyproject.toml (so CI keeps
testing the bounds qdrl declares); the others take the newest releases that install.
Needs the network (PyPI) and a few minutes per version.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import re
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
from pythons import find_python  # noqa: E402

VERSIONS = ("3.11", "3.12", "3.13")
LOWEST = frozenset({"3.11"})
_LOWER_BOUND = re.compile(r"^([A-Za-z0-9_.-]+)(\[[^\]]*\])?\s*>=\s*([^,;\s]+)")


def lower_bounds(pyproject: Path) -> list[str]:
    """`name==version` for every direct dependency (core, test, docs and notebooks) that has a `>=` bound."""
    project = tomllib.loads(pyproject.read_text())["project"]
    extras = project["optional-dependencies"]
    requirements = project["dependencies"] + extras["test"] + extras["docs"] + extras["notebooks"]
    pins = []
    for requirement in requirements:
        match = _LOWER_BOUND.match(requirement)
        if match:
            pins.append(f"{match.group(1)}=={match.group(3)}")
    return pins


def freeze(python: str, lowest: bool) -> str:
    """The `pip freeze` of a fresh venv of `python` holding qdrl[test,docs,notebooks], qdrl left out."""
    with tempfile.TemporaryDirectory() as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([python, "-m", "venv", str(venv)], check=True)
        pip = [str(venv / "bin" / "python"), "-m", "pip"]
        subprocess.run([*pip, "install", "-q", "--upgrade", "pip"], check=True)
        install = [*pip, "install", "-q", f"{REPO}[test,docs,notebooks]"]
        if lowest:
            bounds = Path(tmp) / "lower-bounds.txt"
            bounds.write_text("\n".join(lower_bounds(REPO / "pyproject.toml")) + "\n")
            install += ["-c", str(bounds)]
        subprocess.run(install, check=True)
        out = subprocess.run([*pip, "freeze", "--exclude", "qdrl"], check=True, capture_output=True, text=True)
        return out.stdout


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("versions", nargs="*", default=list(VERSIONS), help="Python versions (X.Y)")
    args = parser.parse_args()
    for version in args.versions:
        python = find_python(version)
        if python is None:
            print(f"regenerate: no working python{version} here; skipped", file=sys.stderr)
            continue
        full = subprocess.run([python, "-c", "import platform; print(platform.python_version())"],
                              check=True, capture_output=True, text=True).stdout.strip()
        lowest = version in LOWEST
        which = "qdrl's lower bounds for its direct dependencies" if lowest else "the newest releases"
        header = (
            f"# Python {version} (resolved on {full}, {platform.machine()}, "
            f"{datetime.date.today().isoformat()}): {which}.\n"
            f"# Written by `python3 constraints/regenerate.py {version}`; do not edit by hand.\n"
            f'# Use: pip install -c constraints/py{version}.txt -e ".[test]"\n'
        )
        path = HERE / f"py{version}.txt"
        path.write_text(header + freeze(python, lowest))
        print(f"wrote {path.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
