"""glibc's heap kept through certification (lesmc/perception/heap.py)."""

from __future__ import annotations

import ctypes
import resource

import pytest

from lesmc.perception import heap

glibc = pytest.mark.skipif(heap._libc() is None, reason="mallopt is glibc's")


def _faults_of_reallocating(times: int, size: int) -> int:
    """Minor page faults of ``malloc``-ing, writing and freeing ``size`` bytes ``times`` times
    (glibc's own calls: numpy asks for huge pages, which hides the count)."""
    lib = ctypes.CDLL(None)
    lib.malloc.restype, lib.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    lib.free.argtypes = [ctypes.c_void_p]
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(times):
        block = lib.malloc(size)
        assert block
        ctypes.memset(block, 1, size)  # every page touched
        lib.free(block)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


@glibc
def test_a_kept_heap_reuses_freed_blocks_and_is_returned_afterwards() -> None:
    """64 MiB allocated and freed ten times: glibc maps it afresh each time (above its largest
    mmap threshold), so every page faults each time; in the block the freed memory is reused
    and only the first allocation's pages fault."""
    size = 64 << 20
    outside = _faults_of_reallocating(10, size)
    with heap.kept_heap():
        inside = _faults_of_reallocating(10, size)
    after = _faults_of_reallocating(10, size)
    assert inside < outside / 3
    assert after > inside * 3  # the thresholds are back: freed memory returns to the system


@glibc
def test_nested_blocks_keep_the_heap_until_the_outermost_ends() -> None:
    size = 64 << 20
    with heap.kept_heap():
        with heap.kept_heap():
            pass
        inner_done = _faults_of_reallocating(10, size)
        assert heap._open == 1
    assert heap._open == 0
    assert inner_done < _faults_of_reallocating(10, size) / 3


def test_restored_values_follow_the_environment(monkeypatch) -> None:
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    assert heap.restored(heap.M_TRIM_THRESHOLD) == 65536
    assert heap.restored(heap.M_MMAP_THRESHOLD) == heap.AFTER[heap.M_MMAP_THRESHOLD]
    monkeypatch.setenv("MALLOC_TOP_PAD_", "not a number")
    assert heap.restored(heap.M_TOP_PAD) == heap.AFTER[heap.M_TOP_PAD]
