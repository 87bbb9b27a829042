"""``DIR/results.jsonl``: one JSON object per unit, appended as soon as it is known.

Only the client writes it. Each row is one ``write`` of one complete line on a
descriptor opened with O_APPEND, followed by ``fsync``: a crash, Ctrl-C or
SIGKILL leaves at most a torn final line (no newline), which the next run
truncates before appending; a finished key is never written twice.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from lesmc.common.errors import InputError, Location
from lesmc.common.fields import is_version

FORMAT = "lesmc-campaign-row"
VERSION = 2


def read_rows(path: Path, repair: bool = False) -> list[dict[str, Any]]:
    """The complete rows of ``path`` (none if it does not exist).

    A final line without its newline is a write cut short: with ``repair`` it
    is truncated away, otherwise ignored. Any other line that is not a row is
    an error (the file is not ours, or was edited).
    """
    if not path.exists():
        return []
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    if end < len(data) and repair:
        with open(path, "r+b") as fh:
            fh.truncate(end)
            fh.flush()
            os.fsync(fh.fileno())
    rows = []
    for n, line in enumerate(data[:end].splitlines(), start=1):
        try:
            obj = json.loads(line)
        except ValueError as exc:
            raise InputError(f"not a JSON line ({exc})", Location(str(path), n)) from None
        if not (isinstance(obj, dict) and obj.get("format") == FORMAT and "key" in obj):
            raise InputError(f"not a {FORMAT} object", Location(str(path), n))
        if not is_version(obj.get("version"), VERSION):
            raise InputError(
                f"row version {obj.get('version')!r}, expected {VERSION}", Location(str(path), n)
            )
        rows.append(obj)
    return rows


class Appender:
    """Appends rows to ``results.jsonl`` durably, skipping keys it already holds."""

    def __init__(self, path: Path, done: set[str]) -> None:
        self.path = path
        self.done = set(done)
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def append(self, row: dict[str, Any]) -> bool:
        """Write one row (one line, one write, fsync); False if its key is already there."""
        if row["key"] in self.done:
            return False
        line = json.dumps(
            {"format": FORMAT, "version": VERSION, **row}, separators=(",", ":"), allow_nan=False
        )
        data = (line + "\n").encode()
        view = memoryview(data)
        while view:  # a regular file takes it in one write; loop for the exotic cases
            n = os.write(self._fd, view)
            view = view[n:]
        os.fsync(self._fd)
        self.done.add(row["key"])
        return True

    def close(self) -> None:
        os.close(self._fd)

    def __enter__(self) -> Appender:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
