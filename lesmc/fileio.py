"""File plumbing shared by every stage: strict JSON reading and atomic writing."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from lesmc.errors import InputError, LesmcError, Location, source_line


def read_json(path: str | Path, error: type[LesmcError] = InputError) -> Any:
    """Parse a JSON file; syntax errors and NaN/Infinity become ``FILE:LINE:COL`` errors."""

    def reject(token: str) -> Any:
        raise ValueError(f"{token} is not allowed (numbers must be finite)")

    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"cannot read file: {exc}", Location(str(path))) from None
    try:
        return json.loads(text, parse_constant=reject)
    except json.JSONDecodeError as exc:
        loc = Location(str(path), exc.lineno, exc.colno, source_line(text, exc.lineno))
        raise error(f"invalid JSON: {exc.msg}", loc) from None
    except ValueError as exc:
        raise error(str(exc), Location(str(path))) from None


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` so that readers never see a half-written file."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: str | Path, data: Any) -> None:
    """Atomically write ``data`` as indented JSON (NaN and infinities are refused)."""
    atomic_write_text(path, json.dumps(data, indent=1, allow_nan=False) + "\n")
