"""Where a scene file's problems sit: a loader's names (``frame 5, detection '5:c'``) mapped to
the JSON path of the offending field and then to its ``FILE:LINE:COL``
(lesmc/common/locations.py).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lesmc.common.errors import InputError
from lesmc.common.files import parse_json, read_text
from lesmc.common.locations import (
    error_at_items,
    item_keys,
)


def scene_error(path: str, data: Any, problems: list[tuple[str, str]]) -> InputError:
    """One error listing a scene's problems, each at its ``FILE:LINE:COL`` when ``path`` is
    the file ``data`` was read from (it is read again: errors only; ``data`` None: the
    file as it is), else as ``FILE: item: message``."""
    read = _text_of(path, data)
    if read is None:
        return InputError.many(path, problems)
    text, doc = read
    return error_at_items(path, text, problems, lambda item, msg: _json_item(doc, item, msg))


def _text_of(path: str, data: Any) -> tuple[str, dict[str, Any]] | None:
    """The text of the regular file ``path`` and its document, when that is an object and
    ``data`` (unless None); else None."""
    try:
        if not Path(path).is_file():
            return None
        text = read_text(path)
        doc = parse_json(text, path)
    except (InputError, OSError):
        return None
    ok = isinstance(doc, dict) and (data is None or doc == data)
    return (text, doc) if ok else None


_FRAME = re.compile(r"frame (\d+)")
_NAMED = re.compile(r"(detection|candidate|truth track) '(.*)'")
#: The key a problem's message starts with (``payoff must ...``, ``model.R[0][1] must ...``)
#: or names as unknown.
_LEADING_KEY = re.compile(
    r"(?:unknown key '([^']*)'|([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*|\[\d+\])*))"
)


def _json_item(data: Any, item: str, msg: str) -> str:
    """The JSON path (``frames[5].detections[1].payoff``) of a scene problem the loader
    names by frame step and id (``frame 5, detection '5:c'``: ``payoff must be ...``): the
    frame and the object by their step and id, then the key the message starts with
    when that object has it."""
    head, _, rest = item.partition(", ")
    if (m := _FRAME.fullmatch(head)) is not None:
        step = int(m.group(1))
        head = _find(data.get("frames"), "frames", lambda f: f.get("step") == step)
    elif (m := _NAMED.fullmatch(head)) is not None:
        tid = m.group(2)
        head = _find(data.get("truth"), "truth", lambda t: t.get("id") == tid)
    elif head.startswith("key '"):
        head = head[len("key '") : -1]
    if (m := _NAMED.fullmatch(rest)) is not None:
        kind = "detections" if m.group(1) == "detection" else "candidates"
        frame = _at(data, head)
        got = frame.get(kind) if isinstance(frame, dict) else None
        # a duplicate id is the later of the two objects, and the id is what is wrong
        dup, did = msg.startswith("duplicate"), m.group(2)
        head = _find(got, f"{head}.{kind}", lambda d: d.get("id") == did, dup)
        msg = "id" if dup else msg
    elif rest:
        head = f"{head}.{rest}"
    obj = _at(data, head)
    key = _LEADING_KEY.match(msg)
    if key is not None and isinstance(obj, dict):
        name = key.group(1) or key.group(2)
        if re.split(r"[.\[]", name)[0] in obj:
            return f"{head}.{name}"
    return head


def _find(
    items: Any, where: str, match: Callable[[dict[str, Any]], bool], last: bool = False
) -> str:
    """``where[i]`` of the first (``last``: the last) object of ``items`` that ``match`` es;
    ``where`` if none."""
    found = where
    if isinstance(items, list):
        for i, x in enumerate(items):
            if isinstance(x, dict) and match(x):
                found = f"{where}[{i}]"
                if not last:
                    break
    return found


def _at(data: Any, item: str) -> Any:
    """The value of ``data`` at ``item`` (:func:`~lesmc.common.locations.item_keys`); None if
    there is none."""
    for key in item_keys(item) or []:
        ok = isinstance(data, dict) if isinstance(key, str) else isinstance(data, list)
        if not ok or (isinstance(key, int) and key >= len(data)):
            return None
        data = data.get(key) if isinstance(key, str) else data[key]
    return data
