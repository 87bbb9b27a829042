"""Stopping cleanly: SIGINT, SIGTERM, SIGHUP and a closed stdout.

Python turns SIGINT into :class:`KeyboardInterrupt`; here SIGTERM and SIGHUP
become :class:`Terminated`, another :class:`BaseException` that no
``except Exception`` catches. Both unwind the stack, so every ``finally`` and
context manager runs: temporary files and staging directories (lesmc/fileio.py)
are removed, nothing half-written is renamed into place. The entry point then
exits with 128 + the signal's number: 130 (SIGINT), 143 (SIGTERM), 129 (SIGHUP).

A closed stdout (``lesmc check ... | head``) is :data:`EXIT_BROKEN_PIPE`
(141, what a shell reports for a process killed by SIGPIPE), never 1 ("violated").

Light on purpose (standard library only): :func:`lesmc.cli.entry.main` installs
the handlers before the command line's modules are imported.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

#: Exit status after a closed stdout: 128 + SIGPIPE.
EXIT_BROKEN_PIPE = 128 + 13

_HANDLED = ("SIGTERM", "SIGHUP")


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwind like Ctrl-C, then exit 128 + ``signum``."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_status(self) -> int:
        return 128 + self.signum


class DeadlinePassed(BaseException):
    """``--timeout`` passed by :data:`HARD_GRACE` seconds in work that checks no clock
    (imports, loading, a long numpy call): the command stops, exit 3, nothing written."""


#: Seconds past ``--timeout`` after which the alarm stops the command whatever it does.
HARD_GRACE = 0.4


def _deadline(_signum: int, _frame: FrameType | None) -> None:
    raise DeadlinePassed


def arm_deadline(seconds: float) -> Callable[[], None]:
    """Raise :class:`DeadlinePassed` in ``seconds`` + :data:`HARD_GRACE` (SIGALRM, main thread
    only); returns the function that disarms it and puts the previous handler back."""
    if not (hasattr(signal, "setitimer") and _main_thread()):  # pragma: no cover - Windows
        return lambda: None
    previous = signal.signal(signal.SIGALRM, _deadline)
    signal.setitimer(signal.ITIMER_REAL, seconds + HARD_GRACE)

    def disarm() -> None:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous if previous is not None else signal.SIG_DFL)

    return disarm


def _terminate(signum: int, _frame: FrameType | None) -> None:
    raise Terminated(signum)


@contextmanager
def handlers() -> Iterator[None]:
    """SIGTERM and SIGHUP raise :class:`Terminated` inside the block (main thread only).

    SIGINT keeps Python's handler (:class:`KeyboardInterrupt`), restored if
    something replaced it; a signal the parent made the process ignore (``nohup``,
    a background job's SIGINT) stays ignored. The previous handlers come back when
    the block ends, so calling the entry point from a test leaves the test runner as it was.
    """
    if not _main_thread():
        yield
        return
    previous: dict[int, Any] = {}
    wanted: list[tuple[int, Callable[..., Any]]] = [(signal.SIGINT, signal.default_int_handler)]
    wanted += [(getattr(signal, n), _terminate) for n in _HANDLED if hasattr(signal, n)]
    try:
        for signum, handler in wanted:
            old = signal.getsignal(signum)
            if old is signal.SIG_IGN or (signum == signal.SIGINT and old is not signal.SIG_DFL):
                continue  # ignored on purpose, or a handler of the caller's (pytest's)
            previous[signum] = old
            signal.signal(signum, handler)
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old if old is not None else signal.SIG_DFL)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def stdout_closed() -> int:
    """After a write to a closed stdout: silence stdout for good, return 141.

    Python would otherwise report the broken pipe again when it flushes stdout at exit.
    """
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # pragma: no cover - stdout replaced or gone
        pass
    return EXIT_BROKEN_PIPE
