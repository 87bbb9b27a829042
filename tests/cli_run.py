"""Running the real entry point, ``python -m lesmc``, from the tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

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
