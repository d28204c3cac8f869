"""The experiment specs shipped with qdrl, found by name.

The repository's `agents/*.toml` are installed with the package as the data
package `qdrl._specs` (see setup.py), so `qdrl run default` works from any
directory. From a source tree that is not installed (PYTHONPATH), the `agents/`
directory beside the `qdrl` package is used instead.

    qdrl run default                 # a packaged spec, by name
    qdrl run agents/default.toml     # a path works as before
"""

from __future__ import annotations

import difflib
import importlib.resources
from pathlib import Path
from typing import Any

from qdrl.config import ConfigError, apply_overrides, load_toml

__all__ = ["describe", "resolve", "spec_dir", "spec_names"]


def spec_dir() -> Path | None:
    """The directory of the packaged specs, or None when there is none."""
    try:
        root = importlib.resources.files("qdrl._specs")
    except ModuleNotFoundError:
        root = None
    if root is not None and root.is_dir():
        return Path(str(root))
    source = Path(__file__).resolve().parents[1] / "agents"
    return source if source.is_dir() else None


def spec_names() -> list[str]:
    """The names of the packaged specs (file stems), sorted."""
    d = spec_dir()
    return sorted(p.stem for p in d.glob("*.toml")) if d is not None else []


def _is_name(text: str) -> bool:
    return "/" not in text and "\\" not in text and not text.startswith(".")


def resolve(spec: str | Path) -> Path:
    """The spec file of `spec`: an existing path, or the name of a packaged spec
    (with or without `.toml`); ConfigError naming what was expected otherwise."""
    path = Path(spec)
    if path.is_file():
        return path
    text = str(spec)
    if _is_name(text):
        name = text.removesuffix(".toml")
        d = spec_dir()
        if d is not None and (d / f"{name}.toml").is_file():
            return d / f"{name}.toml"
        close = difflib.get_close_matches(name, spec_names(), n=3)
        hint = f"; close names: {', '.join(close)}" if close else ""
        raise ConfigError(
            f"spec {text!r}: expected a spec file or the name of a packaged spec "
            f"(`qdrl list` shows them){hint}"
        )
    raise ConfigError(f"spec file {text!r} not found")


_NOT_AN_END = ("al.", "e.g.", "i.e.", "vs.", "approx.")


def describe(path: str | Path) -> str:
    """A spec's description: the first sentence of the comment block it opens with (its first
    comment line when no sentence ends sooner; empty without a comment)."""
    words: list[str] = []
    with Path(path).open(encoding="utf-8") as f:
        for line in f:
            stripped = line.strip()
            text = stripped.lstrip("#").strip()
            if not stripped.startswith("#") or not text:
                break
            for word in text.split():
                words.append(word)
                if word.endswith(".") and not word.endswith(_NOT_AN_END):
                    return " ".join(words)
            if not words:
                continue
            if text.endswith(":"):
                return " ".join(words)
    return " ".join(words)


def load_spec(spec_path: str | Path, overrides: list[str] | None = None) -> dict[str, Any]:
    """The spec at `spec_path` (a path, or a packaged spec's name: `resolve`) with `--set`
    overrides; `experiment.name` defaults to the file's stem."""
    spec_path = resolve(spec_path)
    spec = apply_overrides(load_toml(spec_path), overrides or [])
    exp = spec.setdefault("experiment", {})
    if isinstance(exp, dict) and not exp.get("name"):
        exp["name"] = spec_path.stem
    return spec
