"""The binary form of a model: the arrays of an ArrayModel in a NumPy ``.npz`` file.

``lesmc build -o MODEL.npz`` writes it and ``lesmc check MODEL.npz`` reads it
(docs/lts-format.md, "Binary form"): the JSON ``.lts`` stays the interchange
format; this one loads at the speed of the disk. The archive holds one array per
column of :class:`~lesmc.model.arrays.ArrayModel`, already laid out (states in
step order, transitions grouped by source in (rank, target) order), the state
ids when they are not the default ``k{step}.{row}`` (``ids``: fixed-width UTF-8
bytes, numpy ``S``, checked without a string per state), and a ``header``:
UTF-8 JSON with the format, version, component and observation names, labels
and meta. Version 1 kept the ids in the header's JSON; it is still read, and
written for the rare ids a fixed width cannot hold (ending in a NUL character).

Read with ``allow_pickle=False`` (an object array is refused, never unpickled),
each array's dtype and shape checked, then every rule of the JSON form
(:func:`lesmc.model.validate_arrays.check_arrays`): a bad file is a located
:class:`~lesmc.common.errors.ModelError`, never an internal error.
"""

from __future__ import annotations

import io
import json
import os
import struct
import sys
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from lesmc.common.errors import Location, ModelError, Problems
from lesmc.common.fields import header, is_name, is_version, show
from lesmc.common.files import atomic_open, parse_json
from lesmc.model.arrays import ArrayModel, IdArray
from lesmc.model.validate import HALTED, check_tracks, meta_problems
from lesmc.model.validate_arrays import check_arrays

FORMAT = "lesmc-lts-npz"
VERSION = 2
#: The version that kept the ids in the header's JSON.
HEADER_IDS = 1
SUFFIX = ".npz"
#: The format of a multi-target model's binary file (lesmc/model/multi_format.py).
MULTI_FORMAT = "lesmc-multi-npz"

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
OPTIONAL = {
    "cov": (np.int64, 1),
    "P_table": (np.float64, 3),
    "obs": (np.int64, 1),
    "nis": (np.float64, 1),
}
#: The positions of the ground-truth tracks (with the header's ``tracks``), if any.
TRACKS = "tracks_at"
#: The state ids (fixed-width UTF-8), when they are not the default ones.
IDS = "ids"
_HEADER_KEYS = {"format", "version", "components", "obs_names", "labels", "meta"}


def is_binary(path: str | Path) -> bool:
    """Whether ``path`` names the binary form (by its suffix)."""
    return str(path).endswith(SUFFIX)


def save_lts_npz(model: ArrayModel, path: str | Path) -> None:
    """Write ``model`` in the binary form, atomically."""
    head: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "components": list(model.components),
        "obs_names": list(model.obs_names),
        "labels": {str(k): list(v) for k, v in model.labels.items()},
        "meta": model.meta,
    }
    arrays = {name: getattr(model, name) for name in REQUIRED}
    arrays |= {n: getattr(model, n) for n in OPTIONAL if getattr(model, n) is not None}
    if model.ids is not None and not _default_ids(model):
        raw = _id_bytes(model.ids)
        if raw is not None:
            arrays[IDS] = raw
        else:
            head |= {"version": HEADER_IDS, "ids": list(model.ids)}
    if model.tracks is not None:
        head["tracks"] = {
            "components": list(model.tracks.components),
            "ids": list(model.tracks.ids),
        }
        arrays[TRACKS] = model.tracks.at
    blob = np.frombuffer(json.dumps(head, allow_nan=False).encode(), dtype=np.uint8)
    with atomic_open(path, binary=True) as fh:
        write_npz(fh, {"header": blob, **arrays})


#: Where each array's data starts in the file: a multiple of this many bytes.
ALIGN = 64
#: The zip extra field that pads a member's local header (zipalign's: the alignment, then zeros).
_PAD_FIELD = 0xD935


def write_npz(fh: IO[bytes], arrays: dict[str, np.ndarray]) -> None:
    """The arrays as ``NAME.npy`` members of a stored (uncompressed) zip, what
    ``numpy.savez`` writes, with each member's local header padded by an extra field
    so that its data start at a multiple of ``ALIGN`` in the file (the ``.npy`` header
    pads itself to a multiple of 64): the reader then uses the file's bytes in place."""
    with zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
        for name, array in arrays.items():
            a = np.ascontiguousarray(array)
            head = io.BytesIO()
            np.lib.format.write_array_header_1_0(head, np.lib.format.header_data_from_array_1_0(a))
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_STORED
            info.file_size = head.tell() + a.nbytes
            zip64 = info.file_size * 1.05 > zipfile.ZIP64_LIMIT  # zipfile's own rule
            fixed = fh.tell() + 30 + len(info.filename.encode()) + 6 + (20 if zip64 else 0)
            pad = -fixed % ALIGN
            info.extra = struct.pack("<HHH", _PAD_FIELD, 2 + pad, ALIGN) + bytes(pad)
            with z.open(info, "w", force_zip64=zip64) as member:
                member.write(head.getvalue())
                member.write(a.reshape(-1).view(np.uint8).data if a.size else b"")


def _default_ids(model: ArrayModel) -> bool:
    """Whether the model's ids are the default ``k{step}.{row}`` (or it has none)."""
    return model.ids is None or list(model.ids) == model.default_ids()


def _id_bytes(ids: Sequence[str]) -> np.ndarray | None:
    """The ids as UTF-8 in one fixed width (a multiple of 8 bytes, so the reader hashes
    them a word at a time); None when an id ends in NUL, which the padding would eat."""
    if isinstance(ids, IdArray):
        return ids.raw
    coded = [i.encode() for i in ids]
    if any(c.endswith(b"\0") for c in coded):
        return None
    width = -(-max(map(len, coded)) // 8) * 8
    return np.array(coded, dtype=f"S{width}")


#: What reading a broken archive can raise (zip, zlib, numpy's header parser).
_READ_ERRORS = (
    OSError,
    struct.error,
    ValueError,
    EOFError,
    zipfile.BadZipFile,
    NotImplementedError,
    RuntimeError,
    zlib.error,
)


def load_lts_npz(path: str | Path) -> ArrayModel:
    """Read and validate a binary model."""
    where = str(path)
    return lts_from_arrays(read_npz(where), where)


def read_npz(path: str) -> dict[str, np.ndarray]:
    """The arrays of a binary model file (:func:`_read_arrays`), its header among them; a
    file that is no such archive is a located :class:`ModelError`. The multi-target
    models' form (lesmc/model/multi_format.py) reads its files with this too."""
    try:
        return _read_arrays(path)
    except FileNotFoundError:
        raise ModelError("no such file", Location(path)) from None
    except ModelError:
        raise
    except _READ_ERRORS as exc:
        raise ModelError(f"not a lesmc binary model (.npz): {exc}", Location(path)) from None


def lts_from_arrays(arrays: dict[str, np.ndarray], where: str) -> ArrayModel:
    """Validate the arrays :func:`read_npz` read from ``where`` and build the model."""
    head = _header(arrays.pop("header", None), where)
    tracks_at = arrays.pop(TRACKS, None)
    ids = _ids(head, arrays.pop(IDS, None), where)
    check_present(arrays, where, REQUIRED, OPTIONAL)
    cm = ArrayModel(
        components=tuple(head["components"]),
        obs_names=tuple(head["obs_names"]),
        ids=ids,
        labels={int(k): tuple(sorted(set(v))) for k, v in head["labels"].items()},
        meta=head["meta"],
        **arrays,  # type: ignore[arg-type]
    )
    _check_labels(cm, where)
    check_arrays(cm, where)
    if (tracks_at is None) != ("tracks" not in head):
        raise ModelError.many(
            where, [("tracks", f"the header's tracks and array '{TRACKS}' go together")]
        )
    if tracks_at is not None:
        pr = Problems()
        raw = head["tracks"]
        raw = {**raw, "at": tracks_at} if isinstance(raw, dict) else raw
        cm.tracks = check_tracks(raw, cm.components, cm.end + 1, pr)
        if cm.tracks is None:
            raise ModelError.many(where, pr.items)
    return cm


def _read_arrays(path: str) -> dict[str, np.ndarray]:
    """The archive's arrays: the zip's directory read by ``zipfile``, then the whole file
    in one read. Each member is located by the directory and its local header; only
    stored (uncompressed) members, each CRC checked, each ``.npy`` header read (no object
    dtype), and exactly the bytes that header announces after it (a small file cannot
    claim a huge array). An array whose data start at an aligned offset (lesmc's writer
    puts them there) is a view of the file's bytes; any other is copied."""
    with zipfile.ZipFile(path) as z:
        infos = z.infolist()
    with open(path, "rb") as fh:
        buf = bytearray(os.fstat(fh.fileno()).st_size)
        if fh.readinto(buf) != len(buf):
            raise ModelError("the file changed while it was read", Location(path))
    view = memoryview(buf)
    arrays = {}
    for info in infos:
        name = info.filename.removesuffix(".npy")
        if name in arrays:  # numpy.load and zipfile would take the last silently
            raise ModelError.many(
                path, [(f"array '{name}'", "the archive holds it twice: one member per array")]
            )
        if info.compress_type != zipfile.ZIP_STORED:
            raise ModelError.many(path, [(f"array '{name}'", "compressed: write it with save")])
        start = _member_start(view, info)
        data = view[start : start + info.compress_size]
        if len(data) != info.compress_size or zlib.crc32(data) != info.CRC:
            raise zipfile.BadZipFile(f"member {info.filename!r} is damaged (size or CRC)")
        head = io.BytesIO(data[:_NPY_HEAD])
        shape, fortran, dtype = _npy_header(head, name, path)
        if dtype.hasobject or fortran:
            raise ModelError.many(path, [(f"array '{name}'", "not a plain array")])
        count = int(np.prod(shape, dtype=object))
        size = count * dtype.itemsize
        if head.tell() + size != len(data):
            raise ModelError.many(
                path, [(f"array '{name}'", f"does not hold the {size} bytes it announces")]
            )
        flat = np.frombuffer(buf, dtype, count, offset=start + head.tell())
        arrays[name] = (flat if flat.flags.aligned else flat.copy()).reshape(shape)
    return arrays


#: Bytes of a member that hold its .npy header, at most (numpy's own limit is 10,000).
_NPY_HEAD = 1 << 16


def _npy_header(head: IO[bytes], name: str, path: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    """A member's ``.npy`` header (shape, Fortran order, dtype); one that numpy cannot
    read, or whose shape has a negative length, is an error naming the member (numpy's
    own message may show its parser's internals: ``<ast.Call object at 0x...>``)."""
    try:
        version = np.lib.format.read_magic(head)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(head)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(head)
    except _READ_ERRORS:
        shape = None
    if shape is None or any(n < 0 for n in shape):
        raise ModelError.many(
            path,
            [
                (
                    f"array '{name}'",
                    "its .npy header is not numpy's: a magic string, then a dict of "
                    "'descr', 'fortran_order' and 'shape' (a tuple of lengths >= 0)",
                )
            ],
        )
    return shape, fortran, dtype


def _dtype_text(dtype: np.dtype) -> str:
    """A dtype's name, with its byte order when it is not this machine's
    (``float64`` and ``>f8`` have one name)."""
    if dtype.isnative:
        return dtype.name
    return f"{dtype.name} {'big' if dtype.byteorder == '>' else 'little'}-endian"


def _member_start(view: memoryview, info: zipfile.ZipInfo) -> int:
    """Where a member's data start: after its local header (30 bytes, then its name
    and extra field, whose lengths the local header gives)."""
    sig, *_, name_len, extra_len = struct.unpack_from("<4s5H3L2H", view, info.header_offset)
    if sig != b"PK\x03\x04":
        raise zipfile.BadZipFile(f"member {info.filename!r}: no local header")
    return int(info.header_offset) + 30 + int(name_len) + int(extra_len)


def _ids(head: dict[str, Any], raw: np.ndarray | None, path: str) -> Sequence[str] | None:
    """The state ids: the header's list (version 1) or the array (version 2), if any."""
    if head["version"] == HEADER_IDS:
        if raw is not None:
            raise ModelError.many(path, [(f"array '{IDS}'", "unknown in version 1")])
        ids: list[str] | None = head["ids"]
        return ids
    if raw is None:
        return None
    if raw.dtype.kind != "S" or raw.ndim != 1:
        want = "fixed-width bytes (numpy S) with 1 dimension(s)"
        raise ModelError.many(
            path, [(f"array '{IDS}'", f"must be {want}, got {_dtype_text(raw.dtype)} {raw.shape}")]
        )
    return IdArray(raw)


def _header(blob: np.ndarray | None, path: str) -> dict[str, Any]:
    """The header's JSON, each field checked."""
    if blob is None or blob.dtype != np.uint8 or blob.ndim != 1:
        raise ModelError.many(path, [("header", "missing: not a lesmc binary model")])
    data = header_object(blob, path)
    if data.get("format") == MULTI_FORMAT:
        raise ModelError.many(
            path,
            [
                (
                    "header.format",
                    f"'{MULTI_FORMAT}' is a multi-target model (lesmc build --design sort|gnn): "
                    "lesmc check and lesmc export --format drn|prism read it, this reads "
                    "single-target models only",
                )
            ],
        )
    pr = Problems()
    old = is_version(data.get("version"), HEADER_IDS)
    header(data, FORMAT, HEADER_IDS if old else VERSION, pr)
    keys = _HEADER_KEYS | ({"ids"} if old else set())
    for key in sorted((set(data) ^ keys) - {"tracks"}):
        pr.add(f"header.{key}", "unknown key" if key in data else "missing")
    comps = data.get("components")
    if not (isinstance(comps, list) and comps and all(is_name(c) for c in comps)):
        pr.add("header.components", f"must be a non-empty list of names, got {show(comps)}")
    names = data.get("obs_names")
    if not (isinstance(names, list) and all(isinstance(x, str) for x in names)):
        pr.add("header.obs_names", f"must be a list of strings, got {show(names)}")
    ids = data.get("ids")
    if ids is not None and not (
        isinstance(ids, list) and set(map(type, ids)) <= {str} and "" not in ids
    ):
        pr.add("header.ids", "must be null or a list of non-empty strings")
    labels = data.get("labels")
    if not (
        isinstance(labels, dict)
        and all(
            k.isascii() and k.isdecimal() and len(k) <= 18 and _string_list(v)
            for k, v in labels.items()
        )
    ):
        pr.add("header.labels", "must map state rows to lists of labels")
    if not isinstance(data.get("meta"), dict):
        pr.add("header.meta", "must be an object")
    pr.items.extend(meta_problems(data.get("meta"), "header.meta"))
    if pr.items:
        raise ModelError.many(path, pr.items)
    return data


def header_object(blob: np.ndarray, path: str) -> dict[str, Any]:
    """The ``header`` array's UTF-8 JSON object (a bad one: a ModelError at ``header``,
    with the line and column in the header's text); the multi-target models' reader
    (lesmc/model/multi_format.py) reads its header with this too."""
    try:
        data = parse_json(blob.tobytes(), path, ModelError)
    except ModelError as exc:  # located in the header's text, not in the file
        where = exc.location
        at = f" (line {where.line}, column {where.column})" if where and where.line else ""
        raise ModelError.many(path, [("header", f"{exc.message}{at}")]) from None
    if not isinstance(data, dict):
        raise ModelError.many(path, [("header", "must be a JSON object")])
    return data


def _string_list(v: Any) -> bool:
    return isinstance(v, list) and all(isinstance(x, str) for x in v)


#: Arrays by name, each with its dtype and number of dimensions.
ArraySpec = dict[str, tuple[Any, int]]


def check_present(
    arrays: dict[str, np.ndarray], path: str, required: ArraySpec, optional: ArraySpec
) -> None:
    """Every ``required`` array there, none but those and the ``optional`` ones, each of
    its dtype and dimension; the missing optional ones set to None."""
    pr = Problems()
    for name in sorted(set(arrays) - set(required) - set(optional)):
        pr.add(f"array '{name}'", "unknown")
    for name in sorted(set(required) - set(arrays)):
        pr.add(f"array '{name}'", "missing")
    for name, (dtype, ndim) in (required | optional).items():
        a = arrays.get(name)
        if a is None:
            continue
        if a.dtype != dtype or a.ndim != ndim:
            order = f" {sys.byteorder}-endian" if not a.dtype.isnative else ""
            want = f"{np.dtype(dtype).name}{order} with {ndim} dimension(s)"
            pr.add(f"array '{name}'", f"must be {want}, got {_dtype_text(a.dtype)} {a.shape}")
    if pr.items:
        raise ModelError.many(path, pr.items)
    for name in optional:
        arrays.setdefault(name, None)  # type: ignore[arg-type]


def _check_labels(cm: ArrayModel, path: str) -> None:
    bad = [r for r in cm.labels if not 0 <= r < cm.n_states]
    if bad:
        raise ModelError.many(path, [("header.labels", f"row {bad[0]} is not a state")])
    if any(HALTED in v for v in cm.labels.values()):
        raise ModelError.many(path, [("header.labels", "halting is the array 'halted'")])
