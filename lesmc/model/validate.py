"""Structural checks of a <PO>²-LTS over arrays, reported item by item (docs/lts-format.md).

:class:`Parts` holds a model's columns in file order, as read: ids, steps,
the entries of every s and P flattened, transitions by their endpoints' ids.
:func:`build` checks every structural rule with numpy, reports each problem
with the offending id and lays the model out as an
:class:`~lesmc.model.arrays.ArrayModel`: states in (step, id) order,
transitions grouped by source (CSR) and sorted by (rank, target id).

Messages and their order are those of the object-based checker this replaces:
first the states' and transitions' own problems (duplicate ids, sizes, unknown
endpoints, steps, duplicate pairs); only when there are none, the order and
path rules (unique lowest rank, initial, original, reachability, halting:
lesmc/model/path_rules.py). A model
given as laid-out arrays (the binary form) is checked against the same rules by
lesmc/model/validate_arrays.py.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import islice, repeat
from typing import Any

import numpy as np

from lesmc.common.errors import ModelError, Problems
from lesmc.common.fields import MAX_STEP, show
from lesmc.model.arrays import ArrayModel, Tracks
from lesmc.model.path_rules import Report, Rows, check_order, check_original, check_states

HALTED = "halted"
"""Label of a state where the tracker stopped (trace(P) too large): no successors."""


_HASH = np.random.default_rng(0x1E5).integers(-(2**62), 2**62, size=4096, dtype=np.int64)
"""Fixed multipliers of the row hash that deduplicates covariances (deterministic)."""


def default_components(n: int) -> tuple[str, ...]:
    """Names s0, s1, ... used when a model does not name its components."""
    return tuple(f"s{i}" for i in range(n))


@dataclass
class Parts:
    """A model's columns in file order, each field type-checked, the structure not yet."""

    ids: list[str]
    step: np.ndarray  # (n,) int64
    s_len: np.ndarray  # (n,) int64: entries of each s
    s_flat: np.ndarray  # (sum s_len,) float64: the s's one after the other
    P_shape: np.ndarray  # (n, 2) int64: rows and columns of each P, -1 where none
    P_flat: np.ndarray  # float64: the P's present, row-major, in state order
    halted: np.ndarray  # (n,) bool
    labels: dict[int, tuple[str, ...]]  # file row -> labels other than halted, sorted
    src: list[str]
    dst: list[str]
    payoff: np.ndarray  # (m,) float64
    rank: np.ndarray  # (m,) int64
    obs: list[str | None] | None  # None: no transition has an observation
    initial: str
    original: list[str]
    components: Sequence[str] | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    nis: np.ndarray | None = None  # (m,) float64, NaN: no update; None: no transition has one


def build(parts: Parts, path: str = "<model>") -> ArrayModel:
    """Check every structural rule and lay the model out; raise one ModelError listing all."""
    ids = parts.ids
    n = len(ids)
    if n == 0:
        raise ModelError.many(path, [("", "the model has no states")])
    head: list[tuple[str, str]] = []
    dim = int(parts.s_len[0])
    if parts.components is not None:
        if len(set(parts.components)) != len(parts.components):
            head.append(("components", "component names must be unique"))
        dim = len(parts.components)
    index = _first_index(ids)
    src_f, dst_f = _endpoints(parts, index)
    _check_parts(parts, index, src_f, dst_f, dim, head, path)

    perm, pos, torder, src, dst, rank, step, ptr, halted = _layout(parts, src_f, dst_f)
    sorted_ids = ids if perm is None else [ids[i] for i in perm.tolist()]

    rows = Rows(step, halted, ptr, src, dst, rank, perm, ids)
    rep = Report()
    check_order(rep, rows)
    original = _check_paths(rep, parts, index, pos, rows)
    rep.raise_if_any(path)
    assert original is not None

    S = parts.s_flat.reshape(n, dim)
    if perm is not None:
        S = S[perm]
    cov, P_table = _covariances(parts, perm, dim)
    obs, obs_names = _observations(parts.obs, torder)
    labels = {int(pos[r]): labs for r, labs in parts.labels.items()}
    comps = tuple(parts.components) if parts.components else default_components(dim)
    return ArrayModel(
        components=comps,
        step=np.ascontiguousarray(step, dtype=np.int64),
        S=np.ascontiguousarray(S, dtype=np.float64),
        halted=np.ascontiguousarray(halted, dtype=bool),
        ptr=ptr,
        dst=dst,
        payoff=np.ascontiguousarray(parts.payoff[torder], dtype=np.float64),
        rank=np.ascontiguousarray(rank, dtype=np.int64),
        original=original,
        cov=cov,
        P_table=P_table,
        obs=obs,
        obs_names=obs_names,
        nis=None if parts.nis is None else np.ascontiguousarray(parts.nis[torder]),
        ids=list(sorted_ids),
        labels=dict(sorted(labels.items())),
        meta=parts.meta,
    )


def _layout(parts: Parts, src_f: np.ndarray, dst_f: np.ndarray) -> tuple[Any, ...]:
    """States in (step, id) order, transitions by (source, rank, target): the permutation
    (None: already in order), each row's position, the transitions' order, their sources,
    targets and ranks, the states' steps, the CSR offsets and the halted flags."""
    n = len(parts.ids)
    perm = state_order(parts.step, parts.ids)
    pos = np.arange(n, dtype=np.int64)
    if perm is not None:
        pos[perm] = np.arange(n, dtype=np.int64)
    src_p, dst_p = pos[src_f], pos[dst_f]
    torder = np.lexsort((dst_p, parts.rank, src_p))
    src = src_p[torder]
    step = parts.step if perm is None else parts.step[perm]
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=ptr[1:])
    halted = parts.halted if perm is None else parts.halted[perm]
    return perm, pos, torder, src, dst_p[torder], parts.rank[torder], step, ptr, halted


def state_order(step: np.ndarray, ids: Sequence[str]) -> np.ndarray | None:
    """The rows in (step, id) order (Python string order), or None if they already are."""
    n = len(ids)
    if n < 2:
        return None
    less = np.fromiter(map(operator.lt, ids, islice(ids, 1, None)), dtype=bool, count=n - 1)
    same, up = step[1:] == step[:-1], step[1:] > step[:-1]
    if bool(np.all(up | (same & less))):
        return None
    # numpy's fixed-width strings drop trailing NULs and cost n * width: Python sorts those
    if max(map(len, ids)) * n <= 1 << 26 and "\x00" not in "".join(ids):
        return np.lexsort((np.array(ids), step))
    key = list(zip(step.tolist(), ids, strict=True))
    return np.array(sorted(range(n), key=key.__getitem__), dtype=np.int64)


#: The multiplier of the ids' hash (2^64 / golden ratio, odd).
_MIX = np.uint64(0x9E3779B97F4A7C15)


def id_array_problems(raw: np.ndarray, step: np.ndarray) -> list[tuple[str, str]]:
    """The rules of state ids (non-empty, UTF-8, unique, rows in (step, id) order) checked
    on the binary form's fixed-width bytes (``raw``: numpy ``S``, trailing NULs pad) with
    array operations, no string per state. UTF-8's byte order is code point order, the
    order of Python's strings; uniqueness across steps goes by a 64-bit hash of each id,
    ids whose hashes meet compared exactly."""
    n, width = len(raw), raw.dtype.itemsize
    if n == 0:
        return []
    if width == 0:
        return [("ids", "state ids must be non-empty strings")]
    raw = np.ascontiguousarray(raw)
    cells = raw.view(np.uint8).reshape(n, width)
    if width % 8:
        cells = np.concatenate([cells, np.zeros((n, -width % 8), np.uint8)], axis=1)
    words = cells.view(np.uint64)
    h = words[:, 0].copy()
    empty = h == 0
    for j in range(1, words.shape[1]):
        empty &= words[:, j] == 0
        h *= _MIX
        h ^= words[:, j]
    if empty.any():
        return [("ids", f"row {int(np.argmax(empty))}: state ids must be non-empty strings")]
    try:
        raw.tobytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        return [("ids", f"row {exc.start // width}: not UTF-8")]
    split = (cells[:, 0] & 0xC0) == 0x80  # a character begun at the end of the row before
    if split.any():
        return [("ids", f"row {int(np.argmax(split))}: not UTF-8")]
    same = step[1:] == step[:-1]
    less, equal = _compare_rows(cells)
    if not bool((same <= less).all()):
        twice = np.flatnonzero(same & equal)
        if len(twice):
            return [("ids", _twice(raw, int(twice[0]), int(twice[0]) + 1))]
        return [("ids", "states must be in (step, id) order, as the JSON form lays them out")]
    h ^= h >> np.uint64(29)
    h *= _MIX
    h ^= h >> np.uint64(32)
    bits = (4 * n - 1).bit_length()
    slot = (h >> np.uint64(64 - bits)).astype(np.intp)
    crowded = np.flatnonzero(np.bincount(slot, minlength=1 << bits)[slot] > 1)
    hs = np.sort(h[crowded])
    tied = np.unique(hs[1:][hs[1:] == hs[:-1]])
    if len(tied):  # equal hashes (all but certain for equal ids): compare the ids
        first: dict[bytes, int] = {}
        for r in np.flatnonzero(np.isin(h, tied)).tolist():
            seen = first.setdefault(bytes(raw[r]), r)
            if seen != r:
                return [("ids", _twice(raw, seen, r))]
    return []


def _compare_rows(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row of bytes (n, 8w) against the next, in byte order: (less, equal), n - 1 each;
    eight bytes at a time, as big-endian words."""
    words = cells.view(">u8").astype(np.uint64)
    less = np.zeros(len(cells) - 1, dtype=bool)
    equal = np.ones(len(cells) - 1, dtype=bool)
    for j in range(words.shape[1]):
        a, b = words[:-1, j], words[1:, j]
        less |= equal & (a < b)
        equal &= a == b
    return less, equal


def _twice(raw: np.ndarray, a: int, b: int) -> str:
    return f"state ids must be unique: {show(bytes(raw[b]).decode())} at rows {a} and {b}"


def _first_index(ids: list[str]) -> dict[str, int]:
    """id -> the row of its first occurrence."""
    n = len(ids)
    index = dict(zip(ids, range(n), strict=True))
    if len(index) < n:
        index = dict(zip(reversed(ids), range(n - 1, -1, -1), strict=True))
    return index


def _endpoints(parts: Parts, index: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """The rows of the transitions' endpoints (first occurrences), −1 for unknown ids."""
    return _lookup(index, parts.src), _lookup(index, parts.dst)


def _lookup(index: dict[str, int], keys: list[str]) -> np.ndarray:
    try:
        return np.array(list(map(index.__getitem__, keys)), dtype=np.int64).reshape(-1)
    except KeyError:
        return np.fromiter(map(index.get, keys, repeat(-1)), dtype=np.int64, count=len(keys))


def _check_parts(
    parts: Parts,
    index: dict[str, int],
    src: np.ndarray,
    dst: np.ndarray,
    dim: int,
    head: list[tuple[str, str]],
    path: str,
) -> None:
    """Duplicate ids, sizes of s and P, endpoints, steps, payoffs, duplicate pairs."""
    ids = parts.ids
    n = len(ids)
    rep = Report()
    rows = np.arange(n, dtype=np.int64)
    dup = np.zeros(n, dtype=bool)
    if len(index) < n:
        first = np.fromiter(map(index.__getitem__, ids), dtype=np.int64, count=n)
        dup = first != rows
        for i in np.flatnonzero(dup).tolist():
            rep.add((0, i, 0), f"state '{ids[i]}'", "duplicate state id")
    for i in np.flatnonzero(~dup & (parts.s_len != dim)).tolist():
        rep.add((0, i, 1), f"state '{ids[i]}'", f"s has {parts.s_len[i]} entries, expected {dim}")
    shape = parts.P_shape
    bad_p = ~dup & (shape[:, 0] >= 0) & ((shape[:, 0] != dim) | (shape[:, 1] != dim))
    for i in np.flatnonzero(bad_p).tolist():
        got = f"{shape[i, 0]}x{shape[i, 1]}"
        rep.add((0, i, 2), f"state '{ids[i]}'", f"P must be {dim}x{dim}, got {got}")

    def item(j: int) -> str:
        return f"transition {j} ({parts.src[j]} -> {parts.dst[j]})"

    unknown = (src < 0) | (dst < 0)
    for j in np.flatnonzero(unknown).tolist():
        missing = parts.src[j] if src[j] < 0 else parts.dst[j]
        rep.add((1, j, 0), item(j), f"unknown state '{missing}'")
    check_transitions(rep, np.flatnonzero(~unknown), src, dst, parts.step, parts.payoff, item)
    rep.raise_if_any(path, head)


def check_transitions(
    rep: Report,
    known: np.ndarray | None,
    src: np.ndarray,
    dst: np.ndarray,
    step: np.ndarray,
    payoff: np.ndarray,
    item: Callable[[int], str],
) -> None:
    """The transitions ``known`` (with known endpoints; None: all of them): one step up,
    payoff finite and >= 0, no second transition between the same states."""
    n = step.shape[0]
    if known is not None:
        src, dst, payoff = src[known], dst[known], payoff[known]

    def index(at: np.ndarray) -> list[int]:  # positions among the checked -> transitions
        out: list[int] = (at if known is None else known[at]).tolist()
        return out

    ks, kd = step[src], step[dst]
    jump = np.flatnonzero(kd != ks + 1)
    for j, a, b in zip(index(jump), ks[jump].tolist(), kd[jump].tolist(), strict=True):
        rep.add((1, j, 1), item(j), f"goes from step {a} to step {b}; must go to step {a + 1}")
    if payoff.size and not (payoff.min() >= 0 and payoff.max() < np.inf):  # NaN: not >= 0
        bad = np.flatnonzero(~(np.isfinite(payoff) & (payoff >= 0)))
        for j, v in zip(index(bad), payoff[bad].tolist(), strict=True):
            rep.add((1, j, 2), item(j), f"payoff must be finite and >= 0, got {v}")
    if src.size > 1:
        key = src * n + dst
        if bool((key[1:] > key[:-1]).all()):  # increasing (as lesmc lays models out): distinct
            return
        o = np.argsort(key, kind="stable")
        again = np.zeros(src.size, dtype=bool)
        again[o[1:]] = key[o[1:]] == key[o[:-1]]
        for j in index(np.flatnonzero(again)):
            rep.add((1, j, 3), item(j), "a second transition between the same states")


def _check_paths(
    rep: Report,
    parts: Parts,
    index: dict[str, int],
    pos: np.ndarray,
    rows: Rows,
) -> np.ndarray | None:
    """Initial, original path, reachability, steps beyond e, halting; the original's rows."""
    initial, original = parts.initial, parts.original
    if initial not in index:
        rep.add((1, 0, 0), "initial", f"unknown state '{initial}'")
        return None
    q0 = int(pos[index[initial]])
    if rows.step[q0] != 0:
        rep.add((1, 0, 1), "initial", f"state '{initial}' must be at step 0")
    if not original:
        rep.add((1, 0, 2), "original", "the original path is empty")
        return None
    if original[0] != initial:
        rep.add((1, 0, 2), "original", f"must start at the initial state '{initial}'")
    found = _lookup(index, original)
    missing = np.flatnonzero(found < 0)
    stop = int(missing[0]) if missing.size else len(original)
    op: np.ndarray = pos[found[:stop]]
    check_original(rep, original, op, rows)
    if missing.size:
        rep.add((2, stop, 0), f"original[{stop}]", f"unknown state '{original[stop]}'")
        return None
    check_states(rep, q0, len(original) - 1, rows)
    return op


def _covariances(
    parts: Parts, perm: np.ndarray | None, dim: int
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """cov (row -> table index, −1: none) and the distinct P's, in order of first use."""
    has = parts.P_shape[:, 0] >= 0
    if not has.any():
        return None, None
    n = has.shape[0]
    which = np.full(n, -1, dtype=np.int64)  # file row -> its P among those present
    which[has] = np.arange(int(has.sum()), dtype=np.int64)
    if perm is not None:
        which = which[perm]
    rows = parts.P_flat.reshape(-1, dim * dim)
    present = which >= 0
    table, inverse = dedup_rows(rows[which[present]])
    cov = np.full(n, -1, dtype=np.int64)
    cov[present] = inverse
    return cov, table.reshape(-1, dim, dim)


def dedup_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of a float64 (p, k) array by exact bytes, in order of first
    appearance, and each row's index among them."""
    rows = np.ascontiguousarray(rows, dtype=np.float64)
    p, k = rows.shape
    if p == 0:
        return rows, np.zeros(0, dtype=np.int64)
    bits = rows.view(np.int64)
    if k <= _HASH.shape[0]:
        h = bits @ _HASH[:k]  # wraps around: a hash of the exact bit patterns
        _, first, inverse = np.unique(h, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        if not np.array_equal(bits, bits[first[inverse]]):  # a hash collision: compare bytes
            first, inverse = _unique_bytes(bits)
    else:
        first, inverse = _unique_bytes(bits)
    o = np.argsort(first, kind="stable")
    renumber = np.empty_like(o)
    renumber[o] = np.arange(o.shape[0], dtype=np.int64)
    return rows[first[o]], renumber[inverse].astype(np.int64)


def _unique_bytes(bits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    void = bits.view(np.dtype((np.void, bits.shape[1] * 8))).reshape(-1)
    _, first, inverse = np.unique(void, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def _observations(
    obs: list[str | None] | None, torder: np.ndarray
) -> tuple[np.ndarray | None, tuple[str, ...]]:
    if obs is None:
        return None, ()
    distinct = set(obs)
    distinct.discard(None)
    if not distinct:
        return None, ()
    names = sorted(n for n in distinct if n is not None)
    code: dict[str | None, int] = {name: i for i, name in enumerate(names)}
    code[None] = -1
    codes = np.array(list(map(code.__getitem__, obs)), dtype=np.int64).reshape(-1)
    return codes[torder], tuple(names)


def check_tracks(raw: Any, components: tuple[str, ...], steps: int, pr: Problems) -> Tracks | None:
    """A model's ``tracks`` (the JSON form's object, or the binary form's header entry with
    its array as ``at``): ground-truth tracks over some of the model's components, one row
    per step 0..e, ``null`` (NaN) where a track is absent. Problems go to ``pr``."""
    if not isinstance(raw, dict) or set(raw) != {"components", "ids", "at"}:
        pr.add("tracks", "must be an object with components, ids and the positions")
        return None
    comps, ids, at = raw["components"], raw["ids"], raw["at"]
    if not (
        isinstance(comps, list)
        and comps
        and len(set(comps)) == len(comps)
        and all(isinstance(c, str) and c in components for c in comps)
    ):
        pr.add("tracks.components", f"must be distinct components of the model, got {comps!r:.80}")
        return None
    if not (isinstance(ids, list) and all(isinstance(i, str) and i for i in ids)) or len(
        set(ids)
    ) != len(ids):
        pr.add("tracks.ids", "must be distinct non-empty strings")
        return None
    want = (len(ids), steps, len(comps))
    if not isinstance(at, np.ndarray) or at.dtype != np.float64 or at.shape != want:
        got = at.shape if isinstance(at, np.ndarray) else type(at).__name__
        pr.add(
            "tracks", f"positions must be {want[0]} tracks x {steps} steps x {want[2]}, got {got}"
        )
        return None
    absent = np.isnan(at)
    if np.isinf(at).any() or (absent.any(axis=2) != absent.all(axis=2)).any():
        pr.add("tracks", "a position is finite numbers, or absent as a whole (null)")
        return None
    empty = np.nonzero(absent.all(axis=(1, 2)))[0]
    if empty.size:
        pr.add(f"track '{ids[int(empty[0])]}'", "is absent at every step")
        return None
    return Tracks(tuple(comps), tuple(ids), at)


def meta_problems(meta: Any, item: str = "meta") -> list[tuple[str, str]]:
    """What is wrong with the keys of a model's ``meta`` that lesmc reads (docs/lts-format.md):
    ``first_frame`` an integer in 0..10^6, ``window`` two such integers in order,
    ``design`` a string; every other key is the writer's and ignored (as is a ``meta``
    that is not an object, in the JSON form)."""
    if not isinstance(meta, dict):
        return []

    def step(v: Any) -> bool:
        return isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_STEP

    out = []
    if "first_frame" in meta and not step(meta["first_frame"]):
        out.append((f"{item}.first_frame", f"must be an integer in 0..{MAX_STEP}"))
    w = meta.get("window")
    if "window" in meta and not (
        isinstance(w, list) and len(w) == 2 and all(map(step, w)) and w[0] <= w[1]
    ):
        out.append((f"{item}.window", "must be [L, U], integers with L <= U"))
    if "design" in meta and not isinstance(meta["design"], str):
        out.append((f"{item}.design", "must be a string"))
    return out
