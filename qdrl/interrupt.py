"""Ctrl-C during a run: the first stops it at the next safe point, the second aborts at once.

Python runs signal handlers only in the main thread, between bytecodes, and
XLA compiles and computes in C++ for seconds to minutes without returning. So
long waits go to a worker thread (`Worker`) while the main thread waits on an
event, which a signal interrupts: a handler then runs within milliseconds.
"""

from __future__ import annotations

import queue
import signal
import sys
import threading
import types
from collections.abc import Callable
from typing import Any, TypeVar

import jax

__all__ = ["Interrupts", "Worker"]

T = TypeVar("T")


class Interrupts:
    """A SIGINT handler for the `with` block (in the main thread; elsewhere nothing changes).

    While `abort_at_once` is True, Ctrl-C raises KeyboardInterrupt at once (use it
    while nothing would be lost, e.g. while compiling). Otherwise the first Ctrl-C
    sets `requested` and prints `message`; the second raises KeyboardInterrupt.
    """

    def __init__(self, message: str) -> None:
        self.message = message
        self.abort_at_once = True
        self.requested = False
        self._previous: Any = None
        self._installed = False

    def _handle(self, signum: int, frame: types.FrameType | None) -> None:
        if self.abort_at_once or self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print(f"\n{self.message}", file=sys.stderr, flush=True)

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(self, *exc: object) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, self._previous)
            self._installed = False


class Worker:
    """A daemon thread that runs calls for the main thread, which waits interruptibly.

    A call interrupted by KeyboardInterrupt keeps running in the worker; its
    result is dropped. Handing a call over is cheap next to the XLA calls it runs.
    """

    def __init__(self) -> None:
        self._calls: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None

    def _loop(self) -> None:
        while (item := self._calls.get()) is not None:
            fn, box, done = item
            try:
                box["value"] = fn()
            except BaseException as e:  # handed to the caller
                box["error"] = e
            finally:
                done.set()

    def call(self, fn: Callable[[], T], tick: Callable[[], None] | None = None, period: float = 1.0) -> T:
        """`fn()` run in the worker; `tick()` is called every `period` seconds while it runs."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, name="qdrl-worker", daemon=True)
            self._thread.start()
        box: dict[str, Any] = {}
        done = threading.Event()
        self._calls.put((fn, box, done))
        while not done.wait(period if tick is not None else None):
            if tick is not None:
                tick()
        if "error" in box:
            raise box["error"]
        return box["value"]  # type: ignore[no-any-return]

    def wait_ready(self, tree: Any) -> None:
        """Blocks until every array of `tree` is computed (jax dispatches asynchronously)."""
        leaves = [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array)]
        if all(x.is_ready() for x in leaves):  # type: ignore[attr-defined]
            return
        self.call(lambda: jax.block_until_ready(leaves))

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if self._thread is not None:
            self._calls.put(None)  # the worker ends after its current call
            if exc_type is None:
                # Its calls are done: wait for it to end, so that no daemon thread is still
                # letting go of XLA objects when the interpreter exits (which aborts the process).
                # After an exception (Ctrl-C) its call may still run: the caller exits at once.
                self._thread.join()
            self._thread = None
