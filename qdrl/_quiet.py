"""Silence the notices qdrl's dependencies print on every run, and only those.

- mujoco-mjx prints "Failed to import warp: ..." and "Failed to import mujoco_warp: ..." on
  stdout when it is imported without NVIDIA Warp (its optional GPU backend);
- brax warns (UserWarning) that its pipelines are not actively maintained, each time it
  loads a model;
- MuJoCo's default warning handler prints its warnings on stdout and appends them to
  `MUJOCO_LOG.TXT` in the working directory; brax's half_cheetah.xml triggers one (the
  `settotalmass` compiler attribute is deprecated).

`quiet()` imports nothing: it adds one warnings filter and an import hook that acts when
mujoco or mujoco-mjx is first imported (or at once for a module already imported). Other
MuJoCo warnings still reach the user, as Python warnings (`MujocoWarning`), and no
`MUJOCO_LOG.TXT` is written.
"""

from __future__ import annotations

import contextlib
import io
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from types import ModuleType
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from importlib.abc import Loader
    from importlib.machinery import ModuleSpec

_BRAX_NOTICE = r"Brax System, piplines and environments are not actively being maintained"
_WARP_LINES = ("Failed to import warp:", "Failed to import mujoco_warp:")
_WARP_MODULE = "mujoco.mjx.warp"
_MUJOCO_DROPPED = ("compiler attribute 'settotalmass' is deprecated",)


class MujocoWarning(UserWarning):
    """A warning from the MuJoCo engine (handed to Python instead of MUJOCO_LOG.TXT)."""


def _mujoco_warning(message: str) -> None:
    if any(dropped in message for dropped in _MUJOCO_DROPPED):
        return
    try:
        warnings.warn(f"MuJoCo: {message}", MujocoWarning, stacklevel=2)
    except Exception:
        # MuJoCo calls this from C: an exception escaping it (warnings turned into errors)
        # aborts the process, so the warning goes to stderr instead.
        print(f"MujocoWarning: MuJoCo: {message}", file=sys.stderr)


def _install_mujoco_handler(mujoco: ModuleType) -> None:
    mujoco.set_mju_user_warning(_mujoco_warning)


@contextlib.contextmanager
def _without_stdout_lines(prefixes: Sequence[str]) -> Iterator[None]:
    """Drops the stdout lines that start with one of `prefixes`; the rest is written after."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            yield
    finally:
        kept = [line for line in captured.getvalue().splitlines(keepends=True) if not line.startswith(tuple(prefixes))]
        sys.stdout.write("".join(kept))


class _Loader:
    """Runs a module's own loader, then `after(module)`, with some stdout lines dropped.

    (Not an importlib.abc.Loader subclass: importing importlib.abc costs more than the rest.)
    """

    def __init__(self, inner: Any, prefixes: Sequence[str], after: Callable[[ModuleType], None] | None):
        self._inner, self._prefixes, self._after = inner, prefixes, after

    def create_module(self, spec: ModuleSpec) -> ModuleType | None:
        return self._inner.create_module(spec)  # type: ignore[no-any-return]

    def exec_module(self, module: ModuleType) -> None:
        # The module keeps its own loader (importlib.resources and friends ask it).
        if module.__spec__ is not None:
            module.__spec__.loader = self._inner
        module.__loader__ = self._inner
        with _without_stdout_lines(self._prefixes):
            self._inner.exec_module(module)
        if self._after is not None:
            self._after(module)


# module -> (stdout line prefixes dropped while it is imported, what to run after its import)
_HOOKS: dict[str, tuple[Sequence[str], Callable[[ModuleType], None] | None]] = {
    "mujoco": ((), _install_mujoco_handler),
    _WARP_MODULE: (_WARP_LINES, None),
}


class _QuietImports:
    """Import hook (a meta path finder) for the two noisy modules: mujoco, mujoco.mjx.warp."""

    def find_spec(self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None) -> ModuleSpec | None:
        if fullname not in _HOOKS:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                break
        else:
            return None
        if spec.loader is not None and hasattr(spec.loader, "exec_module"):
            spec.loader = cast("Loader", _Loader(spec.loader, *_HOOKS[fullname]))
        return spec


def quiet() -> None:
    """Silences mujoco-mjx's warp notices, brax's maintenance warning and MuJoCo's log file.

    Idempotent and cheap (imports nothing); `import qdrl` calls it. Only these messages are
    affected; other MuJoCo warnings arrive as `qdrl.MujocoWarning`.
    """
    warnings.filterwarnings("ignore", message=_BRAX_NOTICE, category=UserWarning)
    if "mujoco" in sys.modules:
        _install_mujoco_handler(sys.modules["mujoco"])
    if not any(isinstance(finder, _QuietImports) for finder in sys.meta_path):
        sys.meta_path.insert(0, _QuietImports())
