"""Reading a results file: strictly, and checked against the shipped schema."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lesmc.common.errors import InputError, Location
from lesmc.common.fields import is_version, show
from lesmc.common.files import read_json
from lesmc.results.document import FORMAT, VERSION
from lesmc.results.references import check_multi_steps, check_references
from lesmc.schemas import validate


def load_results(path: str | Path) -> dict[str, Any]:
    """A results file (``lesmc-results``, or a multi-target design's ``lesmc-multi-check``:
    ``lesmc verify --design sort``, ``lesmc check --design sort --json``), validated; an
    :class:`InputError` otherwise."""
    doc = read_json(Path(path), InputError)
    if isinstance(doc, dict) and doc.get("format") == "lesmc-multi-check":
        validate(doc, "multi-check", str(path))
        check_multi_steps(doc, str(path))
        return doc
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(
            f"not a lesmc results file (format must be '{FORMAT}'; write one with "
            "lesmc verify or lesmc check ... --report DIR)",
            Location(str(path)),
        )
    if not is_version(doc.get("version"), VERSION):
        raise InputError(
            f"must be {VERSION}, got {show(doc.get('version'))} (this lesmc reads results files "
            f"of version {VERSION}: make it again with this lesmc)",
            Location(str(path), item="version"),
        )
    validate(doc, "results", str(path))
    check_references(doc, str(path))
    return doc
