"""Whether a note beside a verdict contradicts it (issue 56, item 1): shared by the report's
text check (tests/test_report_agrees.py) and the browser's (tests/test_browser.py)."""

from __future__ import annotations

#: The verdict words (docs/cli.md, "Verdicts"), written out again.
WORDS = ("holds (vacuous)", "holds", "violated (not replayed)", "violated", "unknown")


def _word(note: str) -> str | None:
    """The verdict word a note starts with ("unknown: ..."), if any."""
    return next((w for w in WORDS if note.startswith(w + ":")), None)


def contradictions(status: str, notes: list[str]) -> list[str]:
    """Notes that say another verdict than ``status``, or ask for a replay of a result whose
    status is not "violated (not replayed)"."""
    out = []
    for n in notes:
        w = _word(n)
        wrong_word = w is not None and w != status
        wrong_replay = "not replayed" in n and status != "violated (not replayed)"
        if wrong_word or wrong_replay:
            out.append(f"{status!r} beside the note {n!r}")
    return out
