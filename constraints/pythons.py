"""Find a working interpreter for a Python version: `python3 constraints/pythons.py 3.12`.

Prints the interpreter's path and exits 0, or exits 1 when none runs. `pythonX.Y` on PATH
comes first; a pyenv shim that is on PATH but not active (pyenv answers "command not found")
does not count, and the pyenv install of that version is used instead.
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import sys


def _runs(exe: str, version: str) -> bool:
    try:
        out = subprocess.run(
            [exe, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
            capture_output=True, text=True, timeout=60, check=False,
        )
    except OSError:
        return False
    return out.returncode == 0 and out.stdout.strip() == version


def _patch_level(exe: str) -> int:
    patch = exe.split(os.sep)[-3].split(".")[-1]
    return int(patch) if patch.isdigit() else -1


def find_python(version: str) -> str | None:
    """The path of an interpreter that runs Python `version` ("3.12"), or None."""
    candidates = []
    on_path = shutil.which(f"python{version}")
    if on_path:
        candidates.append(on_path)
    pyenv_root = os.environ.get("PYENV_ROOT") or os.path.expanduser("~/.pyenv")
    installs = glob.glob(os.path.join(pyenv_root, "versions", f"{version}.*", "bin", f"python{version}"))
    candidates += sorted(installs, key=_patch_level, reverse=True)
    return next((exe for exe in candidates if _runs(exe, version)), None)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python3 constraints/pythons.py X.Y")
    found = find_python(sys.argv[1])
    if found is None:
        sys.exit(1)
    print(found)
