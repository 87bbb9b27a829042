"""The states and transitions of a ``.lts`` document, checked column by column.

:class:`States` and :class:`Transitions` take the decoded lists of
lesmc/model/lts_format.py's reader: one list comprehension per field pulls the
values out of the objects, their types are checked over whole columns at once
(``set(map(type, column))``) and numpy does the rest. Only when a column holds a
wrong value is it walked item by item, to name the offending ids; the problems
come out in file order. :func:`is_number` and :func:`show` (a short repr of a
value from the file) serve the reader's ``tracks`` too.
"""

from __future__ import annotations

import math
import reprlib
from collections.abc import Callable, Iterable, Sequence
from itertools import chain
from operator import itemgetter
from typing import Any, TypeGuard

import numpy as np

from lesmc.model.validate import HALTED

_STATE_KEYS = {"id", "step", "s", "P", "labels", "meta"}
_TRANS_KEYS = {"src", "dst", "payoff", "rank", "obs", "nis"}
_NUMBER_TYPES = {int, float}
_I64 = (-(2**63), 2**63 - 1)
_ABSENT: Any = object()

_REPR = reprlib.Repr()
_REPR.maxstring = 60
_REPR.maxother = 60


class _Rows:
    """The objects of one list, checked column by column; problems in file order."""

    section = ""

    def __init__(self, raw: list[Any]) -> None:
        self._found: list[tuple[tuple[int, int], str, str]] = []
        rows: Sequence[int] = range(len(raw))
        self._plain = set(map(type, raw)) <= {dict}  # no subclass may answer a missing key
        if not self._plain:
            rows = [i for i, r in enumerate(raw) if isinstance(r, dict)]
            for i in sorted(set(range(len(raw))) - set(rows)):
                self._found.append(((i, 0), f"{self.section}[{i}]", "must be an object"))
        self.rows = rows  # file index of each object
        self.recs: list[dict[Any, Any]] = raw if len(rows) == len(raw) else [raw[i] for i in rows]
        self.keys: set[Any] = set().union(*self.recs)

    def item(self, j: int) -> str:
        raise NotImplementedError

    def bad(
        self, field: int, js: Sequence[int] | np.ndarray, message: Callable[[int], str]
    ) -> None:
        """Report the objects ``js`` (positions among the objects) with ``message(j)``."""
        idx = js.tolist() if isinstance(js, np.ndarray) else js
        for j in idx:
            self._found.append(((self.rows[j], field), self.item(j), message(j)))

    def unknown_keys(self, field: int, allowed: set[str]) -> None:
        if not self.keys - allowed:
            return
        for j, r in enumerate(self.recs):
            for key in sorted(set(r) - allowed, key=str):
                self._found.append(((self.rows[j], field), self.item(j), f"unknown key '{key}'"))

    def column(self, key: str, default: Any = None) -> list[Any]:
        """The values of ``key`` (``default`` where absent), in one pass."""
        if key not in self.keys:
            return [default] * len(self.recs)
        if self._plain:
            try:
                return list(map(itemgetter(key), self.recs))
            except KeyError:
                pass
        return [r.get(key, default) for r in self.recs]

    @property
    def problems(self) -> list[tuple[str, str]]:
        self._found.sort(key=lambda x: x[0])  # stable: one field's messages keep their order
        return [(item, msg) for _, item, msg in self._found]


class States(_Rows):
    section = "states"

    def __init__(self, raw: list[Any]) -> None:
        super().__init__(raw)
        n = len(self.recs)
        ids = self.column("id")
        self._ids = ids
        if not (_all_types(ids, {str}) and (n == 0 or min(map(len, ids)) > 0)):
            self.bad(
                0,
                _where(ids, lambda x: not (isinstance(x, str) and x)),
                _msg("id must be a non-empty string"),
            )
        self.unknown_keys(1, _STATE_KEYS)
        steps = self.column("step")
        self.step, fits = _ints(steps)
        self.bad(
            2,
            np.flatnonzero(~fits | (self.step < 0)),
            lambda j: f"step must be an integer >= 0{_fit(steps[j])}, got {show(steps[j])}",
        )
        self.s_flat, self.s_len, ok = _vectors(self.column("s"))
        self.bad(3, np.flatnonzero(~ok), _msg("s must be a non-empty list of finite numbers"))
        self.P_shape = np.full((n, 2), -1, dtype=np.int64)
        self.P_flat = np.zeros(0)
        if "P" in self.keys:
            Ps = self.column("P", _ABSENT)
            has = [j for j, p in enumerate(Ps) if p is not _ABSENT]
            self.P_flat, size, ok = _matrices([Ps[j] for j in has])
            self.P_shape[has] = size[:, None]
            self.bad(
                4,
                [has[i] for i in np.flatnonzero(~ok).tolist()],
                _msg("P must be a square list of lists of finite numbers"),
            )
        self.halted = np.zeros(n, dtype=bool)
        self.labels: dict[int, tuple[str, ...]] = {}
        if "labels" in self.keys:
            raw_labels = self.column("labels", _ABSENT)
            wrong = []
            for j, labs in enumerate(raw_labels):
                if labs is _ABSENT:
                    continue
                if not (isinstance(labs, list) and all(isinstance(x, str) for x in labs)):
                    wrong.append(j)
                    continue
                self.halted[j] = HALTED in labs
                other = set(labs) - {HALTED}
                if other:
                    self.labels[j] = tuple(sorted(other))
            self.bad(5, wrong, _msg("labels must be a list of strings"))
        self.ids: list[str] = ids

    def item(self, j: int) -> str:
        sid = self._ids[j]
        return f"state '{sid}'" if isinstance(sid, str) and sid else f"states[{self.rows[j]}]"


class Transitions(_Rows):
    section = "transitions"

    def __init__(self, raw: list[Any]) -> None:
        super().__init__(raw)
        self.src = self.column("src")
        self.dst = self.column("dst")
        self.unknown_keys(1, _TRANS_KEYS)
        if not (_all_types(self.src, {str}) and _all_types(self.dst, {str})):
            ends = zip(self.src, self.dst, strict=True)
            wrong = [j for j, (a, b) in enumerate(ends) if not (_is_str(a) and _is_str(b))]
            self.bad(2, wrong, _msg("src and dst must be state ids"))
        payoffs = self.column("payoff")
        self.payoff, ok = _floats(payoffs)
        self.bad(
            3,
            np.flatnonzero(~ok | ~(self.payoff >= 0)),
            lambda j: f"payoff must be a finite number >= 0, got {show(payoffs[j])}",
        )
        ranks = self.column("rank")
        self.rank, fits = _ints(ranks)
        self.bad(
            4,
            np.flatnonzero(~fits),
            lambda j: f"rank must be an integer{_fit(ranks[j])}, got {show(ranks[j])}",
        )
        obs = self.column("obs")
        self.obs: list[str | None] | None = obs
        types = set(map(type, obs))
        if types <= {type(None)}:
            self.obs = None
        elif types - {str, type(None)}:
            wrong = _where(obs, lambda x: x is not None and not isinstance(x, str))
            self.bad(5, wrong, _msg("obs must be a string or absent"))
        self.nis = self._nis()

    def _nis(self) -> np.ndarray | None:
        """The NIS of each transition's update (NaN: absent or null, no update); None when
        no transition has one."""
        raw = self.column("nis")
        if all(v is None for v in raw):
            return None
        present = [v is not None for v in raw]
        vals, ok = _floats([0.0 if v is None else v for v in raw])
        self.bad(
            6,
            np.flatnonzero(~ok | ~(vals >= 0)),
            lambda j: f"nis must be a finite number >= 0 or absent, got {show(raw[j])}",
        )
        return np.where(np.array(present, dtype=bool).reshape(-1), vals, np.nan)

    def item(self, j: int) -> str:
        src, dst = self.src[j], self.dst[j]
        if isinstance(src, str) and isinstance(dst, str):
            return f"transition {self.rows[j]} ({src} -> {dst})"
        return f"transitions[{self.rows[j]}]"


# --- columns ---------------------------------------------------------------


def _ints(values: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """int64 values (0 where not) and which values are integers that fit in 64 bits."""
    n = len(values)
    if _all_types(values, {int}):
        try:
            return np.fromiter(values, dtype=np.int64, count=n), np.ones(n, dtype=bool)
        except OverflowError:
            pass
    ok = [_is_int(v) and _I64[0] <= v <= _I64[1] for v in values]
    arr = np.fromiter((v if k else 0 for v, k in zip(values, ok, strict=True)), np.int64, n)
    return arr, np.array(ok, dtype=bool).reshape(n)


def _floats(values: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """float64 values (0 where not) and which values are finite numbers."""
    n = len(values)
    if _all_types(values, _NUMBER_TYPES):
        try:
            arr = np.fromiter(values, dtype=np.float64, count=n)
        except OverflowError:
            pass
        else:
            return arr, np.isfinite(arr)
    ok = [is_number(v) and _finite(v) for v in values]
    arr = np.fromiter((v if k else 0.0 for v, k in zip(values, ok, strict=True)), np.float64, n)
    return arr, np.array(ok, dtype=bool).reshape(n)


def _vectors(values: list[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flattened entries, the length of each value, and which are non-empty lists of
    finite numbers (the entries only matter when all are)."""
    n = len(values)
    if n and _all_types(values, {list}):
        lens = _lengths(values)
        ok = lens > 0
        flat = _flat_numbers(chain.from_iterable(values), int(lens.sum()), ok, lens)
        if flat is not None:
            return flat, lens, ok
    vecs = [_vector(v) for v in values]
    lens = np.array([0 if v is None else v.shape[0] for v in vecs], dtype=np.int64).reshape(n)
    ok = np.array([v is not None for v in vecs], dtype=bool).reshape(n)
    present = [v for v in vecs if v is not None]
    flat = np.concatenate(present) if present else np.zeros(0)
    return flat, lens, ok


def _matrices(values: list[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flattened entries, the size r of each (r x r) value, and which are square lists
    of lists of finite numbers."""
    n = len(values)
    if n and _all_types(values, {list}):
        rows = list(chain.from_iterable(values))
        if rows and _all_types(rows, {list}):
            size = _lengths(values)
            row_len = _lengths(rows)
            if bool((size > 0).all()) and np.array_equal(row_len, np.repeat(size, size)):
                ok = np.ones(n, dtype=bool)
                entries = chain.from_iterable(rows)
                flat = _flat_numbers(entries, int(row_len.sum()), ok, size * size)
                if flat is not None:
                    return flat, size, ok
    mats = [_matrix(v) for v in values]
    size = np.array([-1 if m is None else m.shape[0] for m in mats], dtype=np.int64).reshape(n)
    ok = np.array([m is not None for m in mats], dtype=bool).reshape(n)
    present = [m.reshape(-1) for m in mats if m is not None]
    flat = np.concatenate(present) if present else np.zeros(0)
    return flat, np.where(ok, size, 0), ok


def _lengths(values: list[Any]) -> np.ndarray:
    """len() of each value (all of one length is the common case: one set, no array)."""
    distinct = set(map(len, values))
    if len(distinct) == 1:
        return np.full(len(values), distinct.pop(), dtype=np.int64)
    return np.fromiter(map(len, values), dtype=np.int64, count=len(values))


def _flat_numbers(
    entries: Iterable[Any], count: int, ok: np.ndarray, per_value: np.ndarray
) -> np.ndarray | None:
    """The entries of all values as one array if every one is a number (None: walk the
    values one by one); clears ``ok`` of the values with a non-finite entry."""
    flat = list(entries)
    if not _all_types(flat, _NUMBER_TYPES):
        return None
    try:
        arr = np.fromiter(flat, dtype=np.float64, count=count)
    except OverflowError:  # an int beyond the float range
        return None
    inf = ~np.isfinite(arr)
    if inf.any():
        owner = np.repeat(np.arange(per_value.shape[0]), per_value)
        ok[owner[inf]] = False
    return arr


# --- single values -----------------------------------------------------------


def _all_types(values: list[Any], types: set[type]) -> bool:
    """Every value's exact type is one of ``types`` (bool is not int)."""
    return set(map(type, values)) <= types


def _where(values: list[Any], wrong: Callable[[Any], bool]) -> list[int]:
    return [j for j, v in enumerate(values) if wrong(v)]


def _msg(text: str) -> Callable[[int], str]:
    return lambda _j: text


def _fit(x: Any) -> str:
    """A hint for integers beyond int64."""
    return " that fits in 64 bits" if _is_int(x) and not _I64[0] <= x <= _I64[1] else ""


def show(x: Any) -> str:
    """A short repr of a value from the file (huge integers and deep lists abridged)."""
    if _is_int(x) and x.bit_length() > 64:
        return f"{'-' if x < 0 else ''}<an integer of {x.bit_length()} bits>"
    try:
        return _REPR.repr(x)
    except (ValueError, RecursionError):
        return f"<{type(x).__name__}>"


def _is_int(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


def is_number(x: Any) -> TypeGuard[int | float]:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _is_str(x: Any) -> bool:
    return isinstance(x, str)


def _finite(x: int | float) -> bool:
    try:
        return math.isfinite(x)
    except OverflowError:  # an int beyond the float range
        return False


def _vector(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and raw and all(is_number(x) and _finite(x) for x in raw)):
        return None
    return np.asarray([float(x) for x in raw], dtype=np.float64)


def _matrix(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and raw and all(isinstance(r, list) for r in raw)):
        return None
    n = len(raw)
    if any(len(r) != n or not all(is_number(x) and _finite(x) for x in r) for r in raw):
        return None
    return np.asarray([[float(x) for x in r] for r in raw], dtype=np.float64)
