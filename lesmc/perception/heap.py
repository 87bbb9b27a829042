"""glibc's heap kept through certification's large temporaries (issue 31).

A bound propagation allocates and frees tensors of up to tens of MiB many times
a second. glibc serves an allocation above its mmap threshold (at most 32 MiB
however it adapts) with a fresh mapping, and trims the heap's free top beyond
its trim threshold: either way the pages go back to the kernel on ``free`` and
are faulted in, zeroed, on the next allocation. On ``bench_certify``'s windows
that was 1.5-1.8 million minor page faults for 96 windows, and 12-15% of the
time (docs/performance.md, "Issue 31, sixteenth round").

:func:`kept_heap` raises both thresholds for the block, so freed tensors stay in
the heap and are reused, then puts them back and returns the free memory to the
system (``malloc_trim``): the process is as lean after the block as before it.
Only glibc has these knobs; elsewhere (musl, macOS) the block changes nothing.
Python's ``ctypes`` is the whole interface; no library wraps ``mallopt``.
"""

from __future__ import annotations

import ctypes
import os
import platform
import threading
from collections.abc import Iterator
from contextlib import contextmanager

#: mallopt parameters (glibc's malloc.h).
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
#: Within the block: nothing below this is mapped on its own or trimmed away.
KEPT_BYTES = 1 << 30
#: ... and the heap grows by at least this much at a time.
KEPT_PAD = 1 << 26
#: glibc's values after the adaptive threshold has risen to its cap (a process that
#: has freed a tensor of 32 MiB or more), and its default top pad (mallopt(3)).
AFTER = {M_MMAP_THRESHOLD: 32 << 20, M_TRIM_THRESHOLD: 64 << 20, M_TOP_PAD: 128 << 10}
#: glibc's environment variables for the same parameters: a value set there (Dask's
#: nannies set MALLOC_TRIM_THRESHOLD_) is the one put back.
ENV = {
    M_MMAP_THRESHOLD: "MALLOC_MMAP_THRESHOLD_",
    M_TRIM_THRESHOLD: "MALLOC_TRIM_THRESHOLD_",
    M_TOP_PAD: "MALLOC_TOP_PAD_",
}

_lock = threading.Lock()
_open = 0


def _libc() -> ctypes.CDLL | None:
    """The running glibc, or None where there is no ``mallopt`` to call."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    try:
        lib = ctypes.CDLL(None)
    except OSError:
        return None
    return lib if hasattr(lib, "mallopt") and hasattr(lib, "malloc_trim") else None


def restored(param: int) -> int:
    """The value ``param`` gets back after the block: the environment's, else glibc's."""
    raw = os.environ.get(ENV[param], "")
    return int(raw) if raw.isdigit() else AFTER[param]


@contextmanager
def kept_heap() -> Iterator[None]:
    """Freed memory stays in the heap for the block (nested blocks: the outermost
    counts); afterwards the thresholds are put back and free memory returned."""
    global _open
    lib = _libc()
    if lib is None:
        yield
        return
    with _lock:
        if _open == 0:
            lib.mallopt(M_MMAP_THRESHOLD, KEPT_BYTES)
            lib.mallopt(M_TRIM_THRESHOLD, KEPT_BYTES)
            lib.mallopt(M_TOP_PAD, KEPT_PAD)
        _open += 1
    try:
        yield
    finally:
        with _lock:
            _open -= 1
            if _open == 0:
                for param in (M_MMAP_THRESHOLD, M_TRIM_THRESHOLD, M_TOP_PAD):
                    lib.mallopt(param, restored(param))
                lib.malloc_trim(0)
