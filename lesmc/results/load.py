"""Reading a results file: strictly, and checked against the shipped schema; each problem
at its field's ``FILE:LINE:COL``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lesmc.common.errors import InputError, Location
from lesmc.common.fields import is_version, show
from lesmc.common.files import parse_json, read_text
from lesmc.common.locations import json_location
from lesmc.results.document import FORMAT, VERSION
from lesmc.results.references import check_multi_steps, check_references
from lesmc.schemas import validate


def replay_ok(obj: Any, document: str) -> bool:
    """Whether ``obj`` is a replay object as a result of the ``document`` schema holds one
    (``"results"``: a point design's, ``"multi-check"``: a multi-target design's): an
    OUT/cache entry read back is trusted only then (a corrupted or hand-edited one is
    replayed again, not copied into the results)."""
    from lesmc.schemas import errors, schema

    root = schema(document)
    defs = root["$defs"]
    part = defs["replay"] if document == "results" else defs["result"]["properties"]["replay"]
    return isinstance(obj, dict) and not errors(obj, part, root)


def load_results(path: str | Path) -> dict[str, Any]:
    """A results file (``lesmc-results``, or a multi-target design's ``lesmc-multi-check``:
    ``lesmc verify --design sort``, ``lesmc check --design sort --json``), validated; an
    :class:`InputError` otherwise."""
    text = read_text(Path(path))
    doc = parse_json(text, str(path))
    if isinstance(doc, dict) and doc.get("format") == "lesmc-multi-check":
        validate(doc, "multi-check", str(path), text)
        check_multi_steps(doc, str(path), text)
        return doc
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(
            f"not a lesmc results file (format must be '{FORMAT}'; write one with "
            "lesmc verify or lesmc check ... --report DIR)",
            Location(str(path)),
        )
    if not is_version(doc.get("version"), VERSION):
        raise InputError(
            f"version: must be {VERSION}, got {show(doc.get('version'))} (this lesmc reads "
            f"results files of version {VERSION}: make it again with this lesmc)",
            json_location(str(path), text, "version"),
        )
    validate(doc, "results", str(path), text)
    check_references(doc, str(path), text)
    return doc
