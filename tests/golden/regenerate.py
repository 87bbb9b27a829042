"""Write tests/golden/<case>/expected.json anew from this checkout (an intended change only).

Run ``python tests/golden/regenerate.py`` from the repository, then read ``git diff
tests/golden`` before committing: the test itself never writes these files.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from golden_cases import CASES, GOLDEN, REFERENCE_ENGINE, results


def main() -> None:
    for case in CASES:
        path = GOLDEN / case / "expected.json"
        path.write_text(json.dumps(results(case, REFERENCE_ENGINE), indent=1) + "\n")
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
