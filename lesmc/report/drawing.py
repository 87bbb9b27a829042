"""The report's figures drawn by two processes: this one and a copy of it made by fork.

Drawing the figures is most of a report's time (matplotlib's text layout, Agg's
rasterising, PNG encoding), on one core: the figures are independent, but
matplotlib holds the GIL. When this process may run on two cores or more, it forks
once the figures to draw are known: the copy draws every second one and writes
their PNG bytes to an unnamed temporary file, this process draws the others and
then reads the copy's. The copy shares this process's memory until it writes to
it (fork's copy on write): it adds the pages its own drawing touches, not another
interpreter with matplotlib and the results loaded (docs/performance.md).

A figure is the same bytes whichever process draws it (tests/test_report_drawing.py).
The copy ignores SIGINT (a terminal sends it to the whole job; this process decides),
prints nothing and leaves with ``os._exit``, so that none of this process's cleanup
runs twice. If this process is interrupted or fails while the copy draws, the copy
is killed and waited for; if the copy fails, this process draws its figures itself.
Forking is only done from the main thread of a Linux process (a Dask worker's
tasks run on other threads), and ``LESMC_DRAW_PROCESSES=1`` turns it off.

Each process frees a figure's memory before it draws the next (:func:`draw_each`):
that keeps a default ``lesmc verify``, which holds torch, and its copy within the
600 MB it is held to (docs/performance.md).
"""

from __future__ import annotations

import contextlib
import gc
import os
import signal
import struct
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import Any, BinaryIO

Job = tuple[Callable[..., bytes], tuple[Any, ...]]

#: Each PNG the copy writes is preceded by its job's index and its length.
_HEADER = struct.Struct("<II")


def draw_all(jobs: Sequence[Job]) -> list[bytes]:
    """``draw(*args)`` of every job, in order; every second one by a forked copy when this
    process may use two cores (:func:`may_fork`)."""
    if len(jobs) < 2 or not may_fork():
        return draw_each(jobs)
    from lesmc.report.figures import pyplot

    pyplot()  # imported before the fork: the copy shares matplotlib's modules and fonts
    ours, theirs = list(jobs[0::2]), list(jobs[1::2])
    with tempfile.TemporaryFile() as out:
        try:
            pid = _fork(theirs, out)
        except OSError:  # no process to be had (EAGAIN, ENOMEM): one after the other
            return draw_each(jobs)
        try:
            mine = draw_each(ours)
            drawn = _collect(pid, out, len(theirs))
        except BaseException:
            _kill(pid)
            raise
    if drawn is None:  # the copy failed: its figures are drawn here
        drawn = draw_each(theirs)
    return [mine[i // 2] if i % 2 == 0 else drawn[i // 2] for i in range(len(jobs))]


def draw_each(jobs: Sequence[Job]) -> list[bytes]:
    """``draw(*args)`` of every job, one after the other (:func:`_drawn`)."""
    return list(_drawn(jobs))


def _drawn(jobs: Sequence[Job]) -> Iterator[bytes]:
    """Each job's PNG as it is drawn, each figure's memory freed before the next: a closed
    figure is a web of reference cycles (its renderer's buffers, its images) that waits
    for the collector's next full pass, so 16 figures drawn in turn kept about 100 MB
    more than one did (docs/performance.md). The objects that exist before are frozen
    meanwhile, so each collection looks only at the figure's own (and in the forked
    copy, leaves this process's pages alone)."""
    from lesmc.common.memory import release

    gc.freeze()
    try:
        for draw, args in jobs:
            png = draw(*args)
            gc.collect()
            release()
            yield png
    finally:
        gc.unfreeze()


def may_fork() -> bool:
    """Whether a second drawing process may help and is safe: Linux, the main thread, two
    cores or more in this process's affinity, and not ``LESMC_DRAW_PROCESSES=1``."""
    if os.environ.get("LESMC_DRAW_PROCESSES", "").strip() == "1":
        return False
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return False
    if threading.current_thread() is not threading.main_thread():
        return False
    return len(os.sched_getaffinity(0)) >= 2


def _fork(jobs: list[Job], out: BinaryIO) -> int:
    """Start the copy that draws ``jobs`` into ``out``; its process id."""
    gc.freeze()  # the copy's collector then leaves this process's objects (and pages) alone
    try:
        pid = os.fork()
    except BaseException:
        gc.unfreeze()
        raise
    if pid == 0:  # the copy: never returns
        _draw_and_leave(jobs, out.fileno())
    gc.unfreeze()
    return pid


def _draw_and_leave(jobs: list[Job], fd: int) -> None:
    """In the copy: draw, write, leave (0 when all were written, 1 on any failure)."""
    status = 1
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        for name in ("SIGTERM", "SIGHUP"):
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_DFL)
        warnings.simplefilter("ignore")
        for i, png in enumerate(_drawn(jobs)):
            _write_all(fd, _HEADER.pack(i, len(png)) + png)
        status = 0
    except BaseException:  # the parent draws what the copy could not
        status = 1
    finally:
        os._exit(status)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _collect(pid: int, out: BinaryIO, n: int) -> list[bytes] | None:
    """Wait for the copy; its ``n`` PNGs in order, or None if it failed."""
    _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        return None
    out.seek(0)
    data = out.read()
    pngs: list[bytes | None] = [None] * n
    at = 0
    while at + _HEADER.size <= len(data):
        i, size = _HEADER.unpack_from(data, at)
        at += _HEADER.size
        if i >= n or at + size > len(data):
            return None
        pngs[i] = data[at : at + size]
        at += size
    if at != len(data) or any(p is None for p in pngs):
        return None
    return [p for p in pngs if p is not None]


def _kill(pid: int) -> None:
    """End the copy now and reap it."""
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)
    with contextlib.suppress(ChildProcessError):
        os.waitpid(pid, 0)
