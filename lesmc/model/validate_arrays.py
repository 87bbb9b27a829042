"""Structural checks of a <PO>²-LTS given as arrays laid out already (the binary .npz form,
lesmc/model/lts_binary.py): the layout itself (shapes, CSR offsets, index ranges, finite
numbers, the order of rows), then the rules of :func:`lesmc.model.validate.build` with
the same messages (docs/lts-format.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from lesmc.common.errors import ModelError
from lesmc.model.arrays import ArrayModel, IdArray
from lesmc.model.path_rules import Report, Rows, check_order, check_original, check_states
from lesmc.model.validate import check_transitions, id_array_problems, state_order


def check_arrays(cm: ArrayModel, path: str = "<model>") -> None:
    """The rules of :func:`build` on a model given as arrays (the binary .npz form, laid
    out already): the layout itself first (shapes, CSR offsets, index ranges, finite
    numbers, states in step order, each state's transitions in (rank, target) order),
    then the same transition, order, path and state rules, with the same messages."""
    src = _check_layout(cm, path)
    ids: Sequence[str] = cm.ids if cm.ids is not None else _DefaultIds(cm)
    rep = Report()

    def item(j: int) -> str:
        return f"transition {j} ({ids[src[j]]} -> {ids[cm.dst[j]]})"

    check_transitions(rep, None, src, cm.dst, cm.step, cm.payoff, item)
    rep.raise_if_any(path)
    rows = Rows(cm.step, cm.halted, cm.ptr, src, cm.dst, cm.rank, None, ids)
    check_order(rep, rows)
    original = [ids[q] for q in cm.original.tolist()]
    if cm.step[cm.initial] != 0:
        rep.add((1, 0, 1), "initial", f"state '{original[0]}' must be at step 0")
    check_original(rep, original, cm.original, rows)
    check_states(rep, cm.initial, cm.end, rows)
    rep.raise_if_any(path)


def _check_layout(cm: ArrayModel, path: str) -> np.ndarray:
    """Shapes, offsets, index ranges, finite numbers and the order of rows: what the
    arrays must be before the model's own rules can be checked. Returns each
    transition's source row."""
    n, m = cm.step.shape[0], cm.dst.shape[0]
    d = cm.S.shape[1] if cm.S.ndim == 2 else -1
    bad: list[tuple[str, str]] = []

    def need(ok: bool, item: str, message: str) -> None:
        if not ok:
            bad.append((item, message))

    need(n > 0, "step", "the model has no states")
    need(cm.S.shape == (n, d) and d >= 1, "S", f"must be {n} x d (d >= 1), got {cm.S.shape}")
    need(cm.halted.shape == (n,), "halted", f"must have {n} entries, got {cm.halted.shape}")
    need(cm.ptr.shape == (n + 1,), "ptr", f"must have {n + 1} entries, got {cm.ptr.shape}")
    for name in ("payoff", "rank") + (("obs",) if cm.obs is not None else ()):
        got = getattr(cm, name).shape
        need(got == (m,), name, f"must have {m} entries (one per transition), got {got}")
    need(cm.original.ndim == 1 and cm.original.size > 0, "original", "must be a non-empty path")
    need(len(cm.components) == d, "components", f"must name the {d} components of S")
    need(len(set(cm.components)) == len(cm.components), "components", "names must be unique")
    if cm.ids is not None:
        need(len(cm.ids) == n, "ids", f"must have {n} entries, got {len(cm.ids)}")
        if isinstance(cm.ids, IdArray):
            if len(cm.ids) == n:
                for item, msg in id_array_problems(cm.ids.raw, cm.step):
                    need(False, item, msg)
        else:
            need(len(set(cm.ids)) == len(cm.ids), "ids", "state ids must be unique")
    if bad:
        raise ModelError.many(path, bad)
    ptr = cm.ptr
    deg = np.diff(ptr)
    need(ptr[0] == 0 and ptr[-1] == m, "ptr", f"must run from 0 to {m} (the transitions)")
    need(bool((deg >= 0).all()), "ptr", "must not decrease")
    need(_within(cm.dst, n), "dst", f"must be states 0..{n - 1}")
    need(_within(cm.original, n), "original", "unknown state")
    need(bool(np.isfinite(cm.S).all()), "S", "must be finite numbers")
    need(bool((cm.step[1:] >= cm.step[:-1]).all()), "step", "states must be in step order")
    ids = cm.ids
    if ids is not None and not isinstance(ids, IdArray) and state_order(cm.step, ids) is not None:
        need(False, "ids", "states must be in (step, id) order, as the JSON form lays them out")
    _check_tables(cm, need, d)
    if bad:
        raise ModelError.many(path, bad)
    src = np.repeat(np.arange(n, dtype=np.int64), deg)
    r, t = cm.rank, cm.dst
    up = (r[1:] > r[:-1]) | ((r[1:] == r[:-1]) & (t[1:] >= t[:-1]))
    ordered = bool((up | (src[1:] != src[:-1])).all())
    need(ordered, "rank", "each state's transitions must be in (rank, target) order")
    if bad:
        raise ModelError.many(path, bad)
    return src


def _within(rows: np.ndarray, n: int) -> bool:
    """Every entry a row 0..n-1 (two reductions, no mask)."""
    return rows.size == 0 or (int(rows.min()) >= 0 and int(rows.max()) < n)


class _DefaultIds(Sequence[str]):
    """The default ids ``k{step}.{row}`` of a model without ids, made when a message
    names one (a list of them all would cost more than the checks)."""

    def __init__(self, cm: ArrayModel) -> None:
        self._cm = cm

    def __len__(self) -> int:
        return self._cm.n_states

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        return self._cm.state_id(int(i))


def _check_tables(cm: ArrayModel, need: Callable[[bool, str, str], None], d: int) -> None:
    """Covariances and observations: their tables, and indices into them (−1: none)."""
    if (cm.cov is None) != (cm.P_table is None):
        need(False, "cov", "cov and P_table come together")
        return
    if cm.cov is not None and cm.P_table is not None:
        c = cm.P_table.shape[0]
        need(cm.cov.shape == cm.step.shape, "cov", "must have one entry per state")
        need(cm.P_table.shape == (c, d, d), "P_table", f"must be c x {d} x {d}")
        need(bool(np.isfinite(cm.P_table).all()), "P_table", "must be finite numbers")
        need(bool(((cm.cov >= -1) & (cm.cov < c)).all()), "cov", f"must be -1..{c - 1}")
    if cm.obs is not None:
        k = len(cm.obs_names)
        need(bool(((cm.obs >= -1) & (cm.obs < k)).all()), "obs", f"must be -1..{k - 1}")
    if cm.nis is not None:
        ok = cm.nis.shape == cm.dst.shape
        need(ok, "nis", f"must have {cm.dst.shape[0]} entries (one per transition)")
        if ok:
            bad = ~(np.isnan(cm.nis) | (np.isfinite(cm.nis) & (cm.nis >= 0)))
            need(not bad.any(), "nis", "must be finite numbers >= 0, or NaN (no update)")
