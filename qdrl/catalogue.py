"""What `qdrl list` prints: the packaged specs, the algorithms, the emitter kinds and the tasks."""

from __future__ import annotations

from qdrl import specs
from qdrl.algorithms import ALGORITHMS
from qdrl.envs import PURE_JAX_ENVS
from qdrl.envs.brax import BACKENDS, brax_env_names
from qdrl.qd.emitters.registry import EMITTER_KINDS
from qdrl.tasks import TASKS

__all__ = ["listing", "shorten"]


def shorten(text: str, width: int = 90) -> str:
    """`text` cut at a word boundary to at most `width` characters ("..." marks a cut)."""
    if len(text) <= width:
        return text
    return text[: width - 3].rsplit(" ", 1)[0].rstrip(",;:(") + "..."


def listing() -> str:
    """The lines of `qdrl list`."""
    lines = []
    directory = specs.spec_dir()
    names = specs.spec_names()
    where = f" ({directory}; run one by name: qdrl run NAME)" if directory is not None else ""
    lines.append(f"specs{where}:")
    width = max((len(n) for n in names), default=0)
    for name in names:
        assert directory is not None
        lines.append(f"  {name:<{width}}  {shorten(specs.describe(directory / f'{name}.toml'))}".rstrip())
    lines.append("algorithms:")
    width = max(len(n) for n in ALGORITHMS)
    lines.extend(f"  {n:<{width}}  {ALGORITHMS[n].description}".rstrip() for n in sorted(ALGORITHMS))
    lines.append("emitter kinds (the [emitter] kind of QD specs, or each [[emitters]] of a pool):")
    lines.extend(f"  {name}: {kind.description}" for name, kind in sorted(EMITTER_KINDS.items()))
    lines.append("tasks:")
    lines.append(f"  QD tasks (the [task] section of QD specs): {', '.join(sorted(TASKS))}")
    lines.append(f"  pure-JAX environments: {', '.join(PURE_JAX_ENVS)}")
    lines.append(f"  brax environments ({', '.join(BACKENDS)} backends): {', '.join(brax_env_names())}")
    return "\n".join(lines)
