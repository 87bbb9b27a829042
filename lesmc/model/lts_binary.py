"""The binary form of a model: the arrays of an ArrayModel in a NumPy ``.npz`` file.

``lesmc build -o MODEL.npz`` writes it and ``lesmc check MODEL.npz`` reads it
(docs/lts-format.md, "Binary form"): the JSON ``.lts`` stays the interchange
format; this one loads at the speed of the disk. The archive holds one array per
column of :class:`~lesmc.model.arrays.ArrayModel`, already laid out (states in
step order, transitions grouped by source in (rank, target) order), and a
``header``: UTF-8 JSON with the format, version, component and observation
names, the ids (null: the default ``k{step}.{row}``), labels and meta.

Read with ``allow_pickle=False`` (an object array is refused, never unpickled),
each array's dtype and shape checked, then every rule of the JSON form
(:func:`lesmc.model.validate.check_arrays`): a bad file is a located
:class:`~lesmc.common.errors.ModelError`, never an internal error.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.errors import Location, ModelError, Problems
from lesmc.common.fields import header, show
from lesmc.common.files import atomic_open
from lesmc.model.arrays import ArrayModel
from lesmc.model.validate import HALTED, check_arrays

FORMAT = "lesmc-lts-npz"
VERSION = 1
SUFFIX = ".npz"

#: The arrays every file has, with their dtypes and dimensions.
REQUIRED = {
    "step": (np.int64, 1),
    "S": (np.float64, 2),
    "halted": (np.bool_, 1),
    "ptr": (np.int64, 1),
    "dst": (np.int64, 1),
    "payoff": (np.float64, 1),
    "rank": (np.int64, 1),
    "original": (np.int64, 1),
}
#: The arrays a file may have: covariances (both or neither) and observations.
OPTIONAL = {"cov": (np.int64, 1), "P_table": (np.float64, 3), "obs": (np.int64, 1)}
_HEADER_KEYS = {"format", "version", "components", "obs_names", "ids", "labels", "meta"}


def is_binary(path: str | Path) -> bool:
    """Whether ``path`` names the binary form (by its suffix)."""
    return str(path).endswith(SUFFIX)


def save_lts_npz(model: ArrayModel, path: str | Path) -> None:
    """Write ``model`` in the binary form, atomically."""
    head = {
        "format": FORMAT,
        "version": VERSION,
        "components": list(model.components),
        "obs_names": list(model.obs_names),
        "ids": None if _default_ids(model) else model.ids,
        "labels": {str(k): list(v) for k, v in model.labels.items()},
        "meta": model.meta,
    }
    arrays = {name: getattr(model, name) for name in REQUIRED}
    arrays |= {n: getattr(model, n) for n in OPTIONAL if getattr(model, n) is not None}
    blob = np.frombuffer(json.dumps(head, allow_nan=False).encode(), dtype=np.uint8)
    with atomic_open(path, binary=True) as fh:
        np.savez(fh, header=blob, **arrays)


def _default_ids(model: ArrayModel) -> bool:
    """Whether the model's ids are the default ``k{step}.{row}`` (or it has none)."""
    ids = model.ids
    return ids is None or ids == [f"k{k}.{i}" for i, k in enumerate(model.step.tolist())]


def load_lts_npz(path: str | Path) -> ArrayModel:
    """Read and validate a binary model."""
    where = str(path)
    try:
        with np.load(where, allow_pickle=False) as z:
            names = set(z.files)
            arrays = {name: z[name] for name in names}
    except FileNotFoundError:
        raise ModelError("no such file", Location(where)) from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ModelError(f"not a lesmc binary model (.npz): {exc}", Location(where)) from None
    head = _header(arrays.pop("header", None), where)
    _check_arrays_present(arrays, where)
    cm = ArrayModel(
        components=tuple(head["components"]),
        obs_names=tuple(head["obs_names"]),
        ids=head["ids"],
        labels={int(k): tuple(v) for k, v in head["labels"].items()},
        meta=head["meta"],
        **arrays,
    )
    _check_labels(cm, where)
    check_arrays(cm, where)
    return cm


def _header(blob: np.ndarray | None, path: str) -> dict[str, Any]:
    """The header's JSON, each field checked."""
    if blob is None or blob.dtype != np.uint8 or blob.ndim != 1:
        raise ModelError.many(path, [("header", "missing: not a lesmc binary model")])
    try:
        data = json.loads(blob.tobytes().decode())
    except (UnicodeDecodeError, ValueError) as exc:
        raise ModelError.many(path, [("header", f"not JSON ({exc})")]) from None
    if not isinstance(data, dict):
        raise ModelError.many(path, [("header", "must be a JSON object")])
    pr = Problems()
    header(data, FORMAT, VERSION, pr)
    for key in sorted(set(data) ^ _HEADER_KEYS):
        pr.add(f"header.{key}", "unknown key" if key in data else "missing")
    strings = ("components", "obs_names")
    for key in strings:
        v = data.get(key)
        if not (isinstance(v, list) and all(isinstance(x, str) for x in v)):
            pr.add(f"header.{key}", f"must be a list of strings, got {show(v)}")
    ids = data.get("ids")
    if ids is not None and not (isinstance(ids, list) and set(map(type, ids)) <= {str}):
        pr.add("header.ids", "must be null or a list of strings")
    labels = data.get("labels")
    if not (
        isinstance(labels, dict)
        and all(
            k.isdigit() and isinstance(v, list) and all(isinstance(x, str) for x in v)
            for k, v in labels.items()
        )
    ):
        pr.add("header.labels", "must map state rows to lists of labels")
    if not isinstance(data.get("meta"), dict):
        pr.add("header.meta", "must be an object")
    if pr.items:
        raise ModelError.many(path, pr.items)
    return data


def _check_arrays_present(arrays: dict[str, np.ndarray], path: str) -> None:
    """Every required array there, no unknown one, each of its dtype and dimension."""
    pr = Problems()
    for name in sorted(set(arrays) - set(REQUIRED) - set(OPTIONAL)):
        pr.add(f"array '{name}'", "unknown")
    for name in sorted(set(REQUIRED) - set(arrays)):
        pr.add(f"array '{name}'", "missing")
    for name, (dtype, ndim) in (REQUIRED | OPTIONAL).items():
        a = arrays.get(name)
        if a is None:
            continue
        if a.dtype != dtype or a.ndim != ndim:
            want = f"{np.dtype(dtype).name} with {ndim} dimension(s)"
            pr.add(f"array '{name}'", f"must be {want}, got {a.dtype.name} {a.shape}")
    if pr.items:
        raise ModelError.many(path, pr.items)
    for name in OPTIONAL:
        arrays.setdefault(name, None)  # type: ignore[arg-type]


def _check_labels(cm: ArrayModel, path: str) -> None:
    bad = [r for r in cm.labels if not 0 <= r < cm.n_states]
    if bad:
        raise ModelError.many(path, [("header.labels", f"row {bad[0]} is not a state")])
    if any(HALTED in v for v in cm.labels.values()):
        raise ModelError.many(path, [("header.labels", "halting is the array 'halted'")])
