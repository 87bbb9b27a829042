"""torch's threads fitted to the cores actually free (issue 31: certification on a busy machine).

torch's OpenMP threads spin-wait for each other: with more threads than idle
cores (a campaign's other workers, any CPU-bound process beside lesmc) every
parallel region waits for a thread that is not running, and a certificate
takes 3-10x as long. :func:`free_cores` counts the cores this process may run
on (its affinity) that were mostly idle over a short sample of /proc/stat, this
process's own CPU time not counted as load (OpenCV keeps a thread busy for about
0.1 s after its import, which made a process that loaded the networks right after
importing cv2 fit one thread on an idle machine);
:func:`fit_torch_threads` sets torch's intra-op threads to that, once per
process, when the networks are loaded (lesmc/perception/cnn.py). Set
``LESMC_THREADS=N`` to choose the count yourself.

Small batches parallelise badly inside torch: DeepFool's forward and backward
passes on 128 windows of 21x21 run only 1.2-1.35x faster on two threads than on
one. :func:`in_lanes` runs independent batches side by side instead, one Python
thread per torch thread, each batch on one torch thread (torch releases the GIL in
its kernels): 1.3-1.5x the speed of the batches one after the other on two
threads, and a batch's bits are those of one thread whatever the load
(docs/performance.md, "Issue 31, ninth round"). :func:`torch_lanes` holds that
setting over a whole loop (perception's frames), so that torch's thread count is
not switched back and forth at every call (about 3 ms a switch).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: A core counts as free when it was idle at least this fraction of the sample.
IDLE_FRACTION = 0.5
#: Seconds between the two readings of /proc/stat.
SAMPLE_SECONDS = 0.1

_fitted: int | None = None


def _cpu_times() -> dict[int, tuple[int, int]]:
    """Per core: (idle + iowait jiffies, all jiffies) from /proc/stat (empty if unreadable)."""
    out = {}
    try:
        with open("/proc/stat", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("cpu") and line[3].isdigit():
                    name, *fields = line.split()
                    ticks = [int(x) for x in fields]
                    out[int(name[3:])] = (ticks[3] + ticks[4], sum(ticks[:8]))
    except (OSError, ValueError, IndexError):
        return {}
    return out


def free_cores(sample: float = SAMPLE_SECONDS) -> int:
    """Cores of this process's affinity that were at least :data:`IDLE_FRACTION` idle over
    ``sample`` seconds, this process's own work not counted (:func:`_free`); at least 1.
    Where /proc/stat cannot be read: the affinity's size."""
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if not allowed:
        return max(1, os.cpu_count() or 1)
    before, own = _cpu_times(), time.process_time()
    time.sleep(sample)
    after, own = _cpu_times(), time.process_time() - own
    if not before or not after:
        return len(allowed)
    return _free(before, after, allowed, own * os.sysconf("SC_CLK_TCK"))


def _free(
    before: dict[int, tuple[int, int]],
    after: dict[int, tuple[int, int]],
    allowed: list[int],
    own: float,
) -> int:
    """The cores of ``allowed`` at least :data:`IDLE_FRACTION` idle between two readings of
    :func:`_cpu_times`, once ``own`` ticks (this process's CPU time meanwhile) are taken
    off the busiest cores: a thread of ours that is busy while the caller waits (OpenCV
    starts one for about 0.1 s after its import) is not another process competing for
    the cores, and torch's threads would not wait for it once it is done. At least 1."""
    cores = []
    for cpu in allowed:
        if cpu in before and cpu in after:
            total = after[cpu][1] - before[cpu][1]
            if total > 0:
                cores.append((total - (after[cpu][0] - before[cpu][0]), total))
    cores.sort(key=lambda c: c[0] / c[1], reverse=True)
    free = 0
    for busy, total in cores:
        mine = min(own, busy)
        own -= mine
        free += (total - busy + mine) / total >= IDLE_FRACTION
    return max(1, free)


def fit_torch_threads() -> int:
    """Set torch's intra-op threads to the free cores (or ``LESMC_THREADS``), once per
    process; returns the count."""
    global _fitted
    if _fitted is None:
        import torch

        wanted = os.environ.get("LESMC_THREADS", "").strip()
        n = int(wanted) if wanted.isdigit() and int(wanted) > 0 else free_cores()
        torch.set_num_threads(n)
        _fitted = n
    return _fitted


_lanes_lock = threading.Lock()
_lanes_open = 0  #: blocks inside :func:`torch_lanes` (torch's thread count is process-wide)
_lanes_width = 1  #: torch's thread count before the first of them: the lanes, and restored
_in_lane = threading.local()  #: ``inside`` is set on the threads that run a lane


def in_lanes(fn: Callable[[T], R], items: Iterable[T], side_by_side: bool = True) -> list[R]:
    """``[fn(x) for x in items]``, each ``fn(x)`` on one torch thread.

    Side by side, the items run on up to one Python thread per torch thread (the
    free cores, :func:`fit_torch_threads`); otherwise, or with one torch thread (a
    busy machine, ``LESMC_THREADS=1``), or called from a lane, one after the other
    on the calling thread, still on one torch thread. So an item's numbers never
    depend on the machine's load: oneDNN may round a batch otherwise on two threads
    than on one. ``fn`` must not depend on the other items, and must set any
    thread-local torch mode (``inference_mode``, ``no_grad``) itself. An exception
    (Ctrl-C included) cancels the items not yet started.
    """
    todo = list(items)
    with torch_lanes() as lanes:
        nested = getattr(_in_lane, "inside", False)
        width = min(lanes, len(todo)) if side_by_side and not nested else 1
        if width <= 1:
            return [fn(x) for x in todo]

        def lane(x: T) -> R:
            _in_lane.inside = True
            return fn(x)

        pool = ThreadPoolExecutor(width, thread_name_prefix="lesmc-lane")
        try:
            return list(pool.map(lane, todo))
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


@contextmanager
def torch_lanes() -> Iterator[int]:
    """torch on one thread (per lane) for the block; yields the lanes: torch's thread
    count before the outermost such block, which it restores on leaving."""
    global _lanes_open, _lanes_width
    import torch

    with _lanes_lock:
        if _lanes_open == 0:
            _lanes_width = torch.get_num_threads()
            torch.set_num_threads(1)
        _lanes_open += 1
        width = _lanes_width
    try:
        yield width
    finally:
        with _lanes_lock:
            _lanes_open -= 1
            if _lanes_open == 0:
                torch.set_num_threads(_lanes_width)


@contextmanager
def all_torch_threads() -> Iterator[None]:
    """Within a :func:`torch_lanes` block, torch on the block's lanes again, for work
    that parallelises well inside torch and runs alone (certification's propagations:
    19 s for 64 windows on two threads against 31-37 s on one). Outside such a block,
    or on a lane, nothing changes."""
    import torch

    with _lanes_lock:
        width = _lanes_width if _lanes_open else 1
    if width <= 1 or getattr(_in_lane, "inside", False):
        yield
        return
    torch.set_num_threads(width)
    try:
        yield
    finally:
        torch.set_num_threads(1)
