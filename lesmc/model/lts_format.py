"""The explicit model file (.lts, JSON): reading with full validation, atomic writing.

The format is documented in docs/lts-format.md. Nothing in a file is executed;
every field is type-checked and every problem is reported with the offending id.

Reading goes straight from the decoded JSON to an
:class:`~lesmc.model.arrays.ArrayModel`: one list comprehension per field pulls
the values out of the state and transition objects, their types are checked
over whole columns at once (``set(map(type, column))``) and numpy does the
rest (:mod:`lesmc.model.validate`). Only when a column holds a wrong value is
it walked item by item, to name the offending ids.
"""

from __future__ import annotations

import json
import math
import re
import reprlib
from collections.abc import Callable, Iterable, Sequence
from itertools import chain
from operator import itemgetter
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeGuard

import numpy as np

from lesmc.common.errors import ModelError, Problems
from lesmc.common.fields import header, is_name
from lesmc.common.files import EncodedItems, read_json, write_json
from lesmc.model.arrays import ArrayModel, Tracks
from lesmc.model.validate import HALTED, Parts, build, check_tracks, meta_problems, state_order

if TYPE_CHECKING:
    from lesmc.model.lts import LTS

FORMAT = "lesmc-lts"
VERSION = 1
_TOP_KEYS = {
    "format",
    "version",
    "components",
    "initial",
    "original",
    "states",
    "transitions",
    "comment",
    "meta",
    "tracks",
}
_STATE_KEYS = {"id", "step", "s", "P", "labels", "meta"}
_TRANS_KEYS = {"src", "dst", "payoff", "rank", "obs", "nis"}
_NUMBER_TYPES = {int, float}
_I64 = (-(2**63), 2**63 - 1)
_ABSENT: Any = object()

_REPR = reprlib.Repr()
_REPR.maxstring = 60
_REPR.maxother = 60


def load_lts(path: str | Path) -> ArrayModel:
    """Read and validate a model: a .lts JSON file, or its binary form (``.npz``,
    lesmc/model/lts_binary.py)."""
    from lesmc.model.lts_binary import is_binary, load_lts_npz

    if is_binary(path):
        return load_lts_npz(path)
    return lts_from_dict(read_json(path, ModelError), str(path))


def lts_from_dict(data: Any, path: str = "<model>") -> ArrayModel:
    """Validate a decoded .lts document and build the model."""
    pr = Problems()
    if not isinstance(data, dict):
        raise ModelError.many(path, [("", "the top level must be a JSON object")])
    for key in sorted(set(data) - _TOP_KEYS, key=str):
        pr.add(f"key '{key}'", "unknown top-level key")
    header(data, FORMAT, VERSION, pr)
    components = data.get("components")
    if components is not None and not (
        isinstance(components, list) and components and all(is_name(c) for c in components)
    ):
        pr.add("components", "must be a non-empty list of names")
        components = None
    initial = data.get("initial")
    if not isinstance(initial, str):
        pr.add("initial", "must be a state id (string)")
    original = data.get("original")
    if not (isinstance(original, list) and all(isinstance(x, str) for x in original)):
        pr.add("original", "must be a list of state ids, one per step 0..e")
        original = []
    pr.items.extend(meta_problems(data.get("meta")))
    states, trans = _rows_of(data, pr)
    pr.items.extend(states.problems)
    pr.items.extend(trans.problems)
    if pr.items:
        raise ModelError.many(path, pr.items)
    meta = data.get("meta")
    parts = Parts(
        ids=states.ids,
        step=states.step,
        s_len=states.s_len,
        s_flat=states.s_flat,
        P_shape=states.P_shape,
        P_flat=states.P_flat,
        halted=states.halted,
        labels=states.labels,
        src=trans.src,
        dst=trans.dst,
        payoff=trans.payoff,
        rank=trans.rank,
        obs=trans.obs,
        nis=trans.nis,
        initial=str(initial),
        original=original,
        components=components,
        meta=meta if isinstance(meta, dict) else {},
    )
    cm = build(parts, path)
    if "tracks" in data:
        cm.tracks = _tracks(data["tracks"], cm, path)
    return cm


def _rows_of(data: dict[str, Any], pr: Problems) -> tuple[_States, _Transitions]:
    """The document's states and transitions, each column type-checked."""
    raw_states = data.get("states")
    raw_trans = data.get("transitions")
    if not isinstance(raw_states, list) or not raw_states:
        pr.add("states", "must be a non-empty list")
        raw_states = []
    if not isinstance(raw_trans, list):
        pr.add("transitions", "must be a list")
        raw_trans = []
    return _States(raw_states), _Transitions(raw_trans)


def _tracks(raw: Any, cm: ArrayModel, path: str) -> Tracks:
    """``tracks``: ``{"components": [...], "paths": [{"id", "at": [[x, y] | null, ...]}]}``,
    one entry of ``at`` per step 0..e (validate.check_tracks)."""
    pr = Problems()
    steps = cm.end + 1
    paths = raw.get("paths") if isinstance(raw, dict) else None
    if not (isinstance(raw, dict) and set(raw) == {"components", "paths"}) or not isinstance(
        paths, list
    ):
        raise ModelError.many(path, [("tracks", "must be an object with components and paths")])
    comps = raw["components"]
    width = len(comps) if isinstance(comps, list) else 0
    at = np.full((len(paths), steps, width), np.nan)
    ids: list[Any] = []
    for i, p in enumerate(paths):
        rows = p.get("at") if isinstance(p, dict) and set(p) == {"id", "at"} else None
        ids.append(p.get("id") if isinstance(p, dict) else None)
        if not isinstance(rows, list) or len(rows) != steps:
            pr.add(
                f"tracks.paths[{i}]", f"must be {{id, at}} with one position per step 0..{cm.end}"
            )
            continue
        for k, v in enumerate(rows):
            if v is None:
                continue
            if not (isinstance(v, list) and len(v) == width and all(map(_is_number, v))):
                pr.add(
                    f"tracks.paths[{i}].at[{k}]", f"must be null or {width} numbers, got {_show(v)}"
                )
                break
            at[i, k] = v
    if not pr.items:
        check = check_tracks({"components": comps, "ids": ids, "at": at}, cm.components, steps, pr)
        if check is not None:
            return check
    raise ModelError.many(path, pr.items)


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


class _States(_Rows):
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
            lambda j: f"step must be an integer >= 0{_fit(steps[j])}, got {_show(steps[j])}",
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


class _Transitions(_Rows):
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
            lambda j: f"payoff must be a finite number >= 0, got {_show(payoffs[j])}",
        )
        ranks = self.column("rank")
        self.rank, fits = _ints(ranks)
        self.bad(
            4,
            np.flatnonzero(~fits),
            lambda j: f"rank must be an integer{_fit(ranks[j])}, got {_show(ranks[j])}",
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
            lambda j: f"nis must be a finite number >= 0 or absent, got {_show(raw[j])}",
        )
        return np.where(np.array(present, dtype=bool).reshape(-1), vals, np.nan)

    def item(self, j: int) -> str:
        src, dst = self.src[j], self.dst[j]
        if isinstance(src, str) and isinstance(dst, str):
            return f"transition {self.rows[j]} ({src} -> {dst})"
        return f"transitions[{self.rows[j]}]"


def lts_to_dict(model: ArrayModel | LTS) -> dict[str, Any]:
    """The JSON document of a model (states in (step, id) order, transitions in rank order).

    States with the same covariance share one list for ``P`` (copy it before
    mutating one). An :class:`~lesmc.model.lts.LTS` is converted first.
    """
    model, ids, order, pos = _rows(model)
    return _document(
        model, ids, _states_json(model, ids, order, pos), _transitions_json(model, ids, pos)
    )


def _rows(model: ArrayModel | LTS) -> tuple[ArrayModel, list[str], np.ndarray, np.ndarray]:
    """The model as arrays, its ids, its rows in file order and each row's place in it."""
    if not isinstance(model, ArrayModel):
        from lesmc.model.lts import to_arrays

        model = to_arrays(model)
    n = model.n_states
    ids = model.state_ids()
    perm = state_order(model.step, ids)
    order = np.arange(n, dtype=np.int64) if perm is None else perm
    pos = np.empty(n, dtype=np.int64)
    pos[order] = np.arange(n, dtype=np.int64)
    return model, ids, order, pos


def _document(
    model: ArrayModel, ids: list[str], states: list[Any], trans: list[Any]
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "version": VERSION,
        "components": list(model.components),
        "initial": ids[model.initial],
        "original": [ids[q] for q in model.original.tolist()],
        "states": states,
        "transitions": trans,
        **({"meta": model.meta} if model.meta else {}),
        **({"tracks": _tracks_json(model.tracks)} if model.tracks is not None else {}),
    }


def _tracks_json(tracks: Tracks) -> dict[str, Any]:
    """The JSON form of a model's ground-truth tracks (null where a track is absent)."""
    return {
        "components": list(tracks.components),
        "paths": [
            {"id": tid, "at": [None if np.isnan(p).any() else p.tolist() for p in at]}
            for tid, at in zip(tracks.ids, tracks.at, strict=True)
        ],
    }


def _states_json(
    model: ArrayModel, ids: list[str], order: np.ndarray, pos: np.ndarray
) -> list[dict[str, Any]]:
    """The states in file order (``order``; ``pos``: each state's place in it), with their
    covariances and labels (halted states get HALTED)."""
    rows = order.tolist()
    doc_states: list[dict[str, Any]] = [
        {"id": ids[i], "step": k, "s": s}
        for i, k, s in zip(rows, model.step[order].tolist(), model.S[order].tolist(), strict=True)
    ]
    if model.cov is not None and model.P_table is not None:
        table = model.P_table.tolist()
        for d, c in zip(doc_states, model.cov[order].tolist(), strict=True):
            if c >= 0:
                d["P"] = table[c]
    for i, labs in _state_labels(model).items():
        doc_states[int(pos[i])]["labels"] = labs
    return doc_states


def _state_labels(model: ArrayModel) -> dict[int, list[str]]:
    """Each labelled state's labels, sorted, ``halted`` among them where it halted."""
    out = {}
    for i in set(model.labels) | set(np.flatnonzero(model.halted).tolist()):
        labs = set(model.labels.get(i, ())) | ({HALTED} if model.halted[i] else set())
        if labs:
            out[i] = sorted(labs)
    return out


def _transition_order(model: ArrayModel, pos: np.ndarray) -> np.ndarray:
    """The transitions in file order: by source (in file order), rank and target."""
    return np.lexsort((pos[model.dst], model.rank, pos[model.src]))


def _transitions_json(model: ArrayModel, ids: list[str], pos: np.ndarray) -> list[dict[str, Any]]:
    """The transitions by source (in file order), rank and target, with their observations."""
    src, dst = model.src, model.dst
    torder = _transition_order(model, pos)
    doc_trans: list[dict[str, Any]] = [
        {"src": ids[a], "dst": ids[b], "payoff": p, "rank": r}
        for a, b, p, r in zip(
            src[torder].tolist(),
            dst[torder].tolist(),
            model.payoff[torder].tolist(),
            model.rank[torder].tolist(),
            strict=True,
        )
    ]
    if model.obs is not None:
        names = model.obs_names
        for d, c in zip(doc_trans, model.obs[torder].tolist(), strict=True):
            if c >= 0:
                d["obs"] = names[c]
    if model.nis is not None:
        for d, v in zip(doc_trans, model.nis[torder].tolist(), strict=True):
            if v == v:  # not NaN: the transition updates
                d["nis"] = v
    return doc_trans


def save_lts(model: ArrayModel | LTS, path: str | Path) -> None:
    """Write a model atomically: JSON, or the binary form when ``path`` ends in .npz."""
    from lesmc.model.lts_binary import is_binary, save_lts_npz

    if is_binary(path):
        if not isinstance(model, ArrayModel):
            from lesmc.model.lts import to_arrays

            model = to_arrays(model)
        save_lts_npz(model, path)
        return
    write_json(path, lts_document(model))


def lts_document(model: ArrayModel | LTS) -> dict[str, Any]:
    """:func:`lts_to_dict`'s document for :func:`~lesmc.common.files.write_json`, its
    states and transitions formatted column by column as JSON texts (the same file,
    about four times sooner: no dict per row for the encoder to walk).

    A model with a non-finite number gets the plain document, which ``write_json``
    refuses as it always has.
    """
    model, ids, order, pos = _rows(model)
    finite = np.isfinite(model.S).all() and np.isfinite(model.payoff).all()
    if not finite or (model.P_table is not None and not np.isfinite(model.P_table).all()):
        return _document(
            model, ids, _states_json(model, ids, order, pos), _transitions_json(model, ids, pos)
        )
    quoted = _quoted(ids)
    states = _state_texts(model, quoted, order, pos)
    return _document(model, ids, states, _transition_texts(model, quoted, pos))


#: Ids that are JSON strings as they are: printable ASCII without '"' and '\'.
_PLAIN = re.compile(r"[ !#-\[\]-~]*")


def _quoted(ids: list[str]) -> list[str]:
    """Every id as a JSON string."""
    if _PLAIN.fullmatch("".join(ids)):
        return [f'"{i}"' for i in ids]
    return [json.dumps(i) for i in ids]


def _state_texts(
    model: ArrayModel, quoted: list[str], order: np.ndarray, pos: np.ndarray
) -> EncodedItems:
    """The states' JSON objects in file order, as :func:`_states_json` has them."""
    n = model.n_states
    tables = [""]  # "" for -1: no covariance
    cov = [-1] * n
    if model.cov is not None and model.P_table is not None:
        # a list's str is its JSON when it holds finite floats only (repr, ", ")
        tables = [f', "P": {p}' for p in map(str, model.P_table.tolist())] + [""]
        cov = model.cov[order].tolist()
    labels = [""] * n
    for i, labs in _state_labels(model).items():
        labels[int(pos[i])] = f', "labels": {json.dumps(labs)}'
    steps, S = model.step[order].tolist(), model.S[order].tolist()
    rows = zip(order.tolist(), steps, S, cov, labels, strict=True)
    return EncodedItems(
        f'{{"id": {quoted[i]}, "step": {k}, "s": {s}{tables[c]}{lab}}}' for i, k, s, c, lab in rows
    )


def _transition_texts(model: ArrayModel, quoted: list[str], pos: np.ndarray) -> EncodedItems:
    """The transitions' JSON objects in file order, as :func:`_transitions_json` has them."""
    src, dst = model.src, model.dst
    torder = _transition_order(model, pos)
    obs = [-1] * len(torder) if model.obs is None else model.obs[torder].tolist()
    names = [f', "obs": {json.dumps(o)}' for o in model.obs_names] + [""]
    nis = [""] * len(torder)
    if model.nis is not None:
        nis = [f', "nis": {v!r}' if v == v else "" for v in model.nis[torder].tolist()]
    rows = zip(
        src[torder].tolist(),
        dst[torder].tolist(),
        model.payoff[torder].tolist(),
        model.rank[torder].tolist(),
        obs,
        nis,
        strict=True,
    )
    return EncodedItems(
        f'{{"src": {quoted[a]}, "dst": {quoted[b]}, "payoff": {p!r}, "rank": {r}{names[o]}{z}}}'
        for a, b, p, r, o, z in rows
    )


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
    ok = [_is_number(v) and _finite(v) for v in values]
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


def _show(x: Any) -> str:
    """A short repr of a value from the file (huge integers and deep lists abridged)."""
    if _is_int(x) and x.bit_length() > 64:
        return f"{'-' if x < 0 else ''}<an integer of {x.bit_length()} bits>"
    try:
        return _REPR.repr(x)
    except (ValueError, RecursionError):
        return f"<{type(x).__name__}>"


def _is_int(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_number(x: Any) -> TypeGuard[int | float]:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _is_str(x: Any) -> bool:
    return isinstance(x, str)


def _finite(x: int | float) -> bool:
    try:
        return math.isfinite(x)
    except OverflowError:  # an int beyond the float range
        return False


def _vector(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and raw and all(_is_number(x) and _finite(x) for x in raw)):
        return None
    return np.asarray([float(x) for x in raw], dtype=np.float64)


def _matrix(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and raw and all(isinstance(r, list) for r in raw)):
        return None
    n = len(raw)
    if any(len(r) != n or not all(_is_number(x) and _finite(x) for x in r) for r in raw):
        return None
    return np.asarray([[float(x) for x in r] for r in raw], dtype=np.float64)
