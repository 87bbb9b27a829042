"""One exception hierarchy for everything a user can get wrong.

Every user-facing error renders as ``FILE:LINE:COL: message`` (text files) or
``FILE: <id>: message`` (JSON files, where the offending id is the locator),
optionally followed by the source line and a caret. The CLI prints it and exits
with status 2; nothing else in lesmc prints tracebacks for user mistakes.

Lines are counted at ``\\n`` only (:func:`split_lines`), as lark and ``json``
count them. Text from input files is shown with control characters escaped
(:func:`escape_control`); :func:`escape_text` also neutralises rich markup, for
tables and other output printed through rich.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Self

#: Characters that must not reach a terminal verbatim: C0 controls except tab and
#: newline, DEL, C1 controls, lone surrogates, line/paragraph separators and the
#: bidirectional overrides and isolates (which can make text read out of order).
_CONTROL_RE = re.compile(
    r"[\x00-\x08\x0b-\x1f\x7f-\x9f\ud800-\udfff\u2028\u2029\u200e\u200f\u202a-\u202e\u2066-\u2069]"
)

#: Longest stretch of a quoted source line shown on each side of the caret.
_SHOWN_HALF = 80


def _escape_char(match: re.Match[str]) -> str:
    code = ord(match.group())
    return f"\\x{code:02x}" if code <= 0xFF else f"\\u{code:04x}"


def escape_control(text: str) -> str:
    """``text`` with terminal control characters shown as ``\\x1b``, ``\\u2028`` etc.

    Tabs and newlines are kept; so is everything printable. Used on every string
    from an input file that an error message quotes.
    """
    if _CONTROL_RE.search(text) is None:
        return text
    return _CONTROL_RE.sub(_escape_char, text)


def clipped(text: str, limit: int = 40) -> str:
    """``text`` from the user as a message quotes it: escaped (:func:`escape_control`),
    cut to ``limit`` characters with ``...``."""
    return escape_control(text if len(text) <= limit else text[: limit - 3] + "...")


def exception_line(exc: BaseException) -> str:
    """An exception's message as one line of a user's error (a library's, torch's for one,
    may run to many lines)."""
    lines = str(exc).strip().splitlines()
    return clipped(f"{type(exc).__name__}: {lines[0] if lines else ''}", 300)


def escape_text(text: str) -> str:
    """``text`` made safe to print through rich: no markup, no control characters.

    Ids, observation names and messages read from input files may contain ``[``
    (rich markup) or escape sequences; pass them through this before handing them
    to a rich ``Console``/``Table``. The result shows the same text, escapes
    written out (``\\x1b``), markup brackets preceded by a backslash that rich
    removes again when rendering.
    """
    from rich.markup import escape  # lazy: rich is slow to import and errors.py is not

    return escape(escape_control(text))


def split_lines(text: str) -> list[str]:
    """The lines of ``text``: split at ``\\n`` only, a ``\\r`` before it dropped.

    This is the rule the spec parser (lark) and ``json`` use to count lines and
    columns; ``str.splitlines`` also splits at ``\\x0b``, ``\\x0c``, ``\\x1c``-``\\x1e``,
    ``\\x85``, U+2028 and U+2029 and so must not be used for positions.
    """
    return [line.removesuffix("\r") for line in text.split("\n")]


@dataclass
class Location:
    """Where in an input file a problem is: a text position or a JSON object id."""

    path: str
    line: int | None = None
    column: int | None = None
    source_line: str | None = None
    item: str | None = None

    def prefix(self) -> str:
        """``FILE:LINE:COL`` or ``FILE: item`` or ``FILE``."""
        if self.line is not None:
            col = self.column if self.column is not None else 1
            return f"{self.path}:{self.line}:{col}"
        if self.item is not None:
            return f"{self.path}: {self.item}"
        return self.path

    @classmethod
    def at(cls, path: str, text: str, pos: int) -> Location:
        """The location of character offset ``pos`` of ``text`` (lines split at ``\\n``)."""
        pos = min(max(pos, 0), len(text))
        line_start = text.rfind("\n", 0, pos) + 1
        line_end = text.find("\n", pos)
        shown = text[line_start : len(text) if line_end < 0 else line_end].removesuffix("\r")
        return cls(path, text.count("\n", 0, pos) + 1, pos - line_start + 1, shown)


class LesmcError(Exception):
    """Base class of the errors lesmc reports to users (exit status 2)."""

    def __init__(self, message: str, location: Location | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.location = location
        self.preformatted = False

    @classmethod
    def many(cls, path: str, problems: list[tuple[str, str]], limit: int = 20) -> Self:
        """One error listing every ``(item, message)`` problem, a line each."""
        lines = [f"{path}: {item}: {msg}" if item else f"{path}: {msg}" for item, msg in problems]
        if len(lines) > limit:
            lines = [*lines[:limit], f"{path}: ... and {len(problems) - limit} more problems"]
        first = problems[0][0] if problems else ""
        err = cls("\n".join(lines), Location(path, item=first or None))
        err.preformatted = True
        return err

    def render(self) -> str:
        """The full user-facing text: locator, message and, if known, a caret line.

        Control characters from the input (in the path, item, message or quoted
        line) are shown escaped, so that an error never drives the terminal.
        """
        if self.preformatted:
            return escape_control(self.message)
        if self.location is None:
            return f"error: {escape_control(self.message)}"
        loc = self.location
        text = escape_control(f"{loc.prefix()}: {self.message}")
        if loc.source_line is not None and loc.column is not None:
            text += _quote(loc.source_line, loc.column)
        return text

    def __str__(self) -> str:
        return self.render()


class InputError(LesmcError):
    """An input file is malformed (with its file, line and column, or the JSON item)."""


class SpecError(InputError):
    """A property file is malformed or means something impossible."""


class ModelError(InputError):
    """A model (.lts) file is malformed or inconsistent."""


class UsageError(LesmcError):
    """Command-line options that contradict each other or the inputs."""


class BudgetError(LesmcError):
    """A budget (``--timeout``, ``--max-states``, ``--max-memory``) ran out before a
    command that has no verdict to give (``build``) was done: exit 3, nothing written."""


def source_line(text: str, line: int) -> str | None:
    """The 1-based ``line`` of ``text`` as :func:`split_lines` counts, or None when out of range."""
    if line < 1:
        return None
    parts = text.split("\n", line)
    if len(parts) < line:
        return None
    return parts[line - 1].removesuffix("\r")


def _quote(line: str, column: int) -> str:
    """The quoted source line and a caret under ``column``, escaped and clipped."""
    line = line.rstrip("\r\n")
    cut = min(max(column - 1, 0), len(line))
    # clipped before escaping too, so that a long line costs no more than a short one
    before = escape_control(line[max(cut - _SHOWN_HALF, 0) : cut])
    after = escape_control(line[cut : cut + _SHOWN_HALF])
    if len(before) > _SHOWN_HALF or cut > _SHOWN_HALF:
        before = "…" + before[-_SHOWN_HALF:]
    if len(after) > _SHOWN_HALF or len(line) - cut > _SHOWN_HALF:
        after = after[:_SHOWN_HALF] + "…"
    # keep tabs so the caret lines up with what the terminal shows
    pad = "".join("\t" if ch == "\t" else " " for ch in before)
    return f"\n    {before}{after}\n    {pad}^"


class Problems:
    """Collects ``(item, message)`` pairs so one validation pass reports every problem."""

    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def add(self, item: str, message: str) -> None:
        self.items.append((item, message))
