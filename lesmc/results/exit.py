"""The exit-status contract of ``lesmc check`` (and of every verb that checks).

Light on purpose (no lesmc imports at run time): the command line's entry point
reads the constants before any command has imported the engines.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lesmc.engines.result import CheckResult

EXIT_HOLDS = 0
"""Every property holds."""
EXIT_VIOLATED = 1
"""At least one property is violated (takes precedence over unknown: a real failure)."""
EXIT_USAGE = 2
"""Bad input or usage; nothing was checked or written."""
EXIT_UNKNOWN = 3
"""None violated, but a budget ran out before at least one verdict was proven."""
EXIT_INTERNAL = 4
"""A bug in lesmc (an unexpected exception): no verdict; please report it."""
EXIT_INTERRUPTED = 130
"""Interrupted (SIGINT, Ctrl-C): no verdict (128 + SIGINT, as shells report it)."""


def exit_status(results: Sequence[CheckResult]) -> int:
    """0 all hold, 1 some violated, 3 some unknown (and none violated)."""
    verdicts = {r.verdict for r in results}
    if "violated" in verdicts:
        return EXIT_VIOLATED
    if "unknown" in verdicts:
        return EXIT_UNKNOWN
    return EXIT_HOLDS
