"""MkDocs hook: the notebooks of notebooks/ as pages of the site, converted at build time.

Each `notebooks/NAME.ipynb` becomes the page `notebooks/NAME.md` (markdown cells as
they are, code cells as Python blocks, outputs below them) and is offered for
download beside it. The committed notebooks carry no outputs; when
`$QDRL_NOTEBOOKS_EXECUTED` names a directory holding executed copies (what
`pytest -m notebooks` writes there, as `.ci/run` does before building the site),
the pages show those copies' outputs: text, tables and figures. Reading the JSON
needs nothing beyond the standard library.
"""

from __future__ import annotations

import base64
import json
import os
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
# pandas' HTML tables: its <style> block and table attributes go, so the theme styles the table.
_STYLE = re.compile(r"<style[^>]*>.*?</style>", re.S)
_TABLE_ATTRS = re.compile(r"<table[^>]*>")


def _text(value: str | list[str]) -> str:
    return value if isinstance(value, str) else "".join(value)


def _fence(text: str, language: str = "text") -> str:
    text = _ANSI.sub("", text).rstrip("\n")
    fence = "````" if "```" in text else "```"
    return f"{fence}{language}\n{text}\n{fence}"


def _output(output: dict[str, Any], image: str) -> tuple[str, bytes | None]:
    """The Markdown of one output, and the PNG it shows (saved as `image`), if any."""
    kind = output.get("output_type")
    if kind == "stream":
        return _fence(_text(output.get("text", ""))), None
    if kind == "error":
        return _fence("\n".join(output.get("traceback", []))), None
    data = output.get("data", {})
    if "image/png" in data:
        return f"![output]({Path(image).name})", base64.b64decode(_text(data["image/png"]))
    if "text/html" in data:
        html = _TABLE_ATTRS.sub("<table>", _STYLE.sub("", _text(data["text/html"])))
        return f'<div class="notebook-output">\n{html.strip()}\n</div>', None
    if "text/markdown" in data:
        return _text(data["text/markdown"]), None
    if "text/plain" in data:
        return _fence(_text(data["text/plain"])), None
    return "", None


def render(notebook: dict[str, Any], name: str, executed: bool) -> tuple[str, dict[str, bytes]]:
    """A notebook's page (Markdown) and the images it links to, by file name."""
    blocks: list[str] = []
    images: dict[str, bytes] = {}
    titled = False
    for cell in notebook.get("cells", []):
        source = _text(cell.get("source", ""))
        if cell.get("cell_type") == "markdown":
            title, found, rest = source.partition("\n")
            if not titled and title.startswith("# "):  # below the page's title: where it comes from
                blocks += [title, _origin(name, executed)] + ([rest] if found and rest.strip() else [])
                titled = True
            else:
                blocks.append(source)
        elif cell.get("cell_type") == "code" and source.strip():
            blocks.append(_fence(source, "python"))
            for output in _merged_streams(cell.get("outputs", [])):
                image = f"{name}_{len(images)}.png"
                text, png = _output(output, image)
                if png is not None:
                    images[image] = png
                if text:
                    blocks.append(text)
    return "\n\n".join(blocks) + "\n", images


def _merged_streams(outputs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The outputs with consecutive pieces of one stream joined (a kernel flushes stdout as it
    goes, so a loop's prints arrive in several pieces): one text block each."""
    merged: list[dict[str, Any]] = []
    for output in outputs:
        previous = merged[-1] if merged else None
        if (
            previous is not None and output.get("output_type") == "stream"
            and previous.get("output_type") == "stream" and previous.get("name") == output.get("name")
        ):
            merged[-1] = {**previous, "text": _text(previous.get("text", "")) + _text(output.get("text", ""))}
        else:
            merged.append(output)
    return merged


def _origin(name: str, executed: bool) -> str:
    shown = "the outputs of an executed copy (CI's, for the published site)" if executed else (
        "no outputs (build the site with `$QDRL_NOTEBOOKS_EXECUTED` set to show them; see "
        "`tests/test_notebooks.py`)"
    )
    return (
        f"!!! note \"A notebook\"\n    `notebooks/{name}.ipynb` in the repository "
        f"([download]({name}.ipynb)), shown here with {shown}. Run it with "
        f"`pip install -e \".[notebooks]\"` and Jupyter, or `pytest -m notebooks`."
    )


def on_files(files: Files, config: Any) -> Files:
    root = Path(config["config_file_path"]).parent / "notebooks"
    executed_dir = os.environ.get("QDRL_NOTEBOOKS_EXECUTED")
    for path in sorted(root.glob("*.ipynb")):
        shown = Path(executed_dir) / path.name if executed_dir else path
        executed = shown != path and shown.is_file()
        notebook = json.loads((shown if executed else path).read_text(encoding="utf-8"))
        page, images = render(notebook, path.stem, executed)
        files.append(File.generated(config, f"notebooks/{path.stem}.md", content=page))
        files.append(File.generated(config, f"notebooks/{path.name}", content=path.read_bytes()))
        for image, png in images.items():
            files.append(File.generated(config, f"notebooks/{image}", content=png))
    return files
