"""File plumbing shared by every stage: strict text and JSON reading, atomic writing.

Input files are UTF-8 (a leading byte-order mark is skipped). JSON inputs are
strict: no duplicate keys, no NaN or infinities, integers within 64 bits, floats
that stay finite, nesting at most :data:`MAX_JSON_DEPTH` deep. Every violation
is reported as ``FILE:LINE:COL: message`` (docs/cli.md, "Limits").
"""

from __future__ import annotations

import codecs
import contextlib
import gc
import json
import math
import os
import re
import stat
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

from lesmc.common.errors import (
    InputError,
    LesmcError,
    Location,
    UsageError,
    escape_control,
)

#: Deepest nesting of arrays and objects a JSON input may have.
MAX_JSON_DEPTH = 64

#: Integers in JSON inputs must fit in a signed 64-bit integer (at most 19 digits).
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1

_BOM = codecs.BOM_UTF8.decode("utf-8")

# JSON's structural bytes are ASCII and never occur inside a UTF-8 multi-byte
# sequence, so the depth check can work on the raw bytes.
_KEEP = frozenset(b'"[]{}')
_STRUCTURE_DELETE = bytes(b for b in range(256) if b not in _KEEP)
_STRUCTURE_TABLE = bytes.maketrans(b"{}", b"[]")

_WS_RE = re.compile(r"[ \t\n\r]*")
# json's own NUMBER_RE uses \d, which also matches non-ASCII digits; json does not.
_NUMBER_RE = re.compile(r"-?(?:0|[1-9][0-9]*)(\.[0-9]+)?([eE][-+]?[0-9]+)?")
_SHOWN_NUMBER = 24
_STRING_DECODER = json.JSONDecoder()  # raw_decode at a '"' reads one string token


class _Rejected(Exception):
    """Raised by the decoding hooks; the caller locates the problem by re-scanning."""


def decode_text(data: bytes, path: str, error: type[LesmcError] = InputError) -> str:
    """``data`` decoded as UTF-8, a leading BOM skipped; bad bytes give ``FILE:LINE:COL``."""
    if data.startswith(codecs.BOM_UTF8):
        data = data[len(codecs.BOM_UTF8) :]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        bad = exc.start
        line_start = data.rfind(b"\n", 0, bad) + 1
        line_end = data.find(b"\n", bad)
        if line_end < 0:
            line_end = len(data)
        column = len(data[line_start:bad].decode("utf-8")) + 1  # valid: before the first bad byte
        shown = data[line_start:line_end].removesuffix(b"\r").decode("utf-8", "backslashreplace")
        line = data.count(b"\n", 0, bad) + 1
        raise error(
            f"invalid UTF-8 (byte 0x{data[bad]:02x}); the file must be UTF-8 text",
            Location(path, line, column, shown),
        ) from None


def file_sha256(path: str | Path) -> str:
    """sha256 of a file's bytes (a written weights file; a network a scene was made with)."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_text(path: str | Path, error: type[LesmcError] = InputError) -> str:
    """Read a UTF-8 text file (BOM skipped); unreadable files and bad bytes become ``error``."""
    return decode_text(_read_bytes(path, error), str(path), error)


def read_json(path: str | Path, error: type[LesmcError] = InputError) -> Any:
    """Parse a JSON file strictly; every problem becomes a ``FILE:LINE:COL`` ``error``."""
    return parse_json(_read_bytes(path, error), str(path), error)


def read_toml(path: str | Path, error: type[LesmcError] = InputError) -> Any:
    """Parse a TOML file (stdlib ``tomllib``); a syntax error becomes a ``FILE:LINE:COL`` ``error``.

    TOML has no null and its floats may be inf or nan: the loaders that read it
    check every value as they do for JSON.
    """
    import tomllib

    text = read_text(path, error)
    try:
        data = tomllib.loads(text)
    except RecursionError:  # arrays or inline tables nested thousands deep
        raise error(f"nesting deeper than {MAX_JSON_DEPTH}", _toml_deep(str(path), text)) from None
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        at = re.search(r"\s*\(at line (\d+), column (\d+)\)$", msg)
        if at is None:
            at = re.search(r"\s*\(at end of document\)$", msg)
            loc = Location.at(str(path), text, len(text))
        else:
            line, col = int(at.group(1)), int(at.group(2))
            lines = text.split("\n")
            shown = lines[line - 1].removesuffix("\r") if line <= len(lines) else None
            loc = Location(str(path), line, col, shown)
        raise error(msg[: at.start()] if at else msg, loc) from None
    if _big_ints(data):
        raise _toml_big_int(str(path), text, error)
    return data


#: What may be an integer token of TOML (decimal with underscores, hex, octal, binary),
#: not part of a float, a date or a bare key; it may also be in a comment or a string.
_TOML_INT = re.compile(
    r"(?<![\w.:-])[+-]?(?:0x[0-9a-fA-F_]+|0o[0-7_]+|0b[01_]+|\d[\d_]*)(?![\w.:-])"
)


def _toml_deep(path: str, text: str) -> Location:
    """Where TOML ``text`` first opens more than :data:`MAX_JSON_DEPTH` arrays or inline
    tables (brackets counted, comments and strings not told apart: a hint)."""
    depth = 0
    for pos, ch in enumerate(text):
        depth += (ch in "[{") - (ch in "]}")
        if depth > MAX_JSON_DEPTH:
            return Location.at(path, text, pos)
    return Location(path)


def _big_ints(value: Any) -> int:
    """How many integers outside 64 bits a parsed TOML document holds (``tomllib`` keeps
    any size; TOML allows 64 bits, and a float() of a bigger one overflows)."""
    if isinstance(value, dict):
        return sum(_big_ints(v) for v in value.values())
    if isinstance(value, list):
        return sum(_big_ints(v) for v in value)
    return int(type(value) is int and not INT64_MIN <= value <= INT64_MAX)


def _toml_big_int(path: str, text: str, error: type[LesmcError]) -> LesmcError:
    """The error for a TOML integer outside 64 bits, at its token's ``FILE:LINE:COL``: the
    first big token whose replacement by 0 removes a big integer from the document (one
    in a comment or a string does not)."""
    import tomllib

    count = _big_ints(tomllib.loads(text))
    for m in _TOML_INT.finditer(text):
        try:
            v = int(m.group(), 0)
        except ValueError:  # a leading zero: not an integer TOML reads
            continue
        if INT64_MIN <= v <= INT64_MAX:
            continue
        try:
            fewer = _big_ints(tomllib.loads(text[: m.start()] + "0" + text[m.end() :])) < count
        except tomllib.TOMLDecodeError:
            continue
        if fewer:
            what = f"integer {_clip(m.group())} is out of range (integers must fit in 64 bits)"
            return error(what, Location.at(path, text, m.start()))
    return error("an integer is out of range (integers must fit in 64 bits)", Location(path))


def _read_bytes(path: str | Path, error: type[LesmcError]) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise error(f"cannot read file: {exc.strerror or exc}", Location(str(path))) from None


def parse_json(
    data: bytes | str, path: str = "<json>", error: type[LesmcError] = InputError
) -> Any:
    """Parse JSON text (bytes are decoded as by :func:`decode_text`) as :func:`read_json` does.

    The happy path is :func:`json.loads` with light hooks (duplicate keys,
    integer range, finite floats) and a depth check on the raw bytes; only when
    something is wrong is the text re-scanned in Python to find the position.
    """
    if isinstance(data, str):
        text = data.removeprefix(_BOM)
        raw = text.encode("utf-8", "surrogatepass")
    else:
        text = decode_text(data, path, error)
        raw = data
    # number hooks run once per number: only where a token could be out of range
    classes = raw.translate(_NUMBER_CLASSES)
    long_digits = _LONG_DIGITS in classes
    hooks: dict[str, Any] = {}
    if long_digits:
        hooks["parse_int"] = _int
    if long_digits or any(x in classes for x in _BIG_EXPONENTS):
        hooks["parse_float"] = _float
    try:
        with _no_gc():
            value = json.loads(text, object_pairs_hook=_object, parse_constant=_constant, **hooks)
    except json.JSONDecodeError as exc:
        raise error(f"invalid JSON: {exc.msg}", Location.at(path, text, exc.pos)) from None
    except _Rejected as exc:
        raise _located(text, path, error, str(exc)) from None
    except RecursionError:
        raise _located(text, path, error, f"nesting deeper than {MAX_JSON_DEPTH}") from None
    if _deeper_than(raw, MAX_JSON_DEPTH):
        raise _located(text, path, error, f"nesting deeper than {MAX_JSON_DEPTH}")
    return value


@contextlib.contextmanager
def _no_gc() -> Iterator[None]:
    """The cyclic garbage collector paused: a parsed JSON value is a tree (no cycles),
    and the collector's passes over its growing heap of new containers cost about a
    fifth of :func:`json.loads` on a large file."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()


# --- hooks: cheap checks on the happy path ---------------------------------------------

#: Bytes mapped to classes (digits -> 1, e/E -> e, signs -> s) for a quick scan in C.
_NUMBER_CLASSES = bytes.maketrans(b"0123456789eE+-", b"1111111111eess")
#: A run of 19 digits: an integer that may not fit in 64 bits (or a float with a mantissa
#: long enough to overflow).
_LONG_DIGITS = b"1" * 19
#: An exponent of three digits or more: a float that may overflow to infinity.
_BIG_EXPONENTS = (b"e111", b"es111")


def _object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj = dict(pairs)
    if len(obj) != len(pairs):
        raise _Rejected("duplicate key")
    return obj


def _constant(name: str) -> Any:
    raise _Rejected(f"{name} is not allowed")


def _int(token: str) -> int:
    if len(token) > 18:  # anything shorter fits in 64 bits
        problem = _int_problem(token)
        if problem:
            raise _Rejected(problem)
    return int(token)


def _float(token: str) -> float:
    value = float(token)
    if value - value != 0.0:  # inf - inf is nan; the parser never produces nan here
        raise _Rejected(_float_problem(token))
    return value


def _int_problem(token: str) -> str | None:
    digits = token.removeprefix("-")
    if len(digits) <= 19 and INT64_MIN <= int(token) <= INT64_MAX:
        return None
    return f"integer {_clip(token)} is out of range (integers must fit in 64 bits)"


def _float_problem(token: str) -> str:
    return f"number {_clip(token)} is out of range (it overflows to infinity)"


def _clip(token: str) -> str:
    if len(token) <= _SHOWN_NUMBER:
        return token
    return f"{token[: _SHOWN_NUMBER - 4]}... ({len(token)} characters)"


def _deeper_than(raw: bytes, limit: int) -> bool:
    """Whether the valid JSON ``raw`` nests arrays/objects more than ``limit`` deep.

    Works on the bytes with C-speed string operations only: drop escaped
    backslashes and quotes, keep quotes and brackets, drop string contents, then
    peel one level of innermost ``[]`` per round.
    """
    if raw.count(b"[") + raw.count(b"{") <= limit:
        return False
    if b"\\" in raw:
        raw = raw.replace(b"\\\\", b"").replace(b'\\"', b"")
    shape = raw.translate(_STRUCTURE_TABLE, _STRUCTURE_DELETE).replace(b'""', b"")
    if b'"' in shape:  # strings that contain brackets: keep what lies between them
        shape = b"".join(shape.split(b'"')[::2])
    for _ in range(limit):  # round k removes every container of height k
        if not shape:
            return False
        shape = shape.replace(b"[]", b"")
    return bool(shape)


# --- slow path: find where the problem is -------------------------------------------------


def _located(text: str, path: str, error: type[LesmcError], fallback: str) -> LesmcError:
    found = _first_problem(text)
    if found is None:  # pragma: no cover - the hooks and the scan agree on what is wrong
        return error(fallback, Location(path))
    pos, message = found
    return error(message, Location.at(path, text, pos))


def _first_problem(text: str) -> tuple[int, str] | None:
    """Position and message of the first strictness problem in ``text``, scanning in order.

    Only called after :func:`json.loads` rejected something, so the text is valid
    JSON up to that problem; on anything unexpected the scan gives up (None).
    """
    stack: list[set[str] | None] = []  # the keys seen so far for an object, None for an array
    expect_key = False
    pos, end = 0, len(text)
    while True:
        pos = _WS_RE.match(text, pos).end()  # type: ignore[union-attr]  # always matches
        if pos >= end:
            return None
        ch = text[pos]
        if ch in "[{":
            if len(stack) >= MAX_JSON_DEPTH:
                return pos, f"nesting deeper than {MAX_JSON_DEPTH}"
            stack.append(set() if ch == "{" else None)
            expect_key = ch == "{"
            pos += 1
        elif ch in "]}":
            if stack:
                stack.pop()
            expect_key = False
            pos += 1
        elif ch == ",":
            expect_key = bool(stack) and stack[-1] is not None
            pos += 1
        elif ch == ":":
            expect_key = False
            pos += 1
        elif ch == '"':
            try:
                string, after = _STRING_DECODER.raw_decode(text, pos)
            except ValueError:
                return None
            keys = stack[-1] if stack else None
            if expect_key and keys is not None:
                if string in keys:
                    return pos, f"duplicate key {_show_key(string)}"
                keys.add(string)
            expect_key = False
            pos = after
        else:
            scanned = _scalar(text, pos)
            if scanned is None or scanned[1] is not None:
                return None if scanned is None else (pos, str(scanned[1]))
            pos = scanned[0]


def _scalar(text: str, pos: int) -> tuple[int, str | None] | None:
    """A number, true, false or null at ``pos``: where it ends and its strictness problem
    (None: it is fine); None when it is none of these (the scan gives up)."""
    for name in ("NaN", "Infinity", "-Infinity"):
        if text.startswith(name, pos):
            return pos, f"{name} is not allowed (numbers must be finite)"
    match = _NUMBER_RE.match(text, pos)
    if match is not None:
        token = match.group()
        if match.group(1) or match.group(2):
            if not math.isfinite(float(token)):
                return pos, _float_problem(token)
        elif len(token) > 18 and (problem := _int_problem(token)):
            return pos, problem
        return match.end(), None
    if text.startswith(("true", "null"), pos):
        return pos + 4, None
    if text.startswith("false", pos):
        return pos + 5, None
    return None


def _show_key(key: str) -> str:
    shown = json.dumps(key, ensure_ascii=False)
    return shown if len(shown) <= 60 else shown[:56] + '..."'


def _umask() -> int:
    """The process umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def new_file_mode(target: str | Path) -> int:
    """Permission bits a file written to ``target`` gets: the existing file's if it is
    replaced, otherwise ``0o666`` minus the process umask (as ``open(path, "w")`` gives)."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        return 0o666 & ~_umask()


def output_target(path: str | Path) -> Path:
    """The file an output named ``path`` replaces: ``path`` with its symlinks resolved.
    :class:`UsageError` if that exists and is not a regular file, or if ``path`` ends in
    a slash (a directory's name: the file would be written without it)."""
    target = Path(os.path.realpath(path))
    named_dir = str(path).endswith(("/", os.sep))  # realpath drops the slash
    if named_dir or (target.exists() and not target.is_file()):
        shown = escape_control(str(path))
        raise UsageError(f"{shown}: not a regular file: lesmc writes its outputs to files only")
    return target


@contextlib.contextmanager
def atomic_open(path: str | Path, binary: bool = False) -> Iterator[IO[Any]]:
    """A file to write ``path`` through, so that readers never see it half-written.

    The data go to a temporary file beside ``path`` (``.NAME.XXXXXXXX``), renamed
    over ``path`` when the ``with`` block ends normally, with the permissions of
    :func:`new_file_mode`. On any exception, Ctrl-C and SIGTERM included
    (lesmc/cli/signals.py), the temporary file is removed and ``path`` is untouched.
    A symlink is written through (its target is replaced, the link kept); a ``path``
    that exists and is not a regular file (a device, a FIFO, a directory) is refused
    with :class:`UsageError`, since renaming over it would replace it.
    """
    target = output_target(path)
    tmp: str | None = None
    try:
        fd, tmp = _temporary_beside(path, target)
        mode = new_file_mode(target)
        with os.fdopen(fd, "wb" if binary else "w", encoding=None if binary else "utf-8") as fh:
            os.fchmod(fh.fileno(), mode)
            yield fh
        os.replace(tmp, target)
        tmp = None
    finally:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)


def _temporary_beside(path: str | Path, target: Path) -> tuple[int, str]:
    """A new temporary file in ``target``'s directory (made if missing), for
    :func:`atomic_open`. :class:`UsageError` naming ``path`` if that cannot be: a
    parent is a file, the directory is not writable."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        return tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    except OSError as exc:
        why = exc.strerror or str(exc)
        if isinstance(exc, FileExistsError | NotADirectoryError):
            why = "a directory on its path is a file"
        raise UsageError(f"cannot write the file: {why}", Location(str(path))) from None


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_open`)."""
    with atomic_open(path, binary=True) as fh:
        fh.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_open`)."""
    with atomic_open(path) as fh:
        fh.write(text)


def write_json(path: str | Path, data: Any, on_chunk: Callable[[], None] | None = None) -> None:
    """Atomically write ``data`` as JSON (NaN and infinities are refused).

    Layout: lists that hold objects, and objects that hold those or other objects,
    are spread over lines, one member or item a line; everything else is written
    on one line by json's C encoder (``indent`` would send all of it through the
    pure-Python one, several times slower and holding every fragment in memory).
    Written in chunks as produced; ``on_chunk()`` is called between them (a
    budget: it raises to stop, and the temporary file is removed).
    """
    with atomic_open(path) as fh:
        for chunk in _json_chunks(data, 0):
            fh.write(chunk)
            if on_chunk is not None:
                on_chunk()
        fh.write("\n")


def json_text(data: Any) -> str:
    """``data`` as JSON text laid out as :func:`write_json` writes it (NaN and infinities
    refused)."""
    return "".join(_json_chunks(data, 0)) + "\n"


_DUMPS = json.JSONEncoder(allow_nan=False).encode
_CHUNK_ITEMS = 4096


class EncodedItems(list[str]):
    """A JSON array whose items are already JSON texts (objects, one a line).

    :func:`write_json` lays it out as it would the list of those objects: a writer
    that formats many rows column by column (a model's states) passes the texts
    instead of building a dict per row for the encoder to walk.
    """


def _spread(value: Any) -> bool:
    """Whether ``value`` is written over several lines: a list holding objects, or an
    object holding such a list or another object."""
    if isinstance(value, dict):
        return any(isinstance(v, dict) or _has_objects(v) for v in value.values())
    return _has_objects(value)


def _has_objects(value: Any) -> bool:
    if isinstance(value, EncodedItems):
        return bool(value)
    return isinstance(value, list) and any(isinstance(x, dict) for x in value)


def _json_chunks(value: Any, depth: int) -> Iterator[str]:
    if not _spread(value):
        yield _DUMPS(value)
        return
    pad = "\n" + " " * (depth + 1)
    if isinstance(value, dict):
        if not value:
            yield "{}"
            return
        yield "{"
        for i, (key, item) in enumerate(value.items()):
            yield ("," if i else "") + pad + _DUMPS(str(key)) + ": "
            yield from _json_chunks(item, depth + 1)
        yield "\n" + " " * depth + "}"
        return
    yield "["
    sep = "," + pad
    if isinstance(value, EncodedItems):
        for i in range(0, len(value), _CHUNK_ITEMS):
            yield ("," if i else "") + pad + sep.join(value[i : i + _CHUNK_ITEMS])
        yield "\n" + " " * depth + "]"
        return
    simple: list[str] = []
    first = True
    for item in value:
        if _spread(item):
            if simple:
                yield ("" if first else ",") + pad + sep.join(simple)
                first, simple = False, []
            yield ("" if first else ",") + pad
            first = False
            yield from _json_chunks(item, depth + 1)
        else:
            simple.append(_DUMPS(item))
            if len(simple) >= _CHUNK_ITEMS:
                yield ("" if first else ",") + pad + sep.join(simple)
                first, simple = False, []
    if simple:
        yield ("" if first else ",") + pad + sep.join(simple)
    yield "\n" + " " * depth + "]"
