"""The messages of a property file's syntax errors: lark's exception turned into a
:class:`SpecError` at ``FILE:LINE:COL`` that names what was found and, in words, what the
grammar expected there (``allow`` followed by no action has its own message); and the
clipping of long tokens that every message of the parser quotes (lesmc/language/parser.py).
"""

from __future__ import annotations

import re
from collections.abc import Collection
from functools import cache

from lark import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from lesmc.common.errors import Location, SpecError, source_line, split_lines
from lesmc.language import actions
from lesmc.language.lark_parser import lalr_parser

#: Longest token text quoted in a message; longer tokens are clipped.
_SHOWN_TOKEN = 24

#: Readable names for grammar terminals in "expected ..." messages.
_TERMINAL_NAMES = {
    "NAME": "a name",
    "INT": "a whole number",
    "NUMBER": "a number",
    "CMP": "a comparison (>, >=, <, <=)",
    "MATRIX": "a matrix (F, H, Q or R)",
    "FAULT_OP": "'*' (scale) or '=' (set)",
    "NET": "a network (detector or locator)",
    "HOLDS_CMP": "'>' or '>='",
    "NORM": "1, 2 or inf",
    "END": "'end'",
    "PAYOFF_AGG": "'sum' or 'mean'",
    "RANGE_AGG": "'sum' or 'max'",
    "TAU_AGG": "'rise'",
    "LBRACE": "'{'",
    "RBRACE": "'}'",
    "LPAR": "'('",
    "RPAR": "')'",
    "COMMA": "','",
    "DOT": "'.'",
    "$END": "end of file",
}


def syntax_error(exc: UnexpectedInput, text: str, path: str) -> SpecError:
    bare = _bare_allow(exc, text, path)
    if bare is not None:
        return bare
    line = getattr(exc, "line", None) or 1
    col = getattr(exc, "column", None) or 1
    expected: Collection[str]
    if isinstance(exc, UnexpectedEOF):
        lines = split_lines(text)
        line, col = len(lines), len(lines[-1]) + 1
        found = "end of file"
        expected = exc.expected
    elif isinstance(exc, UnexpectedToken):
        found = "end of file" if exc.token.type == "$END" else f"'{clip(str(exc.token))}'"
        expected = exc.accepts or exc.expected
    elif isinstance(exc, UnexpectedCharacters):
        found = f"'{exc.char}'"
        expected = exc.allowed or set()
    else:  # pragma: no cover - lark has no other subclasses
        found, expected = "input", set()
    names = sorted({_terminal_name(t) for t in expected})
    message = f"unexpected {found}"
    if names:
        message += "; expected " + _join(names)
    return SpecError(message, Location(path, line, col, source_line(text, line)))


#: ``allow``, the actions already listed (each followed by a comma), and what follows,
#: up to where the parser stopped: a keyword or nothing
_ALLOW_TAIL = re.compile(
    r"\ballow(?P<gap>\s+)(?:[A-Za-z_][A-Za-z0-9_\-]*\s*,\s*)*"
    r"(?P<word>[A-Za-z_][A-Za-z0-9_\-]*)?\s*$"
)


def _bare_allow(exc: UnexpectedInput, text: str, path: str) -> SpecError | None:
    """``allow`` (or ``allow hide,``) followed by a keyword of the language (``allow end 5``,
    which the lexer reads as an action named ``end``) or by no name at all (``allow }``,
    ``allow hide,`` then ``minimize`` on the next line): "allow needs an
    action" at the keyword or the token after ``allow``; None for any other error."""
    if isinstance(exc, UnexpectedToken):
        stop = len(text) if exc.token.type == "$END" else exc.token.start_pos
    else:
        stop = getattr(exc, "pos_in_stream", None)
    if stop is None:
        return None
    m = _ALLOW_TAIL.search(text, 0, stop)
    if m is None:
        return None
    word = m.group("word")
    if word is not None and (word not in keywords() or word in actions.names()):
        return None
    at = m.start("word") if word is not None else stop
    line = text.count("\n", 0, at) + 1
    col = at - (text.rfind("\n", 0, at) + 1) + 1
    return SpecError(actions.needs_action(word), Location(path, line, col, source_line(text, line)))


@cache
def keywords() -> frozenset[str]:
    """The grammar's keywords (its string terminals that read as names)."""
    out = set()
    for t in lalr_parser().terminals:
        if t.pattern.type == "str" and str(t.pattern.value).isidentifier():
            out.add(str(t.pattern.value))
    return frozenset(out)


def _terminal_name(name: str) -> str:
    if name in _TERMINAL_NAMES:
        return _TERMINAL_NAMES[name]
    pattern = lalr_parser().get_terminal(name).pattern if name in _terminals() else None
    if pattern is not None and pattern.type == "str":
        return f"'{pattern.value}'"
    return name.lower()


@cache
def _terminals() -> frozenset[str]:
    return frozenset(t.name for t in lalr_parser().terminals)


def _join(items: list[str]) -> str:
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " or " + items[-1]


def clip(token: str) -> str:
    """``token`` for a message: long ones (a 5000-digit number) shortened."""
    if len(token) <= _SHOWN_TOKEN:
        return token
    return f"{token[: _SHOWN_TOKEN - 4]}... ({len(token)} characters)"
