"""The documentation's generated tables: built from the code, and every marker in docs/ resolves."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import jax
import jax.numpy as jnp

from qdrl import docgen
from qdrl.algorithms.qd import RepertoireConfig
from qdrl.off_policy import TrainConfig
from qdrl.qd.emitters.qd_rl import PGAMEConfig

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"<!-- keys (\S+):(\S+) (\S+) -->")


def test_a_key_table_gives_each_key_its_default_what_it_accepts_and_its_comment() -> None:
    table = docgen.keys_table(RepertoireConfig, "repertoire").splitlines()
    assert table[0] == "| key | default | accepts | meaning |"
    kind = next(line for line in table if line.startswith("| `repertoire.kind` |"))
    # a comment of several lines above the key is its meaning
    assert kind.startswith("| `repertoire.kind` | `\"grid\"` | one of 'grid', 'cvt', 'sliding', 'categorical' | regular grid")
    assert kind.endswith("as pyribs' CategoricalArchive) |")
    assert "| `repertoire.grid_shape` | `[32, 32]` | a list of positive integers |" in table[3]
    # with sliding's and categorical's keys, cvt_seed, CMA-MAE's learning_rate and threshold_min, fitness_range
    assert len(table) == 2 + 12
    assert table[11].startswith("| `repertoire.learning_rate` | `1.0` |")
    assert table[10].startswith("| `repertoire.cvt_seed` | (none) | an integer >= 0 or nothing")
    train = docgen.keys_table(TrainConfig, "train")
    assert "| `train.learning_starts` | `10000` | an integer >= 0 |" in train


def test_nested_configs_give_their_keys_under_the_spec_names() -> None:
    table = docgen.keys_table(PGAMEConfig, "pg").splitlines()
    rows = {row.split(" | ")[0].strip("| `"): row for row in table[2:]}
    # PGConfig's own keys, its TD3's under the [pg] names, then the GA's share; no [emitter] key.
    assert list(rows)[:5] == [
        "pg.num_critic_training_steps", "pg.num_pg_training_steps", "pg.policy_learning_rate",
        "pg.training_batch_size", "pg.replay_buffer_size",
    ]
    assert "pg.critic_learning_rate" in rows and "pg.critic_hidden" in rows and "pg.ga" not in rows
    assert rows["pg.critic_learning_rate"].split(" | ")[1] == "`0.0003`"
    assert "Adam step size of the twin Q critics" in rows["pg.critic_learning_rate"]  # TD3Config's comment
    assert rows["pg.proportion_mutation_ga"].endswith("Share of the batch made by the GA; the rest by Q-PG (QDax's PGA-ME: 0.5). |")


def test_task_and_spec_tables() -> None:
    tasks = docgen.tasks_table(["arm", "sphere"]).splitlines()
    assert len(tasks) == 4 and tasks[2].startswith("| `arm` | Planar arm")
    assert "end-effector x, end-effector y in [0, 1] × [0, 1] | -0.5 | `num_dofs=100` |" in tasks[2]
    specs = docgen.specs_table(["default"]).splitlines()
    assert specs[2].startswith("| `default` | The README's one-minute demo")


def test_every_keys_marker_of_the_docs_names_a_config_dataclass() -> None:
    markers = [m.groups() for page in (ROOT / "docs").rglob("*.md") for m in MARKER.finditer(page.read_text())]
    assert len(markers) >= 18
    for module, name, section in markers:
        cls = getattr(importlib.import_module(module), name)
        assert docgen.keys_table(cls, section).count(f"`{section}.") >= 1, (module, name)


def test_the_task_example_of_the_docs_runs() -> None:
    page = (ROOT / "docs" / "extending.md").read_text()
    (code,) = [c for c in re.findall(r"```python\n(.*?)```", page, flags=re.S) if "def ring" in c]
    namespace: dict = {}
    exec(code, namespace)
    task = namespace["ring"](4)
    x = jnp.asarray([[1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5]])
    evaluation = task.scoring_fn(x, jax.random.PRNGKey(0))
    assert evaluation.fitnesses.tolist() == [0.0, 0.0] and task.descriptor_names == ("x_0", "x_1")
    assert float(task.qd_offset) < -1.0
