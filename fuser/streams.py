"""The command's standard output when its reader has gone (``bingham-fuser listen | head -5``).

A reader that stops is the end of the printing, not a failure of the command: ``listen`` then stops listening, as at
``--count``, and any other command, whose printing comes after its work, exits 0 (both said "Broken pipe", exit 1).
The descriptor is pointed at the null device, so that the interpreter's last flush does not fail again ("Exception
ignored ... BrokenPipeError"), as Python's documentation on SIGPIPE advises.
"""

from __future__ import annotations

import contextlib
import io
import os
import select
import sys
from typing import TextIO

__all__ = ["let_go", "stdout_gone"]


def let_go(out: TextIO) -> None:
    """Point ``out``'s descriptor at the null device: its reader is gone."""
    with contextlib.suppress(OSError, ValueError, io.UnsupportedOperation):
        os.dup2(os.open(os.devnull, os.O_WRONLY), out.fileno())


def stdout_gone() -> bool:
    """True if standard output is a pipe whose reader has gone (``poll`` reports an error on it; where there is no
    ``poll``, False: a socket's broken pipe, a TCP link's, must still fail the command); it is then let go."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        gone = any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll (Windows), or no descriptor (a test's captured output)
        return False
    if gone:
        let_go(sys.stdout)
    return gone
