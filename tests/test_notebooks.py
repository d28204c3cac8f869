"""The notebooks of notebooks/: committed without outputs, listed in the site, and each run top to
bottom in a fresh kernel of this interpreter (`pytest -m notebooks`, after
`pip install -e ".[notebooks]"`; left out of the default run, as `slow` is).

`$QDRL_NOTEBOOKS_EXECUTED`, when set, names a directory that receives each executed
notebook, outputs included: the documentation site shows those (docs/notebooks_hook.py).
"""

from __future__ import annotations

import json
import os
import re
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
CELL_TIMEOUT_S = 600


def test_notebooks_are_committed_clean_and_in_the_site() -> None:
    assert [p.stem for p in NOTEBOOKS] == [
        "cma_family", "map_elites", "multi_objective", "qd_rl_comparison", "skills",
    ]
    nav = (ROOT / "mkdocs.yml").read_text()
    for path in NOTEBOOKS:
        notebook = json.loads(path.read_text())
        assert notebook["metadata"]["kernelspec"]["name"] == "python3", path.name
        for cell in notebook["cells"]:
            if cell["cell_type"] == "code":
                # Outputs come from a real execution only (CI's, for the site), never committed.
                assert cell["outputs"] == [] and cell["execution_count"] is None, path.name
        assert f"notebooks/{path.stem}.md" in nav, f"{path.name}: not in mkdocs.yml's nav"


@pytest.fixture(scope="module")
def this_python_kernel(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A kernelspec `python3` that starts this interpreter, found before any other (JUPYTER_PATH
    comes first), so the notebooks import the qdrl under test."""
    from ipykernel.kernelspec import write_kernel_spec

    jupyter = tmp_path_factory.mktemp("jupyter")
    write_kernel_spec(jupyter / "kernels" / "python3")
    return str(jupyter)


@pytest.mark.notebooks
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_top_to_bottom(
    path: Path, tmp_path: Path, this_python_kernel: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import nbclient
    import nbformat

    monkeypatch.setenv("JUPYTER_PATH", this_python_kernel)
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    # Temporary files land in tmp_path/tmp; the kernel's working directory, tmp_path/cwd, must
    # stay empty: a notebook writes nothing outside its temporary directory.
    (tmp_path / "tmp").mkdir()
    (tmp_path / "cwd").mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        notebook, timeout=CELL_TIMEOUT_S, kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path / "cwd")}},
    )
    started = time.perf_counter()
    client.execute()
    elapsed = time.perf_counter() - started
    print(f"{path.name}: {elapsed:.1f} s")
    assert not list((tmp_path / "cwd").iterdir()), f"{path.name} wrote into its working directory"
    errors = [o for c in notebook.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    figures = sum("image/png" in o.get("data", {}) for c in notebook.cells for o in c.get("outputs", []))
    assert figures >= 1, f"{path.name} showed no figure"
    warnings = [
        o.text for c in notebook.cells for o in c.get("outputs", [])
        if o.output_type == "stream" and o.name == "stderr" and re.search(r"Warning\b", o.text)
    ]
    assert not warnings, f"{path.name} printed warnings: {warnings}"
    out = os.environ.get("QDRL_NOTEBOOKS_EXECUTED")
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        nbformat.write(notebook, Path(out) / path.name)
