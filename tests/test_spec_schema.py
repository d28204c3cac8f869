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


# Every key of every packaged spec given bad values, checked by both: test_spec_validation.py's walk.


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
