"""One exception hierarchy for everything a user can get wrong.

Every user-facing error renders as ``FILE:LINE:COL: message`` (text files) or
``FILE: <id>: message`` (JSON files, where the offending id is the locator),
optionally followed by the source line and a caret. The CLI prints it and exits
with status 2; nothing else in lesmc prints tracebacks for user mistakes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Self


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
        err = cls("\n".join(lines))
        err.preformatted = True
        return err

    def render(self) -> str:
        """The full user-facing text: locator, message and, if known, a caret line."""
        if self.preformatted:
            return self.message
        if self.location is None:
            return f"error: {self.message}"
        text = f"{self.location.prefix()}: {self.message}"
        loc = self.location
        if loc.source_line is not None and loc.column is not None:
            line = loc.source_line.rstrip("\n")
            # keep tabs so the caret lines up with what the terminal shows
            pad = "".join("\t" if ch == "\t" else " " for ch in line[: max(loc.column - 1, 0)])
            text += f"\n    {line}\n    {pad}^"
        return text

    def __str__(self) -> str:
        return self.render()


class SpecError(LesmcError):
    """A property file is malformed or means something impossible."""


class ModelError(LesmcError):
    """A model (.lts) file is malformed or inconsistent."""


class InputError(LesmcError):
    """Any other input file (CSV items, scenes) is malformed."""


class UsageError(LesmcError):
    """Command-line options that contradict each other or the inputs."""


def source_line(text: str, line: int) -> str | None:
    """The 1-based ``line`` of ``text``, or None when out of range."""
    lines = text.splitlines()
    if 1 <= line <= len(lines):
        return lines[line - 1]
    return None


class Problems:
    """Collects ``(item, message)`` pairs so one validation pass reports every problem."""

    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def add(self, item: str, message: str) -> None:
        self.items.append((item, message))
