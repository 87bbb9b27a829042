"""Give freed memory back to the system between frames.

Perception and replay allocate and free large arrays for every frame (tensors of
the attack, aligned images). glibc's allocator keeps what was freed inside its
heap, so a process that perceives 24 frames of 2048x2048 grew to 1.3 GB although
it held under 50 MB of arrays at any time (docs/performance.md). ``malloc_trim``
returns the free pages; it costs 25-60 ms a frame on the default video. On a C
library without it (macOS, musl) :func:`release` does nothing.

A thread's allocations go to an arena of its own, whose freed pages ``malloc_trim``
did not return: rendering's two helper threads (lesmc/video/synth.py) kept 65 MB
for the rest of a ``verify``. The command line therefore runs with one arena
(:func:`one_arena`, what ``MALLOC_ARENA_MAX=1`` does); lesmc's and torch's threads
allocate little, and perception ran in the same time with it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from functools import cache
from typing import Any


@cache
def _libc() -> Any:
    name = ctypes.util.find_library("c")
    try:
        lib = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return lib if lib is not None and hasattr(lib, "malloc_trim") else None


#: mallopt's parameter for the most arenas (glibc's malloc.h).
M_ARENA_MAX = -8


def one_arena() -> None:
    """Let every thread created from now on allocate from the main arena (glibc only)."""
    lib = _libc()
    if lib is not None and hasattr(lib, "mallopt"):
        lib.mallopt(M_ARENA_MAX, 1)


def release() -> None:
    """Return the allocator's free memory to the system (glibc's ``malloc_trim(0)``)."""
    lib = _libc()
    if lib is not None:
        lib.malloc_trim(0)
