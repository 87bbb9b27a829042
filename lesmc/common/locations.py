"""Where a key or an item sits in a JSON or TOML text: the ``FILE:LINE:COL`` of an input
error (brief: "for JSON: the line and the offending id or field").

:func:`key_locations` finds each key's first mention; :func:`json_location` follows an
item path such as ``runs[0].paths[2].states`` or ``model.Q[3][2]`` through the text (run
only when a document is refused: unrelated values are skipped with the C JSON decoder);
:func:`error_at_keys` and :func:`error_at_items` list several problems, each at its place.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

from lesmc.common.errors import InputError, Location, clipped
from lesmc.common.files import read_text

_WS_RE = re.compile(r"[ \t\n\r]*")
_STRING_DECODER = json.JSONDecoder()  # raw_decode at a '"' reads one string token


def key_locations(path: str, text: str, is_json: bool) -> dict[str, Location]:
    """Where each key's first mention is: ``key =`` (TOML, a bare or quoted key, or a
    table ``[key]``) or ``"key":`` (JSON)."""
    pattern = _JSON_KEY if is_json else _TOML_KEY
    out: dict[str, Location] = {}
    for m in pattern.finditer(text):
        key = next(g for g in m.groups() if g is not None)
        if not is_json and m.group(1) is not None and "\\" in key:
            key = _toml_basic_key(key)
        if key not in out:
            lead = len(m.group(0)) - len(m.group(0).lstrip(" \t"))
            out[key] = Location.at(path, text, m.start(0) + lead)
    return out


def error_at_keys(
    path: str,
    where: dict[str, Location],
    problems: list[tuple[str, str]],
    name_keys: bool = True,
) -> InputError:
    """One error listing each ``(key, message)`` at the key's line (``where``:
    :func:`key_locations`; the file's name when the key is not in it, as for a missing
    key), located at the first problem's key. With ``name_keys`` a message is prefixed
    with its key unless it starts with it already."""
    lines = []
    for key, msg in problems:
        loc = where.get(key, Location(path))
        named = name_keys and key and not msg.startswith(key)
        shown = f"{clipped(key, 60)}: " if named else ""
        lines.append(f"{loc.prefix()}: {shown}{msg}")
    first = where.get(problems[0][0], Location(path)) if problems else Location(path)
    err = InputError("\n".join(lines), first)
    err.preformatted = True
    return err


#: A JSON item as the validators name it: ``runs[0].paths[2].states``, ``model.Q[3][2]``.
_ITEM_PART = re.compile(r"\.?([^.\[\]\s,'\"()]+)|\[(\d+)\]")


def item_keys(item: str) -> list[str | int] | None:
    """The keys and indices of an item named as ``runs[0].paths[2]``; None when ``item``
    is not of that form (``frame 5, detection 'a'``)."""
    keys: list[str | int] = []
    pos = 0
    while pos < len(item):
        m = _ITEM_PART.match(item, pos)
        if m is None or (pos == 0 and item.startswith(".")):
            return None
        keys.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    return keys


def json_offset(text: str, keys: list[str | int]) -> tuple[int, int]:
    """Where in JSON ``text`` (valid: it was parsed) the value at ``keys`` is named: the
    opening quote of its key (an object's member), the start of its element (an
    array's), the start of the text for no keys; when a key is not there, where the
    deepest value on the way that is there is named. Returns the offset and how many of
    ``keys`` it reached.

    Values off the way are skipped by the C decoder, so this costs at most about one
    parse of the text; it runs only when a document is refused."""
    named = value = _WS_RE.match(text).end()  # type: ignore[union-attr]  # always matches
    for depth, key in enumerate(keys):
        found = _member(text, value, key)
        if found is None:
            return named, depth
        named, value = found
    return named, len(keys)


def _member(text: str, pos: int, key: str | int) -> tuple[int, int] | None:
    """Member ``key`` (a string: of an object; an int: of an array) of the value at
    ``pos``: where it is named (its key's quote, or the element) and where its value
    starts; None when there is none."""
    opening, closing = ("{", "}") if isinstance(key, str) else ("[", "]")
    if not text.startswith(opening, pos):
        return None
    pos = _skip_ws(text, pos + 1)
    index = 0
    while not text.startswith(closing, pos):
        at = pos
        if opening == "{":
            name, pos = _STRING_DECODER.raw_decode(text, pos)
            pos = _skip_ws(text, _skip_ws(text, pos) + 1)  # past the ':'
            if name == key:
                return at, pos
        elif index == key:
            return at, at
        _, pos = _STRING_DECODER.raw_decode(text, pos)
        pos = _skip_ws(text, pos)
        if not text.startswith(",", pos):
            return None
        pos = _skip_ws(text, pos + 1)
        index += 1
    return None


def _skip_ws(text: str, pos: int) -> int:
    return _WS_RE.match(text, pos).end()  # type: ignore[union-attr]  # always matches


def json_location(path: str, text: str, item: str) -> Location:
    """The ``FILE:LINE:COL`` of the JSON item named ``item`` (:func:`item_keys`) in
    ``text``, or of the deepest value on its way that is there; ``FILE: item`` when
    ``item`` names no JSON path (the location then carries the item)."""
    keys = item_keys(item)
    if keys is None:
        return Location(path, item=item or None)
    loc = Location.at(path, text, json_offset(text, keys)[0])
    loc.item = item
    return loc


def error_at_items(
    path: str,
    text: str,
    problems: list[tuple[str, str]],
    where: Callable[[str, str], str] | None = None,
) -> InputError:
    """One error listing each ``(item, message)`` of a JSON document at its
    ``FILE:LINE:COL``, the item named after it; the error's location is the first
    problem's, and a single problem also quotes its line. The place is
    :func:`json_location` of the item, or of ``where(item, message)`` (the JSON path of
    a problem its validator names otherwise, as a scene's ``frame 5, detection 'a'``)."""

    def loc(item: str, msg: str) -> Location:
        return json_location(path, text, item if where is None else where(item, msg))

    if len(problems) == 1:
        item, msg = problems[0]
        return InputError(f"{item}: {msg}" if item else msg, loc(item, msg))
    lines = []
    for item, msg in problems[:20]:
        shown = f"{item}: " if item else ""
        lines.append(f"{loc(item, msg).prefix()}: {shown}{msg}")
    if len(problems) > 20:
        lines.append(f"{path}: ... and {len(problems) - 20} more problems")
    err = InputError("\n".join(lines), loc(*problems[0]))
    err.preformatted = True
    return err


def _toml_basic_key(raw: str) -> str:
    """A TOML basic-string key's text (``"\\u00e9"`` is ``é``), as the parser reads it;
    ``raw`` itself when it is no valid key."""
    import tomllib

    try:
        return next(iter(tomllib.loads(f'"{raw}" = 0')))
    except tomllib.TOMLDecodeError:
        return raw


_JSON_KEY = re.compile(r'"((?:[^"\\]|\\.)*)"\s*:')
_TOML_KEY = re.compile(
    r'^[ \t]*\[?[ \t]*(?:"([^"]*)"|\'([^\']*)\'|([A-Za-z0-9_-]+))[ \t]*[=\]]', re.M
)


def error_in_file(
    path: str, problems: list[tuple[str, str]], text: str | None = None
) -> InputError:
    """:func:`error_at_items` of the JSON file ``path`` (its ``text`` when the caller has
    read it): each ``(item, message)`` at its ``FILE:LINE:COL``; ``FILE: item`` for a
    file that is not there to read (a document given as data)."""
    if text is None:
        if not Path(path).is_file():
            return InputError.many(path, problems)
        text = read_text(path)
    return error_at_items(path, text, problems)
