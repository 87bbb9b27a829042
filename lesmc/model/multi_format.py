"""The file of a built multi-target model (:class:`~lesmc.model.multi.MultiModel`): its
arrays in a NumPy ``.npz`` archive, as the binary form of the single-target models
(lesmc/model/lts_binary.py, whose writer and reader this module calls), with a JSON
``header`` of format ``lesmc-multi-npz`` (docs/lts-format.md, "Multi-target models").

``lesmc build SCENE --design sort|gnn -o MODEL.npz`` writes it, ``lesmc check MODEL SPEC``
and ``lesmc export MODEL --format drn|prism`` read it. Reading never unpickles (object
arrays are refused by the shared reader); every array's dtype and shape is checked, then
every rule the engine relies on (levels, indices, the subsets' lengths): a bad file is a
located :class:`~lesmc.common.errors.ModelError` (exit status 2), never an internal error.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.errors import ModelError, Problems
from lesmc.common.fields import MAX_STEP, header, is_int, show
from lesmc.common.files import atomic_open
from lesmc.language import actions
from lesmc.model.arrays import ArrayModel
from lesmc.model.identity import NONE
from lesmc.model.lts_binary import (
    MULTI_FORMAT,
    check_present,
    header_object,
    is_binary,
    lts_from_arrays,
    read_npz,
    write_npz,
)
from lesmc.model.multi import MultiModel

FORMAT = MULTI_FORMAT
VERSION = 1

#: The per-state arrays (n states) and per-transition arrays (t transitions): dtype, ndim.
STATES = {
    "step": (np.int64, 1),
    "tid": (np.int64, 1),
    "ref": (np.bool_, 1),
    "last": (np.int64, 1),
    "box": (np.float64, 2),
    "gone": (np.bool_, 1),
}
TRANSITIONS = {
    "src": (np.int64, 1),
    "dst": (np.int64, 1),
    "payoff": (np.float64, 1),
    "count": (np.int64, 1),
}
#: The cheapest options of each transition, as CSR: ``NAME_ptr`` (t + 1) and ``NAME``.
SUBSETS = ("by_payoff", "by_count")
ARRAYS = (
    STATES
    | TRANSITIONS
    | {"refbox": (np.float64, 2), "header": (np.uint8, 1)}
    | {f"{n}{s}": (np.int64, 1) for n in SUBSETS for s in ("", "_ptr")}
)
_HEADER_KEYS = {"format", "version", "end", "window", "target", "frames", "names", "detections"}
_HEADER_KEYS |= {"meta"}
#: What ``meta`` holds (MultiModel.meta), each checked on reading.
META_KEYS = ("design", "tracker", "reference", "radius", "actions", "last_step", "unpriced")


def is_multi(model: object) -> bool:
    """Whether ``model`` is a multi-target model (the verbs dispatch on it)."""
    return isinstance(model, MultiModel)


def save_multi(model: MultiModel, path: str | Path) -> None:
    """Write ``model`` (with its ``meta``) as a ``lesmc-multi-npz`` file, atomically."""
    head = {
        "format": FORMAT,
        "version": VERSION,
        "end": model.end,
        "window": list(model.window),
        "target": model.target,
        "frames": list(model.frames),
        "names": [list(n) for n in model.names],
        "detections": list(model.detections),
        "meta": {k: model.meta.get(k) for k in META_KEYS},
    }
    arrays: dict[str, np.ndarray] = {n: getattr(model, n) for n in (*STATES, *TRANSITIONS)}
    arrays["refbox"] = model.refbox
    for name in SUBSETS:
        arrays[f"{name}_ptr"], arrays[name] = _csr(getattr(model, name))
    blob = np.frombuffer(json.dumps(head, allow_nan=False).encode(), dtype=np.uint8)
    with atomic_open(path, binary=True) as fh:
        write_npz(fh, {"header": blob, **arrays})


def load_model_file(path: str | Path) -> ArrayModel | MultiModel:
    """A built model of either kind: a ``.npz`` file is read once and told apart by its
    header's format; anything else is a single-target ``.lts`` (JSON)."""
    from lesmc.model.lts_format import load_lts

    where = str(path)
    if not is_binary(where):
        return load_lts(where)
    arrays = read_npz(where)
    if _format_of(arrays.get("header")) == FORMAT:
        return multi_from_arrays(arrays, where)
    return lts_from_arrays(arrays, where)


def load_multi(path: str | Path) -> MultiModel:
    """A multi-target model file, validated."""
    where = str(path)
    return multi_from_arrays(read_npz(where), where)


def _format_of(blob: Any) -> Any:
    """The ``format`` of a header array, if it is a JSON object that has one."""
    if not isinstance(blob, np.ndarray) or blob.dtype != np.uint8 or blob.ndim != 1:
        return None
    try:
        data = json.loads(blob.tobytes())
    except (ValueError, RecursionError):
        return None
    return data.get("format") if isinstance(data, dict) else None


def multi_from_arrays(arrays: dict[str, np.ndarray], where: str) -> MultiModel:
    """Validate the arrays of a ``lesmc-multi-npz`` file read from ``where`` and build its
    model; every problem is a located ModelError."""
    check_present(arrays, where, dict(ARRAYS), {})
    head = _header(arrays["header"], where)
    pr = Problems()
    _check_states(arrays, head, pr)
    if not pr.items:
        _check_transitions(arrays, head, pr)
    subsets: dict[str, tuple[tuple[int, ...], ...]] = {}
    if not pr.items:
        for name in SUBSETS:
            subsets[name] = _subsets(arrays, name, head, pr)
    if not pr.items:
        got = np.array([len(s) for s in subsets["by_count"]], dtype=np.int64)
        bad = np.nonzero(got != arrays["count"])[0]
        if bad.size:
            t = int(bad[0])
            pr.add(
                f"array 'count'[{t}]",
                f"must be by_count[{t}]'s length {int(got[t])}, got {int(arrays['count'][t])}",
            )
    if pr.items:
        raise ModelError.many(where, pr.items)
    return MultiModel(
        step=arrays["step"],
        tid=arrays["tid"],
        ref=arrays["ref"],
        last=arrays["last"],
        src=arrays["src"],
        dst=arrays["dst"],
        payoff=arrays["payoff"],
        count=arrays["count"],
        by_payoff=subsets["by_payoff"],
        by_count=subsets["by_count"],
        frames=tuple(head["frames"]),
        names=tuple(tuple(n) for n in head["names"]),
        end=head["end"],
        window=(head["window"][0], head["window"][1]),
        box=arrays["box"],
        gone=arrays["gone"],
        refbox=arrays["refbox"],
        target=head["target"],
        detections=tuple(head["detections"]),
        meta=head["meta"],
    )


def _csr(rows: tuple[tuple[int, ...], ...]) -> tuple[np.ndarray, np.ndarray]:
    """Rows of indices as CSR: the offsets (len(rows) + 1) and the indices."""
    ptr = np.zeros(len(rows) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(r) for r in rows])
    flat = np.fromiter((j for r in rows for j in r), dtype=np.int64, count=int(ptr[-1]))
    return ptr, flat


def _header(blob: np.ndarray, where: str) -> dict[str, Any]:
    """The header's JSON, each field checked (``header.FIELD`` in messages)."""
    data = header_object(blob, where)
    pr = Problems()
    header(data, FORMAT, VERSION, pr)
    for key in sorted(set(data) ^ _HEADER_KEYS):
        pr.add(f"header.{key}", "unknown key" if key in data else "missing")
    if pr.items:
        raise ModelError.many(where, pr.items)
    end, window = data["end"], data["window"]
    if not (is_int(end) and 1 <= end <= MAX_STEP):
        pr.add("header.end", f"must be a step >= 1, got {show(end)}")
    elif not (
        isinstance(window, list)
        and len(window) == 2
        and all(is_int(v) for v in window)
        and 1 <= window[0] <= window[1] <= end
    ):
        pr.add(
            "header.window", f"must be [l, u] with 1 <= l <= u <= end = {end}, got {show(window)}"
        )
    if not (is_int(data["target"]) and data["target"] >= NONE):
        pr.add("header.target", f"must be a track id (-1: none), got {show(data['target'])}")
    if not pr.items:
        _per_step(data, pr)
        _meta(data["meta"], end, pr, None if pr.items else data["names"])
    if pr.items:
        raise ModelError.many(where, pr.items)
    return data


def _per_step(data: dict[str, Any], pr: Problems) -> None:
    """``frames``, ``names`` and ``detections``: one entry per step 0..end."""
    steps = data["end"] + 1
    frames, names, dets = data["frames"], data["names"], data["detections"]
    if not (isinstance(frames, list) and len(frames) == steps and all(map(is_int, frames))):
        pr.add("header.frames", f"must be {steps} frame numbers (one per step 0..end)")
    elif any(b <= a for a, b in itertools.pairwise(frames)):
        pr.add("header.frames", f"must increase from step to step, got {show(frames)}")
    ok = isinstance(names, list) and len(names) == steps
    for k, row in enumerate(names if ok else []):
        if not (isinstance(row, list) and all(isinstance(x, str) for x in row)):
            pr.add(f"header.names[{k}]", "must be a list of detection ids")
            return
        if len(set(row)) != len(row):
            dup = next(x for i, x in enumerate(row) if x in row[:i])
            pr.add(f"header.names[{k}]", f"must name each detection once, got {show(dup)} twice")
            return
    if not ok:
        pr.add("header.names", f"must be {steps} lists of detection ids (one per step 0..end)")
        return
    if not (isinstance(dets, list) and len(dets) == steps):
        pr.add("header.detections", f"must be {steps} counts (one per step 0..end)")
        return
    for k, (n, row) in enumerate(zip(dets, names, strict=True)):
        if not (is_int(n) and 0 <= n <= len(row)):
            pr.add(
                f"header.detections[{k}]",
                f"must be a count 0..{len(row)} (step {k}'s names), got {show(n)}",
            )
            return


def _meta(meta: Any, end: int, pr: Problems, names: list[list[str]] | None = None) -> None:
    """``meta``: what the model was built for (:data:`META_KEYS`); ``names``, the steps'
    names when they are valid, for ``unpriced``'s detection."""
    if not isinstance(meta, dict) or set(meta) != set(META_KEYS):
        pr.add("header.meta", f"must be an object with keys {', '.join(META_KEYS)}")
        return
    if not isinstance(meta["design"], str) or not meta["design"]:
        pr.add("header.meta.design", f"must be a design's name, got {show(meta['design'])}")
    if not isinstance(meta["tracker"], dict):
        pr.add("header.meta.tracker", "must be an object (the tracker's parameters)")
    if meta["reference"] not in ("truth", "unattacked"):
        pr.add(
            "header.meta.reference",
            f'must be "truth" or "unattacked", got {show(meta["reference"])}',
        )
    r = meta["radius"]
    if r is not None and not (
        isinstance(r, int | float) and not isinstance(r, bool) and math.isfinite(r) and r >= 0
    ):
        pr.add("header.meta.radius", f"must be null or a radius >= 0, got {show(r)}")
    acts = meta["actions"]
    if not (
        isinstance(acts, list)
        and acts
        and all(a in actions.names() for a in acts)
        and len(set(acts)) == len(acts)
    ):
        pr.add(
            "header.meta.actions",
            f"must be a non-empty list of {', '.join(actions.names())}, got {show(acts)}",
        )
    last = meta["last_step"]
    if not (is_int(last) and end <= last <= MAX_STEP):
        pr.add("header.meta.last_step", f"must be the scene's last step (>= end = {end})")
    un = meta["unpriced"]
    if un is not None and not (
        isinstance(un, list)
        and len(un) == 2
        and is_int(un[0])
        and 0 <= un[0] <= end
        and isinstance(un[1], str)
    ):
        pr.add("header.meta.unpriced", f"must be null or [step, detection id], got {show(un)}")
    elif un is not None and names is not None and un[1] not in names[un[0]]:
        pr.add("header.meta.unpriced", f"{show(un[1])} is no detection of step {un[0]}")


def _check_states(arrays: dict[str, np.ndarray], head: dict[str, Any], pr: Problems) -> None:
    """The per-state arrays: one length, levels 0..end in order, ids >= -1."""
    step = arrays["step"]
    n = step.shape[0]
    if n == 0:
        pr.add("array 'step'", "must hold at least the initial state")
        return
    for name, (_, ndim) in STATES.items():
        want = (n, 4) if ndim == 2 else (n,)
        if arrays[name].shape != want:
            pr.add(
                f"array '{name}'",
                f"must have shape {want} (one per state), got {arrays[name].shape}",
            )
    end = head["end"]
    if arrays["refbox"].shape != (end + 1, 4):
        pr.add("array 'refbox'", f"must have shape {(end + 1, 4)} (one box per step 0..end)")
    if pr.items:
        return
    if step[0] != 0 or (n > 1 and step[1] == 0):
        pr.add("array 'step'", "state 0 must be the only state of step 0")
    elif np.any(np.diff(step) < 0) or np.any(np.diff(step) > 1) or step[-1] > end:
        pr.add("array 'step'", f"must number the states level by level, steps 0..{end} in order")
    for name in ("box", "refbox"):  # nan: no box; every other entry finite
        infinite = np.argwhere(np.isinf(arrays[name]))
        if infinite.size:
            i, j = (int(v) for v in infinite[0])
            pr.add(
                f"array '{name}'[{i}, {j}]",
                f"must be finite (nan: no box), got {float(arrays[name][i, j])}",
            )
    for name in ("tid", "last"):
        bad = np.nonzero(arrays[name] < NONE)[0]
        if bad.size:
            pr.add(
                f"array '{name}'[{int(bad[0])}]",
                f"must be a track id (-1: none), got {int(arrays[name][bad[0]])}",
            )


def _check_transitions(arrays: dict[str, np.ndarray], head: dict[str, Any], pr: Problems) -> None:
    """The per-transition arrays: one length, each from a state to one of the next level."""
    src, dst = arrays["src"], arrays["dst"]
    t = src.shape[0]
    for name in TRANSITIONS:
        if arrays[name].shape != (t,):
            pr.add(
                f"array '{name}'",
                f"must have shape {(t,)} (one per transition), got {arrays[name].shape}",
            )
    if pr.items:
        return
    n = arrays["step"].shape[0]
    for name, a in (("src", src), ("dst", dst)):
        bad = np.nonzero((a < 0) | (a >= n))[0]
        if bad.size:
            pr.add(
                f"array '{name}'[{int(bad[0])}]",
                f"must be a state 0..{n - 1}, got {int(a[bad[0]])}",
            )
    if pr.items:
        return
    step = arrays["step"]
    bad = np.nonzero(step[dst] != step[src] + 1)[0]
    if bad.size:
        i = int(bad[0])
        pr.add(
            f"transition {i}",
            f"must go from a state of step k to one of step k + 1 ({int(src[i])} -> {int(dst[i])})",
        )
    pay = arrays["payoff"]
    bad = np.nonzero(~(np.isnan(pay) | ((pay >= 0) & np.isfinite(pay))))[0]
    if bad.size:
        pr.add(
            f"array 'payoff'[{int(bad[0])}]",
            f"must be a finite payoff >= 0 (nan: unpriced), got {float(pay[bad[0]])!r}",
        )
    unpriced = np.nonzero(np.isnan(pay))[0]
    if unpriced.size and head["meta"]["unpriced"] is None:
        pr.add(
            f"array 'payoff'[{int(unpriced[0])}]",
            "is nan (an unpriced detection hidden), but header.meta.unpriced is null",
        )


def _subsets(
    arrays: dict[str, np.ndarray], name: str, head: dict[str, Any], pr: Problems
) -> tuple[tuple[int, ...], ...]:
    """The CSR rows ``name`` as tuples: each transition's distinct indices into its
    step's names, in increasing order."""
    ptr, flat = arrays[f"{name}_ptr"], arrays[name]
    t = arrays["src"].shape[0]
    if ptr.shape != (t + 1,) or ptr[0] != 0 or ptr[-1] != flat.shape[0] or np.any(np.diff(ptr) < 0):
        pr.add(
            f"array '{name}_ptr'", f"must be {t + 1} offsets from 0 up to the length of '{name}'"
        )
        return ()
    sizes = np.array([len(n) for n in head["names"]], dtype=np.int64)
    row = np.repeat(np.arange(t), np.diff(ptr))
    limit = sizes[arrays["step"][arrays["dst"]]][row]
    bad = np.nonzero((flat < 0) | (flat >= limit))[0]
    if bad.size:
        i = int(row[bad[0]])
        pr.add(
            f"array '{name}' of transition {i}",
            f"index {int(flat[bad[0]])} names no detection of its step",
        )
        return ()
    rising = np.ones(flat.shape[0], dtype=bool)
    rising[1:] = (flat[1:] > flat[:-1]) | (row[1:] != row[:-1])
    bad = np.nonzero(~rising)[0]
    if bad.size:
        pr.add(
            f"array '{name}' of transition {int(row[bad[0]])}",
            "indices must be distinct and increasing",
        )
        return ()
    cuts = ptr.tolist()
    values = flat.tolist()
    return tuple(tuple(values[a:b]) for a, b in itertools.pairwise(cuts))
