"""A model out as the ``.lts`` JSON format itself (docs/lts-format.md): ``lesmc check``
reads it back."""

from __future__ import annotations

from pathlib import Path

from lesmc.common import files
from lesmc.exporters.request import Request
from lesmc.model.arrays import ArrayModel
from lesmc.model.lts_format import lts_document


def write_json(model: ArrayModel, path: str | Path, request: Request) -> dict[str, object]:
    """The JSON writer of the registry (lesmc/exporters/formats.py): JSON whatever the file's
    name (``save_lts`` would choose the binary form for a ``.npz`` name)."""
    files.write_json(path, lts_document(model))
    return {}
