"""Hostile inputs: spec and JSON files only ever give positioned LesmcErrors, never tracebacks.

Hypothesis mutates the shipped specs and the test models/scenes (odd line
separators, digits of other scripts, huge numbers, deep nesting, bad UTF-8)
and checks that the parsers return or raise a LesmcError whose position lies
inside the text and quotes that very line; then one explicit test per problem
the fuzzing campaign found.
"""

from __future__ import annotations

import codecs
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lesmc.common.errors import (
    InputError,
    LesmcError,
    Location,
    ModelError,
    SpecError,
    escape_control,
    escape_text,
    source_line,
    split_lines,
)
from lesmc.common.files import MAX_JSON_DEPTH, _deeper_than, decode_text, parse_json, read_json
from lesmc.language.parser import MAX_STEP, load_spec, parse_spec
from lesmc.model.lts_format import load_lts

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
SPEC_TEXTS = [
    p.read_text(encoding="utf-8")
    for p in sorted(
        [
            *(ROOT / "specs").glob("*.spec"),
            *(TESTS / "golden").glob("*/*.spec"),
            *(TESTS / "scenes").glob("*.spec"),
        ]
    )
]
JSON_TEXTS = [
    p.read_text(encoding="utf-8")
    for p in sorted(
        [
            *(TESTS / "scenes").glob("*.json"),
            TESTS / "golden" / "tiny" / "model.lts",
            TESTS / "golden" / "knapsack12" / "model.lts",
        ]
    )
]
BOM = "\ufeff"

#: Characters str.splitlines() splits at but lark and json do not.
ODD_SEPARATORS = ["\u2028", "\u2029", "\x0b", "\x0c", "\x1c", "\x1d", "\x1e", "\x85"]
FOREIGN_DIGITS = ["٦", "٨", "۳", "०", "৭", "１", "߂", "𝟕"]
HUGE_NUMBERS = [
    "9" * 5000,
    "1" + "0" * 400,
    "1e400",
    "-1e400",
    "1e-400",
    "0" * 30 + "7",
    "1000001",
    "99999999999999999999",
    "9223372036854775808",
    "-9223372036854775809",
    "12345678901234567890.5",
]
COMMON = [
    *ODD_SEPARATORS,
    *FOREIGN_DIGITS,
    *HUGE_NUMBERS,
    "\n",
    "\r\n",
    "\r",
    "\t",
    " ",
    "\x00",
    "\x1b[31m",
    "\x9b",
    "\ud800",
    BOM,
    "é",
    "😀",
    "[bold]",
]
SPEC_PIECES = [
    *COMMON,
    "..",
    ".",
    "{",
    "}",
    "(",
    ")",
    ",",
    "#",
    "end",
    "inf",
    "property q {",
    "attack window",
    "minimize payoff",
    "holds if optimum >",
    "subject to",
    "dist.at(",
    "monitor uncertainty tolerance",
    "norm ",
    "on x, y",
]
JSON_PIECES = [
    *COMMON,
    "NaN",
    "Infinity",
    "-Infinity",
    "{",
    "}",
    "[",
    "]",
    ",",
    ":",
    '"',
    '"id": "x",',
    '"step": 1,',
    "\\",
    "\\u",
    "\\ud800",
    '\\"',
    "true",
    "null",
    "[" * 70,
    "]" * 70,
    "[" * 3000,
    "{" * 3000,
]


@st.composite
def mutated(draw: st.DrawFn, bases: list[str], pieces: list[str]) -> str:
    """A base text after 1-4 insertions, deletions, replacements or number swaps."""
    text = draw(st.sampled_from(bases))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["insert", "delete", "replace", "number", "nest"]))
        pos = draw(st.integers(0, len(text)))
        piece = draw(st.one_of(st.sampled_from(pieces), st.text(max_size=3)))
        if op == "insert":
            text = text[:pos] + piece + text[pos:]
        elif op == "delete":
            text = text[:pos] + text[pos + draw(st.integers(1, 8)) :]
        elif op == "replace":
            text = text[:pos] + piece + text[pos + len(piece) :]
        elif op == "number":
            numbers = list(re.finditer(r"[0-9]+(?:\.[0-9]+)?", text))
            if numbers:
                m = draw(st.sampled_from(numbers))
                new = draw(st.sampled_from([*HUGE_NUMBERS, *FOREIGN_DIGITS, "٦٧"]))
                text = text[: m.start()] + new + text[m.end() :]
        else:  # nest: a value wrapped in many brackets
            depth = draw(st.sampled_from([MAX_JSON_DEPTH - 1, MAX_JSON_DEPTH, 65, 200, 20000]))
            text = text[:pos] + "[" * depth + "1" + "]" * depth + text[pos:]
    return text


def _check_location(err: LesmcError, text: str) -> None:
    """The error points inside ``text`` (lines split at \\n) and quotes that very line."""
    loc = err.location
    assert loc is not None and loc.line is not None and loc.column is not None, err.render()
    lines = split_lines(text)
    assert 1 <= loc.line <= len(lines), (loc, len(lines))
    line = lines[loc.line - 1]
    assert 1 <= loc.column <= len(line) + 1, (loc, line)
    assert loc.source_line == line
    rendered = err.render()
    assert rendered.startswith(f"{loc.path}:{loc.line}:{loc.column}: ")
    assert escape_control(rendered) == rendered  # nothing left that drives a terminal
    assert rendered.splitlines()[-1].strip() == "^"


# --- fuzzing ------------------------------------------------------------------------------


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated(SPEC_TEXTS, SPEC_PIECES))
def test_fuzzed_specs_parse_or_raise_positioned_spec_errors(text: str) -> None:
    try:
        spec = parse_spec(text, "f.spec")
    except SpecError as err:
        _check_location(err, text.removeprefix(BOM))
        return
    for prop in spec.properties:
        lo, hi = prop.window
        assert 0 <= lo <= MAX_STEP and (hi is None or 0 <= hi <= MAX_STEP)
        assert prop.end is None or 0 <= prop.end <= MAX_STEP


@settings(max_examples=150, deadline=None)
@given(
    mutated(SPEC_TEXTS, SPEC_PIECES),
    st.lists(
        st.tuples(
            st.integers(0, 10**6), st.sampled_from([b"\xff", b"\xc3", b"\xe2\x82", b"\xed\xa0\x80"])
        ),
        max_size=2,
    ),
)
def test_fuzzed_spec_bytes_decode_with_positions(text: str, bad: list[tuple[int, bytes]]) -> None:
    data = text.encode("utf-8", "surrogatepass")
    for at, chunk in bad:
        at %= len(data) + 1
        data = data[:at] + chunk + data[at:]
    try:
        decoded = decode_text(data, "f.spec", SpecError)
    except SpecError as err:
        # positions count characters of the valid prefix; the line is shown with \xNN escapes
        shown = data.removeprefix(codecs.BOM_UTF8).decode("utf-8", "backslashreplace")
        _check_location(err, shown)
        assert "invalid UTF-8" in err.message
        return
    try:
        parse_spec(decoded, "f.spec")
    except SpecError as err:
        _check_location(err, decoded.removeprefix(BOM))


def _strict_reference(text: str) -> Any:
    """What plain json says, with duplicate keys and non-finite numbers refused."""

    def pairs(items: list[tuple[str, Any]]) -> dict[str, Any]:
        assert len({k for k, _ in items}) == len(items), "duplicate key accepted"
        return dict(items)

    def constant(name: str) -> Any:
        raise AssertionError(f"{name} accepted")

    return json.loads(text, object_pairs_hook=pairs, parse_constant=constant)


def _depth(value: Any) -> int:
    if isinstance(value, dict):
        return 1 + max((_depth(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return 1 + max((_depth(v) for v in value), default=0)
    return 0


def _numbers_in_range(value: Any) -> bool:
    if isinstance(value, dict):
        return all(_numbers_in_range(v) for v in value.values())
    if isinstance(value, list):
        return all(_numbers_in_range(v) for v in value)
    if isinstance(value, bool):
        return True
    if isinstance(value, int):
        return -(2**63) <= value < 2**63
    if isinstance(value, float):
        return value - value == 0.0
    return True


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated(JSON_TEXTS, JSON_PIECES))
def test_fuzzed_json_parses_strictly_or_raises_positioned_errors(text: str) -> None:
    try:
        value = parse_json(text, "f.json", ModelError)
    except ModelError as err:
        _check_location(err, text.removeprefix(BOM))
        return
    # accepted: it is what json itself reads, and it is within every limit
    assert value == _strict_reference(text.removeprefix(BOM))
    assert _depth(value) <= MAX_JSON_DEPTH
    assert _numbers_in_range(value)


@settings(max_examples=150, deadline=None)
@given(
    mutated(JSON_TEXTS, JSON_PIECES),
    st.integers(0, 10**6),
    st.sampled_from([b"\xff", b"\x80", b"\xc3(", b"\xf0\x9f", b"\xed\xa0\x80", b"\xc0\xaf"]),
)
def test_fuzzed_json_bytes_raise_only_lesmc_errors(text: str, at: int, chunk: bytes) -> None:
    data = text.encode("utf-8", "surrogatepass")
    at %= len(data) + 1
    data = data[:at] + chunk + data[at:]
    with pytest.raises(LesmcError) as exc:
        parse_json(data, "f.json")
    shown = data.removeprefix(codecs.BOM_UTF8).decode("utf-8", "backslashreplace")
    _check_location(exc.value, shown)


JSON_SCALARS = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(alphabet='[]{}"\\ab\n', max_size=6),
    st.booleans(),
    st.none(),
)
JSON_VALUES = st.recursive(
    JSON_SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3),
        st.dictionaries(st.text(alphabet='[]{}"\\k', max_size=3), inner, max_size=3),
    ),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(JSON_VALUES, st.integers(0, 8), st.booleans())
def test_the_byte_level_depth_check_matches_the_real_depth(
    value: Any, limit: int, indent: bool
) -> None:
    raw = json.dumps(value, indent=1 if indent else None, ensure_ascii=False).encode("utf-8")
    assert _deeper_than(raw, limit) == (_depth(value) > limit)


@settings(max_examples=100, deadline=None)
@given(JSON_VALUES)
def test_valid_json_within_limits_round_trips(value: Any) -> None:
    if _depth(value) > MAX_JSON_DEPTH:
        with pytest.raises(InputError, match="nesting deeper"):
            parse_json(json.dumps(value), "f.json")
    else:
        assert parse_json(json.dumps(value), "f.json") == value


# --- 1. numbers in specs are bounded --------------------------------------------------------

GOOD = (
    "property p {\n    attack window 6..8\n    minimize payoff\n"
    "    subject to dist.sum(0..end) > 120\n    holds if optimum > 3.0\n}\n"
)


def _spec_error(text: str) -> SpecError:
    with pytest.raises(SpecError) as exc:
        parse_spec(text, "f.spec")
    _check_location(exc.value, text.removeprefix(BOM))
    return exc.value


@pytest.mark.parametrize(
    ("old", "new", "where", "message"),
    [
        ("6..8", "6.." + "9" * 5000, "2:22", "is too large (steps are at most 1000000)"),
        ("6..8", "6..1000001", "2:22", "step 1000001 is too large"),
        ("6..8", "99999999999999999999..8", "2:19", "is too large"),
        ("0..end", "0.." + "7" * 4400, "4:28", "is too large"),
        ("    holds", "    end " + "1" * 30 + "\n    holds", "5:9", "is too large"),
        ("> 120", "> " + "9" * 5000, "4:35", "must be finite"),
        ("> 3.0", "> -1e400", "5:24", "must be finite, got -1e400"),
    ],
)
def test_spec_numbers_are_bounded(old: str, new: str, where: str, message: str) -> None:
    err = _spec_error(GOOD.replace(old, new))
    rendered = err.render()
    assert rendered.startswith(f"f.spec:{where}: "), rendered
    assert message in rendered
    assert len(rendered) < 600  # a 5000-digit number is clipped, in the message and the quote


def test_largest_step_and_leading_zeros_are_accepted() -> None:
    (p,) = parse_spec(GOOD.replace("6..8", f"{'0' * 5000}6..{MAX_STEP}")).properties
    assert p.window == (6, MAX_STEP)


# --- 2. one line-splitting rule -----------------------------------------------------------


@pytest.mark.parametrize("sep", [*ODD_SEPARATORS, "\r"])
def test_odd_line_separators_before_an_error_keep_line_and_caret_right(sep: str) -> None:
    text = f"# a comment{sep}with{sep}separators\n" + GOOD.replace("minimize", "minimise")
    err = _spec_error(text)
    assert err.render().startswith("f.spec:4:5: unexpected 'minimise'")
    assert err.location is not None and err.location.source_line == "    minimise payoff"
    assert err.render().splitlines()[-2:] == ["        minimise payoff", "        ^"]


def test_crlf_files_give_the_same_positions_as_lf_files() -> None:
    bad = GOOD.replace("> 120", "> abc")
    lf, crlf = _spec_error(bad), _spec_error(bad.replace("\n", "\r\n"))
    assert lf.render() == crlf.render()


def test_source_line_counts_newlines_only() -> None:
    text = "a\u2028b\x0cc\r\nd\x85e\n\nlast"
    assert split_lines(text) == ["a\u2028b\x0cc", "d\x85e", "", "last"]
    assert [source_line(text, n) for n in range(0, 6)] == [
        None,
        "a\u2028b\x0cc",
        "d\x85e",
        "",
        "last",
        None,
    ]
    assert source_line("", 1) == ""
    loc = Location.at("f", text, text.index("e"))
    assert (loc.line, loc.column, loc.source_line) == (2, 3, "d\x85e")


def test_json_errors_after_odd_separators_quote_the_right_line() -> None:
    text = '{"a": "x\u2028y\x85z",\n "b": nope}'
    with pytest.raises(InputError) as exc:
        parse_json(text, "f.json")
    assert exc.value.render().startswith("f.json:2:7: invalid JSON")
    assert exc.value.location is not None and exc.value.location.source_line == ' "b": nope}'


# --- 3. and 9. bad UTF-8 gives the line and column of the first bad byte -----------------


def test_non_utf8_spec_reports_line_and_column(tmp_path: Path) -> None:
    p = tmp_path / "bad.spec"
    p.write_bytes(GOOD.replace("minimize payoff", "minimize payoff # café").encode() + b"")
    p.write_bytes(p.read_bytes().replace("café".encode(), "café".encode() + b"\xff"))
    with pytest.raises(SpecError) as exc:
        load_spec(p)
    rendered = exc.value.render()
    assert rendered.startswith(f"{p}:3:27: invalid UTF-8 (byte 0xff)"), rendered
    assert rendered.splitlines()[-2:] == ["        minimize payoff # café\\xff", " " * 30 + "^"]


def test_non_utf8_json_reports_line_and_column(tmp_path: Path) -> None:
    p = tmp_path / "bad.json"
    p.write_bytes(b'{\n  "id": "\xe2\x82",\n  "x": 1}')
    with pytest.raises(InputError) as exc:
        read_json(p)
    assert exc.value.render().startswith(f"{p}:2:10: invalid UTF-8 (byte 0xe2)")


def test_unreadable_files_are_reported(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="cannot read file"):
        load_spec(tmp_path / "missing.spec")
    with pytest.raises(InputError, match="cannot read file"):
        read_json(tmp_path)  # a directory


# --- 4. ASCII digits only ---------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "where"),
    [
        ("6..8", "٦..٨", "2:19"),
        ("6..8", "6..８", "2:22"),
        ("> 120", "> ١٢٠", "4:35"),
        ("> 3.0", "> 3.٠", "5:26"),
        ("0..end", "۰..end", "4:25"),
    ],
)
def test_digits_of_other_scripts_are_rejected(old: str, new: str, where: str) -> None:
    err = _spec_error(GOOD.replace(old, new))
    assert err.render().startswith(f"f.spec:{where}: unexpected"), err.render()


# --- 5. byte-order mark ------------------------------------------------------------------


def test_a_leading_bom_is_skipped(tmp_path: Path) -> None:
    p = tmp_path / "bom.spec"
    p.write_bytes(codecs.BOM_UTF8 + GOOD.encode())
    assert load_spec(p).properties[0].window == (6, 8)
    p.write_bytes(codecs.BOM_UTF8 + GOOD.replace("minimize", "minimise").encode())
    with pytest.raises(SpecError) as exc:
        load_spec(p)
    assert exc.value.render().startswith(f"{p}:3:5: ")
    j = tmp_path / "bom.json"
    j.write_bytes(codecs.BOM_UTF8 + b'{"a": [1]}')
    assert read_json(j) == {"a": [1]}
    assert parse_json(BOM + "[2]") == [2]


def test_a_bom_elsewhere_is_an_error() -> None:
    assert _spec_error(
        GOOD.replace("    minimize", "    " + BOM + "minimize")
    ).location == Location("f.spec", 3, 5, "    " + BOM + "minimize payoff")


# --- 6.-8. strict JSON with positions -----------------------------------------------------


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        ('{"a": 1,\n "b": {"c": 2, "c": 3}}', "2:16", 'duplicate key "c"'),
        ('{"a": 1, "a": 1}', "1:10", 'duplicate key "a"'),
        ('[{"x": {}}, {"k": 1, "k": {"k": 2}}]', "1:22", 'duplicate key "k"'),
        ('{"a": NaN}', "1:7", "NaN is not allowed"),
        ("[1,\n Infinity]", "2:2", "Infinity is not allowed"),
        ("[-Infinity]", "1:2", "-Infinity is not allowed"),
        ('{"n": 12345678901234567890}', "1:7", "integer 12345678901234567890 is out of range"),
        ("[9223372036854775808]", "1:2", "out of range"),
        ("[-9223372036854775809]", "1:2", "out of range"),
        ("[0, " + "1" * 5000 + "]", "1:5", "(5000 characters) is out of range"),
        ('{"p": 1e400}', "1:7", "number 1e400 is out of range (it overflows to infinity)"),
        ("[-1.5E+999]", "1:2", "overflows to infinity"),
        ("[" + "9" * 400 + ".0]", "1:2", "overflows to infinity"),
        ("[" * 100_000 + "]" * 100_000, "1:65", f"nesting deeper than {MAX_JSON_DEPTH}"),
        ("[" * 65 + "]" * 65, "1:65", "nesting deeper than 64"),
        ('{"a":' * 65 + "1" + "}" * 65, "1:321", "nesting deeper than 64"),
        ("[1,\n" * 70 + "1" + "]" * 70, "65:1", "nesting deeper than 64"),
        ('{"a": [1, 2}', "1:12", "invalid JSON: Expecting ',' delimiter"),
    ],
)
def test_strict_json_errors_have_positions(text: str, where: str, message: str) -> None:
    with pytest.raises(ModelError) as exc:
        parse_json(text, "m.lts", ModelError)
    rendered = exc.value.render()
    assert rendered.startswith(f"m.lts:{where}: "), rendered[:200]
    assert message in rendered, rendered[:200]
    _check_location(exc.value, text)
    assert len(rendered) < 800


@pytest.mark.parametrize(
    "text",
    [
        "[9223372036854775807, -9223372036854775808, 1e308, -1e-400, 0]",
        "[" * 64 + "]" * 64,
        '{"a": "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[\\"{{{{"}',
        '{"a": {"a": {"a": 1}}, "b": [{"a": 1}, {"a": 2}]}',
        '{"NaN": "Infinity", "k": "1e400"}',
    ],
)
def test_json_within_the_limits_is_accepted(text: str) -> None:
    assert parse_json(text) == json.loads(text)


def test_loaders_report_duplicate_keys_with_positions(tmp_path: Path) -> None:
    text = (TESTS / "golden" / "tiny" / "model.lts").read_text()
    p = tmp_path / "m.lts"
    p.write_text(text.replace('"step": 1, "s": [5]', '"step": 1, "step": 1, "s": [5]', 1))
    with pytest.raises(ModelError) as exc:
        load_lts(p)
    assert exc.value.render().startswith(f'{p}:10:26: duplicate key "step"')


def test_cli_reports_deep_json_without_a_traceback(tmp_path: Path) -> None:
    p = tmp_path / "deep.lts"
    p.write_text("[" * 100_000 + "]" * 100_000)
    r = subprocess.run(
        [sys.executable, "-m", "lesmc", "check", str(p), str(ROOT / "specs" / "robustness.spec")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"{p}:1:65: nesting deeper than 64"), r.stderr[:300]
    assert "Traceback" not in r.stderr


# --- 10. escaping text for the terminal ---------------------------------------------------


def test_escape_control_neutralises_terminal_controls() -> None:
    assert (
        escape_control("plain [text]\twith\ttabs\nand é 😀") == "plain [text]\twith\ttabs\nand é 😀"
    )
    assert escape_control("\x1b[31mred\x1b[0m") == "\\x1b[31mred\\x1b[0m"
    assert escape_control("a\rb\x00c\x7fd\x9be\x85f") == "a\\x0db\\x00c\\x7fd\\x9be\\x85f"
    assert escape_control("x\u2028y\u202ez\ud800") == "x\\u2028y\\u202ez\\ud800"


def test_escape_text_neutralises_rich_markup_too() -> None:
    from rich.console import Console
    from rich.text import Text

    raw = "[bold red]id[/] \x1b]0;title\x07 [link=http://x]y"
    safe = escape_text(raw)
    assert "\x1b" not in safe and "\x07" not in safe
    console = Console(width=200, color_system=None, force_terminal=False)
    with console.capture() as cap:
        console.print(safe, end="")
    assert cap.get() == escape_control(raw)  # rich prints it literally
    assert Text.from_markup(safe).plain == escape_control(raw)


def test_render_escapes_items_messages_and_quoted_lines() -> None:
    err = InputError("unknown state \x1b[2J", Location("s.json", item="state '\x1b[2J'"))
    assert err.render() == "s.json: state '\\x1b[2J': unknown state \\x1b[2J"
    text = "property p\x1b[2J {\n"
    spec_err = _spec_error(text)
    assert spec_err.render().splitlines()[1:] == ["    property p\\x1b[2J {", "              ^"]
    many = InputError.many("s.json", [("\x1b[1m", "bad \x07")])
    assert many.render() == "s.json: \\x1b[1m: bad \\x07"


def test_caret_follows_escapes_and_long_lines_are_clipped() -> None:
    err = SpecError("bad", Location("f", 1, 4, "\x1b\tab"))
    assert err.render().splitlines()[1:] == ["    \\x1b\tab", "        \t ^"]
    long = "x" * 1000 + "!" + "y" * 1000
    err = SpecError("bad", Location("f", 1, 1001, long))
    quoted, caret = err.render().splitlines()[1:]
    assert quoted == "    …" + "x" * 80 + "!" + "y" * 79 + "…"
    assert caret.index("^") == quoted.index("!")
