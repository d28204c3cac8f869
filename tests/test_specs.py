"""Specs ship with the package: found by name, described by `qdrl list`, mapped into the wheel."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from qdrl import specs
from qdrl.cli import main
from qdrl.config import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def test_a_name_a_name_with_suffix_and_a_path_resolve_to_the_same_file(tmp_path: Path) -> None:
    by_name = specs.resolve("default")
    assert by_name.resolve() == (ROOT / "agents" / "default.toml").resolve()
    assert specs.resolve("default.toml") == by_name
    assert specs.resolve(ROOT / "agents" / "default.toml") == ROOT / "agents" / "default.toml"
    own = tmp_path / "default.toml"  # a path always wins over a packaged name
    own.write_text("[experiment]\nalgorithm = 'sac'\n")
    assert specs.resolve(str(own)) == own


def test_an_unknown_name_suggests_close_ones() -> None:
    with pytest.raises(ConfigError, match=r"spec 'map_elite_arm': expected a spec file or the name .*map_elites_arm"):
        specs.resolve("map_elite_arm")
    with pytest.raises(ConfigError, match=re.escape("spec file 'nowhere/x.toml' not found")):
        specs.resolve("nowhere/x.toml")


def test_every_packaged_spec_has_a_one_line_description() -> None:
    names = specs.spec_names()
    assert {"default", "map_elites_arm", "sac_halfcheetah"} <= set(names)
    assert specs.describe(specs.resolve("default")).startswith("The README's one-minute demo: SAC")
    missing = [n for n in names if not specs.describe(specs.resolve(n))]
    assert missing == []


def test_list_shows_each_spec_by_name_with_its_description(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    (line,) = [x for x in lines if x.split()[:1] == ["map_elites_arm"]]
    assert "MAP-Elites on the planar arm" in line and len(line) <= 140


def test_run_by_name_checks_the_packaged_spec(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "map_elites_arm", "--check", "--set", "qd.num_iterations=100"]) == 0
    resolved = tomllib.loads(capsys.readouterr().out)
    assert resolved["experiment"]["name"] == "map_elites_arm" and resolved["qd"]["num_iterations"] == 100
    assert main(["run", "map_elites_armm", "--check"]) == 2
    assert "close names: map_elites_arm" in capsys.readouterr().err


def test_the_wheel_maps_agents_into_the_package() -> None:
    """What setuptools is told (a real wheel is built and run outside the clone by .ci/run)."""
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert tool["package-dir"] == {"qdrl._specs": "agents"}
    assert tool["package-data"]["qdrl._specs"] == ["*.toml"]
    assert "qdrl._specs" in (ROOT / "setup.py").read_text()
    assert (ROOT / "agents" / "__init__.py").is_file()
