"""glibc's heap kept through certification (lesmc/perception/heap.py)."""

from __future__ import annotations

import ctypes
import os
import resource
import subprocess
import sys
from pathlib import Path

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
        if heap.kept_threshold <= size:
            pytest.skip("this glibc refuses an mmap threshold above 32 MiB")
        inside = _faults_of_reallocating(10, size)
    after = _faults_of_reallocating(10, size)
    assert inside < outside / 3
    assert after > inside * 3  # the thresholds are back: freed memory returns to the system
    assert heap.kept_threshold == 0


@glibc
def test_nested_blocks_keep_the_heap_until_the_outermost_ends() -> None:
    size = 64 << 20
    with heap.kept_heap():
        if heap.kept_threshold <= size:
            pytest.skip("this glibc refuses an mmap threshold above 32 MiB")
        with heap.kept_heap():
            pass
        inner_done = _faults_of_reallocating(10, size)
        assert heap._open == 1
    assert heap._open == 0
    assert inner_done < _faults_of_reallocating(10, size) / 3


@glibc
def test_an_error_in_the_block_still_puts_the_heap_back() -> None:
    with pytest.raises(KeyError), heap.kept_heap():
        raise KeyError("x")
    assert heap._open == 0 and heap.kept_threshold == 0


@glibc
def test_values_from_the_environment_are_put_back_whole() -> None:
    """4 GiB in the environment (beyond a C int) is put back as the largest int, not cut to
    32 bits (0: every allocation its own mapping): after the block, freed 40 MiB blocks are
    still reused."""
    code = f"""
import sys
sys.path.insert(0, {str(Path(__file__).parent)!r})
from test_heap import _faults_of_reallocating
from lesmc.perception import heap
with heap.kept_heap():
    pass
print(_faults_of_reallocating(10, 40 << 20))
"""
    env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="4294967296", MALLOC_TRIM_THRESHOLD_="4294967296")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) < 2 * (40 << 20) // 4096  # at most about one block's pages


def test_restored_values_follow_the_environment() -> None:
    env = {"MALLOC_TRIM_THRESHOLD_": "65536", "MALLOC_TOP_PAD_": "not a number"}
    assert heap.restored(heap.M_TRIM_THRESHOLD, env) == 65536
    assert heap.restored(heap.M_MMAP_THRESHOLD, env) == heap.AFTER[heap.M_MMAP_THRESHOLD]
    assert heap.restored(heap.M_TOP_PAD, env) == heap.AFTER[heap.M_TOP_PAD]
    tunables = {
        "GLIBC_TUNABLES": "glibc.malloc.top_pad=4096:glibc.malloc.mmap_threshold=9999999999"
    }
    assert heap.restored(heap.M_TOP_PAD, tunables) == 4096
    assert heap.restored(heap.M_MMAP_THRESHOLD, tunables) == heap.INT_MAX
