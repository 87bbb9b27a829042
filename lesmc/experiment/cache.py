"""What ``lesmc verify`` computed before, kept under OUT/cache by the content of its inputs.

Perception (detections and attack payoffs), the monitor's false alarms on the
truth, the replay of the counterexamples and the report's figures are the slow
stages of a verify (docs/performance.md). Each is stored as a JSON file named by
a SHA-256 digest of everything it depends on: the bytes of the frames, of the
networks' files, of the truth, the settings, and the source code of the packages
that compute it (so an edited lesmc never reads a stale entry; a figure's digest:
lesmc/report/figure_cache.py). A rerun with unchanged inputs reads the
entry instead of computing it; anything else computes it again and writes a new
entry. Nothing is ever unpickled: an entry is JSON, read by the strict reader and
checked like any input (a perception entry is a scene file, validated as one);
a broken or foreign entry is ignored and recomputed, never an error.

The cache lives inside the ``--out`` directory the user named; ``rm -r OUT/cache``
empties it.
"""

from __future__ import annotations

import base64
import binascii
import functools
import hashlib
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from lesmc.common.errors import LesmcError
from lesmc.common.files import read_json, write_json

FORMAT = "lesmc-cache"
VERSION = 1
#: lesmc's root package directory (the source of the code digests).
PACKAGE = Path(__file__).resolve().parents[1]


def digest(value: Any) -> str:
    """SHA-256 of a JSON value, keys sorted: the same inputs give the same digest."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def file_digests(paths: Iterable[Path]) -> list[list[str]]:
    """Each file's name and the SHA-256 of its bytes (read once per run while the file's
    size and modification time stay the same: perception and replay key on the frames)."""
    out = []
    for p in paths:
        st = p.stat()
        out.append([p.name, _sha256(str(p), st.st_size, st.st_mtime_ns)])
    return out


@functools.lru_cache(maxsize=4096)
def _sha256(path: str, size: int, mtime_ns: int) -> str:
    """The SHA-256 of a file's bytes (``size`` and ``mtime_ns`` key the memo)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@functools.cache
def code_digest(*packages: str) -> str:
    """SHA-256 of the Python sources of lesmc's ``packages`` (e.g. ``perception``): the
    code does not change while lesmc runs, so once per process."""
    h = hashlib.sha256()
    for name in packages:
        for p in sorted((PACKAGE / name).rglob("*.py")):
            h.update(str(p.relative_to(PACKAGE)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def net_files(nets: tuple[str | None, str | None, str | None]) -> list[Path]:
    """The files a network pair is loaded from (``--nets``, ``--detector``, ``--locator``;
    default: the shipped weights), without loading them (no torch)."""
    directory, detector, locator = nets
    d = Path(directory) if directory else PACKAGE / "perception" / "weights" / "wami"
    files = [d / "nets.json", d / "dr.safetensors", d / "lp.safetensors"]
    return files + [Path(f) for f in (detector, locator) if f]


class StageCache:
    """Entries ``OUT/cache/STAGE-DIGEST.json``: ``get`` a stage's value by the digest of its
    inputs, ``put`` one."""

    def __init__(self, out: Path) -> None:
        self.dir = out / "cache"

    def path(self, stage: str, key: str) -> Path:
        """Where the entry of ``stage`` under ``key`` is (or would be) kept."""
        return self.dir / f"{stage}-{key}.json"

    def get(self, stage: str, key: str) -> Any | None:
        """The stored value, or None (absent, unreadable, or not this stage's entry)."""
        path = self.path(stage, key)
        if not path.is_file():
            return None
        try:
            doc = read_json(path)
        except LesmcError:
            return None
        ok = (
            isinstance(doc, dict)
            and doc.get("format") == FORMAT
            and doc.get("version") == VERSION
            and doc.get("stage") == stage
            and doc.get("key") == key
            and "value" in doc
        )
        return doc["value"] if ok else None

    def put(self, stage: str, key: str, value: Any) -> None:
        """Store ``value`` (JSON) atomically; a cache that cannot be written is no error."""
        doc = {"format": FORMAT, "version": VERSION, "stage": stage, "key": key, "value": value}
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            write_json(self.path(stage, key), doc)
        except (OSError, LesmcError, ValueError):
            pass


#: The first bytes of every PNG file.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class FigureStore:
    """The report's figures as stage ``figure`` of a :class:`StageCache`, keyed by the digest
    of what each is drawn from (lesmc/report/figure_cache.py): the PNG in base64 with its
    SHA-256, which a read checks (a damaged entry is drawn again)."""

    def __init__(self, cache: StageCache) -> None:
        self.cache = cache
        self.asked = 0
        self.found = 0

    def get(self, key: str) -> bytes | None:
        """The PNG kept under ``key``, or None."""
        self.asked += 1
        value = self.cache.get("figure", key)
        if not (isinstance(value, dict) and isinstance(value.get("png"), str)):
            return None
        try:
            png = base64.b64decode(value["png"], validate=True)
        except (binascii.Error, ValueError):
            return None
        if not png.startswith(PNG_SIGNATURE) or hashlib.sha256(png).hexdigest() != value.get(
            "sha256"
        ):
            return None
        self.found += 1
        return png

    def put(self, key: str, png: bytes) -> None:
        """Keep ``png`` under ``key`` (no error if the cache cannot be written)."""
        value = {"png": base64.b64encode(png).decode(), "sha256": hashlib.sha256(png).hexdigest()}
        self.cache.put("figure", key, value)
