"""One progress bar style for every long stage (on stderr, only on a terminal)."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


class Bar:
    """A handle to advance one bar."""

    def __init__(self, progress: Progress, task: Any) -> None:
        self._progress = progress
        self._task = task

    def advance(self, n: int = 1) -> None:
        self._progress.advance(self._task, n)

    def update(self, **fields: Any) -> None:
        self._progress.update(self._task, **fields)


@contextmanager
def progress_bar(label: str, total: int | None) -> Iterator[Bar]:
    """A transient bar labelled ``label`` counting to ``total`` items."""
    err = Console(stderr=True)
    with Progress(
        TextColumn("{task.description:<12}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    ) as progress:
        yield Bar(progress, progress.add_task(label, total=total))


class Counter:
    """Counts done items: a bar with the ETA on a terminal, else a log line every few seconds."""

    def __init__(
        self, label: str, total: int, progress: Progress | None, task: Any, every: float
    ) -> None:
        self.label = label
        self.total = total
        self.done = 0
        self._progress = progress
        self._task = task
        self._every = every
        self._start = time.monotonic()
        self._last = self._start

    def advance(self, n: int = 1) -> None:
        self.done += n
        if self._progress is not None:
            self._progress.advance(self._task, n)
            return
        now = time.monotonic()
        if now - self._last >= self._every or self.done >= self.total:
            self._last = now
            sys.stderr.write(self.line(now) + "\n")
            sys.stderr.flush()

    def line(self, now: float) -> str:
        """``label: done/total (pct), elapsed, ETA`` for logs."""
        spent = now - self._start
        pct = 100.0 * self.done / self.total if self.total else 100.0
        left = _clock(spent / self.done * (self.total - self.done)) if self.done else "?"
        return (
            f"{self.label}: {self.done}/{self.total} ({pct:.1f}%), "
            f"{_clock(spent)} elapsed, ETA {left}"
        )


def _clock(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


@contextmanager
def progress_counter(label: str, total: int, every: float = 5.0) -> Iterator[Counter]:
    """A bar with done/total and the ETA on a terminal; otherwise one log line on stderr
    every ``every`` seconds (and at the end), for long unattended runs."""
    err = Console(stderr=True)
    if not err.is_terminal:
        yield Counter(label, total, None, None, every)
        return
    with Progress(
        TextColumn("{task.description:<12}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=err,
        transient=False,
    ) as progress:
        yield Counter(label, total, progress, progress.add_task(label, total=total), every)
