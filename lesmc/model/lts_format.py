"""The explicit model file (.lts, JSON): reading with full validation, atomic writing.

The format is documented in docs/lts-format.md. Nothing in a file is executed;
every field is type-checked and every problem is reported with the offending id.

Here: the top level and ``tracks`` read (:func:`load_lts`, :func:`lts_from_dict`)
and the document written (:func:`lts_to_dict`, :func:`lts_document`,
:func:`save_lts`). Reading goes straight from the decoded JSON to an
:class:`~lesmc.model.arrays.ArrayModel`: the states and transitions are checked
column by column in :mod:`lesmc.model.lts_columns`, the model built from their
arrays by :mod:`lesmc.model.validate`.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import ModelError, Problems
from lesmc.common.fields import header, is_name
from lesmc.common.files import EncodedItems, read_json, write_json
from lesmc.model.arrays import ArrayModel, Tracks
from lesmc.model.lts_columns import States, Transitions, is_number, show
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


def _rows_of(data: dict[str, Any], pr: Problems) -> tuple[States, Transitions]:
    """The document's states and transitions, each column type-checked."""
    raw_states = data.get("states")
    raw_trans = data.get("transitions")
    if not isinstance(raw_states, list) or not raw_states:
        pr.add("states", "must be a non-empty list")
        raw_states = []
    if not isinstance(raw_trans, list):
        pr.add("transitions", "must be a list")
        raw_trans = []
    return States(raw_states), Transitions(raw_trans)


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
            if not (isinstance(v, list) and len(v) == width and all(map(is_number, v))):
                pr.add(
                    f"tracks.paths[{i}].at[{k}]", f"must be null or {width} numbers, got {show(v)}"
                )
                break
            at[i, k] = v
    if not pr.items:
        check = check_tracks({"components": comps, "ids": ids, "at": at}, cm.components, steps, pr)
        if check is not None:
            return check
    raise ModelError.many(path, pr.items)


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
