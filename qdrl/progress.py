"""The progress line of `qdrl run`: how long compilation has taken, then a progress bar.

On a terminal it is one line redrawn in place (tqdm). Written to anything else (a file,
`2>log` under Slurm, a pipe) it is plain lines instead, one per update and at most one
every `plain_every` seconds (the last one always), so that a log holds readable lines and
not one long line of carriage returns.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

from tqdm import tqdm

__all__ = ["RunProgress"]


class RunProgress:
    """The terminal line of a run: a compile timer, then a bar over iterations or env steps.

    `unit` is the metrics row key the bar counts ("iteration", "env_steps", "log_point")
    and `total` its value at the end of the run. Writes to `stream` (default stderr):
    tqdm on a terminal, plain lines elsewhere (`plain`, default: `stream` is not a
    terminal); nothing when `enabled` is False.
    """

    def __init__(
        self,
        enabled: bool,
        label: str,
        unit: str,
        total: int,
        stream: TextIO | None = None,
        plain: bool | None = None,
        plain_every: float = 30.0,
    ) -> None:
        self.enabled, self.label, self.unit, self.total = enabled, label, unit, total
        self._stream = sys.stderr if stream is None else stream
        self.plain = not _isatty(self._stream) if plain is None else plain
        self.plain_every = plain_every
        self._bar: Any = None
        self._t0 = time.perf_counter()
        self._note = ""
        self._last_line = -float("inf")  # when the last plain line was written
        self._phase = ""  # "preparing", "compiling" or "running" while a line or a bar is live
        self._what = ""  # what the timer line says is under way

    def _line(self, text: str) -> None:
        self._stream.write(text + "\n")
        self._stream.flush()
        self._last_line = time.perf_counter()

    def _begin(self, phase: str, what: str, note: str) -> None:
        """Starts a timer line: `what ... N s` (and `note`) until `_end`."""
        self._t0, self._phase, self._what, self._note = time.perf_counter(), phase, what, note
        if self.plain:
            self._line(what + note)
            return
        self._bar = tqdm(total=None, bar_format="{desc}", dynamic_ncols=True, file=self._stream)
        self.tick()

    def _end(self, text: str) -> None:
        """Ends a timer line with `text` (on a terminal it replaces the line)."""
        self._phase = ""
        if self._bar is not None:
            self._bar.set_description_str(text, refresh=False)
            self._bar.close()
            self._bar = None
        elif self.plain:
            self._line(text)

    def preparing(self, what: str) -> None:
        """Shows a timer for a host computation before compiling (`what`, e.g. "computing 1024
        CVT cells (k-means of 50,000 samples)")."""
        if self.enabled:
            self._begin("preparing", what, "")

    def prepared(self, seconds: float) -> None:
        if self.enabled:
            self._end(f"{self._what}: {seconds:.1f} s")

    def compiling(self, estimate: tuple[float, bool] | None) -> None:
        """Shows the compile timer; `estimate`: (seconds, measured on this very spec) or None."""
        if not self.enabled:
            return
        if estimate is None:
            note = " (first run of this spec here: no estimate yet)"
        elif estimate[1]:
            note = f" (last run of this spec: {estimate[0]:.0f} s)"
        else:
            note = f" (first run of this spec: about {estimate[0]:.0f} s)"
        self._begin("compiling", f"compiling {self.label}", note)

    def tick(self) -> None:
        elapsed = time.perf_counter() - self._t0
        text = f"{self._what} ... {elapsed:.0f} s"
        if self._bar is not None:
            self._bar.set_description_str(text + self._note)
        elif self.plain and self._phase in ("preparing", "compiling") and (
            time.perf_counter() - self._last_line >= self.plain_every
        ):
            self._line(text)

    def compiled(self, compile_s: float, startup_s: float) -> None:
        """Compilation done: `compile_s` the chunk's compile (summary.json's `compile_s`),
        `startup_s` everything before the first chunk (initial state, checkpoint, compiles)."""
        if self.enabled:
            self._end(f"compiled {self.label} in {compile_s:.1f} s (started in {startup_s:.1f} s)")

    def start(self, done: int) -> None:
        if not self.enabled:
            return
        self._t0 = time.perf_counter()
        self._phase = "running"
        if self.plain:
            self._last_line = -float("inf")
            return
        steps = self.unit == "env_steps"
        self._bar = tqdm(
            total=self.total, initial=done, unit="step" if steps else "it", unit_scale=steps,
            dynamic_ncols=True, desc=self.label, file=self._stream,
        )

    def update(self, done: int, shown: dict[str, str]) -> None:
        if self._bar is not None:
            self._bar.set_postfix(shown, refresh=False)
            self._bar.update(done - self._bar.n)
        elif self.plain and self._phase == "running":
            last = done >= self.total
            if last or time.perf_counter() - self._last_line >= self.plain_every:
                elapsed = time.perf_counter() - self._t0
                pct = 100.0 * done / self.total if self.total else 100.0
                values = "".join(f" {k}={v}" for k, v in shown.items())
                self._line(f"{self.label}: {done}/{self.total} {self.unit} ({pct:.0f}%) {elapsed:.0f} s{values}")

    def close(self) -> None:
        self._phase = ""
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def _isatty(stream: TextIO) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # closed or not a file
        return False
