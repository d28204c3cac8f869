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


def test_list_gives_each_spec_a_line_of_its_own(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = specs.spec_names()
    described = {x.split()[0]: x.split(maxsplit=1)[1] for x in lines if x.split()[:1] and x.split()[0] in names}
    assert set(described) == set(names)
    assert len(set(described.values())) == len(names)  # no two specs read the same
    assert described["map_elites_arm"] == "map_elites on arm: 1,000 iterations, 1,024 per batch"
    assert described["dads_ant_omni_cpu"] == (
        "dads on ant_omni (spring): 200,000 env steps, 8 envs, 100-step episodes [2-core variant of dads_ant_omni]"
    )
    assert all("2-core" in described[n] or "2 CPU cores" in described[n] for n in names if "_cpu" in n)
    # twins that differ only in settings the summary does not show: those settings
    assert "pg.num_critic_training_steps=300" in described["pga_me_halfcheetah_uni_cpu_paper_td3"]


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
    assert tool["package-data"]["qdrl._specs"] == [
        "*.toml", "seed_benchmark/*.toml", "metra_baselines/*.toml", "dns_baselines/*.toml", "suites/*.toml"
    ]
    assert "qdrl._specs" in (ROOT / "setup.py").read_text()
    assert (ROOT / "agents" / "__init__.py").is_file()
