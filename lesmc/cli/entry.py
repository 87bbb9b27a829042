"""The console entry point: signal handlers first, then the command line.

``lesmc`` (pyproject.toml) and ``python -m lesmc`` start here. This module
imports nothing at module level but ``sys`` (already loaded by the
interpreter): SIGINT or SIGTERM while the signal handlers, click, numpy and the
rest are being imported also exits 130/143 with one line and no traceback;
:func:`lesmc.cli.main.main` handles everything after that. Only a signal during
the interpreter's own start-up (before this module runs) is Python's to report.
"""

from __future__ import annotations

import sys

EXIT_INTERRUPTED = 130


def main(argv: list[str] | None = None) -> None:
    """Install the handlers (lesmc/cli/signals.py), import the command line and run it."""
    import atexit
    import gc

    # Registered first, so run last: the interpreter's final collections then skip every
    # object still alive (torch's and matplotlib's modules: 0.45 s of a verify's exit);
    # the system frees them with the process. atexit handlers still run before it.
    atexit.unregister(gc.freeze)  # main() run again in one process (tests) registers once
    atexit.register(gc.freeze)
    try:
        _run(argv)
    except SystemExit as exc:
        _leave(exc.code)
        raise
    _leave(0)


def _leave(code: int | str | None) -> None:
    """With a ``--timeout`` (lesmc.cli.signals.exit_fast): exit now, skipping the
    interpreter's teardown; the outputs are written and every ``finally`` has run."""
    signals = sys.modules.get("lesmc.cli.signals")
    if signals is None or not signals.exit_fast_requested() or not isinstance(code, int | None):
        return
    import contextlib
    import os

    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed stdout: status decided
            stream.flush()
    os._exit(code or 0)


def _run(argv: list[str] | None) -> None:
    try:
        from lesmc.cli import signals
        from lesmc.common.memory import one_arena

        one_arena()  # threads' freed memory can go back to the system (common/memory.py)
        try:
            with signals.handlers():
                from lesmc.cli.main import main as run

                run(argv)
        except signals.Terminated as exc:  # before lesmc.cli.main took over
            sys.stderr.write("terminated\n")
            sys.exit(exc.exit_status)
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        sys.exit(EXIT_INTERRUPTED)
    finally:
        _decided()


def _decided() -> None:
    """The exit status is decided and the outputs are written: a signal during the
    interpreter's shutdown (torch's finalisers take a while) is ignored rather than
    printed as a traceback from a finaliser."""
    import signal

    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
