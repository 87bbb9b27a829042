"""The LALR parser of the property language (grammars/lesmc.lark): loaded from its
generated tables (:mod:`.lark_tables`) when they were made from this grammar by this
lark, else built from the grammar; and the tables' source (``python -m
lesmc.language.parser`` writes them). lesmc/language/parser.py parses with it,
lesmc/language/syntax_errors.py names its terminals in messages.
"""

from __future__ import annotations

import hashlib
from contextlib import suppress
from functools import cache
from pathlib import Path
from typing import Any

from lark import Lark
from lark import __version__ as lark_version
from lark.grammar import Rule
from lark.lexer import TerminalDef


def grammar_text() -> str:
    """The grammar source: packaged copy when installed, else the repository's."""
    packaged = Path(__file__).with_name("lesmc.lark")  # importlib.resources costs 50 ms
    if packaged.is_file():
        return packaged.read_text(encoding="utf-8")
    repo = Path(__file__).resolve().parents[2] / "grammars" / "lesmc.lark"
    return repo.read_text(encoding="utf-8")


LARK_OPTIONS: dict[str, Any] = {
    "parser": "lalr",
    "lexer": "contextual",
    "propagate_positions": True,
}
TABLES = Path(__file__).with_name("lark_tables.py")


@cache
def lalr_parser() -> Lark:
    """The LALR parser: loaded from :mod:`.lark_tables` (5 ms) when they were made
    from this grammar by this lark, else built from the grammar (70 ms)."""
    text = grammar_text()
    from lesmc.language import lark_tables

    if _grammar_key(text) == (lark_tables.GRAMMAR_SHA256, lark_tables.LARK_VERSION):
        with suppress(Exception):  # a private lark API (as its standalone tool uses)
            return Lark._load_from_dict(lark_tables.DATA, lark_tables.MEMO)  # type: ignore[no-untyped-call,no-any-return]
    return Lark(text, **LARK_OPTIONS)


def _grammar_key(text: str) -> tuple[str, str]:
    return hashlib.sha256(text.encode("utf-8")).hexdigest(), lark_version


def tables_source() -> str:
    """The source of :mod:`.lark_tables`, built now from the grammar."""
    text = grammar_text()
    built = Lark(text, **LARK_OPTIONS)
    data, memo = built.memo_serialize([TerminalDef, Rule])
    digest, version = _grammar_key(text)
    return (
        '"""LALR tables of grammars/lesmc.lark, serialized by lark: generated, do not edit.\n\n'
        "Made by ``python -m lesmc.language.parser``; loading them saves building the\n"
        "parser at every start. They are used only while the grammar's hash and lark's\n"
        'version match (tests/test_parser_tables.py checks that they are current)."""\n\n'
        "from typing import Any\n\n"
        f"GRAMMAR_SHA256 = {digest!r}\n"
        f"LARK_VERSION = {version!r}\n"
        f"DATA: dict[str, Any] = {data!r}\n"
        f"MEMO: dict[Any, Any] = {memo!r}\n"
    )
