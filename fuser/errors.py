"""Expected failures, each with the exit code it deserves and a message that says what to fix.

The command line (``fuser.cli``) prints such an error as one line on stderr
and exits with its ``exit_code``; anything else it reports as an internal
error. Modules raise these where they know what went wrong in the user's
terms (which file, which port, which option).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["EXIT_RUNTIME", "EXIT_USAGE", "FuserError", "NotALogError", "UsageError", "check_log_file", "log_file_problem",
           "require_package"]

EXIT_RUNTIME = 1
"""It started and failed: a link or port that cannot be opened, a log with nothing readable, a write that failed."""
EXIT_USAGE = 2
"""The command as given cannot run: a bad option or value, a bad configuration, a missing or wrong input file,
a missing optional package."""


class FuserError(Exception):
    """An expected failure; ``str()`` is the one line for the user."""

    exit_code = EXIT_RUNTIME


class UsageError(FuserError):
    """The command, its arguments, its configuration or its input files are wrong."""

    exit_code = EXIT_USAGE


class NotALogError(UsageError, ValueError):
    """The file given as a log is not one at all (empty, random bytes, text, another format)."""


def os_reason(exc: BaseException) -> str:
    """Why a file could not be written or read, in the system's words (``No space left on device``), else the
    exception's type and text."""
    return exc.strerror if isinstance(exc, OSError) and exc.strerror else f"{type(exc).__name__}: {exc}"


def log_file_problem(path: str | Path) -> str | None:
    """What keeps ``path``, given as a log to read, from being read as one: a folder, a device or pipe, or nothing
    there; None for a file. Asked before anything opens it: pymavlink would take a missing .tlog for a serial port."""
    log = Path(path)
    if log.is_file():
        return None
    if log.is_dir():
        return "a folder, not a log file"
    return "not a regular file (a device, a pipe or a socket), not a log file" if log.exists() else "no such log file"


def check_log_file(path: str | Path, what: str = "") -> None:
    """:class:`UsageError` naming :func:`log_file_problem`'s problem and ``path`` (``what``: the command that reads
    it, put before the message)."""
    problem = log_file_problem(path)
    if problem is not None:
        raise UsageError(f"{what + ': ' if what else ''}{problem}: {path}")


def require_package(module: str, extra: str, what: str) -> None:
    """:class:`UsageError` naming the extra to install if ``module``, an optional dependency that ``what`` needs, is
    not installed."""
    from importlib.util import find_spec

    if find_spec(module) is None:
        raise UsageError(f"{what} needs the '{module}' package: pip install 'bingham-fuser[{extra}]' (or pip install {module})")
