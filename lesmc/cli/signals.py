"""Stopping cleanly: SIGINT, SIGTERM, SIGHUP and a closed stdout.

Python turns SIGINT into :class:`KeyboardInterrupt`; here SIGTERM and SIGHUP
become :class:`Terminated`, another :class:`BaseException` that no
``except Exception`` catches. Both unwind the stack, so every ``finally`` and
context manager runs: temporary files and staging directories (lesmc/common/files.py)
are removed, nothing half-written is renamed into place. The entry point then
exits with 128 + the signal's number: 130 (SIGINT), 143 (SIGTERM), 129 (SIGHUP).

A closed stdout (``lesmc check ... | head``) is :data:`EXIT_BROKEN_PIPE`
(141, what a shell reports for a process killed by SIGPIPE), never 1 ("violated").

Light on purpose (standard library only): :func:`lesmc.cli.entry.main` installs
the handlers before the command line's modules are imported.
"""

from __future__ import annotations

import json
import os
import select
import signal
import sys
import threading
import time
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


#: Seconds past ``--timeout`` after which the alarm stops the command whatever it does
#: (a last resort: the engines look at the clock and end with a result before it).
HARD_GRACE = 0.8

#: Seconds past ``--timeout`` at which :func:`native_deadline`'s watchdog stops the first
#: imports of ``verify`` (torch, cv2): no result can be lost there, so it need not wait
#: for :data:`HARD_GRACE`.
IMPORT_GRACE = 0.3


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


#: What a command stopped by the alarm or the watchdog prints (then exit 3).
DEADLINE_MESSAGE = (
    "error: --timeout ran out in work that could not stop sooner; nothing was written\n"
)

#: :data:`DEADLINE_MESSAGE` as the ``--json`` error document (lesmc/schemas/error.json).
DEADLINE_DOCUMENT = (
    json.dumps(
        {
            "format": "lesmc-error",
            "version": 1,
            "exit": 3,
            "error": {
                "message": DEADLINE_MESSAGE.removeprefix("error: ").strip(),
                "file": None,
                "line": None,
                "column": None,
                "item": None,
            },
        },
        indent=1,
    )
    + "\n"
)

#: Seconds added to :data:`IMPORT_GRACE` for :func:`native_deadline`'s watchdog, so that
#: a deadline the budget's own check can catch right after the import is caught there.
WATCHDOG_LAG = 0.05


@contextmanager
def native_deadline(hard: float | None) -> Iterator[None]:
    """Stop the command (exit 3) at ``hard`` (``time.monotonic()``) even inside one long C
    call, where the alarm of :func:`arm_deadline` cannot run its Python handler: the first
    import of torch loads libtorch in one call that holds the interpreter for 0.5-1 s.

    Only for work that writes nothing (imports): a watchdog process waits for the
    block to end; at ``hard`` it prints :data:`DEADLINE_MESSAGE` and sends SIGQUIT,
    whose handler in this process is, for the block's duration, libc's ``_exit``
    itself (no Python: it runs at once, even in C), and SIGQUIT is signal 3, so the
    exit status is 3 ("unknown"). Nothing is unwound: hence no temporary file may
    exist while the block runs. The alarm (SIGALRM) is held back until the block
    ends. ``hard`` None, another platform or thread: no watchdog.
    """
    if hard is None or not _watchable():
        yield
        return
    if time.monotonic() >= hard:
        raise DeadlinePassed
    import ctypes

    libc = ctypes.CDLL(None)
    libc.signal.restype = ctypes.c_void_p
    libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
    previous = signal.getsignal(signal.SIGQUIT)
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the watchdog (coverage does not follow a fork)
        _watchdog(read_end, write_end, hard)
    os.close(read_end)
    libc.signal(signal.SIGQUIT, ctypes.cast(libc._exit, ctypes.c_void_p).value)
    # the alarm waits for the block's end: raised inside an import, DeadlinePassed can
    # leave a library half-initialised (an internal error instead of exit 3)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
    try:
        yield
    finally:
        os.close(write_end)  # the watchdog sees the end of the pipe and exits
        os.waitpid(pid, 0)  # a SIGQUIT it sent arrives before it is reaped
        signal.signal(signal.SIGQUIT, previous if previous is not None else signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a pending alarm is raised now


def _watchable() -> bool:
    return (
        hasattr(os, "fork")
        and getattr(signal, "SIGQUIT", None) == 3  # the exit status "unknown"
        and _main_thread()
    )


def _watchdog(read_end: int, write_end: int, hard: float) -> None:  # pragma: no cover
    """The forked watchdog: wait for the pipe to close or for ``hard``, then stop the parent."""
    try:
        os.close(write_end)
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):  # the parent handles these
            signal.signal(getattr(signal, name), signal.SIG_IGN)
        ready, _, _ = select.select([read_end], [], [], max(0.0, hard - time.monotonic()))
        if not ready:
            os.write(2, DEADLINE_MESSAGE.encode())
            if "--json" in sys.argv[1:]:  # the error document of lesmc/cli/main.py
                os.write(1, DEADLINE_DOCUMENT.encode())
            os.kill(os.getppid(), signal.SIGQUIT)
    finally:
        os._exit(0)


_exit_fast = False


def exit_fast() -> None:
    """Once the outcome is decided and written, leave without the interpreter's teardown
    (:func:`lesmc.cli.entry.main`): with torch loaded it takes over a second, which a
    ``--timeout`` would otherwise overrun by. Every ``finally`` has run by then."""
    global _exit_fast
    _exit_fast = True


def exit_fast_requested() -> bool:
    return _exit_fast


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


@contextmanager
def polite_stop() -> Iterator[None]:
    """Inside the block, a first SIGINT or SIGTERM asks the searches to stop
    (:func:`lesmc.common.budget.request_stop`): each ends with its bounds, reason
    ``interrupted``, and the command writes what it has before it exits 130/143
    (:func:`exit_if_stopped`). A second signal interrupts at once, as outside the block."""
    from lesmc.common.budget import request_stop, stop_requested

    if not _main_thread():
        yield
        return

    def polite(signum: int, frame: FrameType | None) -> None:
        if stop_requested() is not None:
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            raise Terminated(signum)
        request_stop(signum)
        os.write(2, b"lesmc: stopping: writing what was found so far (again to stop now)\n")

    previous: dict[int, Any] = {}
    for name in ("SIGINT", "SIGTERM"):
        signum = getattr(signal, name)
        old = signal.getsignal(signum)
        if old is signal.SIG_IGN:
            continue
        previous[signum] = old
        signal.signal(signum, polite)
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old if old is not None else signal.SIG_DFL)


def exit_if_stopped() -> None:
    """After the outputs are written: exit 130 (SIGINT) or 128 + N if a signal asked the
    searches to stop (:func:`polite_stop`)."""
    from lesmc.common.budget import stop_requested

    signum = stop_requested()
    if signum is not None:
        sys.stderr.write("interrupted\n" if signum == signal.SIGINT else "terminated\n")
        sys.exit(128 + signum)


@contextmanager
def resumable(kept: Callable[[], str]) -> Iterator[None]:
    """On Ctrl-C or SIGTERM inside the block: one line on stderr with what the run kept
    (``kept()``) and the command that resumes it (this very command line), then the
    signal's exit status (130, 143) and nothing more."""
    try:
        yield
    except (KeyboardInterrupt, Terminated) as exc:
        import shlex

        what = "terminated" if isinstance(exc, Terminated) else "interrupted"
        command = shlex.join(["lesmc", *sys.argv[1:]])
        sys.stderr.write(f"{what}: {kept()}; resume with: {command}\n")
        sys.exit(exc.exit_status if isinstance(exc, Terminated) else 128 + signal.SIGINT)
