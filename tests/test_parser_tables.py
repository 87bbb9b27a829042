"""The shipped LALR tables (lesmc/language/lark_tables.py) are current and parse as
the grammar does: a parser built from grammars/lesmc.lark is the oracle."""

from __future__ import annotations

import hashlib
from pathlib import Path

import lark
import pytest
from lark import Lark, UnexpectedInput

from lesmc.language import lark_tables
from lesmc.language.lark_parser import LARK_OPTIONS, grammar_text, lalr_parser

ROOT = Path(__file__).resolve().parents[1]
SPECS = sorted([*ROOT.glob("specs/*.spec"), *ROOT.glob("examples/**/*.spec")])


@pytest.fixture(scope="module")
def built() -> Lark:
    return Lark((ROOT / "grammars" / "lesmc.lark").read_text(encoding="utf-8"), **LARK_OPTIONS)


def test_the_tables_were_made_from_this_grammar() -> None:
    digest = hashlib.sha256(grammar_text().encode("utf-8")).hexdigest()
    assert digest == lark_tables.GRAMMAR_SHA256, "run: python -m lesmc.language.parser"


def test_the_parser_is_loaded_from_the_tables_under_their_lark() -> None:
    if lark.__version__ != lark_tables.LARK_VERSION:
        pytest.skip(f"tables made by lark {lark_tables.LARK_VERSION}, not {lark.__version__}")
    assert lalr_parser().source_path == "<deserialized>"


def outcome(parser: Lark, text: str) -> object:
    """The tree, or the error's kind, position and expected terminals."""
    try:
        return parser.parse(text)
    except UnexpectedInput as exc:
        expected = getattr(exc, "expected", None) or getattr(exc, "allowed", None) or ()
        return type(exc).__name__, exc.line, exc.column, sorted(expected)


def test_loaded_and_built_parsers_agree_on_specs_and_every_truncation(built: Lark) -> None:
    assert SPECS
    loaded = lalr_parser()
    for path in SPECS:
        text = path.read_text(encoding="utf-8")
        assert outcome(loaded, text) == outcome(built, text), path
        for cut in range(0, len(text), 7):  # prefixes end mid-token and mid-clause
            for bad in (text[:cut], text[:cut] + "}", text[:cut] + " @"):
                assert outcome(loaded, bad) == outcome(built, bad), (path, cut, bad[-30:])
