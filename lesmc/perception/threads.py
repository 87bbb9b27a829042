"""torch's threads fitted to the cores actually free (issue 31: certification on a busy machine).

torch's OpenMP threads spin-wait for each other: with more threads than idle
cores (a campaign's other workers, any CPU-bound process beside lesmc) every
parallel region waits for a thread that is not running, and a certificate
takes 3-10x as long. :func:`free_cores` counts the cores this process may run
on (its affinity) that were mostly idle over a short sample of /proc/stat;
:func:`fit_torch_threads` sets torch's intra-op threads to that, once per
process, when the networks are loaded (lesmc/perception/cnn.py). Set
``LESMC_THREADS=N`` to choose the count yourself.
"""

from __future__ import annotations

import os
import time

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
    ``sample`` seconds; at least 1. Where /proc/stat cannot be read: the affinity's size."""
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if not allowed:
        return max(1, os.cpu_count() or 1)
    before = _cpu_times()
    time.sleep(sample)
    after = _cpu_times()
    if not before or not after:
        return len(allowed)
    free = 0
    for cpu in allowed:
        if cpu not in before or cpu not in after:
            continue
        idle = after[cpu][0] - before[cpu][0]
        total = after[cpu][1] - before[cpu][1]
        free += total > 0 and idle / total >= IDLE_FRACTION
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
