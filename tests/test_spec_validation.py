"""Every value of every spec in agents/ is checked before anything is built.

For each spec and each key of its sections (those the file sets, and, once per
algorithm, every key its sections accept), the key is given a wrong type (a
string, a table, a list), NaN, +inf, -inf, a negative number and zero; lists are
also given lists of those numbers. Whether a value is valid for a key is read
from the key's declaration (its type, `Range`, `OneOf` registry, or the task
builder's annotation) by `accepts` below, written apart from qdrl's own checks:
an invalid value must fail the parse-and-check phase (`check_spec`, no task or
environment built) with one line `<section>.<key>: expected ..., got ...`; a
valid one must pass it or fail with a one-line `ConfigError` of a check across
keys. A sample goes through the real CLI in fresh processes (exit status 2, one
`qdrl: error:` line, no traceback, time).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import re
import subprocess
import sys
import types
import typing
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Annotated, Any

import pytest

from qdrl import spec_schema
from qdrl.config import ConfigError, OneOf, Range, as_table, build, describe, load_toml, table_keys
from qdrl.experiment import CheckedSpec, ExperimentConfig, LogConfig, build_run, check_spec

SPECS = sorted((Path(__file__).resolve().parents[1] / "agents").glob("*.toml"))

# Substitutes for any key; lists are also given lists of the numbers.
WRONG: tuple[tuple[str, Any], ...] = (
    ("a string", "not-a-name"),
    ("a table", {"k": 1}),
    ("a list", ["x"]),
    ("nan", math.nan),
    ("+inf", math.inf),
    ("-inf", -math.inf),
    ("negative", -1),
    ("zero", 0),
)
# One spec per algorithm also gets every key its sections accept, not only those it sets.
FIRST_OF_EACH_ALGORITHM = set({load_toml(p)["experiment"]["algorithm"]: p for p in reversed(SPECS)}.values())
NUMBERS = (("nan", math.nan), ("+inf", math.inf), ("-inf", -math.inf), ("negative", -1), ("zero", 0))


def _task_names() -> list[str]:
    from qdrl.tasks import TASKS

    return sorted(TASKS)


TaskName = Annotated[str, OneOf(_task_names)]


def _hints(owner: Any) -> dict[str, Any]:
    return typing.get_type_hints(owner, include_extras=True)


def accepts(tp: Any, value: Any) -> bool:
    """Whether a key declared as `tp` accepts `value` on its own (checks across keys aside)."""
    meta: tuple[Any, ...] = ()
    if typing.get_origin(tp) is Annotated:
        tp, *rest = typing.get_args(tp)
        meta = tuple(rest)
    rng = next((m for m in meta if isinstance(m, Range)), Range())
    names = next((m for m in meta if isinstance(m, OneOf)), None)
    origin = typing.get_origin(tp)
    if origin in (types.UnionType, typing.Union):
        return any(accepts(arg, value) for arg in typing.get_args(tp))
    if origin is typing.Literal:
        return isinstance(value, str) and value in typing.get_args(tp)
    if origin in (tuple, list, typing.get_origin(typing.Sequence[int])):
        return isinstance(value, list) and all(accepts(typing.get_args(tp)[0], v) for v in value)
    if tp is type(None):
        return value is None
    if tp is bool:
        return isinstance(value, bool)
    if tp is str:
        return isinstance(value, str) and (names is None or value in names.names())
    if tp in (int, float) and isinstance(value, int | float) and not isinstance(value, bool):
        if tp is int and not isinstance(value, int):
            return False
        x = float(value)
        if math.isnan(x) or (math.isinf(x) and rng.finite):
            return False
        low_ok = rng.low is None or (x > rng.low if rng.low_open else x >= rng.low)
        high_ok = rng.high is None or (x < rng.high if rng.high_open else x <= rng.high)
        return low_ok and high_ok
    if tp in (int, float):
        return False
    raise AssertionError(f"no rule for the declared type {tp!r}")


def _table_class(section: str) -> type[Any]:
    """The config class of a section that stays a table of given keys until the run is built."""
    from qdrl.algorithms.rl import ArchiveConfig

    return {"archive": ArchiveConfig}[section]


def declared_keys(checked: CheckedSpec) -> Iterator[tuple[str, str, Any, Any]]:
    """(section, key, declared type, resolved value) of every key the spec's sections accept."""
    from qdrl.tasks import TASKS

    sections: dict[str, Any] = {"experiment": checked.experiment, "log": checked.log}
    for name, value in checked.sections.items():  # an array of tables ([[emitters]]): one section each
        sections.update({f"{name}[{i}]": v for i, v in enumerate(value)} if isinstance(value, tuple) else {name: value})
    for section, obj in sections.items():
        if section == "task":
            yield section, "name", TaskName, obj["name"]
            builder = TASKS[obj["name"]].build
            hints = _hints(builder)
            for key in inspect.signature(builder).parameters:
                yield section, key, hints[key], obj[key]
            continue
        cls = type(obj) if dataclasses.is_dataclass(obj) else _table_class(section)
        values = as_table(obj) if dataclasses.is_dataclass(obj) else as_table(build(cls, obj, section))
        for key, (_, tp) in table_keys(cls).items():
            yield section, key, tp, values[key]


def substitutes(original: Any) -> list[tuple[str, Any]]:
    out = list(WRONG)
    if isinstance(original, list | tuple):
        n = max(1, len(original))
        out += [(f"a list of {label}", [v] * n) for label, v in NUMBERS]
    return out


def with_value(spec: Mapping[str, Any], section: str, key: str, value: Any) -> dict[str, Any]:
    if section.endswith("]"):  # "emitters[1]": a table of an array of tables
        name, index = section[:-1].split("[")
        tables = [dict(t) for t in spec[name]]
        tables[int(index)][key] = value
        return {**spec, name: tables}
    return {**spec, section: {**spec.get(section, {}), key: value}}


def given(spec: Mapping[str, Any], section: str) -> Mapping[str, Any]:
    """The keys the spec file sets in `section` ("emitters[1]": the second [[emitters]] table)."""
    if section.endswith("]"):
        name, index = section[:-1].split("[")
        return dict(spec[name][int(index)])
    return dict(spec.get(section, {}))


@dataclasses.dataclass
class Tally:
    invalid: int = 0
    valid_passed: int = 0
    valid_refused_across_keys: int = 0
    prechecked: int = 0
    failures: list[str] = dataclasses.field(default_factory=list)


def _known_to_the_schema(spec: Mapping[str, Any], section: str) -> bool:
    """Whether the schema holds the table of `section` as `spec` gives it (not an open section,
    nor a task or kind of its own table the packaged specs never reach)."""
    entry = spec_schema._schema()["algorithms"][spec["experiment"]["algorithm"]]["sections"]
    pattern = section.split("[", 1)[0] + "[]" if section.endswith("]") else section
    found = spec_schema._schema()["common"].get(pattern) or entry.get(pattern)
    if found is None:
        return False
    found = spec_schema._table_entry(found)
    if "table" in found:
        return True
    if found.get("open"):
        return False
    value = given(spec, section).get(found["by"], found["default"])
    return isinstance(value, str) and value in found["variants"]


def probe(spec: Mapping[str, Any], section: str, key: str, tp: Any, label: str, value: Any, tally: Tally) -> None:
    """Checks `spec` with `section.key = value` and records whether qdrl did what `accepts` says."""
    case = f"{section}.{key} = {label} ({value!r})"
    changed = with_value(spec, section, key, value)
    try:
        check_spec(changed)
        error = None
    except ConfigError as e:
        error = str(e)
    except Exception as e:  # anything else is a failure of the check
        tally.failures.append(f"{case}: {type(e).__name__}: {e}")
        return
    # The check `qdrl run` makes before importing jax (qdrl.spec_schema) refuses only what
    # the full check refuses, with its message (a kind's registry lists its names in
    # another order), and refuses every bad key and value of a section it knows.
    try:
        spec_schema.precheck(changed)
        early = None
    except ConfigError as e:
        early = str(e)
    if early is not None:
        tally.prechecked += 1
        if error is None or (early != error and key != "kind"):
            tally.failures.append(f"{case}: the precheck says {early!r}, the full check {error!r}")
    elif error is not None and not accepts(tp, value) and _known_to_the_schema(changed, section):
        tally.failures.append(f"{case}: the full check refuses ({error!r}), the precheck accepts")
    if error is not None and "\n" in error:
        tally.failures.append(f"{case}: a message of several lines: {error!r}")
    elif accepts(tp, value):
        if error is None:
            tally.valid_passed += 1
        else:
            tally.valid_refused_across_keys += 1
    elif error is None:
        tally.failures.append(f"{case}: accepted, but {key} is declared as {describe(tp)}")
    elif not (error.startswith(f"{section}.{key}: expected ") and ", got " in error):
        tally.failures.append(f"{case}: the message does not name the key: {error!r}")
    else:
        tally.invalid += 1


@pytest.fixture(scope="module")
def tallies() -> dict[str, Tally]:
    """Counts of every probe, by spec name; filled by `test_every_key_of_every_spec`."""
    return {}


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.stem)
def test_every_key_of_every_spec(path: Path, tallies: dict[str, Tally]) -> None:
    spec = load_toml(path)
    checked = check_spec(spec)  # every spec in agents/ is valid
    tally = tallies.setdefault(path.stem, Tally())
    every_key = path in FIRST_OF_EACH_ALGORITHM
    for section, key, tp, value in declared_keys(checked):
        if key in given(spec, section) or every_key:
            for label, bad in substitutes(value):
                probe(spec, section, key, tp, label, bad, tally)
    assert not tally.failures, "\n".join(tally.failures[:20])
    assert tally.invalid > 0
    assert tally.prechecked > tally.invalid // 2


def test_the_walk_met_valid_and_invalid_values(tallies: dict[str, Tally]) -> None:
    """The declarations decide: some substitutes are valid (a seed of 0, learning_starts = 0)."""
    if len(tallies) < len(SPECS):
        pytest.skip("needs the whole walk (test_every_key_of_every_spec) in this session")
    total = Tally()
    for t in tallies.values():
        total.invalid += t.invalid
        total.valid_passed += t.valid_passed
        total.valid_refused_across_keys += t.valid_refused_across_keys
    assert total.invalid > 10_000
    assert total.valid_passed > 100  # e.g. seed 0, learning_starts 0, experiment.name "not-a-name"


# Numbers whose every finite value means something; every other number declares a Range.
ANY_FINITE_NUMBER = {
    ("agent", "target_entropy"),  # SAC's target entropy: any value (default -action_size)
    ("archive", "low"), ("archive", "high"),  # descriptor bounds: any box (low < high is checked)
    ("archive", "qd_offset"), ("dcrl", "reward_offset"),  # offsets, either sign
    ("pbt", "low"), ("pbt", "high"), ("me_pbt", "low"), ("me_pbt", "high"),  # search ranges (checked per name)
    ("skills", "diversity_scale"), ("skills", "extrinsic_scale"),  # reward weights, either sign
    ("smerl", "target"),  # a target return, either sign
    ("archive", "fitness_range"), ("repertoire", "fitness_range"),  # a return range, either sign (min < max checked)
    ("evaluation", "return_range"),  # the same for feature-space skills' profiles
    ("uvfa", "extrinsic_scale"),  # a reward weight, either sign
    # DMS's discount of unexplored regions and its fitness range: fitness values, either sign
    ("search_archive", "threshold_min"), ("search_archive", "discount_range"),
}


def _numbers_without_range(tp: Any) -> bool:
    """Whether `tp` is (a list of, or an optional) int or float without a declared Range."""
    if typing.get_origin(tp) is Annotated:
        return False
    if typing.get_origin(tp) in (tuple, types.UnionType, typing.Union):
        return any(_numbers_without_range(a) for a in typing.get_args(tp) if a is not Ellipsis)
    return tp in (int, float)


@pytest.mark.parametrize("path", sorted(FIRST_OF_EACH_ALGORITHM), ids=lambda p: p.stem)
def test_every_number_declares_a_range_unless_any_finite_value_means_something(path: Path) -> None:
    for section, key, tp, _ in declared_keys(check_spec(load_toml(path))):
        if _numbers_without_range(tp):
            assert (section, key) in ANY_FINITE_NUMBER, f"{section}.{key}: declare its Range"


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.stem)
def test_sections_of_the_wrong_type_unknown_keys_and_sections(path: Path) -> None:
    spec = load_toml(path)
    for section in spec:
        array = isinstance(spec[section], list)  # [[emitters]]
        expected = rf"a list of tables \(\[\[{section}\]\]" if array else rf"a table \(\[{section}\]"
        for value in (5, "x", [1], 1.5, True):
            with pytest.raises(ConfigError, match=rf"^{section}: expected {expected} followed by"):
                check_spec({**spec, section: value})
        extra = "unknown key for task" if section == "task" else "unknown key;"
        where = f"{section}[0]" if array else section
        with pytest.raises(ConfigError, match=rf"^{re.escape(where)}\.not_a_key: {extra}"):
            check_spec(with_value(spec, where, "not_a_key", 1))
    with pytest.raises(ConfigError, match=r"^not_a_section: unknown section for algorithm"):
        check_spec({**spec, "not_a_section": {}})


def test_missing_algorithm_section_and_required_keys() -> None:
    spec = load_toml(SPECS[0])
    with pytest.raises(ConfigError, match=r"^experiment\.algorithm: missing; expected one of \['adaptive_sampling', "):
        check_spec({**spec, "experiment": {"seed": 0}})
    with pytest.raises(ConfigError, match=r"^experiment\.algorithm: expected one of \[.*\], got 'ppo'$"):
        check_spec(with_value(spec, "experiment", "algorithm", "ppo"))
    with pytest.raises(ConfigError, match=r"^experiment: missing section"):
        check_spec({k: v for k, v in spec.items() if k != "experiment"})
    with pytest.raises(ConfigError, match=r"^task\.name: missing; expected one of \["):
        check_spec({**spec, "task": {"num_dofs": 3}})
    with pytest.raises(ConfigError, match=r"^experiment: expected a table"):
        check_spec({**spec, "experiment": 5})


def test_seed_zero_is_valid_and_seeds_past_32_bits_are_not() -> None:
    assert accepts(_hints(ExperimentConfig)["seed"], 0)
    assert not accepts(_hints(ExperimentConfig)["seed"], 2**32)
    spec = load_toml(SPECS[0])
    check_spec(with_value(spec, "experiment", "seed", 0))
    with pytest.raises(ConfigError, match=r"^experiment\.seed: expected an integer in \[0, 4294967295\], got 4294967296$"):
        check_spec(with_value(spec, "experiment", "seed", 2**32))
    assert LogConfig().checkpoint_every == 1


def test_a_bad_pg_value_of_pga_me_is_reported_before_the_task_is_built(monkeypatch: pytest.MonkeyPatch) -> None:
    """PGA-ME used to build its brax task (about 8 s) before reading [pg]; now [pg] comes first."""
    import qdrl.algorithms.qd as qd_runner

    spec = load_toml(Path(SPECS[0]).parent / "pga_me_halfcheetah_uni_cpu.toml")
    check_spec(spec)  # imports done

    def no_build(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("a task was built before [pg] was checked")

    monkeypatch.setattr(qd_runner, "make_task_of", no_build)
    for key, value, message in (
        ("tau", 2.0, r"^pg\.tau: expected a number in \(0, 1\], got 2\.0$"),
        ("critic_learning_rate", math.nan, r"^pg\.critic_learning_rate: expected a number > 0, got nan$"),
        ("proportion_mutation_ga", 1.0, r"^pg\.proportion_mutation_ga: expected a number in \(0, 1\), got 1\.0$"),
        ("replay_buffer_size", 10, r"^pg\.replay_buffer_size: expected at least emitter\.batch_size"),
    ):
        with pytest.raises(ConfigError, match=message):
            build_run(with_value(spec, "pg", key, value))


def test_check_flag_prints_the_resolved_spec(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import tomllib

    from qdrl.cli import main

    spec = tmp_path / "arm.toml"
    spec.write_text('[experiment]\nalgorithm = "map_elites"\n[task]\nname = "arm"\nnum_dofs = 4\n')
    assert main(["run", str(spec), "--check", "--set", "qd.log_every=10", "--out", str(tmp_path / "o")]) == 0
    resolved = tomllib.loads(capsys.readouterr().out)
    assert resolved["experiment"] == {"algorithm": "map_elites", "seed": 0, "name": "arm", "devices": 0}
    assert resolved["task"] == {"name": "arm", "num_dofs": 4}
    assert resolved["qd"]["log_every"] == 10 and resolved["emitter"]["batch_size"] == 1024
    assert not (tmp_path / "o").exists()  # nothing ran
    assert main(["run", str(spec), "--check", "--set", "emitter.iso_sigma=inf"]) == 2
    assert capsys.readouterr().err == "qdrl: error: emitter.iso_sigma: expected a number >= 0, got inf\n"


# (spec file or inline TOML, --set overrides, the error line expected on stderr)
CLI_SAMPLE: tuple[tuple[str, tuple[str, ...], str], ...] = (
    ("map_elites_arm.toml", ("emitter.line_sigma=inf",), "emitter.line_sigma: expected a number >= 0, got inf"),
    ("default.toml", ("archive.low=[-inf,-inf]",), "archive.low: expected a list of finite numbers, got [-inf, -inf]"),
    ("pga_me_halfcheetah_uni_cpu.toml", ("pg.discount=nan",), "pg.discount: expected a number in [0, 1], got nan"),
    ('qd = 5\n[experiment]\nalgorithm = "map_elites"\n', (), "qd: expected a table ([qd] followed by key = value lines), got 5"),
    ("[experiment]\nseed = 1\n", (), "experiment.algorithm: missing; expected one of ['adaptive_sampling',"),
)


# One fresh process runs every case through `qdrl.cli.main`, each with its own stdout and
# stderr: what a user's shell would show for each command.
_CLI_DRIVER = """
import contextlib, io, json, sys
from qdrl.cli import main
out = []
for args in json.loads(sys.argv[1]):
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(args)
    out.append({"code": code, "stdout": stdout.getvalue(), "stderr": stderr.getvalue()})
print("RESULT " + json.dumps(out))
"""


@pytest.fixture(scope="module")
def cli_results(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """Each case of CLI_SAMPLE through `qdrl run`, in one fresh process (the `qdrl` command's
    imports; how long they take is a benchmark figure: `qdrl bench cli`)."""
    tmp = tmp_path_factory.mktemp("cli")
    commands = []
    for i, (source, overrides, _) in enumerate(CLI_SAMPLE):
        if source.endswith(".toml"):
            spec = SPECS[0].parent / source
        else:
            spec = tmp / f"inline_{i}.toml"
            spec.write_text(source)
        sets = [a for o in overrides for a in ("--set", o)]
        commands.append(["run", str(spec), *sets, "--out", str(tmp / f"never_{i}")])
    done = subprocess.run(
        [sys.executable, "-c", _CLI_DRIVER, json.dumps(commands)], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    line = next(x for x in done.stdout.splitlines() if x.startswith("RESULT "))
    return tmp, json.loads(line.removeprefix("RESULT "))


@pytest.mark.parametrize("index", range(len(CLI_SAMPLE)), ids=[c[2].split(":")[0] for c in CLI_SAMPLE])
def test_a_sample_through_the_cli_fails_in_one_line(
    index: int, cli_results: tuple[Path, list[dict[str, Any]]]
) -> None:
    """The cases seen failing late or with a traceback before (2026-11-26)."""
    tmp, results = cli_results
    res, expected = results[index], CLI_SAMPLE[index][2]
    errors = [line for line in res["stderr"].splitlines() if line.startswith("qdrl: error:")]
    assert res["code"] == 2, res["stderr"]
    assert len(errors) == 1 and errors[0].startswith(f"qdrl: error: {expected}"), res["stderr"]
    assert res["stderr"].splitlines()[-1] == errors[0]
    assert "Traceback" not in res["stderr"] and res["stdout"] == ""
    assert not (tmp / f"never_{index}").exists()
