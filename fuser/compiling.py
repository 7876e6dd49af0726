"""How long numba compiles, and telling the user when a command waits for it.

numba compiles each kernel on its first call (``cache=True``: on disk after that), so the first command after
installing or upgrading spends about 30 s compiling the filter (benchmarks/RESULTS.md) before its first tick
returns. The live commands compile first (:mod:`fuser.warmup`); an offline replay compiles on its first tick, inside
:func:`compile_watch`: its rate leaves those seconds out, and a compile running for longer than
:data:`NOTICE_AFTER_S` is said on stderr (a kernel loaded from the cache takes milliseconds and fires no event).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Callable

from numba.core import event

__all__ = ["COMPILING", "NOTICE_AFTER_S", "CompileWatch", "compile_watch"]

NOTICE_AFTER_S = 2.0
"""A command still compiling after this (s) says so, once (the kernels load from the cache in about 0.3 s)."""

COMPILING = "compiling the filter (once after installing, about 30 s; cached for later runs)..."
"""What a command waiting for the compiler tells the user."""


class CompileWatch(event.Listener):
    """A listener of numba's ``numba:compile`` events: :attr:`seconds` compiling (a compile that nests the compiles of
    its callees counted once), and ``notice`` called once, from a timer thread, when one compile has run for
    :data:`NOTICE_AFTER_S`."""

    def __init__(self, notice: Callable[[], None] | None = None) -> None:
        self.seconds = 0.0
        """Seconds spent compiling while the watch was installed."""
        self._notice = notice
        self._noticed = False
        self._depth = 0
        """Compiles in progress: the outermost and those it started for its callees."""
        self._started = 0.0
        self._timer: threading.Timer | None = None

    def on_start(self, event: event.Event) -> None:  # noqa: ARG002 - numba's Listener interface
        if self._depth == 0:
            self._started = time.perf_counter()
            if self._notice is not None and not self._noticed:
                self._timer = threading.Timer(NOTICE_AFTER_S, self._tell)
                self._timer.daemon = True
                self._timer.start()
        self._depth += 1

    def on_end(self, event: event.Event) -> None:  # noqa: ARG002
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._started
            self.cancel()

    def cancel(self) -> None:
        """Stop a pending notice."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _tell(self) -> None:
        self._noticed = True
        if self._notice is not None:
            self._notice()


@contextmanager
def compile_watch(notice: Callable[[], None] | None = None) -> Iterator[CompileWatch]:
    """A :class:`CompileWatch` listening for the block."""
    watch = CompileWatch(notice)
    try:
        with event.install_listener("numba:compile", watch):
            yield watch
    finally:
        watch.cancel()
