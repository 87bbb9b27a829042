"""The order and path rules of a <PO>²-LTS laid out as rows (docs/lts-format.md): each
state's unattacked successor unique (the lowest rank), the initial state and the original
path, every state reachable, none beyond the path's end, halted exactly where a state has
no successor before the end.
:func:`lesmc.model.validate.build` and :func:`lesmc.model.validate_arrays.check_arrays`
check them once the states' and transitions' own problems are none, into a
:class:`Report` that lists every problem in file order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from lesmc.common.errors import ModelError

_LEVEL_LOOP_MAX = 2048
"""Reachability propagates level by level (one numpy pass per step) up to this many
distinct steps; beyond, a plain depth-first search over the CSR lists is cheaper."""


@dataclass(frozen=True)
class Rows:
    """A model laid out: states in (step, id) order, transitions grouped by source (CSR)
    in (rank, target) order. ``perm`` maps a row to its file row (None: the same) and
    ``ids`` names states by file row, for messages."""

    step: np.ndarray
    halted: np.ndarray
    ptr: np.ndarray
    src: np.ndarray  # each transition's source row
    dst: np.ndarray
    rank: np.ndarray
    perm: np.ndarray | None
    ids: Sequence[str]

    def file_rows(self, rows: np.ndarray) -> np.ndarray:
        """The file rows of sorted rows, so that problems are listed in file order."""
        return rows if self.perm is None else self.perm[rows]

    def id_of(self, row: int) -> str:
        return self.ids[row] if self.perm is None else self.ids[int(self.perm[row])]


class Report:
    """Problems keyed by (section, row, field) so that they come out in file order."""

    def __init__(self) -> None:
        self.items: list[tuple[tuple[int, int, int], str, str]] = []

    def add(self, key: tuple[int, int, int], item: str, message: str) -> None:
        self.items.append((key, item, message))

    def raise_if_any(self, path: str, before: list[tuple[str, str]] | None = None) -> None:
        if self.items or before:
            self.items.sort(key=lambda x: x[0])  # stable: same-key messages keep their order
            listed = [*(before or []), *((item, msg) for _, item, msg in self.items)]
            raise ModelError.many(path, listed)


def check_order(rep: Report, rows: Rows) -> None:
    """≺ must have a unique minimum per state: the transition taken when not attacked.

    Each state's transitions are in rank order (both readers lay them out so), so the
    minimum is unique where a state's first two ranks differ; the ties are counted
    only when there are some."""
    ptr, src, rank, ids = rows.ptr, rows.src, rows.rank, rows.ids
    m = rank.shape[0]
    if m < 2:
        return
    first = ptr[:-1][np.diff(ptr) >= 2]
    if not bool((rank[first] == rank[first + 1]).any()):
        return
    lowest = rank[np.minimum(ptr[:-1], m - 1)]  # each state's first (lowest) rank
    at_min = rank == lowest[src]
    count = np.bincount(src[at_min], minlength=ptr.shape[0] - 1)
    bad = np.flatnonzero(count > 1)
    file_rows = rows.file_rows(bad).tolist()
    for r, c, lo in zip(file_rows, count[bad].tolist(), lowest[bad].tolist(), strict=True):
        rep.add(
            (0, r, 0),
            f"state '{ids[r]}'",
            f"{c} transitions share the lowest rank {lo}; the unattacked successor must be unique",
        )


def check_original(rep: Report, original: list[str], op: np.ndarray, rows: Rows) -> None:
    """The original path (rows ``op``): state k at step k, each link rank-minimal."""
    step = rows.step
    k = np.arange(op.shape[0], dtype=np.int64)
    for kk in np.flatnonzero(step[op] != k).tolist():
        sid = original[kk]
        rep.add((2, kk, 0), f"original[{kk}]", f"state '{sid}' is at step {step[op[kk]]}, not {kk}")
    _check_links(rep, original, op, rows)


def check_states(rep: Report, q0: int, e: int, rows: Rows) -> None:
    """Every state reachable from ``q0``, at a step <= e, halted exactly where it has no
    successor before e."""
    step, halted = rows.step, rows.halted
    deg = np.diff(rows.ptr)
    reach = _reachable(q0, step, rows.ptr, rows.src, rows.dst)
    succ = deg > 0
    masks = (~reach, step > e, (halted & succ) | (~succ & (step < e) & ~halted))
    for kind, mask in enumerate(masks):
        qs = np.flatnonzero(mask)
        for r, q in zip(rows.file_rows(qs).tolist(), qs.tolist(), strict=True):
            if kind == 0:
                msg = "not reachable from the initial state"
            elif kind == 1:
                msg = f"step {step[q]} is beyond the original path's end {e}"
            elif halted[q]:
                msg = "is labelled halted but has successors"
            else:
                msg = (
                    f"has no successor before step {e}; label it 'halted' if the "
                    "tracker stopped there"
                )
            rep.add((3, r, kind), f"state '{rows.ids[r]}'", msg)


def _check_links(rep: Report, original: list[str], op: np.ndarray, rows: Rows) -> None:
    """Each step of the original path (rows ``op``) is the rank-minimal transition."""
    ptr, src, dst, n = rows.ptr, rows.src, rows.dst, len(rows.ids)
    stop, m, deg = len(op), dst.shape[0], np.diff(ptr)
    if stop > 1 and m:
        prev, cur = op[:-1], op[1:]
        pick = np.where(deg[prev] > 0, dst[np.minimum(ptr[prev], m - 1)], -1)
        off = np.flatnonzero(pick != cur)
        if off.size:
            edges = src * n + dst
            exists = np.isin(prev[off] * n + cur[off], edges)
            for i, ok in zip(off.tolist(), exists.tolist(), strict=True):
                kk, a, b = i + 1, original[i], original[i + 1]
                if ok:
                    p = rows.id_of(int(pick[i]))
                    msg = (
                        f"'{b}' is not the unattacked (rank-minimal) successor of '{a}', "
                        f"which is '{p}'"
                    )
                else:
                    msg = f"no transition from '{a}' to '{b}'"
                rep.add((2, kk, 1), f"original[{kk}]", msg)
    elif stop > 1:
        for kk in range(1, stop):
            msg = f"no transition from '{original[kk - 1]}' to '{original[kk]}'"
            rep.add((2, kk, 1), f"original[{kk}]", msg)


def _reachable(
    q0: int, step: np.ndarray, ptr: np.ndarray, src: np.ndarray, dst: np.ndarray
) -> np.ndarray:
    """States reachable from q0; rows are sorted by step and every transition climbs one step."""
    n = step.shape[0]
    reach = np.zeros(n, dtype=bool)
    reach[q0] = True
    starts = np.flatnonzero(np.r_[True, step[1:] != step[:-1]])
    if starts.size <= _LEVEL_LOOP_MAX:
        bounds = np.r_[starts, n]
        tb = ptr[bounds].tolist()
        for a, b in pairwise(tb):
            if a < b:
                reach[dst[a:b][reach[src[a:b]]]] = True
        return reach
    ptr_l, dst_l = ptr.tolist(), dst.tolist()
    seen = bytearray(n)
    seen[q0] = 1
    todo = [q0]
    while todo:
        q = todo.pop()
        for t in dst_l[ptr_l[q] : ptr_l[q + 1]]:
            if not seen[t]:
                seen[t] = 1
                todo.append(t)
    return np.frombuffer(bytes(seen), dtype=np.uint8).astype(bool)
