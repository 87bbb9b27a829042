"""How many random cases the injection tests run (issue 61's acceptance scale).

The default run keeps a sample that fits the suite's time; ``LESMC_INJECT_FULL=1`` runs
the issue's scale: 200 random models/scenes per design against the brute forces, and
Storm on 60 exported models (docs/semantics.md, "Injection on the joint design")."""

from __future__ import annotations

import os

#: the issue's scale is asked for
FULL = os.environ.get("LESMC_INJECT_FULL", "") not in ("", "0")


def cases(default: int, full: int) -> int:
    """``full`` under ``LESMC_INJECT_FULL=1``, else ``default``."""
    return full if FULL else default
