"""Writing a report directory safely: staged, moved in at the end, one run at a time.

The files are first written to a hidden directory next to their destination,
then moved in, each with an atomic rename: a reader never sees half a report,
and an interrupted run leaves the previous files as they were. Nothing the
run did not create is deleted: a figure of an earlier run that this run does
not draw stays where it is. Two runs writing into one directory do not mix:
the second fails at once with a clear message (an exclusive lock on a file
beside the directory).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from lesmc.common.errors import UsageError


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """Hold an exclusive lock for ``out`` (fail at once if another run holds it)."""
    import fcntl

    lock = out.parent / f".{out.name}.lesmc-lock"
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise UsageError(
                f"{out}: another lesmc run is writing this directory; wait for it or give "
                "another --out"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:  # else the file was removed by the run that held it: lock the new one
            break
        os.close(fd)
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(lock)
        os.close(fd)


@contextlib.contextmanager
def staged(out_dir: str | Path) -> Iterator[Path]:
    """A fresh hidden directory to write into; its files replace those of ``out_dir`` at the end.

    Subdirectories are merged file by file. On an error nothing is moved and the
    staging directory is removed (it is this run's own).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out} exists and is not a directory")
    out.parent.mkdir(parents=True, exist_ok=True)
    with _locked(out):
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
        try:
            yield tmp
            os.chmod(tmp, 0o777 & ~_umask())
            with _signals_held():
                if not out.exists():
                    tmp.rename(out)  # the whole directory at once
                    return
                _merge(tmp, out)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


#: Files moved in last, in this order: a results file never stands beside an older scene.
LAST = ("report.html", "results.json")


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM wait while the staged files are moved in (a few renames): an
    interrupt then finds ``out`` all old or all new, never half of each.

    The signals are recorded by a Python handler and raised again once the renames are
    done. Not a thread signal mask: the kernel hands a process's signal to any thread
    that does not block it (the progress logger's, torch's), and CPython then runs the
    handler in the main thread at once, mask or not.
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return
    got: list[int] = []

    def hold(signum: int, _frame: object) -> None:
        got.append(signum)

    old = {s: signal.signal(s, hold) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
        if got:
            signal.raise_signal(got[0])  # handled now, by the handler put back


def _merge(src: Path, dst: Path) -> None:
    for item in sorted(
        src.iterdir(),
        key=lambda p: (p.name in LAST, LAST.index(p.name) if p.name in LAST else 0, p.name),
    ):
        target = dst / item.name
        if item.is_dir():
            if target.exists() and not target.is_dir():
                raise UsageError(f"{target} exists and is not a directory")
            target.mkdir(exist_ok=True)
            _merge(item, target)
        else:
            if target.is_dir():
                raise UsageError(f"{target} is a directory; the report writes a file there")
            item.replace(target)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
