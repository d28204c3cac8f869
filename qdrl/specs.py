"""The experiment specs shipped with qdrl, found by name.

The repository's `agents/*.toml` are installed with the package as the data
package `qdrl._specs` (see setup.py), so `qdrl run default` works from any
directory. From a source tree that is not installed (PYTHONPATH), the `agents/`
directory beside the `qdrl` package is used instead.

    qdrl run default                 # a packaged spec, by name
    qdrl run seed_benchmark/map_elites_ant_omni_cpu   # one in a folder of packaged specs
    qdrl run agents/default.toml     # a path works as before

Folders of packaged specs: `seed_benchmark/` (the skill-discovery benchmark of Chalumeau,
Boige et al. 2023, one spec per algorithm and task), `metra_baselines/` (DIAYN and DADS at
METRA's 2-core settings, for the `metra_cpu` suite), `dns_baselines/` (MAP-Elites at the settings of
the DNS comparison, for the `dns_walker2d` suite) and `suites/` (suite files, `qdrl suite`).
"""

from __future__ import annotations

import difflib
import importlib.resources
from pathlib import Path
from typing import Any

from qdrl.config import ConfigError, apply_overrides, load_toml

__all__ = ["SPEC_FOLDERS", "describe", "resolve", "spec_dir", "spec_names"]

# The folders of packaged specs whose files `resolve` finds as "<folder>/<name>".
SPEC_FOLDERS = ("seed_benchmark", "metra_baselines", "dns_baselines")


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


def spec_names(folder: str | None = None) -> list[str]:
    """The names of the packaged specs (file stems), sorted; those of one of `SPEC_FOLDERS`
    (as "<folder>/<stem>") with `folder`."""
    d = spec_dir()
    if d is None:
        return []
    if folder is None:
        return sorted(p.stem for p in d.glob("*.toml"))
    return sorted(f"{folder}/{p.stem}" for p in (d / folder).glob("*.toml"))


def _is_name(text: str) -> bool:
    head, _, tail = text.partition("/")
    if tail and head in SPEC_FOLDERS:
        return "/" not in tail and "\\" not in tail and not tail.startswith(".")
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
        folder = name.partition("/")[0] if "/" in name else None
        close = difflib.get_close_matches(name, spec_names(folder), n=3)
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
