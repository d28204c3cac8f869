"""The spec schema: `qdrl run` refuses a bad key or value before jax is imported, with the
full check's message, and never refuses a spec the full check accepts."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from typing import Any

import pytest

from qdrl import spec_recording, spec_schema, specs
from qdrl.algorithms import ALGORITHMS
from qdrl.config import ConfigError, as_table, load_toml
from qdrl.experiment import check_spec
from qdrl.qd.emitters.registry import EMITTER_KINDS
from qdrl.tasks import TASKS

PACKAGED = {name: load_toml(specs.resolve(name)) for name in specs.spec_names()}


def test_the_packaged_schema_is_the_one_the_table_gives() -> None:
    recorded = json.loads(spec_schema.SCHEMA_FILE.read_text())
    assert recorded == json.loads(json.dumps(spec_recording.record())), "run: python -m qdrl.spec_recording"
    assert sorted(recorded["algorithms"]) == sorted(ALGORITHMS)


def test_every_task_name_and_emitter_kind_has_its_table() -> None:
    schema = json.loads(spec_schema.SCHEMA_FILE.read_text())
    for name, entry in schema["algorithms"].items():
        task = entry["sections"].get("task")
        if task is not None:
            assert task["by"] == "name" and sorted(task["variants"]) == sorted(TASKS), name
        emitter = entry["sections"].get("emitter", {})
        if "by" in emitter:
            assert set(emitter["variants"]) <= set(EMITTER_KINDS) and emitter["default"] in emitter["variants"]
    kinds = schema["algorithms"]["map_elites"]["sections"]["emitter"]["variants"]
    assert len(kinds) >= 5  # the GA kinds, the CMA kinds, ...


def _resolved(spec: dict[str, Any]) -> dict[str, Any]:
    """The spec with every default written out, as the checked sections give it."""
    checked = check_spec(spec)

    def table(v: Any) -> Any:
        if isinstance(v, tuple):
            return [table(x) for x in v]
        return as_table(v) if dataclasses.is_dataclass(v) else dict(v)

    return {
        "experiment": as_table(checked.experiment),
        "log": as_table(checked.log),
        **{k: table(v) for k, v in checked.sections.items()},
    }


@pytest.mark.parametrize("name", sorted(PACKAGED))
def test_every_packaged_spec_and_its_resolved_form_pass(name: str) -> None:
    spec = PACKAGED[name]
    spec_schema.precheck(spec)
    spec_schema.precheck(_resolved(spec))


BAD_VALUES = ("oops", -1, 1.5, 2.0, float("nan"), [1, "x"], True)


def _one_spec_per_algorithm() -> list[str]:
    first: dict[str, str] = {}
    for name, spec in sorted(PACKAGED.items()):
        first.setdefault(spec["experiment"]["algorithm"], name)
    return sorted(first.values())


@pytest.mark.parametrize("name", _one_spec_per_algorithm())
def test_a_bad_value_of_any_key_is_refused_as_the_full_check_refuses_it(name: str) -> None:
    # Every key of every section of the resolved spec, given each bad value in turn: where the
    # precheck refuses, the full check refuses with the same message; where the full check
    # refuses the key itself (type, range, name), the precheck refuses it too.
    resolved = _resolved(PACKAGED[name])
    tried = refused = 0
    for section, table in resolved.items():
        if not isinstance(table, dict) or section == "experiment":
            continue
        for key in table:
            for value in BAD_VALUES:
                spec = json.loads(json.dumps(PACKAGED[name]))
                spec.setdefault(section, {})[key] = value
                try:
                    spec_schema.precheck(spec)
                    early = None
                except ConfigError as e:
                    early = str(e)
                try:
                    check_spec(spec)
                    full = None
                except ConfigError as e:
                    full = str(e)
                tried += 1
                if early is not None:
                    refused += 1
                    assert full is not None, (section, key, value, early)
                    if key != "kind":  # a kind's registry names itself in another order
                        assert early == full, (section, key, value)
                elif full is not None and full.startswith(f"{section}.{key}: expected"):
                    pytest.fail(f"{section}.{key} = {value!r}: the full check refuses ({full}), the precheck not")
    assert refused > tried // 3


def test_unknown_names_sections_and_keys_get_the_full_checks_message() -> None:
    spec = PACKAGED["map_elites_arm"]
    cases = [
        {**spec, "task": {"name": "armm"}},
        {**spec, "emitter": {"kind": "isolin"}},
        {**spec, "emitter": {"kind": "cma_improvement", "sigma00": 1.0}},
        {**spec, "repertoire": {**spec.get("repertoire", {}), "grid_shap": [4, 4]}},
        {**spec, "tsak": {}},
        {**spec, "experiment": {**spec["experiment"], "algorithm": "map_elite"}},
        {**spec, "task": {"name": "arm", "num_joint": 3}},
    ]
    for case in cases:
        with pytest.raises(ConfigError) as early:
            spec_schema.precheck(case)
        with pytest.raises(ConfigError) as full:
            check_spec(case)
        if "kind" not in str(full.value).split(":")[0]:
            assert str(early.value) == str(full.value)
    with pytest.raises(ConfigError, match="did you mean 'arm'"):
        spec_schema.precheck(cases[0])


def test_a_bad_value_through_the_cli_never_imports_jax() -> None:
    code = (
        "import sys\n"
        "from qdrl import cli\n"
        "rc = cli.main(['run', 'default', '--set', 'agent.discount=2', '--out', 'unused'])\n"
        "heavy = sorted(m for m in ('jax', 'brax', 'jumanji', 'haiku', 'numpy') if m in sys.modules)\n"
        "print(rc, heavy)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "2 []"
    assert out.stderr.strip() == "qdrl: error: agent.discount: expected a number in [0, 1], got 2"
