"""Running the real entry point, ``python -m lesmc``, from the tests."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def lesmc(
    *args: str, cwd: Path | None = None, timeout: float = 1200
) -> subprocess.CompletedProcess[str]:
    """``python -m lesmc ARGS`` in ``cwd`` (the repository by default), output captured.

    The repository is on PYTHONPATH, so that processes the command starts itself
    (a campaign's Dask workers) import this checkout too.
    """
    return subprocess.run(
        [sys.executable, "-m", "lesmc", *args],
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
        timeout=timeout,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


def lesmc_logged(
    *args: str, cwd: Path | None = None, timeout: float = 1200
) -> tuple[subprocess.CompletedProcess[str], list[float]]:
    """:func:`lesmc` with stderr read as it comes: also the seconds since the start at
    which each stderr line arrived (stderr is a pipe: the command writes log lines)."""
    import threading
    import time

    proc = subprocess.Popen(
        [sys.executable, "-m", "lesmc", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd or ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    t0 = time.monotonic()
    lines: list[str] = []
    times: list[float] = []

    def read() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            times.append(time.monotonic() - t0)
            lines.append(line)

    out: list[str] = []

    def read_out() -> None:
        assert proc.stdout is not None
        out.append(proc.stdout.read())

    readers = [threading.Thread(target=f, daemon=True) for f in (read, read_out)]
    for t in readers:
        t.start()
    proc.wait(timeout=timeout)
    for t in readers:
        t.join(timeout=10)
    times.append(time.monotonic() - t0)  # the end: the last gap counts too
    done = subprocess.CompletedProcess(proc.args, proc.returncode, "".join(out), "".join(lines))
    return done, times


def sort_hijack_document() -> dict[str, Any]:
    """``lesmc check examples/crossing.json examples/hijack.spec --design sort --json``'s
    ``lesmc-multi-check`` document (the example's hijack is violated: exit 1)."""
    r = lesmc(
        "check", str(ROOT / "examples" / "crossing.json"), str(ROOT / "examples" / "hijack.spec"),
        "--design", "sort", "--json",
    )  # fmt: skip
    assert r.returncode == 1, r.stderr
    doc: dict[str, Any] = json.loads(r.stdout)
    assert doc["format"] == "lesmc-multi-check"
    return doc
