"""The golden cases (tests/golden/<case>/): how their results are computed and compared.

Shared by tests/test_golden.py, which compares, and tests/golden/regenerate.py, which
writes the expected files when a change is intended (a reviewer reads the diff).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from lesmc.engines.check import check
from lesmc.language.parser import load_spec
from lesmc.model.lts_format import load_lts

GOLDEN = Path(__file__).parent / "golden"
CASES = sorted(p.name for p in GOLDEN.iterdir() if (p / "model.lts").exists())
#: The engine whose answer the expected files hold (the others may tie-break otherwise).
REFERENCE_ENGINE = "bnb"


def results(case: str, engine: str) -> list[dict[str, Any]]:
    """``lesmc check --json``'s results of a case, without statistics; spec paths relative
    to the case's folder (so that the files do not depend on the checkout's place)."""
    d = GOLDEN / case
    cwd = os.getcwd()
    os.chdir(d)
    try:
        specs = [load_spec(p.name) for p in sorted(d.glob("*.spec"))]
        got = check(load_lts("model.lts"), specs, engine=engine)  # type: ignore[arg-type]
    finally:
        os.chdir(cwd)
    out = []
    for r in got:
        doc = r.to_dict()
        doc.pop("stats")
        out.append(doc)
    return out
