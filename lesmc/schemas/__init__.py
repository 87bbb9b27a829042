"""JSON Schemas of lesmc's JSON documents, shipped in the package (``lesmc/schemas/*.json``).

Every document lesmc writes (``--json`` of each verb, results files) has a
``format`` and a ``version`` and is described by one schema here; the tests
validate every output against its schema with the ``jsonschema`` package.
:func:`validate` checks a document at run time with a small validator of the
subset these schemas use (type, enum, const, minimum, maximum, exclusiveMinimum,
pattern, minItems, maxItems, uniqueItems, properties, required, additionalProperties,
items, anyOf, oneOf, $ref to #/$defs), so that reading a results file needs no extra dependency.
"""

from __future__ import annotations

import json
import re
from collections.abc import Hashable
from functools import cache
from importlib import resources
from typing import Any

from lesmc.common.errors import InputError, Location
from lesmc.common.locations import error_at_items
from lesmc.designs import registry
from lesmc.engines import payoff_modes
from lesmc.engines import registry as engines
from lesmc.exporters import formats
from lesmc.language import actions, measures

#: format name of each document -> its schema file (without .json)
SCHEMAS = {
    "lesmc-results": "results",
    "lesmc-check": "check",
    "lesmc-multi-check": "multi-check",
    "lesmc-track": "track",
    "lesmc-report": "report",
    "lesmc-build": "build",
    "lesmc-synth": "synth",
    "lesmc-train": "train",
    "lesmc-reduce": "reduce",
    "lesmc-perceive": "perceive",
    "lesmc-campaign-summary": "campaign-summary",
    "lesmc-campaign-row": "campaign-row",
    "lesmc-replay": "replay",
    "lesmc-error": "error",
    "lesmc-export": "export",
    "lesmc-import": "import",
    "lesmc-alarms": "alarms",
    "lesmc-tune": "tune",
}


@cache
def _text(name: str) -> str:
    return resources.files("lesmc.schemas").joinpath(f"{name}.json").read_text(encoding="utf-8")


def schema(name: str) -> dict[str, Any]:
    """The schema ``lesmc/schemas/NAME.json``, with the registries' names.

    The enums of registered names are not spelled in the files; they are filled from
    the registries now, so that a variant registered at run time is accepted too:
    ``#/$defs/designs`` (every registered design), ``#/$defs/trackers`` (the designs
    that bring a tracker) and ``#/$defs/multi_designs`` (the multi-target designs) from
    lesmc/designs/registry.py, ``#/$defs/engines`` and ``#/$defs/multi_engine`` (the
    multi-target designs' engine) from lesmc/engines/registry.py,
    ``#/$defs/payoff_modes`` from lesmc/engines/payoff_modes.py,
    ``#/$defs/export_formats`` from lesmc/exporters/formats.py (and, in the export
    document, the MDP facts each property-stating format writes under its name),
    ``#/$defs/measure_sources`` (a property's ``objective_source``,
    ``constraint_source``) from lesmc/language/measures/ and ``#/$defs/attack_actions``
    from lesmc/language/actions.py.
    """
    out: dict[str, Any] = json.loads(_text(name))
    defs = out.setdefault("$defs", {})
    defs["designs"] = {"enum": list(registry.names())}
    defs["trackers"] = {"enum": list(registry.tracker_names())}
    defs["multi_designs"] = {"enum": list(registry.multi_names())}
    defs["engines"] = {"enum": list(engines.names())}
    defs["multi_engine"] = {"const": engines.MULTI}
    defs["payoff_modes"] = {"enum": list(payoff_modes.names())}
    defs["export_formats"] = {"enum": list(formats.names())}
    defs["measure_sources"] = {"enum": list(measures.sources())}
    defs["attack_actions"] = {"enum": list(actions.names())}
    if name == "export":  # a property's MDP: its size, under the format's name
        for fmt in formats.where(lambda f: f.states_property):
            out["properties"][fmt] = {"$ref": "#/$defs/mdp"}
    return out


_TYPES: dict[str, tuple[type, ...]] = {
    "object": (dict,),
    "array": (list,),
    "string": (str,),
    "boolean": (bool,),
    "null": (type(None),),
    "integer": (int,),
    "number": (int, float),
}


def _is(value: Any, t: str) -> bool:
    if t in ("integer", "number") and isinstance(value, bool):
        return False
    return isinstance(value, _TYPES[t])


def errors(value: Any, sch: dict[str, Any], root: dict[str, Any], where: str = "") -> list[str]:
    """Where ``value`` breaks ``sch`` (empty: it conforms), as 'path: what' lines."""
    if "$ref" in sch:
        name = sch["$ref"].removeprefix("#/$defs/")
        return errors(value, root["$defs"][name], root, where)
    at = where or "(document)"
    if "type" in sch:
        types = sch["type"] if isinstance(sch["type"], list) else [sch["type"]]
        if not any(_is(value, t) for t in types):
            return [f"{at}: expected {' or '.join(types)}, got {type(value).__name__}"]
    out = _siblings(value, sch, root, where)
    for key in ("anyOf", "oneOf"):  # beside the node's own checks, not instead of them
        if key in sch:
            out += _forms(value, sch[key], root, where, one=key == "oneOf")
    return out


def _siblings(value: Any, sch: dict[str, Any], root: dict[str, Any], where: str) -> list[str]:
    """Where ``value`` breaks the checks of ``sch`` other than ``type`` and its forms."""
    at = where or "(document)"
    out: list[str] = []
    # equal as JSON Schema reads them: 1 and 1.0 are, true and 1 (or false and 0) are not
    if "const" in sch and _canonical(value) != _canonical(sch["const"]):
        out.append(f"{at}: must be {sch['const']!r}")
    if "enum" in sch and _canonical(value) not in {_canonical(e) for e in sch["enum"]}:
        out.append(f"{at}: must be one of {', '.join(map(repr, sch['enum']))}")
    out += _bounds(value, sch, at)
    if "pattern" in sch and isinstance(value, str) and not re.search(sch["pattern"], value):
        out.append(f"{at}: must match {sch['pattern']}")
    if isinstance(value, list):
        if len(value) < sch.get("minItems", 0):
            out.append(f"{at}: must have at least {sch['minItems']} items")
        if "maxItems" in sch and len(value) > sch["maxItems"]:
            out.append(f"{at}: must have at most {sch['maxItems']} items")
        if sch.get("uniqueItems") and _repeats(value):
            out.append(f"{at}: must not repeat an item")
    if isinstance(value, dict):
        for key in sch.get("required", []):
            if key not in value:
                out.append(f"{at}: missing '{key}'")
        props = sch.get("properties", {})
        extra = sch.get("additionalProperties", True)
        for key, v in value.items():
            sub = f"{where}.{key}" if where else key
            if key in props:
                out += errors(v, props[key], root, sub)
            elif extra is False:
                out.append(f"{at}: unknown field '{key}'")
            elif isinstance(extra, dict):
                out += errors(v, extra, root, sub)
    if isinstance(value, list) and "items" in sch:
        for i, v in enumerate(value):
            out += errors(v, sch["items"], root, f"{where}[{i}]")
    return out


def _repeats(items: list[Any]) -> bool:
    """Whether two of ``items`` are equal as JSON Schema reads them (1 and 1.0 are); one
    pass over hashable keys, so that a long hostile list costs linear time."""
    keys = {_canonical(v) for v in items}
    return len(keys) < len(items)


def _canonical(value: Any) -> Hashable:
    """A hashable key of ``value`` that is equal exactly where JSON Schema calls two values
    equal: each number as a float, each bool apart from the numbers, key order ignored."""
    if isinstance(value, bool):
        return ("bool", value)
    if isinstance(value, (int, float)):
        return ("number", float(value))
    if isinstance(value, list):
        return ("array", tuple(_canonical(v) for v in value))
    if isinstance(value, dict):
        return ("object", frozenset((k, _canonical(v)) for k, v in value.items()))
    return ("other", value)


def _forms(
    value: Any, forms: list[dict[str, Any]], root: dict[str, Any], where: str, one: bool
) -> list[str]:
    """``anyOf`` (``one`` False) or ``oneOf``: where ``value`` matches none of ``forms``
    (or, for ``oneOf``, more than one)."""
    at = where or "(document)"
    each = [errors(value, s, root, where) for s in forms]
    matched = sum(not e for e in each)
    if one and matched > 1:
        return [f"{at}: matches more than one of the allowed forms"]
    if matched:
        return []
    # the one form of the value's type (a nullable array, say): the field it breaks
    typed = [e for e in each if not e[0].startswith(f"{at}: expected ")]
    return typed[0] if len(typed) == 1 else [f"{at}: matches none of the allowed forms"]


def _bounds(value: Any, sch: dict[str, Any], at: str) -> list[str]:
    """A number's ``minimum``, ``maximum`` and ``exclusiveMinimum``."""
    if not _is(value, "number"):
        return []
    out = []
    if "minimum" in sch and value < sch["minimum"]:
        out.append(f"{at}: must be >= {sch['minimum']}")
    if "maximum" in sch and value > sch["maximum"]:
        out.append(f"{at}: must be <= {sch['maximum']}")
    if "exclusiveMinimum" in sch and value <= sch["exclusiveMinimum"]:
        out.append(f"{at}: must be > {sch['exclusiveMinimum']}")
    return out


def validate(doc: Any, name: str, path: str = "<document>", text: str | None = None) -> None:
    """Raise an InputError naming the first offending field when ``doc`` breaks schema NAME;
    given the JSON ``text`` ``doc`` was read from, at the field's ``FILE:LINE:COL``."""
    sch = schema(name)
    problems = errors(doc, sch, sch)
    if problems:
        field, _, what = problems[0].partition(": ")
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        if text is None:
            raise InputError(f"{what}{more}", Location(path, item=field))
        whole = field == "(document)"
        raise error_at_items(
            path, text, [(field, f"{what}{more}")], lambda f, _: "" if whole else f
        )
