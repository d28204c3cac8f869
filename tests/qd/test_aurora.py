"""AURORA's archive: recorded sequences, container size control, the training schedule, and runs."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from qdrl.config import ConfigError, dump_toml
from qdrl.experiment import check_spec, run_spec
from qdrl.qd.autoencoder import make_autoencoder
from qdrl.qd.base import Evaluation
from qdrl.qd.repertoires.aurora import AuroraSettings, aurora_archive, observation_sequences
from qdrl.types import Transition


def _transitions(desc: jax.Array, obs: jax.Array) -> Transition:
    steps, n = desc.shape[:2]
    zeros = jnp.zeros((steps, n))
    return Transition(
        obs=obs, action=jnp.zeros((steps, n, 1)), reward=zeros, next_obs=obs, terminated=zeros,
        truncated=zeros, desc=desc, next_desc=desc,
    )


def _settings(**kw: Any) -> AuroraSettings:
    ae = make_autoencoder("mlp", 4, 2, 2, hidden=(16,), learning_rate=1e-2, batch_size=16)
    return AuroraSettings(autoencoder=ae, **{"period": 3, "length": 4, **kw})


def test_sequences_sample_every_period_and_hold_the_last_step_after_the_end() -> None:
    steps, n = 12, 2
    t = jnp.arange(steps, dtype=jnp.float32)
    desc = jnp.stack([t, 10 * t], -1)[:, None, :].repeat(n, 1)  # (T, n, 2): the step index
    obs = jnp.broadcast_to(jnp.arange(5.0), (steps, n, 5))
    mask = jnp.ones((steps, n)).at[7:, 1].set(0.0)  # episode 1 ends after step 6
    extras = {"transitions": _transitions(desc, obs), "mask": mask}
    seq = observation_sequences(extras, _settings())
    assert seq.shape == (2, 4, 2)
    np.testing.assert_array_equal(seq[0, :, 0], [0, 3, 6, 9])  # every 3 steps
    np.testing.assert_array_equal(seq[1, :, 0], [0, 3, 6, 6])  # step 9 is past the end: step 6's
    full = observation_sequences(extras, _settings(observation="full", max_features=3))
    assert full.shape == (2, 4, 5)  # 2 descriptor entries + the observation's first 3
    np.testing.assert_array_equal(full[0, 1], [3, 30, 0, 1, 2])
    with pytest.raises(ValueError, match=r"extras\['transitions'\]"):
        observation_sequences({}, _settings())


def _evaluation(key: jax.Array, n: int, steps: int = 12) -> Evaluation:
    """n straight-line trajectories of random directions: a descriptor x-y moving each step."""
    k1, k2 = jax.random.split(key)
    direction = jax.random.normal(k1, (n, 2))
    t = jnp.arange(steps, dtype=jnp.float32)[:, None, None]
    desc = t * direction[None] / steps
    extras = {"transitions": _transitions(desc, desc), "mask": jnp.ones((steps, n))}
    return Evaluation(jax.random.uniform(k2, (n,)), desc[-1], extras, jnp.asarray(n * steps, jnp.int32))


def _archive(**kw: Any) -> Any:
    settings = _settings(**{"target_size": 8, "csc_every": 2, "train_every": 3, "epochs": 3, **kw})
    return aurora_archive(jnp.zeros(3), settings, capacity=64, l_value=0.05, key=jax.random.PRNGKey(0))


def test_trainings_follow_the_growing_schedule_and_every_elite_is_re_encoded() -> None:
    archive = _archive()
    add = jax.jit(lambda a, g, e: a.add_evaluation(g, e))
    trained_at = []
    for i in range(13):
        ev = _evaluation(jax.random.PRNGKey(i), 16)
        before = int(archive.trainings)
        archive, _ = add(archive, jnp.zeros((16, 3)), ev)
        if int(archive.trainings) > before:
            trained_at.append(i)
    # after the initial batch (0), then gaps of 3, 6, 9: batches 3, 9, 18
    assert trained_at == [0, 3, 9]
    assert int(archive.next_training) == 18
    assert math.isfinite(float(archive.loss))
    # codes of the stored elites are the current encoder's codes of their sequences
    filled = np.asarray(archive.filled)
    codes = archive.settings.autoencoder.encode(archive.model, archive.sequences)
    np.testing.assert_allclose(np.asarray(archive.descriptors)[filled], np.asarray(codes)[filled], atol=1e-5)
    # stored codes are pairwise at least l apart (the unstructured archive's invariant)
    d = np.asarray(archive.descriptors)[filled]
    dist = np.linalg.norm(d[:, None] - d[None], axis=-1) + np.eye(len(d)) * 1e9
    assert dist.min() >= float(archive.l_value) - 1e-6


def test_each_training_draws_a_fresh_key_from_the_archive_s_own_key() -> None:
    ev = _evaluation(jax.random.PRNGKey(3), 16)
    a = _archive()
    once, _ = a.add_evaluation(jnp.zeros((16, 3)), ev)
    assert int(once.trainings) == 1
    # the key moved on at the training, and it is not the one the autoencoder was initialised from
    assert not np.array_equal(jax.random.key_data(once.key), jax.random.key_data(a.key))
    # the same state trains to the same model; another key to another one
    again, _ = a.add_evaluation(jnp.zeros((16, 3)), ev)
    np.testing.assert_array_equal(np.asarray(once.loss), np.asarray(again.loss))
    other, _ = dataclasses.replace(a, key=jax.random.PRNGKey(7)).add_evaluation(jnp.zeros((16, 3)), ev)
    assert float(other.loss) != float(once.loss)


@pytest.mark.parametrize(("target", "direction"), [(2, 1.0), (60, -1.0)])
def test_container_size_control_moves_the_threshold_towards_the_target(target: int, direction: float) -> None:
    archive = _archive(target_size=target, train_every=1000, csc_gain=1e-3)
    archive, _ = archive.add_evaluation(jnp.zeros((16, 3)), _evaluation(jax.random.PRNGKey(0), 16))  # trains
    n, l0 = int(archive.num_filled), float(archive.l_value)
    assert 2 < n < 60
    controlled = jax.jit(lambda a: a.control_size())(archive)
    # the error is unchanged since the training: the threshold moves by gain x (elites - target)
    assert float(controlled.l_value) == pytest.approx(l0 + 1e-3 * (n - target), rel=1e-5)
    assert direction * (float(controlled.l_value) - l0) > 0  # too many elites: l grows; too few: it shrinks
    assert int(controlled.num_filled) <= n  # a larger threshold can only drop elites


def _tiny_spec(tmp_path: Path, algorithm: str = "aurora", **search: Any) -> Path:
    spec = {
        "experiment": {"algorithm": algorithm, "seed": 0},
        "task": {"name": "point_maze", "episode_length": 50, "policy_hidden": [8]},
        "repertoire": {"kind": "cvt", "num_centroids": 32, "cvt_samples": 1000},
        "emitter": {"kind": "isoline", "batch_size": 16},
        "search_archive": {
            "num_observations": 5, "capacity": 64, "target_size": 32, "epochs": 3, "late_epochs": 2,
            "batch_size": 16, "train_every": 2, "csc_every": 2, **search,
        },
        "qd": {"num_iterations": 8, "log_every": 4, "init_batch_size": 16},
        "log": {"checkpoint_every": 1},
    }
    if algorithm == "pga_aurora":
        spec["pg"] = {
            "num_critic_training_steps": 2, "num_pg_training_steps": 2, "training_batch_size": 16,
            "replay_buffer_size": 2000, "critic_hidden": [8],
        }
    path = tmp_path / "spec.toml"
    path.write_text(dump_toml(spec))
    return path


@pytest.mark.parametrize(("algorithm", "encoder"), [("aurora", "lstm"), ("pga_aurora", "mlp")])
def test_a_tiny_run_learns_codes_fills_the_result_archive_and_resumes_bit_identically(
    algorithm: str, encoder: str, tmp_path: Path, resumes_bit_identically: Any
) -> None:
    spec = _tiny_spec(tmp_path, algorithm, encoder=encoder, hidden=[16])
    out = tmp_path / "out"
    summary = run_spec(spec, [], out)
    rows = pd.read_csv(out / "metrics.csv")
    assert len(rows) == 2
    # the result archive over the hand-made descriptor (final x-y) is what the QD metrics read
    assert summary["num_elites"] > 0 and summary["coverage"] > 0
    assert summary["aurora_elites"] > 0 and summary["autoencoder_trainings"] >= 3  # batches 0, 2, 6
    assert math.isfinite(summary["autoencoder_loss"]) and summary["l_value"] > 0
    for plot in ("autoencoder_loss", "aurora_elites", "l_value", "repertoire", "learnt_descriptors"):
        assert (out / "plots" / f"{plot}.png").exists(), plot
    keys = ("qd_score", "coverage", "aurora_elites", "l_value", "autoencoder_loss", "evaluations")
    resumes_bit_identically(spec, out, summary, keys)


@pytest.mark.parametrize(
    ("task", "search", "message"),
    [
        ({"name": "arm"}, {}, "search_archive.kind: AURORA learns descriptors from what a policy observes"),
        ({"name": "point_maze", "episode_length": 40}, {}, "search_archive.num_observations: expected"),
        ({"name": "point_maze"}, {"target_size": 100, "capacity": 50}, "search_archive.target_size: expected at most"),
        ({"name": "point_maze"}, {"encoder": "gru"}, "search_archive.encoder"),
        ({"name": "point_maze"}, {"l_value": 0.0}, "search_archive.l_value"),
    ],
)
def test_bad_aurora_specs_are_refused_before_compiling(
    task: dict[str, Any], search: dict[str, Any], message: str
) -> None:
    spec = {
        "experiment": {"algorithm": "aurora"}, "task": task, "search_archive": search,
        "emitter": {"batch_size": 16}, "qd": {"num_iterations": 10, "log_every": 5, "init_batch_size": 16},
    }
    with pytest.raises(ConfigError, match=message.replace("[", r"\[")):
        check_spec(spec)
