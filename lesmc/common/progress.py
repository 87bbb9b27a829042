"""Progress of long work, on stderr: rich bars in a terminal, log lines elsewhere.

In a terminal a stage shows a spinner and a counted stage a bar (transient:
they vanish when done). When stderr is not a terminal (CI logs, ``| tee``),
every stage start is a line ``lesmc VERB: STAGE`` and, while work goes on, a
line at least every :data:`HEARTBEAT` seconds says what is running and how
far it got, so that a log never falls silent for longer (docs/cli.md, "Progress").
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
)

#: Longest silence, in seconds, of a log when stderr is not a terminal.
HEARTBEAT = 10.0
#: Seconds between the lines of a counted stage in a log.
LOG_EVERY = 5.0


class Bar:
    """A counted stage: ``advance`` items done, ``update(total=, completed=)``."""

    def __init__(self, reporter: Reporter, label: str, total: int | None) -> None:
        self._reporter = reporter
        self.label = label
        self.total = total
        self.done = 0
        self._task: Any = None
        self._last = time.monotonic()

    def advance(self, n: int = 1) -> None:
        self.update(completed=self.done + n)

    def update(
        self, total: int | None = None, completed: int | None = None, description: str = ""
    ) -> None:
        if description:
            self.label = description
        if total is not None:
            self.total = total
        if completed is not None:
            self.done = completed
        rep = self._reporter
        if rep.progress is not None and self._task is not None:
            rep.progress.update(
                self._task, total=self.total, completed=self.done, description=self.label
            )
            return
        now = time.monotonic()
        finished = self.total is not None and self.done >= self.total
        if now - self._last >= LOG_EVERY or finished:
            self._last = now
            rep.log(self.text())

    def text(self) -> str:
        """``label: done/total`` (or ``done`` when the total is not known yet)."""
        of = "" if self.total is None else f"/{self.total}"
        return f"{self.label}: {self.done}{of}"


class Reporter:
    """The progress of one command (``verb``): stages and counted stages."""

    def __init__(self, verb: str, console: Console | None = None, live: bool | None = None) -> None:
        self.verb = verb
        self.console = console or Console(stderr=True)
        self.live = self.console.is_terminal if live is None else live
        self.progress: Progress | None = None
        self._stage = ""
        self._bar: Bar | None = None
        self._started = time.monotonic()
        self._last_line = self._started
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._status_task: Any = None
        self._thread: threading.Thread | None = None

    def __enter__(self) -> Reporter:
        if self.live:
            self.progress = Progress(
                SpinnerColumn(),
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=self.console,
                transient=True,
            )
            self.progress.start()
        else:
            self._thread = threading.Thread(target=self._heartbeat, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self.progress is not None:
            self.progress.stop()
        if self._thread is not None:
            self._thread.join(timeout=1.0)

    def log(self, text: str) -> None:
        """One line on stderr (a log only: in a terminal the bars say it)."""
        if self.live:
            return
        with self._lock:
            self._last_line = time.monotonic()
            sys.stderr.write(f"lesmc {self.verb}: {text}\n")
            sys.stderr.flush()

    def stage(self, text: str) -> None:
        """Work called ``text`` starts (a spinner, or a log line)."""
        self._stage = text
        self._bar = None
        if self.progress is not None:
            if self._status_task is None:
                self._status_task = self.progress.add_task(text, total=None)
            else:
                self.progress.update(self._status_task, description=text, total=None, completed=0)
            return
        self.log(text)

    @contextmanager
    def bar(self, label: str, total: int | None) -> Iterator[Bar]:
        """A counted stage ``label`` of ``total`` items (None: not known yet)."""
        bar = Bar(self, label, total)
        self._stage, self._bar = label, bar
        if self.progress is not None:
            bar._task = self.progress.add_task(label, total=total)
        else:
            self.log(f"{label}: started" + ("" if total is None else f" ({total} to do)"))
        try:
            yield bar
        finally:
            if self.progress is not None:
                self.progress.remove_task(bar._task)
            self._bar = None

    def _heartbeat(self) -> None:
        """In a log: a line whenever :data:`HEARTBEAT` seconds passed without one."""
        while not self._stop.wait(1.0):
            now = time.monotonic()
            if now - self._last_line < HEARTBEAT:
                continue
            what = self._bar.text() if self._bar is not None else self._stage or "working"
            self.log(f"{what} (still running, {now - self._started:.0f} s in all)")


@contextmanager
def progress_bar(verb: str, label: str, total: int | None) -> Iterator[Bar]:
    """A counted stage ``label`` of command ``verb`` (a reporter for one bar)."""
    with Reporter(verb) as rep, rep.bar(label, total) as bar:
        yield bar


class _Deferred(Bar):
    """A counted stage that starts (its reporter, its ``started`` line) at its first
    :meth:`update`: what a command checks before, its inputs, fails without it."""

    def __init__(self, stack: ExitStack, verb: str, label: str) -> None:
        self._stack, self._verb = stack, verb
        self._bar: Bar | None = None
        self.label, self.total, self.done = label, None, 0

    def update(
        self, total: int | None = None, completed: int | None = None, description: str = ""
    ) -> None:
        if self._bar is None:
            self._bar = self._stack.enter_context(progress_bar(self._verb, self.label, total))
        self._bar.update(total, completed, description)
        self.label, self.total, self.done = self._bar.label, self._bar.total, self._bar.done


@contextmanager
def deferred_bar(verb: str, label: str) -> Iterator[Bar]:
    """A counted stage ``label`` of command ``verb`` whose reporter starts when the work
    first counts (sets its total or advances): the input errors found before that come
    alone, with no ``label: started`` line before them (``lesmc replay``, ``lesmc
    perceive --detector FILE.toml``)."""
    with ExitStack() as stack:
        yield _Deferred(stack, verb, label)
