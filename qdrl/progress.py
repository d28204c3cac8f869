"""The progress line of `qdrl run`: how long compilation has taken, then a progress bar."""

from __future__ import annotations

import time
from typing import Any

from tqdm import tqdm

__all__ = ["RunProgress"]


class RunProgress:
    """The terminal line of a run: a compile timer, then a bar over iterations or env steps.

    `unit` is the metrics row key the bar counts ("iteration", "env_steps", "log_point")
    and `total` its value at the end of the run. Writes to stderr (tqdm); nothing
    when `enabled` is False.
    """

    def __init__(self, enabled: bool, label: str, unit: str, total: int) -> None:
        self.enabled, self.label, self.unit, self.total = enabled, label, unit, total
        self._bar: Any = None
        self._t0 = time.perf_counter()
        self._note = ""

    def compiling(self, estimate: tuple[float, bool] | None) -> None:
        """Shows the compile timer; `estimate`: (seconds, measured on this very spec) or None."""
        if not self.enabled:
            return

        if estimate is None:
            self._note = " (first run of this spec here: no estimate yet)"
        elif estimate[1]:
            self._note = f" (last run of this spec: {estimate[0]:.0f} s)"
        else:
            self._note = f" (first run of this spec: about {estimate[0]:.0f} s)"
        self._t0 = time.perf_counter()
        self._bar = tqdm(total=None, bar_format="{desc}", dynamic_ncols=True)
        self.tick()

    def tick(self) -> None:
        if self._bar is not None:
            elapsed = time.perf_counter() - self._t0
            self._bar.set_description_str(f"compiling {self.label} ... {elapsed:.0f} s{self._note}")

    def compiled(self, seconds: float) -> None:
        if self._bar is not None:
            self._bar.set_description_str(f"compiled {self.label} in {seconds:.1f} s", refresh=False)
            self._bar.close()
            self._bar = None

    def start(self, done: int) -> None:
        if not self.enabled:
            return

        steps = self.unit == "env_steps"
        self._bar = tqdm(
            total=self.total, initial=done, unit="step" if steps else "it", unit_scale=steps,
            dynamic_ncols=True, desc=self.label,
        )

    def update(self, done: int, shown: dict[str, str]) -> None:
        if self._bar is not None:
            self._bar.set_postfix(shown, refresh=False)
            self._bar.update(done - self._bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
