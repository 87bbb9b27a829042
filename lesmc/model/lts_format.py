"""The explicit model file (.lts, JSON): reading with full validation, atomic writing.

The format is documented in docs/lts-format.md. Nothing in a file is executed;
every field is type-checked and every problem is reported with the offending id.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np

from lesmc.errors import ModelError, Problems
from lesmc.fileio import read_json, write_json
from lesmc.model.lts import LTS, State, Transition

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
}
_STATE_KEYS = {"id", "step", "s", "P", "labels", "meta"}
_TRANS_KEYS = {"src", "dst", "payoff", "rank", "obs"}


def load_lts(path: str | Path) -> LTS:
    """Read and validate a .lts file."""
    return lts_from_dict(read_json(path, ModelError), str(path))


def lts_from_dict(data: Any, path: str = "<model>") -> LTS:
    """Validate a decoded .lts document and build the model."""
    pr = Problems()
    if not isinstance(data, dict):
        raise ModelError.many(path, [("", "the top level must be a JSON object")])
    for key in sorted(set(data) - _TOP_KEYS):
        pr.add(f"key '{key}'", "unknown top-level key")
    if data.get("format") != FORMAT:
        pr.add("format", f'must be "{FORMAT}", got {data.get("format")!r}')
    if data.get("version") != VERSION:
        pr.add("version", f"must be {VERSION}, got {data.get('version')!r}")
    components = data.get("components")
    if components is not None and not (
        isinstance(components, list) and components and all(_is_name(c) for c in components)
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
    raw_states = data.get("states")
    raw_trans = data.get("transitions")
    if not isinstance(raw_states, list) or not raw_states:
        pr.add("states", "must be a non-empty list")
        raw_states = []
    if not isinstance(raw_trans, list):
        pr.add("transitions", "must be a list")
        raw_trans = []
    states = [s for i, r in enumerate(raw_states) if (s := _state(r, i, pr)) is not None]
    trans = [t for i, r in enumerate(raw_trans) if (t := _transition(r, i, pr)) is not None]
    if pr.items:
        raise ModelError.many(path, pr.items)
    model = LTS.from_parts(states, trans, str(initial), original, components, path)
    meta = data.get("meta")
    if isinstance(meta, dict):
        model.meta = meta
    return model


def _state(raw: Any, i: int, pr: Problems) -> State | None:
    if not isinstance(raw, dict):
        pr.add(f"states[{i}]", "must be an object")
        return None
    sid = raw.get("id")
    item = f"state '{sid}'" if isinstance(sid, str) and sid else f"states[{i}]"
    ok = True
    if not (isinstance(sid, str) and sid):
        pr.add(item, "id must be a non-empty string")
        ok = False
    for key in sorted(set(raw) - _STATE_KEYS):
        pr.add(item, f"unknown key '{key}'")
        ok = False
    step = raw.get("step")
    if not _is_int(step) or step < 0:
        pr.add(item, f"step must be an integer >= 0, got {step!r}")
        ok = False
    s = _vector(raw.get("s"))
    if s is None:
        pr.add(item, "s must be a non-empty list of finite numbers")
        ok = False
    P = None
    if "P" in raw:
        P = _matrix(raw["P"])
        if P is None:
            pr.add(item, "P must be a square list of lists of finite numbers")
            ok = False
    labels = raw.get("labels", [])
    if not (isinstance(labels, list) and all(isinstance(x, str) for x in labels)):
        pr.add(item, "labels must be a list of strings")
        ok = False
    if not ok:
        return None
    return State(str(sid), int(step), s, P, frozenset(labels))  # type: ignore[arg-type]


def _transition(raw: Any, i: int, pr: Problems) -> Transition | None:
    item = f"transitions[{i}]"
    if not isinstance(raw, dict):
        pr.add(item, "must be an object")
        return None
    src, dst = raw.get("src"), raw.get("dst")
    if isinstance(src, str) and isinstance(dst, str):
        item = f"transition {i} ({src} -> {dst})"
    ok = True
    for key in sorted(set(raw) - _TRANS_KEYS):
        pr.add(item, f"unknown key '{key}'")
        ok = False
    if not (isinstance(src, str) and isinstance(dst, str)):
        pr.add(item, "src and dst must be state ids")
        ok = False
    payoff = raw.get("payoff")
    if not _is_number(payoff) or not math.isfinite(payoff) or payoff < 0:
        pr.add(item, f"payoff must be a finite number >= 0, got {payoff!r}")
        ok = False
    rank = raw.get("rank")
    if not _is_int(rank):
        pr.add(item, f"rank must be an integer, got {rank!r}")
        ok = False
    obs = raw.get("obs")
    if obs is not None and not isinstance(obs, str):
        pr.add(item, "obs must be a string or absent")
        ok = False
    if not ok:
        return None
    return Transition(str(src), str(dst), float(payoff), int(rank), obs)  # type: ignore[arg-type]


def lts_to_dict(model: LTS) -> dict[str, Any]:
    """The JSON document of a model (states in step order, transitions in rank order)."""
    states = sorted(model.states(), key=lambda st: (st.step, st.id))
    doc_states = []
    for st in states:
        d: dict[str, Any] = {"id": st.id, "step": st.step, "s": [float(x) for x in st.s]}
        if st.P is not None:
            d["P"] = [[float(x) for x in row] for row in st.P]
        if st.labels:
            d["labels"] = sorted(st.labels)
        doc_states.append(d)
    doc_trans = []
    for st in states:
        for t in model.out(st.id):
            d = {"src": t.src, "dst": t.dst, "payoff": t.payoff, "rank": t.rank}
            if t.obs is not None:
                d["obs"] = t.obs
            doc_trans.append(d)
    return {
        "format": FORMAT,
        "version": VERSION,
        "components": list(model.components),
        "initial": model.initial,
        "original": list(model.original),
        "states": doc_states,
        "transitions": doc_trans,
        **({"meta": model.meta} if model.meta else {}),
    }


def save_lts(model: LTS, path: str | Path) -> None:
    """Write a model atomically."""
    write_json(path, lts_to_dict(model))


def _is_int(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_number(x: Any) -> TypeGuard[int | float]:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _is_name(x: Any) -> bool:
    return isinstance(x, str) and x.isidentifier()


def _vector(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and raw and all(_is_number(x) for x in raw)):
        return None
    v = np.asarray(raw, dtype=float)
    return v if np.all(np.isfinite(v)) else None


def _matrix(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and raw and all(isinstance(r, list) for r in raw)):
        return None
    n = len(raw)
    if any(len(r) != n or not all(_is_number(x) for x in r) for r in raw):
        return None
    m = np.asarray(raw, dtype=float)
    return m if np.all(np.isfinite(m)) else None
