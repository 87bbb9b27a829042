"""A command's budget: seconds, states and bytes of memory (``--timeout``, ``--max-states``,
``--max-memory``).

The clock starts when the command starts, so loading, unfolding, checking and
writing all count. Whoever does long work calls :meth:`Budget.exceeded` often
(every batch of states, about every 0.05 s) and stops when it names a reason.
Memory is the process's resident set (``/proc/self/statm``; the peak
``ru_maxrss`` where there is no /proc) plus what the caller is about to
allocate, so that a growing model stops before the machine swaps.
"""

from __future__ import annotations

import math
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field

#: Share of the memory available at start that ``--max-memory`` defaults to.
DEFAULT_MEMORY_SHARE = 0.8

_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
_SIZE_RE = re.compile(r"([0-9]+(?:\.[0-9]+)?)\s*([KMGT]?)(?:i?B)?", re.IGNORECASE)
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def resident_bytes() -> int:
    """The process's resident memory now (its peak where /proc is missing)."""
    try:
        with open("/proc/self/statm", "rb") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):  # pragma: no cover - not Linux
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return int(peak) * (1 if os.uname().sysname == "Darwin" else 1024)


def available_bytes() -> int | None:
    """Memory the system can give without swapping (MemAvailable), if known."""
    try:
        with open("/proc/meminfo", "rb") as fh:
            for line in fh:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, IndexError, ValueError):  # pragma: no cover - not Linux
        pass
    try:  # pragma: no cover - not Linux
        return int(os.sysconf("SC_AVPHYS_PAGES")) * _PAGE
    except (OSError, ValueError, AttributeError):  # pragma: no cover
        return None


def default_max_memory() -> int | None:
    """What the process holds now plus :data:`DEFAULT_MEMORY_SHARE` of what is available."""
    free = available_bytes()
    if free is None:  # pragma: no cover - not Linux
        return None
    return resident_bytes() + int(DEFAULT_MEMORY_SHARE * free)


def parse_size(text: str) -> int:
    """``512M``, ``4G``, ``1.5GiB``, ``1000000`` (bytes) -> bytes; ValueError otherwise."""
    m = _SIZE_RE.fullmatch(text.strip())
    if m is None or not m.group(1).isascii():
        raise ValueError(f"'{text}' is not a size (e.g. 512M, 4G)")
    value = float(m.group(1)) * _UNITS[m.group(2).upper()]
    if not math.isfinite(value) or value < 1 or value > 2**62:
        raise ValueError(f"'{text}' is not a size between 1 byte and 4 EiB")
    return int(value)


def show_size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(n) < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GiB"  # pragma: no cover


@dataclass
class Budget:
    """The limits of one job, in one place; ``None`` means no limit.

    * ``timeout``: seconds for the whole job, loading and writing included (its clock
      starts when the budget is made: ``--timeout`` of check, verify, build);
    * ``check_timeout``: seconds for each property check on its own (``lesmc campaign
      --timeout``: every unit gets them, however long the campaign runs);
    * ``max_states``: states one search may expand, or one build may make;
    * ``max_memory``: bytes the process may hold.

    A check gets :meth:`check_seconds`; in interval mode its two searches share them
    (:meth:`share`). An engine turns what a check gets into its running
    :class:`SearchBudget` (:meth:`search`).
    """

    timeout: float | None = None
    max_states: int | None = None
    max_memory: int | None = None
    check_timeout: float | None = None
    started: float = field(default_factory=time.monotonic)

    def seconds_left(self) -> float | None:
        """Seconds until the job's deadline (0 once past it), or None without a timeout."""
        if self.timeout is None:
            return None
        return max(0.0, self.timeout - (time.monotonic() - self.started))

    def check_seconds(self) -> float | None:
        """Seconds one property check may take from now: what is left of the job's
        time, at most ``check_timeout``."""
        left = [s for s in (self.seconds_left(), self.check_timeout) if s is not None]
        return min(left) if left else None

    def for_check(self) -> Budget:
        """The budget of one property check starting now (its own clock)."""
        return Budget(self.check_seconds(), self.max_states, self.max_memory)

    def share(self, fraction: float) -> Budget:
        """A budget with ``fraction`` of this one's remaining seconds (the first of two
        searches that share a check's time)."""
        left = self.seconds_left()
        return Budget(None if left is None else left * fraction, self.max_states, self.max_memory)

    def search(
        self, reserve: Callable[[], int] | None = None, memory_every: int = 1
    ) -> SearchBudget:
        """An engine's running budget for the rest of this one."""
        return SearchBudget(
            self.max_states, self.seconds_left(), self.max_memory, reserve, memory_every
        )

    def exceeded(self, states: int = 0, reserve: int = 0) -> str | None:
        """Why the work must stop (``timeout``, ``max_states``, ``max_memory``), or None.

        ``states``: states made so far; ``reserve``: bytes about to be allocated.
        """
        if self.timeout is not None and time.monotonic() - self.started > self.timeout:
            return "timeout"
        if self.max_states is not None and states > self.max_states:
            return "max_states"
        if self.max_memory is not None and resident_bytes() + reserve > self.max_memory:
            return "max_memory"
        return None

    def describe(self, reason: str) -> str:
        """The limit behind ``reason``, for messages."""
        if reason == "timeout":
            return f"--timeout {self.timeout:g} s"
        if reason == "max_states":
            return f"--max-states {self.max_states}"
        return f"--max-memory {show_size(self.max_memory or 0)}"


_stop_requested: int | None = None


def request_stop(signum: int) -> None:
    """Ask every running and later search to stop as if its budget ran out (reason
    ``interrupted``): a signal handler's polite first step (lesmc/cli/signals.py)."""
    global _stop_requested
    _stop_requested = signum


def stop_requested() -> int | None:
    """The signal that asked the searches to stop, or None."""
    return _stop_requested


def clear_stop() -> None:
    """Forget a stop request (a new command in the same process)."""
    global _stop_requested
    _stop_requested = None


class SearchBudget:
    """An engine's running budget: expansions counted against ``max_states``, a deadline
    ``timeout`` seconds from now, and a memory ceiling (the resident set plus ``reserve()``,
    what the model's next growth may take, looked at every ``memory_every`` checks)."""

    def __init__(
        self,
        max_states: int | None,
        timeout: float | None,
        max_memory: int | None = None,
        reserve: Callable[[], int] | None = None,
        memory_every: int = 1,
    ) -> None:
        self.max_states = max_states
        self.deadline = None if timeout is None else time.perf_counter() + timeout
        self.max_memory = max_memory
        self.reserve = reserve
        self.memory_every = memory_every
        self.used = 0
        self._checks = 0

    def would_pass(self, seconds: float) -> str | None:
        """``timeout`` when work of ``seconds`` started now would end past the deadline
        (work that cannot look at the clock while it runs), else None."""
        if _stop_requested is not None:
            return "interrupted"
        if self.deadline is not None and time.perf_counter() + seconds > self.deadline:
            return "timeout"
        return None

    def over(self, more: int = 0) -> str | None:
        """Why the search must stop with ``more`` expansions counted (``interrupted``,
        ``max_states``, ``timeout``, ``max_memory``), or None."""
        if _stop_requested is not None:
            return "interrupted"
        if self.max_states is not None and self.used + more > self.max_states:
            return "max_states"
        if self.deadline is not None and time.perf_counter() > self.deadline:
            return "timeout"
        self._checks += 1
        if self.max_memory is not None and self._checks % self.memory_every == 0:
            extra = self.reserve() if self.reserve is not None else 0
            if resident_bytes() + extra > self.max_memory:
                return "max_memory"
        return None
