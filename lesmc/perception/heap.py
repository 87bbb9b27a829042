"""glibc's heap kept through certification's large temporaries (issue 31).

A bound propagation allocates and frees tensors of up to tens of MiB many times
a second. glibc serves an allocation above its mmap threshold (at most 32 MiB
however it adapts) with a fresh mapping, and trims the heap's free top beyond
its trim threshold: either way the pages go back to the kernel on ``free`` and
are faulted in, zeroed, on the next allocation. On ``bench_certify``'s windows
that was 1.5-1.8 million minor page faults for 96 windows, and 12-15% of the
time (docs/performance.md, "Issue 31, sixteenth round").

:func:`kept_heap` raises both thresholds for the block, so freed tensors stay in
the heap and are reused; afterwards it sets them to what glibc's adaptive rule
reaches once a tensor of 32 MiB or more has been freed (any certification frees
such tensors), or to the values given in the environment, and returns the free
memory to the system (``malloc_trim``). One limit: once ``mallopt`` has been
called, glibc no longer adapts the thresholds itself for the rest of the process.
Only glibc has these knobs; elsewhere (musl, macOS) the block changes nothing.
Python's ``ctypes`` is the whole interface; no library wraps ``mallopt``.
"""

from __future__ import annotations

import ctypes
import functools
import os
import platform
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

#: mallopt parameters (glibc's malloc.h).
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
#: Within the block: nothing below this is mapped on its own or trimmed away.
KEPT_BYTES = 1 << 30
#: ... where glibc accepts it: older versions refuse an mmap threshold above this.
KEPT_FALLBACK = 32 << 20
#: ... and the heap grows by at least this much at a time.
KEPT_PAD = 1 << 26
#: glibc's values after the adaptive threshold has risen to its cap, and its default top
#: pad (mallopt(3)).
AFTER = {M_MMAP_THRESHOLD: 32 << 20, M_TRIM_THRESHOLD: 64 << 20, M_TOP_PAD: 128 << 10}
#: The same parameters as environment variables, and as GLIBC_TUNABLES names: a value set
#: there (Dask's nannies set MALLOC_TRIM_THRESHOLD_) is the one put back.
ENV = {
    M_MMAP_THRESHOLD: ("MALLOC_MMAP_THRESHOLD_", "glibc.malloc.mmap_threshold"),
    M_TRIM_THRESHOLD: ("MALLOC_TRIM_THRESHOLD_", "glibc.malloc.trim_threshold"),
    M_TOP_PAD: ("MALLOC_TOP_PAD_", "glibc.malloc.top_pad"),
}
INT_MAX = 2**31 - 1  #: mallopt takes a C int

_lock = threading.Lock()
_open = 0
#: the mmap threshold the outermost open block set (0: none open)
kept_threshold = 0


@functools.cache
def _libc() -> ctypes.CDLL | None:
    """The running glibc, or None where there is no ``mallopt`` to call."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    try:
        lib = ctypes.CDLL(None)
    except OSError:
        return None
    if not (hasattr(lib, "mallopt") and hasattr(lib, "malloc_trim")):
        return None
    lib.mallopt.argtypes, lib.mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    lib.malloc_trim.argtypes, lib.malloc_trim.restype = [ctypes.c_size_t], ctypes.c_int
    return lib


def restored(param: int, environ: Mapping[str, str] | None = None) -> int:
    """The value ``param`` gets back after the block: the environment's (its variable, else
    its GLIBC_TUNABLES entry), else glibc's; at most a C int."""
    env = os.environ if environ is None else environ
    variable, tunable = ENV[param]
    raw = env.get(variable, "")
    if not raw.isdigit():
        entries = dict(e.partition("=")[::2] for e in env.get("GLIBC_TUNABLES", "").split(":"))
        raw = entries.get(tunable, "")
    return min(int(raw), INT_MAX) if raw.isdigit() else AFTER[param]


#: The values to put back, read once: what the process started with.
_AFTER_BLOCK = {param: restored(param) for param in ENV}


@contextmanager
def kept_heap() -> Iterator[None]:
    """Freed memory stays in the heap for the block (nested blocks, from any thread: the
    outermost counts); afterwards the thresholds are put back and free memory returned."""
    global _open, kept_threshold
    lib = _libc()
    if lib is None:
        yield
        return
    with _lock:
        if _open == 0:
            kept_threshold = KEPT_BYTES
            if not lib.mallopt(M_MMAP_THRESHOLD, KEPT_BYTES):
                kept_threshold = (
                    KEPT_FALLBACK if lib.mallopt(M_MMAP_THRESHOLD, KEPT_FALLBACK) else 0
                )
            lib.mallopt(M_TRIM_THRESHOLD, KEPT_BYTES)
            lib.mallopt(M_TOP_PAD, KEPT_PAD)
        _open += 1
    try:
        yield
    finally:
        with _lock:
            _open -= 1
            if _open == 0:
                for param, value in _AFTER_BLOCK.items():
                    lib.mallopt(param, value)
                lib.malloc_trim(0)
                kept_threshold = 0
